"""One frame of a track: the head pose and the 52 ARKit coefficients of a known identity from one frame's dense
landmarks, with a temporal prior on the frames before it.

With the identity fixed (joints, skinning weights), linear blend skinning is a fixed affine map per vertex,
``x = M_v [r_v; 1]``, of the expressive rest vertex ``r_v = t_v + e_v(c)``
(:class:`rig.expressions.ExpressionModel`): :class:`FrameModel` precomputes ``M_v`` for the few vertices the
landmarks lie on (the static points' triangles and the contour's candidates), so a frame's model is a
52-coefficient expression evaluation on ~1,500 vertices, a rigid motion and a pinhole projection.

The unknowns are ``x = [rotation vector (3, rad, an increment on the current rotation), translation (3, mm),
coefficients (52)]``; :func:`solve_frame` runs a few projected Gauss-Newton (Levenberg-Marquardt) steps on

    sum_i (w_i / sum_j w_j) huber(|proj_i(x) - obs_i|)              (reprojection, px: the photo fit's term)
    + lambda_expressions |c|^2 + lambda_sparse sum_i c_i            (coefficients towards rest; c >= 0)
    + lambda_velocity |c - c_1|^2 + lambda_acceleration |c - 2 c_1 + c_2|^2       (the last two frames)
    + the same two on the pose (rotation vector in degrees, translation in mm, own weights)

with the coefficients kept inside their limits. The temporal terms are light (a steady warm start); the
smoothing is :mod:`pipeline.track.smooth`'s, over the whole track.

Example::

    model = FrameModel(rig, theta, weights, layout, focal, (width, height))
    state = solve_frame(model, points, previous=(state1, state2), settings=TrackSettings())
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from landmarks.layout import LandmarkLayout
from pipeline.camera import RIG_TO_OPENCV
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES, JAW_ANGLE_DEG, JAW_INDEX, ExpressionModel, expression_limits
from rig.model import JointRig

NUM_EXPRESSIONS = len(EXPRESSION_NAMES)
JAW_RADIANS = math.radians(JAW_ANGLE_DEG)
OPENCV = np.asarray(RIG_TO_OPENCV, np.float64)
"""Rig axes to OpenCV's (:data:`pipeline.camera.RIG_TO_OPENCV`), float64."""
GAZE_MASK = np.array([n.startswith("eyeLook") for n in EXPRESSION_NAMES])
"""The eight gaze coefficients (eyeLook*)."""


@dataclass(frozen=True)
class TrackSettings:
    """The per-frame solve (``track.frame.*``; the landmark term and the coefficients' prior are the photo
    fit's, :mod:`pipeline.photo.landmark_fit`: each point's weight over the weights' sum, Huber, ``|c|^2``
    with the gaze's weaker weight; the temporal weights were chosen on synthetic validation clips,
    ``benchmarks/bench_track.py``).

    Attributes:
        huber_delta_px: the Huber threshold of a point's pixel error (iteratively reweighted).
        lambda_expressions: weight of ``|c|^2`` against the mean squared pixel error (the photo fit's 0.5 is 1 in
            this normalisation; a fixed identity leaves its errors to the expressions, a stronger prior keeps
            them out). With ``lambda_sparse``, chosen on the validation clip (clip 0 of
            ``benchmarks/bench_track.py``): 3 and 0.5 among (0.5, 1, 2, 3, 4) x (0, 0.25, 0.5, 1).
        lambda_gaze: the eight eyeLook* coefficients' instead (the irises show the gaze).
        lambda_sparse: weight of ``sum_i c_i`` (the coefficients are >= 0: an L1 prior, which keeps the unused
            ones at 0 without holding the used ones back as much as ``|c|^2``); not on the gaze.
        lambda_velocity, lambda_acceleration: the coefficients' temporal prior on the frames before (a light
            one: it keeps the warm start steady; :mod:`pipeline.track.smooth` does the smoothing).
        lambda_pose_velocity, lambda_pose_acceleration: the pose's (per degree, per mm).
        iterations: Gauss-Newton steps per frame (warm started from the last frame).
        damping: Levenberg-Marquardt's start damping (relative to the normal matrix's diagonal).
    """

    huber_delta_px: float = 5.0
    lambda_expressions: float = 3.0
    lambda_sparse: float = 0.5
    lambda_gaze: float = 0.04
    lambda_velocity: float = 0.02
    lambda_acceleration: float = 0.2
    lambda_pose_velocity: float = 0.0
    lambda_pose_acceleration: float = 0.02
    iterations: int = 4
    damping: float = 1e-3

    def __post_init__(self) -> None:
        for name in (
            "huber_delta_px",
            "lambda_expressions",
            "lambda_gaze",
            "lambda_sparse",
            "lambda_velocity",
            "lambda_acceleration",
            "lambda_pose_velocity",
            "lambda_pose_acceleration",
            "damping",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise InputError(f"track.frame.{name} must be a finite number >= 0, got {value!r}")
        if self.huber_delta_px <= 0:
            raise InputError("track.frame.huber_delta_px must be > 0")
        if not (isinstance(self.iterations, int) and 1 <= self.iterations <= 50):
            raise InputError(f"track.frame.iterations must be an integer within [1, 50], got {self.iterations!r}")

    def prior_scale(self) -> np.ndarray:
        """``(52,)`` the square roots of each coefficient's prior weight."""
        scale = np.full(NUM_EXPRESSIONS, math.sqrt(self.lambda_expressions))
        scale[[i for i, n in enumerate(EXPRESSION_NAMES) if n.startswith("eyeLook")]] = math.sqrt(self.lambda_gaze)
        return scale


@dataclass
class FrameState:
    """One frame's head: ``rotation (3, 3)`` rig -> head-pose rotation, ``translation (3,)`` mm (as
    :func:`pipeline.camera.camera_from_head_pose` takes them), ``coefficients (52,)``."""

    rotation: np.ndarray
    translation: np.ndarray
    coefficients: np.ndarray = field(default_factory=lambda: np.zeros(NUM_EXPRESSIONS))

    def copy(self) -> FrameState:
        return FrameState(self.rotation.copy(), self.translation.copy(), self.coefficients.copy())


def rotation_from_vector(v: np.ndarray) -> np.ndarray:
    """``(3,)`` rotation vector (rad) -> ``(3, 3)`` (Rodrigues)."""
    v = np.asarray(v, np.float64)
    angle = float(np.linalg.norm(v))
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    if angle < 1e-9:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + math.sin(angle) / angle * k + (1.0 - math.cos(angle)) / angle**2 * (k @ k)


def rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """``(3, 3)`` -> ``(3,)`` its rotation vector (rad)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(rotation).as_rotvec()


class FrameModel:
    """The landmarks of one identity as a function of ``(rotation, translation, coefficients)`` (module
    docstring), float64.

    Args:
        rig: the joint rig; theta: ``(P,)`` the identity's joint channels; weights: ``(V, K)`` its skinning
            weights (the neural skinning's for its latent Z), or None for the rig's own.
        layout: the landmarks' layout (e.g. :func:`landmarks.mediapipe.layout.mediapipe_layout`).
        focal: pixels; size: ``(width, height)``; principal point: the image centre.
        expression_model: the ARKit shapes (default: built from the rig's asset).
    """

    def __init__(
        self,
        rig: JointRig,
        theta: np.ndarray,
        weights: np.ndarray | None,
        layout: LandmarkLayout,
        focal: float,
        size: tuple[int, int],
        expression_model: ExpressionModel | None = None,
    ) -> None:
        asset = rig.asset
        self.layout = layout
        self.focal = float(focal)
        self.size = (int(size[0]), int(size[1]))
        self.principal = np.array([(size[0] - 1) / 2.0, (size[1] - 1) / 2.0])
        faces = np.asarray(asset.faces, np.int64)
        emb_faces = np.asarray(layout.embedding.faces, np.int64)
        corner_ids = faces[emb_faces]  # (N, 3)
        support = np.asarray(layout.support, np.int64)
        self.vertex_ids = np.unique(np.concatenate([corner_ids.ravel(), support]))
        lookup = np.full(len(asset.vertices), -1, np.int64)
        lookup[self.vertex_ids] = np.arange(len(self.vertex_ids))
        self._lookup = lookup
        corners = lookup[corner_ids]
        bary = np.asarray(layout.embedding.barycentric, np.float64)
        self._contour = np.asarray(layout.contour, np.int64)
        self._num_vertices = len(asset.vertices)
        with torch.no_grad():
            rig64 = rig if rig.template.dtype == torch.float64 else JointRig(asset, dtype=torch.float64)
            theta_t = torch.as_tensor(np.asarray(theta, np.float64))[None]
            _, skinning = rig64.joint_transforms(theta_t)  # (1, K, 4, 4)
            w = rig64.dense_weights() if weights is None else torch.as_tensor(np.asarray(weights, np.float64))
            w = w[torch.as_tensor(self.vertex_ids)]
            m = torch.einsum("vk,kij->vij", w, skinning[0])[:, :3, :].double().numpy()  # (U, 3, 4)
        model = expression_model or ExpressionModel(asset, dtype=torch.float64)
        ids = torch.as_tensor(self.vertex_ids)
        with torch.no_grad():
            basis = model.basis[:, ids].double().numpy()  # (E, U, 3)
            template = model.template[ids].double().numpy()
            jaw_weight = model.jaw_weight[ids].double().numpy()
            q = template - model.jaw_pivot.double().numpy()
        linear = m[:, :, :3]
        # per support vertex: x_v(c) = a_v + B_v c + Ycos_v (cos(a) - 1) + Ysin_v sin(a), a = c_jaw * angle
        self._a = np.einsum("vij,vj->vi", linear, template) + m[:, :, 3]
        self._b = np.einsum("vij,evj->vie", linear, basis)  # (U, 3, E)
        zeros = np.zeros(len(q))
        self._ycos = np.einsum("vij,vj->vi", linear, np.stack([zeros, q[:, 1], q[:, 2]], 1) * jaw_weight[:, None])
        self._ysin = np.einsum("vij,vj->vi", linear, np.stack([zeros, -q[:, 2], q[:, 1]], 1) * jaw_weight[:, None])

        def combine(per_vertex: np.ndarray) -> np.ndarray:
            return np.einsum("nk,nk...->n...", bary, per_vertex[corners])

        self._static = tuple(combine(x) for x in (self._a, self._b, self._ycos, self._ysin))
        self._point_arrays = self._static
        low, high = expression_limits(torch.float64)
        self.low, self.high = low.numpy(), high.numpy()

    # -- the model ---------------------------------------------------------------------------------------

    def support_vertices(self, coefficients: np.ndarray) -> np.ndarray:
        """``(U, 3)`` the support vertices (:attr:`vertex_ids`) with ``coefficients (52,)``, rig space, mm."""
        c = np.asarray(coefficients, np.float64)
        angle = c[JAW_INDEX] * JAW_RADIANS
        return self._a + self._b @ c + self._ycos * (math.cos(angle) - 1.0) + self._ysin * math.sin(angle)

    def pick_contour(self, state: FrameState) -> None:
        """Choose the contour points' vertices on the silhouette as seen in ``state`` (kept until the next
        call)."""
        full = np.zeros((self._num_vertices, 3))
        full[self.vertex_ids] = self.support_vertices(state.coefficients)
        picked = self.layout.pick(full, camera_centre(state))
        rows = self._lookup[np.asarray(picked, np.int64)]
        arrays = [x.copy() for x in self._static]
        if len(self._contour):
            for out, per_vertex in zip(arrays, (self._a, self._b, self._ycos, self._ysin), strict=True):
                out[self._contour] = per_vertex[rows]
        self._point_arrays = tuple(arrays)

    def points(self, coefficients: np.ndarray, jacobian: bool = False):
        """``(N, 3)`` the landmarks in rig space (static points on their triangles, contour points on the
        vertices :meth:`pick_contour` chose); with ``jacobian`` also ``(N, 3, 52)`` their derivative."""
        a, b, ycos, ysin = self._point_arrays
        c = np.asarray(coefficients, np.float64)
        angle = c[JAW_INDEX] * JAW_RADIANS
        cos, sin = math.cos(angle), math.sin(angle)
        points = a + b @ c + ycos * (cos - 1.0) + ysin * sin
        if not jacobian:
            return points
        d = b.copy()
        d[:, :, JAW_INDEX] += (-ycos * sin + ysin * cos) * JAW_RADIANS
        return points, d

    def camera_points(self, state: FrameState, points: np.ndarray) -> np.ndarray:
        """``(N, 3)`` rig-space ``points`` in the camera frame (OpenCV) under ``state``'s head pose."""
        return points @ (OPENCV @ state.rotation).T + state.translation

    def project(self, camera: np.ndarray) -> np.ndarray:
        """``(N, 2)`` pixels of camera-frame points ``(N, 3)``."""
        return camera[:, :2] / np.maximum(camera[:, 2:3], 1.0) * self.focal + self.principal

    def landmarks_px(self, state: FrameState) -> np.ndarray:
        """``(N, 2)`` the projected landmarks of ``state``."""
        return self.project(self.camera_points(state, self.points(state.coefficients)))


def camera_centre(state: FrameState) -> np.ndarray:
    """``(3,)`` the camera centre in rig space, mm, of a head pose."""
    return -state.rotation.T @ (np.asarray(RIG_TO_OPENCV, np.float64).T @ state.translation)


def solve_frame(
    model: FrameModel,
    observed: np.ndarray,
    weights: np.ndarray,
    start: FrameState,
    previous: tuple[FrameState | None, FrameState | None] = (None, None),
    settings: TrackSettings | None = None,
) -> tuple[FrameState, dict]:
    """Fit one frame (module docstring): Levenberg-Marquardt with the analytic Jacobian, the rotation
    re-linearised at every step (``R = exp(omega) R_k``), the coefficients clipped to their limits.

    Args:
        model: :class:`FrameModel` (its contour picked for this frame).
        observed: ``(N, 2)`` the frame's landmarks, pixels. weights: ``(N,)`` per point (0: unused).
        start: where the steps start (the last frame's result, or a first estimate).
        previous: the results of the frame before and the one before that (None at the clip's start or after
            a gap: the temporal terms they feed are left out).
        settings: :class:`TrackSettings`.

    Returns:
        ``(state, info)``: info has ``rms_px`` (weighted RMS reprojection error), ``cost``, ``steps`` and
        ``information`` ``(58, 58)``: the Gauss-Newton matrix ``J^T J`` of the reprojection and the
        coefficients' prior at the result (about ``x = [omega (rad), t (mm), c]``, omega a rotation on the left).
    """
    s = settings or TrackSettings()
    obs = np.asarray(observed, np.float64)
    w = np.asarray(weights, np.float64)
    base = w / max(w.sum(), 1e-12)  # each point's share, as the photo fit's landmark term
    prior = s.prior_scale()
    sparse = np.where(GAZE_MASK, 0.0, s.lambda_sparse) if s.lambda_sparse else None
    p1, p2 = previous
    deg = 180.0 / math.pi
    # the temporal terms' targets: rotation as rotation vectors relative to the last frame (degrees)
    step1 = None if (p1 is None or p2 is None) else rotation_vector(p1.rotation @ p2.rotation.T) * deg
    n_c = NUM_EXPRESSIONS

    def evaluate(state: FrameState, jacobian: bool, sw: np.ndarray):
        c = state.coefficients
        out = model.points(c, jacobian)
        points, dpoints = out if jacobian else (out, None)
        rotated = points @ state.rotation.T  # R p, rig space
        camera = rotated @ OPENCV.T + state.translation
        z = np.maximum(camera[:, 2], 1.0)
        uv = camera[:, :2] / z[:, None] * model.focal + model.principal
        res = [((uv - obs) * sw[:, None]).ravel(), prior * c]
        rows = []
        if jacobian:
            # d uv / d camera (N, 2, 3)
            duv = np.zeros((len(z), 2, 3))
            duv[:, 0, 0] = model.focal / z
            duv[:, 1, 1] = model.focal / z
            duv[:, 0, 2] = -model.focal * camera[:, 0] / z**2
            duv[:, 1, 2] = -model.focal * camera[:, 1] / z**2
            duv *= sw[:, None, None]
            d_cam_omega = np.einsum("ij,njk->nik", OPENCV, -_skew(rotated))  # (N, 3, 3)
            d_cam_c = np.einsum("ij,njk->nik", OPENCV @ state.rotation, dpoints)  # (N, 3, E)
            j = np.concatenate(
                [
                    np.einsum("nij,njk->nik", duv, d_cam_omega),
                    duv,  # d camera / d t = I
                    np.einsum("nij,njk->nik", duv, d_cam_c),
                ],
                axis=2,
            ).reshape(-1, 6 + n_c)
            rows = [j, np.c_[np.zeros((n_c, 6)), np.diag(prior)]]
        if p1 is not None and s.lambda_velocity > 0:
            res.append(math.sqrt(s.lambda_velocity) * (c - p1.coefficients))
            if jacobian:
                rows.append(np.c_[np.zeros((n_c, 6)), math.sqrt(s.lambda_velocity) * np.eye(n_c)])
        if p2 is not None and s.lambda_acceleration > 0:
            res.append(math.sqrt(s.lambda_acceleration) * (c - 2 * p1.coefficients + p2.coefficients))
            if jacobian:
                rows.append(np.c_[np.zeros((n_c, 6)), math.sqrt(s.lambda_acceleration) * np.eye(n_c)])
        if p1 is not None and (s.lambda_pose_velocity > 0 or (step1 is not None and s.lambda_pose_acceleration > 0)):
            turn = rotation_vector(state.rotation @ p1.rotation.T) * deg  # (3,) degrees since the last frame
            move = state.translation - p1.translation  # (3,) mm
            block = np.zeros((6, 6 + n_c))
            block[:3, :3] = np.eye(3) * deg  # d turn / d omega, small angles
            block[3:, 3:6] = np.eye(3)
            if s.lambda_pose_velocity > 0:
                res.append(math.sqrt(s.lambda_pose_velocity) * np.r_[turn, move])
                if jacobian:
                    rows.append(math.sqrt(s.lambda_pose_velocity) * block)
            if step1 is not None and s.lambda_pose_acceleration > 0:
                last_move = p1.translation - p2.translation
                res.append(math.sqrt(s.lambda_pose_acceleration) * np.r_[turn - step1, move - last_move])
                if jacobian:
                    rows.append(math.sqrt(s.lambda_pose_acceleration) * block)
        r = np.concatenate(res)
        return r, (np.concatenate(rows) if jacobian else None), uv

    def robust(uv: np.ndarray) -> np.ndarray:  # sqrt of each point's weight, Huber reweighted at uv
        error = np.linalg.norm(uv - obs, axis=1)
        return np.sqrt(base * np.minimum(1.0, s.huber_delta_px / np.maximum(error, 1e-12)))

    state = start.copy()
    state.coefficients = np.clip(state.coefficients, model.low, model.high)
    sw = np.sqrt(base)
    _, _, uv = evaluate(state, False, sw)
    sw = robust(uv)

    def total(r: np.ndarray, c: np.ndarray) -> float:  # the squares and the L1 prior's linear term
        return float(r @ r) + (0.0 if sparse is None else float(sparse @ c))

    r, jac, uv = evaluate(state, True, sw)
    cost = total(r, state.coefficients)
    damping = s.damping
    steps = 0
    for _ in range(s.iterations):
        jtj = jac.T @ jac
        g = jac.T @ r
        if sparse is not None:
            g = g.copy()
            g[6:] += 0.5 * sparse
        diag = np.maximum(np.diag(jtj), 1e-9)
        accepted = False
        for _attempt in range(8):
            try:
                step = np.linalg.solve(jtj + damping * np.diag(diag), -g)
            except np.linalg.LinAlgError:
                damping *= 10.0
                continue
            trial = FrameState(
                rotation_from_vector(step[:3]) @ state.rotation,
                state.translation + step[3:6],
                np.clip(state.coefficients + step[6:], model.low, model.high),
            )
            r_trial, _, _ = evaluate(trial, False, sw)
            trial_cost = total(r_trial, trial.coefficients)
            if trial_cost <= cost:
                state, accepted = trial, True
                damping = max(damping / 3.0, 1e-9)
                break
            damping *= 4.0
        if not accepted:
            break
        steps += 1
        _, _, uv = evaluate(state, False, sw)
        sw = robust(uv)
        r, jac, uv = evaluate(state, True, sw)
        cost = total(r, state.coefficients)
    err2 = ((uv - obs) ** 2).sum(1)
    rms = float(np.sqrt((err2 * w).sum() / max(w.sum(), 1e-12)))
    # the frame's own information about x (the reprojection and the coefficients' prior, not the temporal
    # terms): what :func:`pipeline.track.smooth.smooth_track` weighs this frame's result by
    data_rows = 2 * len(obs) + n_c
    information = jac[:data_rows].T @ jac[:data_rows]
    return state, {"rms_px": rms, "cost": cost, "steps": steps, "information": information}


def _skew(v: np.ndarray) -> np.ndarray:
    """``(N, 3)`` -> ``(N, 3, 3)`` cross-product matrices."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -v[:, 2], v[:, 1]
    out[:, 1, 0], out[:, 1, 2] = v[:, 2], -v[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -v[:, 1], v[:, 0]
    return out


__all__ = ["FrameModel", "FrameState", "TrackSettings", "camera_centre", "rotation_from_vector", "solve_frame"]
