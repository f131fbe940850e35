"""One frame of a track: the head pose and the 52 ARKit coefficients of a known identity from one frame's dense
landmarks, with a temporal prior on the frames before it.

With the identity fixed (joints, skinning weights), linear blend skinning is a fixed affine map per vertex,
``x = M_v [r_v; 1]``, of the expressive rest vertex ``r_v = t_v + e_v(c)``
(:class:`rig.expressions.ExpressionModel`): :class:`FrameModel` precomputes ``M_v`` for the few vertices the
landmarks lie on (the static points' triangles and the contour's candidates), so a frame's model is a
52-coefficient expression evaluation on ~1,500 vertices, a rigid motion and a pinhole projection.

The unknowns are ``x = [rotation vector (3, rad, an increment on the start's rotation), translation (3, mm),
coefficients (52)]``; :func:`solve_frame` minimises, with the fits' one Levenberg-Marquardt solver
(:func:`pipeline.fitting.least_squares.levenberg_marquardt`) and the fits' own term definitions
(:func:`frame_terms`: :mod:`pipeline.fitting.terms`, :mod:`pipeline.fitting.priors`),

    sum_i (w_i / sum_j w_j) 2 huber(|proj_i(x) - obs_i|)        (reprojection, px: the photo fit's term)
    + |s * c|^2 + lambda_sparse sum_i c_i                          (coefficients towards rest, the gaze's weaker;
                                                                    c >= 0)
    + lambda_velocity |c - c_1|^2 + lambda_acceleration |c - 2 c_1 + c_2|^2       (the last two frames)
    + the same two on the pose (rotation vector in degrees, translation in mm, own weights)

with the coefficients kept inside their limits. :class:`FrameModel` is the fast path of the fixed identity's
head (its landmarks as affine maps of the coefficients); the terms are the same objects every fit uses, so a
term or prior changed there changes the track too. The temporal terms are light (a steady warm start); the
smoothing is :mod:`pipeline.track.smooth`'s, over the whole track.

Example::

    model = FrameModel(rig, theta, weights, layout, focal, (width, height))
    state, info = solve_frame(model, points, weights, start, previous=(state1, state2), settings=TrackSettings())
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix

from landmarks.layout import LandmarkLayout
from pipeline.camera import camera_center_in_rig, head_points_to_pixels
from pipeline.fitting.landmark_term import landmark_pixel_term
from pipeline.fitting.least_squares import LMSettings, forward_difference_jacobian, levenberg_marquardt
from pipeline.fitting.priors import acceleration_term, expression_term, sparsity_term, velocity_term
from pipeline.fitting.terms import Inputs, LeastSquaresTerms, Term
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES, JAW_ANGLE_DEG, JAW_INDEX, ExpressionModel, expression_limits
from rig.model import JointRig

NUM_EXPRESSIONS = len(EXPRESSION_NAMES)
JAW_RADIANS = math.radians(JAW_ANGLE_DEG)
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
            ``benchmarks/bench_track.py``) for this solver: 4 and 4, the weakest pair at the lowest coefficient
            error of (2, 3, 4, 6, 8) x (0, 0.25, 0.5, 1, 2, 4) (docs/track.md).
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
    lambda_expressions: float = 4.0
    lambda_sparse: float = 4.0
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
        rest_offsets: ``(V, 3)`` mm added to the template's expressive shape (the jaw turns the template's points):
            the identity of a head model the joints do not pose (:class:`pipeline.track.tracker.TrackConfig`'s
            ``model``; ``theta`` zeros and ``weights`` None then); None: the joints' identity alone.
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
        *,
        rest_offsets: np.ndarray | None = None,
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
            rest = template.copy()
            if rest_offsets is not None:
                rest += np.asarray(rest_offsets, np.float64)[self.vertex_ids]
            jaw_weight = model.jaw_weight[ids].double().numpy()
            q = template - model.jaw_pivot.double().numpy()
        linear = m[:, :, :3]
        # per support vertex: x_v(c) = a_v + B_v c + Ycos_v (cos(a) - 1) + Ysin_v sin(a), a = c_jaw * angle
        self._a = np.einsum("vij,vj->vi", linear, rest) + m[:, :, 3]
        self._b = np.einsum("vij,evj->vie", linear, basis)  # (U, 3, E)
        zeros = np.zeros(len(q))
        self._ycos = np.einsum("vij,vj->vi", linear, np.stack([zeros, q[:, 1], q[:, 2]], 1) * jaw_weight[:, None])
        self._ysin = np.einsum("vij,vj->vi", linear, np.stack([zeros, -q[:, 2], q[:, 1]], 1) * jaw_weight[:, None])

        def combine(per_vertex: np.ndarray) -> np.ndarray:
            return np.einsum("nk,nk...->n...", bary, per_vertex[corners])

        self._static = tuple(combine(x) for x in (self._a, self._b, self._ycos, self._ysin))
        self._use(self._static)
        self.focal_t = torch.tensor(self.focal, dtype=torch.float64)
        self.principal_t = torch.as_tensor(self.principal)
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
        self._use(tuple(arrays))

    def _use(self, arrays: tuple[np.ndarray, ...]) -> None:
        """The landmarks' affine maps ``(a (N, 3), b (N, 3, E), ycos (N, 3), ysin (N, 3))``, also as tensors."""
        self._point_arrays = arrays
        self._point_tensors = tuple(torch.as_tensor(x) for x in arrays)

    def points(self, coefficients: np.ndarray) -> np.ndarray:
        """``(N, 3)`` the landmarks in rig space of ``coefficients (52,)`` (static points on their triangles,
        contour points on the vertices :meth:`pick_contour` chose)."""
        a, b, ycos, ysin = self._point_arrays
        c = np.asarray(coefficients, np.float64)
        angle = c[JAW_INDEX] * JAW_RADIANS
        return a + b @ c + ycos * (math.cos(angle) - 1.0) + ysin * math.sin(angle)

    def points_batch(self, coefficients: torch.Tensor) -> torch.Tensor:
        """``(B, N, 3)`` float64 the landmarks in rig space of ``coefficients (B, 52)`` (as :meth:`points`)."""
        a, b, ycos, ysin = self._point_tensors
        angle = (coefficients[:, JAW_INDEX] * JAW_RADIANS)[:, None, None]
        return (
            a + torch.einsum("nie,be->bni", b, coefficients) + ycos * (torch.cos(angle) - 1.0) + ysin * torch.sin(angle)
        )

    def landmarks_px(self, state: FrameState) -> np.ndarray:
        """``(N, 2)`` the projected landmarks of ``state`` (:func:`pipeline.camera.head_points_to_pixels`)."""
        with torch.no_grad():
            points = self.points_batch(torch.as_tensor(np.asarray(state.coefficients, np.float64))[None])
            rotation = torch.as_tensor(np.asarray(state.rotation, np.float64))[None]
            translation = torch.as_tensor(np.asarray(state.translation, np.float64))[None]
            return head_points_to_pixels(points, rotation, translation, self.focal_t, self.principal_t)[0].numpy()


def camera_centre(state: FrameState) -> np.ndarray:
    """``(3,)`` the camera centre in rig space, mm, of a head pose."""
    return camera_center_in_rig(state.rotation, state.translation)


def frame_terms(
    observed: np.ndarray,
    weights: np.ndarray,
    previous: tuple[FrameState | None, FrameState | None],
    settings: TrackSettings,
) -> tuple[Term, ...]:
    """The terms of one frame's fit (module docstring), the same definitions as the photo and views fits':
    the landmark reprojection (:func:`pipeline.fitting.landmark_term.landmark_pixel_term`, twice its weight so
    that the squared pixel errors weigh 1 as in :class:`TrackSettings`), the coefficients' prior
    (:func:`pipeline.fitting.priors.expression_term`) and sparsity, and the temporal priors on the frames before.

    The terms read the inputs ``landmarks_px (B, N, 2)``, ``c (B, 52)`` and ``pose_step (B, 6)`` (the turn since
    the frame before, degrees, as a rotation vector, and the move, mm) that :func:`solve_frame` makes.
    """
    s = settings
    target = torch.as_tensor(np.asarray(observed, np.float64))
    w = torch.as_tensor(np.asarray(weights, np.float64))
    terms = [
        landmark_pixel_term(target, w, s.huber_delta_px, weight=2.0),
        expression_term(1.0, scale=torch.as_tensor(s.prior_scale())),
    ]
    if s.lambda_sparse:
        terms.append(sparsity_term(s.lambda_sparse, torch.as_tensor(~GAZE_MASK, dtype=torch.float64)))
    p1, p2 = previous
    if p1 is not None and s.lambda_velocity > 0:
        terms.append(velocity_term(s.lambda_velocity, torch.as_tensor(p1.coefficients), "c", "expressions_velocity"))
    if p1 is not None and p2 is not None and s.lambda_acceleration > 0:
        c1, c2 = torch.as_tensor(p1.coefficients), torch.as_tensor(p2.coefficients)
        terms.append(acceleration_term(s.lambda_acceleration, c1, c2, "c", "expressions_acceleration"))
    if p1 is not None and s.lambda_pose_velocity > 0:
        terms.append(velocity_term(s.lambda_pose_velocity, torch.zeros(6), "pose_step", "pose_velocity"))
    if p1 is not None and p2 is not None and s.lambda_pose_acceleration > 0:
        last_step = torch.as_tensor(pose_step(p1, p2))
        terms.append(velocity_term(s.lambda_pose_acceleration, last_step, "pose_step", "pose_acceleration"))
    return tuple(terms)


def pose_step(state: FrameState, before: FrameState) -> np.ndarray:
    """``(6,)`` the head's turn from ``before`` to ``state`` (rotation vector of ``R R_1^T``, degrees) and its
    move (mm)."""
    turn = np.degrees(rotation_vector(state.rotation @ before.rotation.T))
    return np.r_[turn, state.translation - before.translation]


class FrameProblem:
    """One frame's unknowns ``x = [omega (3, rad: the rotation exp(omega) R_ref), t (3, mm), c (52)]`` and what
    the terms read at a batch of them (:class:`pipeline.fitting.least_squares.LeastSquaresProblem`). ``R_ref`` is
    the frame before's rotation where there is one (so the turn since that frame is ``omega`` itself, no
    logarithm in the loop), else the start's.

    Args:
        model: the frame's :class:`FrameModel` (its contour picked). start: the start.
        last: the frame before's result, or None (no ``pose_step`` input then).
    """

    def __init__(self, model: FrameModel, start: FrameState, last: FrameState | None) -> None:
        self.model = model
        reference = start.rotation if last is None else last.rotation
        self.rotation0 = torch.as_tensor(np.asarray(reference, np.float64))
        omega = np.zeros(3) if last is None else rotation_vector(start.rotation @ reference.T)
        self.start = torch.as_tensor(np.r_[omega, start.translation, start.coefficients])
        self.low = torch.as_tensor(np.r_[np.full(6, -np.inf), model.low])
        self.high = torch.as_tensor(np.r_[np.full(6, np.inf), model.high])
        self.last_translation = None if last is None else torch.as_tensor(last.translation)

    def rotation(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, 3, 3)`` the head rotations of ``x (B, 58)``."""
        return axis_angle_to_rotation_matrix(x[:, :3]) @ self.rotation0

    def inputs(self, x: torch.Tensor) -> Inputs:
        """The terms' inputs at ``x (B, 58)`` (computed when a term reads them)."""
        c = x[:, 6:]

        def pixels() -> torch.Tensor:
            return head_points_to_pixels(
                self.model.points_batch(c), self.rotation(x), x[:, 3:6], self.model.focal_t, self.model.principal_t
            )

        def step() -> torch.Tensor:
            return torch.cat([x[:, :3] * (180.0 / math.pi), x[:, 3:6] - self.last_translation], dim=1)

        return Inputs({"c": c}, landmarks_px=pixels, pose_step=step)

    def state(self, x: torch.Tensor) -> FrameState:
        """The :class:`FrameState` of ``x (58,)``."""
        x64 = x.double()
        rotation = self.rotation(x64[None])[0].numpy()
        return FrameState(rotation, x64[3:6].numpy().copy(), x64[6:].numpy().copy())


def solve_frame(
    model: FrameModel,
    observed: np.ndarray,
    weights: np.ndarray,
    start: FrameState,
    previous: tuple[FrameState | None, FrameState | None] = (None, None),
    settings: TrackSettings | None = None,
) -> tuple[FrameState, dict]:
    """Fit one frame (module docstring): the frame's terms (:func:`frame_terms`) minimised by the fits' one
    Levenberg-Marquardt solver (:func:`pipeline.fitting.least_squares.levenberg_marquardt`, the Huber weights
    re-taken before every Jacobian), the coefficients inside their limits.

    Args:
        model: :class:`FrameModel` (its contour picked for this frame).
        observed: ``(N, 2)`` the frame's landmarks, pixels. weights: ``(N,)`` per point (0: unused).
        start: where the steps start (the last frame's result, or a first estimate).
        previous: the results of the frame before and the one before that (None at the clip's start or after
            a gap: the temporal terms they feed are left out).
        settings: :class:`TrackSettings`.

    Returns:
        ``(state, info)``: info has ``rms_px`` (weighted RMS reprojection error), ``cost`` (the least-squares
        cost of the terms), ``steps`` (accepted steps) and ``information`` ``(58, 58)``: the Gauss-Newton matrix
        of the reprojection and the coefficients' prior at the result, in the units of :class:`TrackSettings`
        (``sum_i w_i e_i^2 / sum_i w_i`` px^2 + ``|prior c|^2``; about ``x = [omega (rad), t (mm), c]``, omega a
        rotation on the left).
    """
    s = settings or TrackSettings()
    obs = np.asarray(observed, np.float64)
    w = np.asarray(weights, np.float64)
    terms = frame_terms(obs, w, previous, s)
    rows = LeastSquaresTerms(terms)
    problem = FrameProblem(model, start, previous[0])
    lm = LMSettings(
        max_iterations=s.iterations, damping=s.damping, damping_up=4.0, damping_down=1.0 / 3.0, tolerance=0.0
    )
    result = levenberg_marquardt(
        lambda x: rows.rows(problem.inputs(x)),
        problem.start,
        lower=problem.low,
        upper=problem.high,
        settings=lm,
        prepare=lambda x: rows.reweight(problem.inputs(x[None])),
    )
    state = problem.state(result.x)
    # the frame's own information about x (the reprojection and the coefficients' prior, not the temporal terms)
    # at the result: what :func:`pipeline.track.smooth.smooth_track` weighs this frame's result by
    at = FrameProblem(model, state, None)
    data = rows.subset([t.name for t in terms[:2]])
    with torch.no_grad():
        jacobian, _ = forward_difference_jacobian(lambda x: data.rows(at.inputs(x)), at.start)
        uv = at.inputs(at.start[None])["landmarks_px"][0].numpy()
    information = 0.5 * (jacobian.T @ jacobian).numpy()  # the rows' 0.5 |r|^2 is TrackSettings' |r|^2 / 2
    err2 = ((uv - obs) ** 2).sum(1)
    rms = float(np.sqrt((err2 * w).sum() / max(w.sum(), 1e-12)))
    return state, {"rms_px": rms, "cost": result.cost, "steps": len(result.costs) - 1, "information": information}


__all__ = [
    "FrameModel",
    "FrameProblem",
    "FrameState",
    "TrackSettings",
    "camera_centre",
    "frame_terms",
    "pose_step",
    "solve_frame",
]
