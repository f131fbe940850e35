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

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera

from landmarks.ibug68 import contour_landmarks, ibug68_embedding, landmark_positions
from landmarks.loss import landmark_reprojection_loss, project_points
from pipeline.evaluation.metrics import landmark_errors
from pipeline.fitting.engine import LearningRates, Loss, Stage, StageLog, run_schedule
from pipeline.fitting.priors import PriorWeights, rig_prior_terms
from pipeline.fitting.state import PhotoState
from pipeline.photo.camera import default_focal, make_camera, solve_pose
from rig.expressions import ExpressionModel
from rig.lbs import ShapeError
from rig.model import JointRig
from rig.optim import Progress
from rig.parameters import NUM_PARAMETERS
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


@dataclass(frozen=True)
class LandmarkFitConfig:
    """Settings of :func:`fit_landmarks`."""

    stages: tuple[Stage, ...] = field(default_factory=landmark_schedule)
    """The schedule; ``free`` groups are ``pose``, ``joints``, ``latent``, ``expressions``."""
    lr: LearningRates = field(default_factory=LearningRates)
    """Adam steps per parameter group."""
    prior: PriorWeights = field(default_factory=PriorWeights)
    """Weights of the rig priors against the reprojection loss in px^2 (:mod:`pipeline.fitting.priors`)."""
    huber_delta_px: float = 5.0
    """Huber threshold of the reprojection loss, pixels."""
    use_neural: bool = True
    """Use the neural skinning (learned linear + decoded residual); else the rig's own weights."""


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

    def __init__(self, asset, landmarks2d: np.ndarray, camera: PinholeCamera, huber_delta_px: float) -> None:
        self.asset, self.camera, self.delta = asset, camera, float(huber_delta_px)
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
                                          delta_px=self.delta)[0]

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
    term = LandmarkTerm(asset, lm, intrinsic_camera, config.huber_delta_px)
    model_points = landmark_positions(start.double().numpy(), term.embedding, term.faces)[0]
    rotation0, translation0 = solve_pose(lm, model_points, width, height, focal)
    state = PhotoState(rig, neural, ExpressionModel(asset, dtype=dtype), rotation0, translation0)

    def objective(free: tuple[str, ...]) -> Loss:
        # forward -> loss (the engine then steps and projects into the limits)
        data = term(state, state.rig_vertices(free), free)
        return Loss({"landmarks_px2": data, **rig_prior_terms(state, config.prior)})

    stages = run_schedule(state, config.stages, objective, config.lr, label="fit_landmarks", progress=progress)
    return _landmark_result(state, term, lm, width, height, focal, stages, t_start)


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
