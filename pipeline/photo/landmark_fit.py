"""Fitting the rig to the 68 iBUG landmarks of one photo (JNR's single-image reconstruction, landmark term).

1. **Camera**: a pinhole with the given focal length (default :func:`pipeline.photo.camera.default_focal`),
   principal point at the image centre.
2. **Pose**: :func:`pipeline.photo.camera.solve_pose` on the template's landmark positions (jaw contour
   left out, since its 3D points slide with the view).
3. **Stages** (:class:`pipeline.scan.fit.Stage`, Adam): pose; pose + expressions (a coarse stage, so an
   open jaw is taken up by ``jawOpen`` rather than by joint motion, as in ``fit_scan``); pose + joints;
   Z; pose + expressions; pose + joints. Each step minimises

       landmark_reprojection_loss (px^2, Huber) + lambda_m L_m + lambda_x L_x + lambda_z |Z|^2
       + lambda_expressions |c|^2 (+ lambda_symmetry |theta - mirror(theta)|^2 / P)

   with the jaw contour (0-16) re-picked every step as the silhouette seen from the current camera
   centre (:func:`landmarks.ibug68.contour_landmarks`); expression coefficients are projected back into
   their limits after each step.

The head pose is the one of :mod:`pipeline.photo.camera`: ``x_cam = RIG_TO_OPENCV @ R @ x_rig + t``.
There is no global scale: from one photo it is interchangeable with the distance ``t_z``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera

from landmarks.ibug68 import contour_landmarks, ibug68_embedding, landmark_positions
from landmarks.loss import (
    CONTOUR_WEIGHT,
    WEIGHTINGS,
    landmark_reprojection_loss,
    landmark_weights,
    project_points,
)
from pipeline.evaluation.metrics import landmark_errors
from pipeline.fitting.engine import LearningRates, Loss, Stage, StageLog, run_schedule
from pipeline.fitting.least_squares import LMSettings, levenberg_marquardt
from pipeline.fitting.priors import PriorWeights, rig_prior_terms
from pipeline.fitting.state import PhotoState
from pipeline.photo.camera import default_focal, make_camera, solve_pose
from rig.expressions import ExpressionModel
from rig.lbs import ShapeError, skin_vertices_shared_weights
from rig.model import JointRig
from rig.optim import Progress
from rig.parameters import NUM_PARAMETERS, mirror_theta
from rig.skinning.neural import LATENT, NeuralSkinning, load_neural

NUM_LANDMARKS = 68


def landmark_schedule(pose_iterations: int = 20, coarse_iterations: int = 20, joint_iterations: int = 40,
                      latent_iterations: int = 15, expression_iterations: int = 30,
                      final_joint_iterations: int = 25) -> tuple[Stage, ...]:
    """The default schedule (150 Adam steps): pose, coarse pose + expressions, then JNR 4.3's alternation
    (pose + joints, Z, pose + expressions) and a last pose + joints stage. A count of 0 leaves a stage out."""
    stages = (Stage("pose", ("pose",), pose_iterations),
              Stage("coarse", ("pose", "expressions"), coarse_iterations),
              Stage("joints 1", ("pose", "joints"), joint_iterations),
              Stage("latent", ("latent",), latent_iterations),
              Stage("expressions", ("pose", "expressions"), expression_iterations),
              Stage("joints 2", ("pose", "joints"), final_joint_iterations))
    return tuple(s for s in stages if s.iterations > 0)


def lm_schedule(pose_iterations: int = 6, expression_iterations: int = 8, joint_iterations: int = 20
                ) -> tuple[Stage, ...]:
    """The default Levenberg-Marquardt schedule (at most 34 Jacobians): pose; pose + expressions (an open
    jaw is taken up by ``jawOpen`` before the joints move); then pose, joints and expressions together.
    Each stage's ``iterations`` is its largest number of LM iterations; a stage stops earlier when it has
    converged."""
    stages = (Stage("pose", ("pose",), pose_iterations),
              Stage("expressions", ("pose", "expressions"), expression_iterations),
              Stage("joints", ("pose", "joints", "expressions"), joint_iterations))
    return tuple(s for s in stages if s.iterations > 0)


SOLVERS = ("lm", "adam")

CONTOUR_UPDATES = 4
"""LM iterations per stage that re-pick the jaw contour's silhouette vertices; later ones keep the last
pick. A pick is discrete: re-picked every iteration, neighbouring vertices took turns near the minimum and
the cost cycled (seen on synthetic heads) instead of converging."""


@dataclass(frozen=True)
class LandmarkFitConfig:
    """Settings of :func:`fit_landmarks`."""

    solver: str = "lm"
    """``lm``: Levenberg-Marquardt on :attr:`lm_stages` (:mod:`pipeline.fitting.least_squares`), the
    default; ``adam``: first-order steps on :attr:`stages` (JNR's schedule)."""
    lm_stages: tuple[Stage, ...] = field(default_factory=lm_schedule)
    """The LM schedule; ``free`` groups are ``pose``, ``joints``, ``expressions`` (the latent Z is not
    fitted to landmarks: 136 coordinates do not determine a 50-d skinning code)."""
    lm: LMSettings = field(default_factory=LMSettings)
    """Damping and stopping of each LM stage (``max_iterations`` comes from the stage)."""
    stages: tuple[Stage, ...] = field(default_factory=landmark_schedule)
    """The Adam schedule; ``free`` groups are ``pose``, ``joints``, ``latent``, ``expressions``."""
    lr: LearningRates = field(default_factory=LearningRates)
    """Adam steps per parameter group."""
    prior: PriorWeights = field(default_factory=PriorWeights)
    """Weights of the rig priors against the reprojection loss in px^2 (:mod:`pipeline.fitting.priors`)."""
    huber_delta_px: float = 5.0
    """Huber threshold of the reprojection loss, pixels."""
    contour_weight: float = CONTOUR_WEIGHT
    """Weight of the 16 jaw-contour landmarks (0-16 but the chin) against 1 for the others: annotators and
    detectors put the face outline only approximately where the template's silhouette is."""
    landmark_weighting: str = "detector"
    """``detector`` (the default): each landmark by the inverse variance of dlib's error on it
    (:func:`landmarks.loss.detector_landmark_weights`: the nose and mouth 1, the eyes ~0.35, the brows
    ~0.18, the jaw contour 0.05-0.14; ``contour_weight`` scales the contour's on top, 0.5 = as measured);
    ``contour``: every landmark 1, the jaw contour ``contour_weight``. On the validation photos
    ``detector`` was better with the true landmarks + 1 px noise and with dlib's (docs/fit_photo.md)."""
    use_neural: bool = True
    """Use the neural skinning (learned linear + decoded residual); else the rig's own weights."""

    def __post_init__(self) -> None:
        if self.landmark_weighting not in WEIGHTINGS:
            raise ValueError(f"landmarks.landmark_weighting must be one of {list(WEIGHTINGS)}, "
                             f"got {self.landmark_weighting!r}")
        if self.solver not in SOLVERS:
            raise ValueError(f"landmarks.solver must be one of {list(SOLVERS)}, got {self.solver!r}")
        bad = [st.name for st in self.lm_stages if "latent" in st.free]
        if bad:
            raise ValueError(f"landmarks.lm_stages: the LM solver does not fit the latent (stages {bad}); "
                             "use solver: adam for a latent stage")


@dataclass(frozen=True)
class LandmarkFit:
    """Result of :func:`fit_landmarks`.

    Attributes:
        theta: ``(P,)`` joint channels (deg, mm, ``scale - 1``).
        z: ``(50,)`` neural-skinning latent (zeros without neural skinning).
        expressions: ``(E,)`` coefficients (:data:`rig.expressions.EXPRESSION_NAMES`).
        rotation, translation: head pose, ``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation`` (mm).
        camera: the fitted ``PinholeCamera`` (world = rig space; :func:`pipeline.photo.camera.make_camera`).
        landmarks_px: ``(68, 2)`` projection of the fitted landmarks (jaw contour dynamic), pixels.
        error_px: ``(68,)`` distance from each input landmark, pixels.
        nme: mean error / inter-ocular distance (outer eye corners 36, 45 of the input).
        landmarks3d: ``(68, 3)`` fitted landmarks in rig space (static embedding), mm.
        losses: per stage name, the total loss at its end; ``"data_px2"`` the final reprojection term.
        stages: one :class:`~pipeline.fitting.engine.StageLog` per stage (every loss term at its end).
        seconds: wall time of the whole fit.
    """

    theta: np.ndarray
    z: np.ndarray
    expressions: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    camera: PinholeCamera
    landmarks_px: np.ndarray
    error_px: np.ndarray
    nme: float
    landmarks3d: np.ndarray
    losses: dict
    stages: tuple[StageLog, ...]
    seconds: float


class LandmarkTerm:
    """The 68-landmark reprojection term of one photo, with the jaw contour re-picked as the silhouette
    seen from the current camera centre.

    Args:
        asset: the rig asset (faces, contour candidates).
        landmarks2d: ``(68, 2)`` target pixels (OpenCV, 0-based), iBUG-68 order.
        camera: ``PinholeCamera`` with identity extrinsics (the model moves points to camera space).
        huber_delta_px: Huber threshold, pixels.
    """

    def __init__(self, asset, landmarks2d: np.ndarray, camera: PinholeCamera, huber_delta_px: float,
                 contour_weight: float = CONTOUR_WEIGHT, weighting: str = "contour") -> None:
        self.asset, self.camera, self.delta = asset, camera, float(huber_delta_px)
        self.weights = landmark_weights(weighting, contour_weight, camera.intrinsics.dtype)
        self.faces = asset.faces
        self.embedding = ibug68_embedding(asset)
        self.target = torch.as_tensor(np.array(landmarks2d, np.float64), dtype=camera.intrinsics.dtype)[None]

    def points3d(self, model: PhotoState, v: torch.Tensor) -> torch.Tensor:
        """``(68, 3)`` rig space, mm: the static embedding, the jaw contour as seen from the camera."""
        static = landmark_positions(v, self.embedding, self.faces)[0]
        contour = contour_landmarks(v, self.faces, model.camera_center(), self.asset)
        return torch.cat([contour, static[17:]])

    def __call__(self, model: PhotoState, v: torch.Tensor, free: tuple[str, ...] = ()) -> torch.Tensor:
        """Scalar loss, px^2 (:func:`landmarks.loss.landmark_reprojection_loss`)."""
        points = model.to_camera(self.points3d(model, v), free)
        return landmark_reprojection_loss(points[None], self.target.to(points.dtype), self.camera,
                                          weights=self.weights.to(points.dtype), delta_px=self.delta)[0]

    def project(self, model: PhotoState, v: torch.Tensor) -> np.ndarray:
        """``(68, 2)`` float64 pixels of the model's landmarks."""
        with torch.no_grad():
            points = model.to_camera(self.points3d(model, v))
            return project_points(points[None], self.camera)[0].double().numpy()


def check_landmarks_2d_shape(landmarks2d, function: str = "fit_landmarks") -> np.ndarray:
    """``(68, 2)`` float64 copy of ``landmarks2d`` (array or tensor, pixels); raises ShapeError for another
    shape and ValueError for NaN or inf (naming ``function``)."""
    lm = np.asarray(landmarks2d.detach().cpu() if isinstance(landmarks2d, torch.Tensor) else landmarks2d,
                    dtype=np.float64)
    if lm.shape != (NUM_LANDMARKS, 2):
        raise ShapeError(f"{function}: landmarks2d must have shape ({NUM_LANDMARKS}, 2) (iBUG-68 order, "
                         f"pixels), got {lm.shape}")
    if not np.isfinite(lm).all():
        bad = np.flatnonzero(~np.isfinite(lm).all(1)).tolist()
        raise ValueError(f"{function}: landmarks2d must be finite; rows {bad} contain NaN or inf")
    return lm


def fit_landmarks(landmarks2d, width: int, height: int, *, focal: float | None = None,
                  config: LandmarkFitConfig | None = None, rig: JointRig | None = None,
                  neural: NeuralSkinning | None = None,
                  progress: Progress | None = None) -> LandmarkFit:
    """Fit pose, joints, Z and expressions of the rig to the 68 iBUG landmarks of one photo.

    Args:
        landmarks2d: ``(68, 2)`` pixels (OpenCV, 0-based; x right, y down), iBUG-68 order.
        width, height: image size, pixels.
        focal: focal length in pixels (default :func:`pipeline.photo.camera.default_focal`).
        config: settings and schedule (default :class:`LandmarkFitConfig`).
        rig, neural: the models (default: the committed rig, float32, and its learned skinning).
        progress: :data:`rig.optim.Progress`, called after every step.

    Returns:
        :class:`LandmarkFit`.

    Raises:
        ValueError: landmarks of the wrong shape or not finite, a bad image size or focal, or a
            landmark set PnP cannot place.
    """
    t_start = time.perf_counter()
    lm = check_landmarks_2d_shape(landmarks2d)
    if not (width > 0 and height > 0):
        raise ValueError(f"fit_landmarks: width and height must be > 0, got {width} x {height}")
    focal = default_focal(width, height) if focal is None else float(focal)
    config = config or LandmarkFitConfig()
    rig = rig or JointRig()
    if config.use_neural and neural is None:
        neural, _ = load_neural(rig)
    if not config.use_neural:
        neural = None
    dtype = rig.template.dtype
    asset = rig.asset
    # The pose is optimised outside the camera: points are moved to camera space by the state, and this
    # camera (identity extrinsics) only projects them.
    intrinsic_camera = make_camera(width, height, focal, dtype=dtype, pose=False)

    with torch.no_grad():
        weights0 = neural(torch.zeros(1, LATENT, dtype=dtype))[0] if neural is not None else None
        start = rig(torch.zeros(1, NUM_PARAMETERS, dtype=dtype), weights=weights0).vertices[0]
    term = LandmarkTerm(asset, lm, intrinsic_camera, config.huber_delta_px, config.contour_weight,
                        config.landmark_weighting)
    model_points = landmark_positions(start.double().numpy(), term.embedding, term.faces)[0]
    rotation0, translation0 = solve_pose(lm, model_points, width, height, focal)
    state = PhotoState(rig, neural, ExpressionModel(asset, dtype=dtype), rotation0, translation0)

    def objective(free: tuple[str, ...]) -> Loss:
        # forward -> loss (the engine then steps and projects into the limits)
        data = term(state, state.rig_vertices(free), free)
        return Loss({"landmarks_px2": data, **rig_prior_terms(state, config.prior)})


    if config.solver == "lm":
        stages = _run_lm(state, term, config, objective, progress, weights0)
    else:
        stages = run_schedule(state, config.stages, objective, config.lr, label="fit_landmarks", progress=progress)
    return _landmark_result(state, term, lm, width, height, focal, stages, t_start)


class _LandmarkLeastSquares:
    """The landmark fit as batched residuals of one float64 vector ``x`` = the free groups' parameters,
    packed ``rotvec (3), translation (3) | theta_n (P) | c (E)`` (only the groups of the stage).

    Residual rows: the 68 landmarks' pixel errors (x and y) weighted by ``sqrt(w_i / sum w)`` times the
    Huber reweighting ``min(1, sqrt(delta / r_i))`` (so ``0.5 |r|^2`` is the Adam objective's Huber mean at
    the fixed point), then the priors: ``sqrt(lambda_identity) M (theta_n - mu)``, ``sqrt(2
    lambda_expressions) c``, the L1 prior ``lambda_m L_m`` reweighted the same way, and the optional
    symmetry rows. Joint and expression limits are the solver's box. Only the ~200 vertices the landmarks
    sit on are skinned, with the weights of the state's latent (fixed here).
    """

    ORDER = ("pose", "joints", "expressions")

    def __init__(self, state: PhotoState, term: LandmarkTerm, config: LandmarkFitConfig, free: tuple[str, ...],
                 identity, weights: torch.Tensor, expressions64: ExpressionModel) -> None:
        from landmarks.ibug68 import CHIN

        f64 = torch.float64
        self.state, self.term, self.config, self.free = state, term, config, free
        self.chin = CHIN
        cam = term.camera.intrinsics[0].to(f64)
        self.focal = cam[[0, 1], [0, 1]]
        self.centre = cam[[0, 1], [2, 2]]
        self.target = term.target[0].to(f64)
        base = term.weights.to(f64)
        self.base_w = base / base.sum()
        self.robust = torch.ones(68, dtype=f64)
        self.l1 = torch.ones(NUM_PARAMETERS, dtype=f64)
        self.weights = weights
        self.expressions = expressions64
        self.flip = state.flip.to(f64)
        self.span = state.span.to(f64)
        emb = term.embedding
        self.static_ids = torch.as_tensor(np.asarray(term.faces)[emb.faces], dtype=torch.long)  # (68, 3)
        self.static_bary = torch.as_tensor(emb.barycentric, dtype=f64)  # (68, 3)
        if identity is not None:
            self.whiten = torch.as_tensor(identity.whitening_matrix, dtype=f64)
            self.mu = torch.as_tensor(identity.mean, dtype=f64)
        self.sizes = {"pose": 6, "joints": NUM_PARAMETERS, "expressions": state.c.numel()}
        self.prepared, self.contour = 0, None
        self._rest: torch.Tensor | None = None
        self._skinning: torch.Tensor | None = None
        self.support_ids = _support_ids(term.asset)
        with torch.no_grad():
            self.fixed = {"pose": torch.cat([state.rotvec, state.translation]).double(),
                          "joints": state.theta_n.double(), "expressions": state.c.double()}

    # -- packing ------------------------------------------------------------------------------------
    def pack(self) -> torch.Tensor:
        return torch.cat([self.fixed[g] for g in self.ORDER if g in self.free])

    def unpack(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        """``x (B, n)`` -> each group ``(B, size)``."""
        out, at = {}, 0
        for g in self.ORDER:
            if g in self.free:
                out[g] = x[:, at:at + self.sizes[g]]
                at += self.sizes[g]
            else:
                out[g] = self.fixed[g][None].expand(x.shape[0], -1)
        return out

    def write(self, x: torch.Tensor) -> None:
        p = self.unpack(x[None])
        s = self.state
        with torch.no_grad():
            s.rotvec.copy_(p["pose"][0, :3])
            s.translation.copy_(p["pose"][0, 3:])
            s.theta_n.copy_(p["joints"][0])
            s.c.copy_(p["expressions"][0])

    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        s = self.state
        inf = torch.full((6,), float("inf"), dtype=torch.float64)
        low = {"pose": -inf, "joints": (s.low / s.span).double(), "expressions": s.c_low.double()}
        high = {"pose": inf, "joints": (s.high / s.span).double(), "expressions": s.c_high.double()}
        order = [g for g in self.ORDER if g in self.free]
        return torch.cat([low[g] for g in order]), torch.cat([high[g] for g in order])

    # -- the residuals ------------------------------------------------------------------------------
    def prepare(self, x: torch.Tensor) -> None:
        """Re-pick the jaw contour from the current camera centre (the first :data:`CONTOUR_UPDATES` times
        in a stage), and the robust (IRLS) weights."""
        from landmarks.ibug68 import contour_vertex_ids

        self.write(x)
        s = self.state
        p = self.unpack(x[None])
        self.prepared += 1
        if self.prepared <= CONTOUR_UPDATES or self.contour is None:
            with torch.no_grad():  # only the vertices the contour's pick reads are skinned
                ids = self.support_ids
                rest = self.expressions.template[ids] + self.expressions(p["expressions"], ids)[0]
                _, skinning = s.rig.joint_transforms(p["joints"] * self.span)
                v = torch.zeros(len(self.expressions.template), 3, dtype=torch.float64)
                v[ids] = skin_vertices_shared_weights(rest, self.weights[ids], skinning)[0]
                self.contour = contour_vertex_ids(v, self.term.faces, s.camera_center(), self.term.asset)
        contour = self.contour
        ids = self.static_ids.clone()
        bary = self.static_bary.clone()
        for k in range(17):
            if k != self.chin:
                ids[k] = contour[k]
                bary[k] = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
        self.vertex_ids, inverse = torch.unique(ids.reshape(-1), return_inverse=True)
        self._rest = None
        self.local_ids = inverse.reshape(68, 3)
        self.bary = bary
        self.rest_weights = self.weights[self.vertex_ids]
        with torch.no_grad():
            err = (self._project(x[None])[0] - self.target).norm(dim=-1)
        delta = self.config.huber_delta_px
        self.robust = torch.where(err > delta, delta / err.clamp_min(1e-12), torch.ones_like(err))
        theta = (p["joints"][0] * self.span).abs()
        self.l1 = 1.0 / theta.clamp_min(1e-3)

    def _project(self, x: torch.Tensor) -> torch.Tensor:
        """``x (B, n)`` -> ``(B, 68, 2)`` pixels."""
        from kornia.geometry.conversions import axis_angle_to_rotation_matrix

        p = self.unpack(x)
        batch = x.shape[0]
        # groups the stage does not move are the same in every row: computed once per stage (the rest
        # shape once per contour pick, which changes the vertices)
        if "expressions" in self.free:
            rest = self.expressions.template[self.vertex_ids] + self.expressions(p["expressions"], self.vertex_ids)
        else:
            if self._rest is None:
                self._rest = (self.expressions.template[self.vertex_ids]
                              + self.expressions(p["expressions"][:1], self.vertex_ids))
            rest = self._rest  # (1, U, 3)
        if "joints" in self.free:
            _, skinning = self.state.rig.joint_transforms(p["joints"] * self.span)
        else:
            if self._skinning is None:
                self._skinning = self.state.rig.joint_transforms(p["joints"][:1] * self.span)[1]
            skinning = self._skinning
        if skinning.shape[0] != batch:
            skinning = skinning.expand(batch, -1, -1, -1)
        if rest.shape[0] != batch:
            rest = rest.expand(batch, -1, -1)
        posed = skin_vertices_shared_weights(rest, self.rest_weights, skinning)  # (B, U, 3)
        points = (posed[:, self.local_ids] * self.bary[..., None]).sum(2)  # (B, 68, 3)
        rotation = axis_angle_to_rotation_matrix(p["pose"][:, :3])  # (B, 3, 3)
        cam = points @ (self.flip @ rotation).transpose(1, 2) + p["pose"][:, None, 3:]
        return cam[..., :2] / cam[..., 2:] * self.focal + self.centre

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """``x (B, n)`` -> residuals ``(B, m)``."""
        w = self.config.prior
        p = self.unpack(x)
        error = (self._project(x) - self.target) * (self.base_w * self.robust).sqrt()[:, None]
        rows = [error.reshape(x.shape[0], -1)]
        if w.lambda_identity:
            rows.append(math.sqrt(w.lambda_identity) * (p["joints"] - self.mu) @ self.whiten.T)
        theta = p["joints"] * self.span
        if w.lambda_m:
            rows.append(theta * (w.lambda_m / 52.0 * self.l1).sqrt())
        if w.lambda_symmetry:
            rows.append(math.sqrt(w.lambda_symmetry / NUM_PARAMETERS) * (theta - mirror_theta(theta)))
        if w.lambda_expressions:
            rows.append(math.sqrt(2.0 * w.lambda_expressions) * p["expressions"])
        return torch.cat(rows, dim=1)


_PER_ASSET: dict[tuple[str, int], object] = {}


def _per_asset(kind: str, asset, make):
    """``make(asset)`` computed once per asset and kind (the landmark fit runs many times per process)."""
    key = (kind, id(asset))
    if key not in _PER_ASSET:
        for stale in [k for k in _PER_ASSET if k[0] == kind]:
            del _PER_ASSET[stale]
        _PER_ASSET[key] = make(asset)
    return _PER_ASSET[key]


def _support_ids(asset) -> torch.Tensor:
    from landmarks.ibug68 import contour_support_ids

    return _per_asset("support", asset, lambda a: torch.as_tensor(contour_support_ids(a), dtype=torch.long))


def _expressions64(asset) -> ExpressionModel:
    return _per_asset("expressions64", asset, lambda a: ExpressionModel(a, dtype=torch.float64))


def _run_lm(state: PhotoState, term: LandmarkTerm, config: LandmarkFitConfig, objective,
            progress: Progress | None, weights: torch.Tensor | None = None) -> tuple[StageLog, ...]:
    """Each stage of ``config.lm_stages`` by Levenberg-Marquardt; logs every term of ``objective`` (the
    Adam objective) at each stage's start and end, so both solvers report the same figures."""
    from pipeline.fitting.priors import cached_identity_prior

    identity = cached_identity_prior() if config.prior.lambda_identity else None
    with torch.no_grad():  # the skinning weights of the state's latent (given: those of Z = 0, already decoded)
        weights = (state.weights() if weights is None else weights).double()
    expressions64 = _expressions64(state.rig.asset)
    logs = []
    start = None
    for stage in config.lm_stages:
        t0 = time.perf_counter()
        if start is None:  # later stages start where the previous one ended
            with torch.no_grad():
                start = float(objective(stage.free).total)
        problem = _LandmarkLeastSquares(state, term, config, stage.free, identity, weights, expressions64)
        low, high = problem.bounds()
        settings = replace(config.lm, max_iterations=stage.iterations)
        result = levenberg_marquardt(problem, problem.pack(), lower=low, upper=high, settings=settings,
                                     prepare=problem.prepare)
        problem.write(result.x)
        state._basis = None  # the rest shape or weights may have changed
        with torch.no_grad():
            end = objective(stage.free)
        if progress is not None:
            progress(stage.name, stage.iterations, stage.iterations)
        logs.append(StageLog(name=stage.name, free=stage.free, iterations=result.iterations, loss_start=start,
                             loss_end=float(end.total), terms={k: float(v) for k, v in end.terms.items()},
                             metrics={"lm_cost": result.cost, "lm_converged": result.converged,
                                      "lm_costs": [round(c, 4) for c in result.costs]},
                             seconds=time.perf_counter() - t0))
        start = float(end.total)
    return tuple(logs)


def _landmark_result(state: PhotoState, term: LandmarkTerm, lm: np.ndarray, width: int, height: int,
                     focal: float, stages: tuple[StageLog, ...], t_start: float) -> LandmarkFit:
    with torch.no_grad():
        v = state.rig_vertices()
        projected = term.project(state, v)
        data = float(term(state, v))
        static3d = landmark_positions(v, term.embedding, term.faces)[0].double().numpy()
        translation = state.translation.double().numpy()
    values = state.arrays()
    losses = {s.name: s.loss_end for s in stages}
    losses["data_px2"] = data
    error, nme = landmark_errors(projected, lm)
    return LandmarkFit(theta=values["theta"], z=values["z"], expressions=values["expressions"],
                       rotation=values["rotation"], translation=translation,
                       camera=make_camera(width, height, focal, rotation=values["rotation"], translation=translation),
                       landmarks_px=projected, error_px=error, nme=nme, landmarks3d=static3d, losses=losses,
                       stages=stages, seconds=time.perf_counter() - t_start)
