"""Fitting the rig to the 2D landmarks of one photo (JNR's single-image reconstruction, landmark term).

The points follow a :class:`landmarks.layout.LandmarkLayout`: :func:`fit_landmarks` defaults to the 68 iBUG
points; ``jnr fit`` fits MediaPipe's 478 dense points by default (:mod:`landmarks.mediapipe.layout`), the 68
only with ``--detector dlib``, a 68-point landmarks file or ``landmarks.dense: false``.

1. **Camera**: a pinhole with the given focal length (default :func:`pipeline.camera.default_focal`),
   principal point at the image centre.
2. **Pose**: :func:`pipeline.camera.solve_pose` on the template's landmark positions (jaw contour
   left out, since its 3D points slide with the view).
3. **Stages**: one list of loss terms (:mod:`pipeline.fitting.terms`), minimised by either solver,

       landmarks (px^2, Huber, :class:`~pipeline.fitting.landmark_term.LandmarkTerm`) + the head model's priors
       (:meth:`~pipeline.fitting.state.FitState.prior_terms`: lambda_m L_m + lambda_x L_x + lambda_z |Z|^2
       + lambda_expressions |c|^2, + lambda_identity identity, + lambda_symmetry symmetry) + the caller's terms

   - ``solver: lm`` (the default): Levenberg-Marquardt stages (:func:`pipeline.fitting.least_squares.
     run_lm_stage`) on pose; pose + expressions; pose, joints and expressions, the terms stacked as residual
     rows (robust ones reweighted, the joint limits as the solver's box), the jaw contour re-picked at the first
     iterations of each stage;
   - ``solver: adam``: the engine's Adam stages (:func:`pipeline.fitting.engine.run_schedule`): pose; pose +
     expressions (a coarse stage, so an open jaw is taken up by ``jawOpen`` rather than by joint motion, as in
     ``fit_scan``); pose + joints; Z; pose + expressions; pose + joints, with the jaw contour (0-16) re-picked
     every step as the silhouette seen from the current camera centre
     (:func:`landmarks.ibug68.contour.contour_landmarks`); joints and expression coefficients are projected back into
     their limits after each step.

The head pose is the one of :mod:`pipeline.camera`: ``x_cam = RIG_TO_OPENCV @ R @ x_rig + t``.
There is no global scale: from one photo it is interchangeable with the distance ``t_z``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera

from landmarks.ibug68.positions import landmark_positions
from landmarks.layout import LandmarkLayout, ibug68_layout
from landmarks.loss import CONTOUR_WEIGHT, WEIGHTINGS
from pipeline.camera import default_focal, make_camera, solve_pose
from pipeline.fitting.engine import LearningRates, Loss, Objective, Stage, StageLog, run_schedule
from pipeline.fitting.identity import IdentityPrior
from pipeline.fitting.identity_regression import IdentityRegressionConfig, conditional_identity
from pipeline.fitting.landmark_term import NUM_LANDMARKS, BatchedLandmarks, LandmarkTerm, face_scale
from pipeline.fitting.least_squares import LMSettings, StateVector, run_lm_stage
from pipeline.fitting.model_state import ModelPhotoState
from pipeline.fitting.priors import PriorWeights
from pipeline.fitting.state import PhotoState
from pipeline.fitting.terms import Inputs, Term, check_unique, term_values
from pipeline.metrics import landmark_errors
from rig.errors import InputError
from rig.expressions import ExpressionModel
from rig.geometry import head_angles
from rig.head_model import HeadParams
from rig.lbs import ShapeError
from rig.model import JointRig
from rig.optim import Progress
from rig.parameters import NUM_PARAMETERS
from rig.skinning.neural import LATENT, NeuralSkinning, load_neural

__all__ = [
    "NUM_LANDMARKS",
    "IdentityRegressionConfig",
    "SOLVERS",
    "LandmarkFit",
    "LandmarkFitConfig",
    "LandmarkProblem",
    "LandmarkTerm",
    "check_landmarks_2d_shape",
    "fit_landmarks",
    "landmark_inputs",
    "landmark_result",
    "run_lm_stages",
    "landmark_schedule",
    "lm_schedule",
]


def landmark_schedule(
    pose_iterations: int = 20,
    coarse_iterations: int = 20,
    joint_iterations: int = 40,
    latent_iterations: int = 15,
    expression_iterations: int = 30,
    final_joint_iterations: int = 25,
) -> tuple[Stage, ...]:
    """The default schedule (150 Adam steps): pose, coarse pose + expressions, then JNR 4.3's alternation
    (pose + joints, Z, pose + expressions) and a last pose + joints stage. A count of 0 leaves a stage out."""
    stages = (
        Stage("pose", ("pose",), pose_iterations),
        Stage("coarse", ("pose", "expressions"), coarse_iterations),
        Stage("joints 1", ("pose", "joints"), joint_iterations),
        Stage("latent", ("latent",), latent_iterations),
        Stage("expressions", ("pose", "expressions"), expression_iterations),
        Stage("joints 2", ("pose", "joints"), final_joint_iterations),
    )
    return tuple(s for s in stages if s.iterations > 0)


def lm_schedule(
    pose_iterations: int = 6, expression_iterations: int = 8, joint_iterations: int = 20
) -> tuple[Stage, ...]:
    """The default Levenberg-Marquardt schedule (at most 34 Jacobians): pose; pose + expressions (an open
    jaw is taken up by ``jawOpen`` before the joints move); then pose, joints and expressions together.
    Each stage's ``iterations`` is its largest number of LM iterations; a stage stops earlier when it has
    converged."""
    stages = (
        Stage("pose", ("pose",), pose_iterations),
        Stage("expressions", ("pose", "expressions"), expression_iterations),
        Stage("joints", ("pose", "joints", "expressions"), joint_iterations),
    )
    return tuple(s for s in stages if s.iterations > 0)


SOLVERS = ("lm", "adam")


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
    regression: IdentityRegressionConfig = field(default_factory=IdentityRegressionConfig)
    """The identity prior read from the detector's 3D points (:class:`IdentityRegressionConfig`)."""
    huber_delta_px: float = 5.0
    """Huber threshold of the reprojection loss, pixels (of a face 100 px between the outer eye corners with
    ``face_scale``)."""
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
    noise_px: float = 1.0
    """The landmarks' error in pixels of a face 100 px between the outer eye corners, for the 68-point layout
    (dlib's points, a file's): the landmark term is divided by its square, so the priors weigh ``noise_px^2`` more
    against noisier points. The priors' weights were chosen with the true points + 1 px noise: 1."""
    dense_noise_px: float = 3.0
    """The same for MediaPipe's 478 points: about their error measured on renders of unseen heads
    (``docs/fit_photo.md``, "How it works", step 3), and the best of the values tried on validation photos
    (heads 0-9, issue 37; the figures: ``docs/fit_photo.md``, "Where the photo fit loses the shape")."""
    face_scale: bool = True
    """Measure the landmark errors in pixels of a face 100 px between the outer eye corners
    (:func:`pipeline.fitting.landmark_term.face_scale`, from the first pose), so the priors weigh the same against
    the landmarks for a small or a large photo of a face; ``false``: raw image pixels (before issue 37: a 4x
    larger photo gave its landmarks 16x the weight)."""
    dense: bool = True
    """``jnr fit``: fit MediaPipe's dense points (478, or 468 from a file) when the detector or the landmarks
    file gives them (:mod:`landmarks.mediapipe.layout`); ``false``: fit the 68 iBUG points mapped from them."""

    def noise_for(self, layout_name: str) -> float:
        """The points' error in pixels of a face 100 px between the eye corners for a layout: ``dense_noise_px``
        for MediaPipe's layouts (``mediapipe``, ``mediapipe_mesh``), else ``noise_px``."""
        return self.dense_noise_px if layout_name.startswith("mediapipe") else self.noise_px

    def __post_init__(self) -> None:
        if self.landmark_weighting not in WEIGHTINGS:
            raise InputError(
                f"landmarks.landmark_weighting must be one of {list(WEIGHTINGS)}, got {self.landmark_weighting!r}"
            )
        if self.solver not in SOLVERS:
            raise InputError(f"landmarks.solver must be one of {list(SOLVERS)}, got {self.solver!r}")
        for name in ("noise_px", "dense_noise_px"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0 < value < float("inf")):
                raise InputError(f"landmarks.{name} must be a finite number > 0 (pixels), got {value!r}")
        bad = [st.name for st in self.lm_stages if "latent" in st.free]
        if bad:
            raise InputError(
                f"landmarks.lm_stages: the LM solver does not fit the latent (stages {bad}); "
                "use solver: adam for a latent stage"
            )


@dataclass(frozen=True)
class LandmarkFit:
    """Result of :func:`fit_landmarks`.

    Attributes:
        theta: ``(P,)`` joint channels (deg, mm, ``scale - 1``).
        z: ``(50,)`` neural-skinning latent (zeros without neural skinning).
        expressions: ``(E,)`` coefficients (:data:`rig.expressions.EXPRESSION_NAMES`).
        rotation, translation: head pose, ``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation`` (mm).
        camera: the fitted ``PinholeCamera`` (world = rig space; :func:`pipeline.camera.make_camera`).
        landmarks_px: ``(N, 2)`` projection of the fitted landmarks (contour dynamic), pixels, in the layout's
            order (iBUG-68: ``N = 68``).
        error_px: ``(N,)`` distance from each input landmark, pixels.
        nme: mean error / inter-ocular distance (the layout's outer eye corners of the input; 36, 45 in iBUG-68).
        landmarks3d: ``(N, 3)`` fitted landmarks in rig space (static embedding), mm.
        layout: the layout's name (``"ibug68"``, ``"mediapipe"``).
        losses: per stage name, the total loss at its end; ``"data_px2"`` the final reprojection term (in the
            term's units: px^2 at a 100 px eye distance with ``face_scale``); ``"face_scale"`` image pixels per
            unit of the term.
        stages: one :class:`~pipeline.fitting.engine.StageLog` per stage (every loss term at its end).
        seconds: wall time of the whole fit.
        head: the fitted head as its model's parameters (:class:`rig.head_model.HeadParams`); for another model
            than JNR's (:func:`pipeline.photo.model_fit.fit_model_landmarks`) ``theta`` and ``z`` are zeros and
            ``expressions`` its own when it has them (None: a record made without a state).
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
    layout: str = "ibug68"
    head: HeadParams | None = None
    identity: IdentityPrior | None = None
    """The conditional identity prior the fit used (:attr:`LandmarkFitConfig.regression`), or None: the
    population's."""


def check_landmarks_2d_shape(landmarks2d, function: str = "fit_landmarks", count: int = NUM_LANDMARKS) -> np.ndarray:
    """``(count, 2)`` float64 copy of ``landmarks2d`` (array or tensor, pixels); raises ShapeError for another
    shape and ValueError for NaN or inf (naming ``function``)."""
    lm = np.asarray(
        landmarks2d.detach().cpu() if isinstance(landmarks2d, torch.Tensor) else landmarks2d, dtype=np.float64
    )
    if lm.shape != (count, 2):
        order = "iBUG-68 order" if count == NUM_LANDMARKS else "the layout's order"
        raise ShapeError(f"{function}: landmarks2d must have shape ({count}, 2) ({order}, pixels), got {lm.shape}")
    if not np.isfinite(lm).all():
        bad = np.flatnonzero(~np.isfinite(lm).all(1)).tolist()
        raise InputError(f"{function}: landmarks2d must be finite; rows {bad} contain NaN or inf")
    return lm


def fit_landmarks(
    landmarks2d,
    width: int,
    height: int,
    *,
    focal: float | None = None,
    config: LandmarkFitConfig | None = None,
    rig: JointRig | None = None,
    neural: NeuralSkinning | None = None,
    progress: Progress | None = None,
    terms: tuple[Term, ...] = (),
    layout: LandmarkLayout | None = None,
    pose: tuple[np.ndarray, np.ndarray] | None = None,
    points3d: np.ndarray | None = None,
) -> LandmarkFit:
    """Fit pose, joints, Z and expressions of the rig to the landmarks of one photo (the 68 iBUG points by
    default, or another ``layout``'s, e.g. MediaPipe's 478 as ``jnr fit`` passes them).

    Args:
        landmarks2d: ``(N, 2)`` pixels (OpenCV, 0-based; x right, y down), in the layout's order (iBUG-68:
            ``N = 68``).
        width, height: image size, pixels.
        focal: focal length in pixels (default :func:`pipeline.camera.default_focal`).
        config: settings and schedule (default :class:`LandmarkFitConfig`).
        rig, neural: the models (default: the committed rig, float32, and its learned skinning).
        progress: :data:`rig.optim.Progress`, called after every step.
        terms: more loss terms (:class:`~pipeline.fitting.terms.Term`, reading the inputs of
            :func:`landmark_inputs`: ``theta``, ``theta_n``, ``z``, ``c``, ``landmarks_px``), minimised with the
            landmark term and the priors by either solver.
        layout: the landmark scheme (:class:`landmarks.layout.LandmarkLayout`; default iBUG-68).
        pose: ``(rotation (3, 3), translation (3,) mm)``, the head pose to start from
            (``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation``) instead of solvePnP's; with stages that do
            not free ``pose`` it is held (the diagnostic benchmark's known pose).
        points3d: ``(478, 3)`` the detector's 3D points (MediaPipe's pixels and relative depth), read by the
            identity regressor when ``config.regression.enabled`` (:class:`IdentityRegressionConfig`).

    Returns:
        :class:`LandmarkFit`.

    Raises:
        ValueError: landmarks of the wrong shape or not finite, a bad image size or focal, a
            landmark set PnP cannot place, or (solver ``lm``) a term Levenberg-Marquardt cannot take.
    """
    t_start = time.perf_counter()
    rig = rig or JointRig()
    layout = ibug68_layout(rig.asset) if layout is None else layout
    lm = check_landmarks_2d_shape(landmarks2d, count=layout.count)
    if not (width > 0 and height > 0):
        raise InputError(f"fit_landmarks: width and height must be > 0, got {width} x {height}")
    focal = default_focal(width, height) if focal is None else float(focal)
    config = config or LandmarkFitConfig()
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
    term = LandmarkTerm(
        asset, lm, intrinsic_camera, config.huber_delta_px, config.contour_weight, config.landmark_weighting, layout
    )
    model_points = landmark_positions(start.double().numpy(), term.embedding, term.faces)[0]
    if pose is None:
        rotation0, translation0 = solve_pose(lm, model_points, width, height, focal, exclude=layout.pose_exclude)
    else:
        rotation0, translation0 = _check_pose(pose)
    if config.face_scale:
        term.scale = face_scale(focal, float(translation0[2]), asset)
    state = PhotoState(rig, neural, ExpressionModel(asset, dtype=dtype), rotation0, translation0)
    weights = config.prior
    identity = conditional_identity(config.regression, points3d, head_angles(rotation0)[0])
    if identity is not None:
        state.identity_prior = identity
        weights = replace(weights, lambda_identity=config.regression.lambda_identity)
        if config.regression.start:
            with torch.no_grad():
                start_theta = torch.as_tensor(identity.mean_theta, dtype=dtype).clamp(state.low, state.high)
                state.theta_n.copy_(start_theta / state.span)
    # the data term, the head model's priors and the caller's: one list, minimised by either solver
    noise = config.noise_for(layout.name)
    all_terms = (term.term(1.0 / noise**2), *state.prior_terms(weights, gaze=layout.sees_irises), *terms)
    check_unique(all_terms)

    def objective(free: tuple[str, ...]) -> Loss:
        # forward -> loss (the engine then steps and projects into the limits)
        return Loss(term_values(all_terms, landmark_inputs(state, term, free)))

    if config.solver == "lm":
        stages = _run_lm(state, term, all_terms, config, objective, progress, weights0)
    else:
        stages = run_schedule(state, config.stages, objective, config.lr, label="fit_landmarks", progress=progress)
    return replace(landmark_result(state, term, lm, width, height, focal, stages, t_start), identity=identity)


def _check_pose(pose) -> tuple[np.ndarray, np.ndarray]:
    try:
        rotation, translation = (np.asarray(x, dtype=np.float64) for x in pose)
    except (TypeError, ValueError):
        raise InputError("fit_landmarks: pose must be a (rotation (3, 3), translation (3,)) pair") from None
    if rotation.shape != (3, 3) or translation.shape != (3,):
        raise InputError(
            f"fit_landmarks: pose must be rotation (3, 3) and translation (3,), "
            f"got {rotation.shape}, {translation.shape}"
        )
    if not (np.isfinite(rotation).all() and np.isfinite(translation).all()):
        raise InputError("fit_landmarks: the pose must be finite")
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) <= 0:
        raise InputError("fit_landmarks: pose's rotation must be a rotation matrix")
    return rotation, translation


def landmark_inputs(state: PhotoState, term: LandmarkTerm, free: tuple[str, ...] = ()) -> Inputs:
    """The inputs of the landmark fit's terms for the Adam engine: the state's parameters
    (:meth:`~pipeline.fitting.state.FitState.term_inputs`) and ``landmarks_px (1, 68, 2)`` of its head, with
    gradients for the groups ``free``."""
    return state.term_inputs().add(landmarks_px=lambda: term.pixels(state, state.rig_vertices(free), free))


class LandmarkProblem:
    """One LM stage of the landmark fit (:class:`~pipeline.fitting.least_squares.LeastSquaresProblem`): ``x`` =
    the stage's free groups of ``state`` (:class:`~pipeline.fitting.least_squares.StateVector`: ``rotvec (3),
    translation (3) | theta_n (P) | c (E)``), the landmark pixels of a batch of ``x`` by
    :class:`~pipeline.fitting.landmark_term.BatchedLandmarks` with the skinning ``weights (V, K)`` fixed.
    """

    def __init__(self, state: PhotoState, term: LandmarkTerm, weights: torch.Tensor, free: tuple[str, ...]) -> None:
        self.state = state
        self.vector = StateVector(state, free)
        self.landmarks = BatchedLandmarks(term, state.rig, weights, free)
        self.span = state.span.double()

    def pack(self) -> torch.Tensor:
        return self.vector.pack()

    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self.vector.bounds()

    def inputs(self, x: torch.Tensor) -> Inputs:
        v = self.vector.unpack(x)
        p = Inputs(
            {name: v[name] for name in ("rotvec", "translation", "theta_n", "z", "c")},
            theta=lambda: v["theta_n"] * self.span,
            landmarks_px=lambda: self.landmarks.pixels(p),
        )
        return p

    def prepare(self, x: torch.Tensor) -> None:
        """Write ``x`` into the state and re-pick the jaw contour from its camera centre."""
        self.vector.write(x)
        self.landmarks.prepare(self.inputs(x[None]), self.state.camera_center())

    def write(self, x: torch.Tensor) -> None:
        self.vector.write(x)


def _run_lm(
    state: PhotoState,
    term: LandmarkTerm,
    terms: tuple[Term, ...],
    config: LandmarkFitConfig,
    objective: Objective,
    progress: Progress | None,
    weights: torch.Tensor | None = None,
) -> tuple[StageLog, ...]:
    """Each stage of ``config.lm_stages`` by Levenberg-Marquardt (:func:`pipeline.fitting.least_squares.
    run_lm_stage`) on ``terms``; logs every term of ``objective`` (the Adam objective) at each stage's start and
    end, so both solvers report the same figures."""
    with torch.no_grad():  # the skinning weights of the state's latent (given: those of Z = 0, already decoded)
        weights = (state.weights() if weights is None else weights).double()

    def problem(stage: Stage) -> LandmarkProblem:
        return LandmarkProblem(state, term, weights, stage.free)

    return run_lm_stages(config.lm_stages, problem, terms, config, objective, progress)


def run_lm_stages(
    stages, make_problem, terms: tuple[Term, ...], config: LandmarkFitConfig, objective: Objective, progress
) -> tuple[StageLog, ...]:
    """``stages`` one after another by :func:`pipeline.fitting.least_squares.run_lm_stage` (later stages start
    where the previous one ended), each on ``make_problem(stage)``'s problem and ``terms``, with
    ``config.lm``'s settings; every term of ``objective`` logged at each stage's start and end."""
    logs: list[StageLog] = []
    for stage in stages:
        log = run_lm_stage(
            make_problem(stage),
            terms,
            stage,
            config.lm,
            objective=objective,
            loss_start=logs[-1].loss_end if logs else None,
            progress=progress,
        )
        logs.append(log)
    return tuple(logs)


def landmark_result(
    state: PhotoState | ModelPhotoState,
    term: LandmarkTerm,
    lm: np.ndarray,
    width: int,
    height: int,
    focal: float,
    stages: tuple[StageLog, ...],
    t_start: float,
) -> LandmarkFit:
    """The :class:`LandmarkFit` of a fit's ``state`` (JNR's or any head model's) at its end."""
    with torch.no_grad():
        v = state.rig_vertices()
        projected = term.project(state, v)
        data = float(term(state, v))
        static3d = landmark_positions(v, term.embedding, term.faces)[0].double().numpy()
        translation = state.translation.double().numpy()
    values = state.arrays()
    losses = {s.name: s.loss_end for s in stages}
    losses["data_px2"] = data
    losses["face_scale"] = term.scale
    error, nme = landmark_errors(projected, lm, term.layout.eye_corners)
    return LandmarkFit(
        theta=values["theta"],
        z=values["z"],
        expressions=values["expressions"],
        rotation=values["rotation"],
        translation=translation,
        camera=make_camera(width, height, focal, rotation=values["rotation"], translation=translation),
        landmarks_px=projected,
        error_px=error,
        nme=nme,
        landmarks3d=static3d,
        losses=losses,
        stages=stages,
        seconds=time.perf_counter() - t_start,
        layout=term.layout.name,
        head=state.head_params(),
    )
