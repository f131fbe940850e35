"""Fitting the rig to the 68 iBUG landmarks of one photo (JNR's single-image reconstruction, landmark term).

1. **Camera**: a pinhole with the given focal length (default :func:`pipeline.photo.camera.default_focal`),
   principal point at the image centre.
2. **Pose**: :func:`pipeline.photo.camera.solve_pose` on the template's landmark positions (jaw contour
   left out, since its 3D points slide with the view).
3. **Stages** (:class:`pipeline.scan.fit.Stage`, Adam): pose; pose + expressions (a coarse stage, so an
   open jaw is taken up by ``jaw_open`` rather than by joint motion, as in ``fit_scan``); pose + joints;
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
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera

from landmarks.ibug68 import contour_landmarks, ibug68_embedding, landmark_positions
from landmarks.loss import landmark_reprojection_loss, project_points
from pipeline.fitting.state import RigState
from pipeline.photo.camera import (
    RIG_TO_OPENCV,
    camera_center_in_rig,
    default_focal,
    make_camera,
    solve_pose,
)
from pipeline.scan.fit import Stage
from rig.expressions import ExpressionModel
from rig.lbs import ShapeError
from rig.losses import limit_loss, regularizer
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS, mirror_theta
from rig.skinning.neural import LATENT, NeuralSkinning, load_neural

NUM_LANDMARKS = 68
EYE_OUTER = (36, 45)
"""Outer eye corners: their distance normalises the NME (the 300-W inter-ocular convention)."""


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
    lr_rotation: float = 0.01
    """Adam step of the head rotation vector, radians."""
    lr_translation: float = 2.0
    """Adam step of the head translation, mm."""
    lr_joints: float = 0.01
    """Adam step of the joint channels, as a fraction of each channel's range."""
    lr_latent: float = 0.05
    lr_expressions: float = 0.05
    lambda_m: float = 0.3
    """L_m (eq. 4, deg / mm / scale-1 per joint) against the reprojection loss in px^2."""
    lambda_x: float = 3.0
    """L_x (eq. 5), the joint-limit penalty."""
    lambda_z: float = 0.01
    """|Z|^2 keeps the latent where the decoder was trained."""
    lambda_expressions: float = 0.5
    """|c|^2 on the expression coefficients."""
    lambda_symmetry: float = 0.0
    """Optional symmetry prior ``|theta - mirror(theta)|^2 / P`` (0: off)."""
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
    seconds: float


class PosedRig(RigState):
    """(pose, joints, Z, expressions) -> rig-space vertices and OpenCV camera-space points (one photo)."""

    def __init__(self, rig: JointRig, neural: NeuralSkinning | None, expressions: ExpressionModel,
                 rotation: np.ndarray, translation: np.ndarray) -> None:
        super().__init__(rig, neural, expressions, rotation)
        dtype = rig.template.dtype
        self.flip = torch.tensor(RIG_TO_OPENCV, dtype=dtype)
        self.translation = torch.tensor(translation, dtype=dtype, requires_grad=True)

    def to_camera(self, points: torch.Tensor, free: tuple[str, ...] = ()) -> torch.Tensor:
        """``(N, 3)`` rig space -> OpenCV camera space, mm."""
        rot, t = (self.rotation(), self.translation) if "pose" in free else (
            self.rotation().detach(), self.translation.detach())
        return points @ (self.flip @ rot).T + t

    def camera_center(self) -> np.ndarray:
        return camera_center_in_rig(self.rotation().detach().double().numpy(),
                                    self.translation.detach().double().numpy())


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

    def points3d(self, model: PosedRig, v: torch.Tensor) -> torch.Tensor:
        """``(68, 3)`` rig space, mm: the static embedding, the jaw contour as seen from the camera."""
        static = landmark_positions(v, self.embedding, self.faces)[0]
        contour = contour_landmarks(v, self.faces, model.camera_center(), self.asset)
        return torch.cat([contour, static[17:]])

    def __call__(self, model: PosedRig, v: torch.Tensor, free: tuple[str, ...] = ()) -> torch.Tensor:
        """Scalar loss, px^2 (:func:`landmarks.loss.landmark_reprojection_loss`)."""
        points = model.to_camera(self.points3d(model, v), free)
        return landmark_reprojection_loss(points[None], self.target.to(points.dtype), self.camera,
                                          delta_px=self.delta)[0]

    def project(self, model: PosedRig, v: torch.Tensor) -> np.ndarray:
        """``(68, 2)`` float64 pixels of the model's landmarks."""
        with torch.no_grad():
            points = model.to_camera(self.points3d(model, v))
            return project_points(points[None], self.camera)[0].double().numpy()


def rig_prior(model: RigState, config) -> torch.Tensor:
    """``lambda_m L_m + lambda_x L_x + lambda_z |Z|^2 + lambda_expressions |c|^2`` (+ the optional symmetry
    prior) with the weights of ``config`` (:class:`LandmarkFitConfig` or a config with the same fields)."""
    theta = model.theta
    loss = config.lambda_m * regularizer(theta[None])[0] \
        + config.lambda_x * limit_loss(theta[None], model.low, model.high)[0] \
        + config.lambda_z * model.z.square().sum() + config.lambda_expressions * model.c.square().sum()
    if config.lambda_symmetry:
        loss = loss + config.lambda_symmetry * (theta - mirror_theta(theta)).square().mean()
    return loss


def landmark_errors(projected: np.ndarray, landmarks2d: np.ndarray) -> tuple[np.ndarray, float]:
    """Per-landmark pixel error ``(68,)`` and the NME (mean error / outer-eye-corner distance of the input)."""
    error = np.linalg.norm(np.asarray(projected) - np.asarray(landmarks2d), axis=1)
    inter_ocular = float(np.linalg.norm(landmarks2d[EYE_OUTER[0]] - landmarks2d[EYE_OUTER[1]]))
    return error, (float(error.mean() / inter_ocular) if inter_ocular > 0 else math.nan)


def _check_landmarks(landmarks2d) -> np.ndarray:
    lm = np.asarray(landmarks2d.detach().cpu() if isinstance(landmarks2d, torch.Tensor) else landmarks2d,
                    dtype=np.float64)
    if lm.shape != (NUM_LANDMARKS, 2):
        raise ShapeError(f"fit_landmarks: landmarks2d must have shape ({NUM_LANDMARKS}, 2) (iBUG-68 order, "
                         f"pixels), got {lm.shape}")
    if not np.isfinite(lm).all():
        bad = np.flatnonzero(~np.isfinite(lm).all(1)).tolist()
        raise ValueError(f"fit_landmarks: landmarks2d must be finite; rows {bad} contain NaN or inf")
    return lm


def fit_landmarks(landmarks2d, width: int, height: int, *, focal: float | None = None,
                  config: LandmarkFitConfig | None = None, rig: JointRig | None = None,
                  neural: NeuralSkinning | None = None,
                  progress: Callable[[str, int, int], None] | None = None) -> LandmarkFit:
    """Fit pose, joints, Z and expressions of the rig to the 68 iBUG landmarks of one photo.

    Args:
        landmarks2d: ``(68, 2)`` pixels (OpenCV, 0-based; x right, y down), iBUG-68 order.
        width, height: image size, pixels.
        focal: focal length in pixels (default :func:`pipeline.photo.camera.default_focal`).
        config: settings and schedule (default :class:`LandmarkFitConfig`).
        rig, neural: the models (default: the committed rig, float32, and its learned skinning).
        progress: called as ``progress(stage_name, iteration, iterations)``.

    Returns:
        :class:`LandmarkFit`.

    Raises:
        ValueError: landmarks of the wrong shape or not finite, a bad image size or focal, or a
            landmark set PnP cannot place.
    """
    t_start = time.perf_counter()
    lm = _check_landmarks(landmarks2d)
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
    faces = asset.faces
    embedding = ibug68_embedding(asset)
    expressions = ExpressionModel(asset, dtype=dtype)
    # The pose is optimised outside the camera: points are moved to camera space by the model, and this
    # camera (identity extrinsics) only projects them.
    photo_camera = make_camera(width, height, focal, dtype=dtype)
    intrinsic_camera = PinholeCamera(photo_camera.intrinsics, torch.eye(4, dtype=dtype)[None],
                                     photo_camera.height, photo_camera.width)

    with torch.no_grad():
        weights0 = neural(torch.zeros(1, LATENT, dtype=dtype))[0] if neural is not None else None
        start = rig(torch.zeros(1, NUM_PARAMETERS, dtype=dtype), weights=weights0).vertices[0]
    model_points = landmark_positions(start.double().numpy(), embedding, faces)[0]
    rotation0, translation0 = solve_pose(lm, model_points, width, height, focal)

    model = PosedRig(rig, neural, expressions, rotation0, translation0)
    lrs = {"joints": [(model.theta_n, config.lr_joints)], "latent": [(model.z, config.lr_latent)],
           "expressions": [(model.c, config.lr_expressions)],
           "pose": [(model.rotvec, config.lr_rotation), (model.translation, config.lr_translation)]}

    term = LandmarkTerm(asset, lm, intrinsic_camera, config.huber_delta_px)

    def objective(free: tuple[str, ...]) -> tuple[torch.Tensor, torch.Tensor]:
        v = model.rig_vertices(free)
        data = term(model, v, free)
        return data + rig_prior(model, config), data.detach()

    losses: dict[str, float] = {}
    if neural is not None:
        for p in neural.decoder.parameters():
            p.requires_grad_(False)
    try:
        for stage in config.stages:
            free = tuple(g for g in stage.free if not (g == "latent" and neural is None))
            if stage.iterations == 0 or not free:
                continue
            opt = torch.optim.Adam([{"params": [t], "lr": lr} for g in free for t, lr in lrs[g]])
            for it in range(stage.iterations):  # forward -> loss -> backward -> step -> project
                loss, _ = objective(free)
                if not torch.isfinite(loss):
                    raise FloatingPointError(f"fit_landmarks diverged in stage {stage.name!r} (non-finite loss)")
                opt.zero_grad()
                loss.backward()
                opt.step()
                if "expressions" in free:  # (only then: a write to c invalidates the cached skinning basis)
                    model.clamp_expressions()
                if "joints" in free:
                    model.clamp_joints()
                if progress is not None:
                    progress(stage.name, it + 1, stage.iterations)
            losses[stage.name] = float(loss.detach())
    finally:
        if neural is not None:
            for p in neural.decoder.parameters():
                p.requires_grad_(True)

    with torch.no_grad():
        v = model.rig_vertices()
        projected = term.project(model, v)
        data = float(term(model, v))
        static3d = landmark_positions(v, term.embedding, faces)[0].double().numpy()
        rotation = model.rotation().double().numpy()
        translation = model.translation.double().numpy()
    losses["data_px2"] = data
    error, nme = landmark_errors(projected, lm)
    return LandmarkFit(theta=model.theta.detach().double().numpy(), z=model.z.detach().double().numpy(),
                       expressions=model.c.detach().double().numpy(), rotation=rotation, translation=translation,
                       camera=make_camera(width, height, focal, rotation=rotation, translation=translation),
                       landmarks_px=projected, error_px=error, nme=nme, landmarks3d=static3d, losses=losses,
                       seconds=time.perf_counter() - t_start)
