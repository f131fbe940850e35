"""Single-photo reconstruction: the landmark fit, then a joint photometric + landmark fit (JNR 4.3 on a photo).

1. **Landmark fit** (:func:`pipeline.photo.landmark_fit.fit_landmarks`): camera, solvePnP pose, then pose,
   joints, Z and expressions against the landmarks: the ``dense`` points when given (``jnr fit``'s default,
   MediaPipe's 478, :mod:`landmarks.mediapipe.layout`), else the 68 iBUG points (``--detector dlib`` or a
   68-point landmarks file).
2. **Photometric fit**: the rig mesh is rendered by :class:`render.renderer.DifferentiableRenderer`
   (Mitsuba 3, CPU) into a square crop around the face, downsampled to ``render_size`` pixels, and
   compared with the photo. Stages (:class:`PhotoStage`) alternate as in JNR 4.3: albedo and light
   alone; pose + joints; Z; pose + expressions; pose + joints, always with albedo and light free.
   Each step minimises

       lambda_photo * photo + lambda_landmarks * landmarks (px^2, Huber)
       + rig prior (L_m, L_x, |Z|^2, |c|^2) + albedo priors (smoothness, symmetry, mean)

   * ``photo``: the Charbonnier distance ``sqrt(|r|^2 + eps^2) - eps`` of the linear-RGB residual,
     averaged over **face-region pixels** (forehead, brows, eyelids, nose, cheeks, lips, chin, as
     ray-cast each step) that are inside the photo and not rejected as outliers. Before each stage the
     outliers (hair, glasses, hands: pixels whose residual exceeds ``median + outlier_mads * 1.4826 MAD``)
     are re-selected. Background, scalp, ears and neck never enter the loss.
   * **Albedo**: one linear-RGB colour per vertex, started from the median colour of the face pixels;
     priors pull it towards its neighbours along mesh edges, its mirror vertex, and that start colour
     (which also keeps unseen vertices plausible).
   * **Light**: ambient + one directional light (:class:`render.lighting.Lighting`). Its direction is
     not differentiable in the renderer: before each stage it is re-picked from 64 directions on the
     camera-side hemisphere by linear least squares (ambient and irradiance per channel) on the
     ray-cast normals; ambient and irradiance are then optimised with the rest.

On synthetic photos (``benchmarks/bench_fit_photo.py``) the photometric stages leave the face geometry
about where the landmark fit put it and fit albedo and light; freer geometry in them made the geometry worse,
since a photo's light is never exactly this model (measured in ``docs/fit_photo.md``, "The photometric
stages" and "Settings: figures moved from the code").

The renderer's world is the OpenCV camera frame of the photo (the model moves rig-space vertices
there, as for the landmarks); the light is reported in rig space as well
(:func:`pipeline.camera.camera_direction_to_rig`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera

from landmarks.layout import LandmarkLayout
from pipeline.camera import (
    camera_direction_to_rig,
    check_focal,
    default_focal,
    make_camera,
)
from pipeline.colour import srgb_to_linear
from pipeline.fitting.engine import StageLog
from pipeline.fitting.model_state import ModelPhotoState, jnr_arrays
from pipeline.fitting.state import PhotoState
from pipeline.metrics import landmark_errors
from pipeline.photo.crop import Crop
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.landmark_fit import (
    LandmarkFit,
    LandmarkTerm,
    check_landmarks_2d_shape,
    fit_landmarks,
)
from pipeline.photo.model_fit import fit_model_landmarks
from pipeline.photo.photometric import fit_appearance
from rig.errors import InputError
from rig.expressions import ExpressionModel
from rig.head_model import HeadParams, create
from rig.model import JointRig
from rig.optim import Progress
from rig.skinning.neural import NeuralSkinning, load_neural


@dataclass(frozen=True)
class PhotoAppearance:
    """The appearance a photo fit gives the head (fitted by the photometric stages; without them, the default,
    shown values: grey albedo 0.5, ambient 0.35, irradiance 2 from the camera's upper left, for the pictures).

    Attributes:
        albedo: ``(V, 3)`` linear RGB per vertex (the start colour where never seen).
        ambient, irradiance: ``(3,)`` linear RGB of the light.
        light_camera, light_rig: ``(3,)`` the unit direction the light travels, in the camera frame (OpenCV) and
            in rig space.
    """

    albedo: np.ndarray
    ambient: np.ndarray
    irradiance: np.ndarray
    light_camera: np.ndarray
    light_rig: np.ndarray


@dataclass(frozen=True)
class PhotoLandmarks:
    """A photo fit's landmarks: the iBUG-68 points given and fitted, and the dense points it fitted, if any.

    Attributes:
        detected: ``(68, 2)`` the input landmarks; fitted: ``(68, 2)`` the fitted head's, pixels (OpenCV, 0-based).
        error_px: ``(68,)`` their distances; nme: mean error / outer-eye-corner distance of ``detected``.
        camera3d: ``(68, 3)`` the fitted landmarks in 3D, camera frame (OpenCV: x right, y down, z forward), mm:
            the static embedding and the jaw contour as this camera sees it (projected: ``fitted``).
        dense_camera3d: ``(N, 3)`` the points of the dense layout fitted (e.g. MediaPipe's 478) as ``camera3d``;
            None when the 68 were fitted. dense_layout: that layout's name.
    """

    detected: np.ndarray
    fitted: np.ndarray
    error_px: np.ndarray
    nme: float
    camera3d: np.ndarray | None = None
    dense_camera3d: np.ndarray | None = None
    dense_layout: str | None = None


@dataclass(frozen=True)
class PhotoFit:
    """Result of :func:`fit_photo`.

    Attributes:
        head: the fitted head as its head model's parameters (:class:`rig.head_model.HeadParams`; the outputs
            build the head from them).
        rotation, translation: head pose, ``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation`` (mm).
        focal, width, height: the pinhole (pixels; principal point at the image centre).
        camera: the fitted ``PinholeCamera`` (world = rig space; it carries the pose).
        rig_vertices: ``(V, 3)`` the fitted head in rig space, mm.
        appearance: :class:`PhotoAppearance`. landmarks: :class:`PhotoLandmarks`.
        landmark_fit: the landmark-only fit it started from.
        stages: one :class:`~pipeline.fitting.engine.StageLog` per photometric stage: every loss term,
            and the metrics ``photo`` (mean Charbonnier residual over the counted face pixels, linear RGB),
            ``landmarks_px2``, ``pixels`` (face pixels counted), ``outlier_fraction`` (of the face pixels,
            rejected at the stage's start), ``light_direction_camera``.
        crop: the photometric crop (None without photometric stages).
        timings: seconds per phase (``landmarks``, ``photometric``, ``total``).

    ``theta``, ``z`` and ``expressions`` read the head's parameters as JNR's arrays (:meth:`jnr_arrays`).
    """

    head: HeadParams
    rotation: np.ndarray
    translation: np.ndarray
    focal: float
    width: int
    height: int
    camera: PinholeCamera
    rig_vertices: np.ndarray
    appearance: PhotoAppearance
    landmarks: PhotoLandmarks
    landmark_fit: LandmarkFit
    stages: tuple[StageLog, ...]
    crop: Crop | None
    timings: dict

    def jnr_arrays(self) -> dict[str, np.ndarray]:
        """``theta``, ``z`` and ``expressions`` of the head (:func:`pipeline.fitting.model_state.jnr_arrays`)."""
        return jnr_arrays(self.head)

    @property
    def theta(self) -> np.ndarray:
        return self.jnr_arrays()["theta"]

    @property
    def z(self) -> np.ndarray:
        return self.jnr_arrays()["z"]

    @property
    def expressions(self) -> np.ndarray:
        return self.jnr_arrays()["expressions"]


def check_photo(image) -> np.ndarray:
    """``(H, W, 3)`` float32 linear RGB of a uint8 sRGB or float linear image; ValueError otherwise."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 16 or img.shape[1] < 16:
        raise InputError(f"fit_photo: image must be (H, W, 3) RGB with H, W >= 16, got {img.shape}")
    if img.dtype == np.uint8:
        return srgb_to_linear(img.astype(np.float32) / 255.0)
    img = img.astype(np.float32)
    if not np.isfinite(img).all() or img.min() < 0 or img.max() > 1:
        raise InputError("fit_photo: a float image must be linear RGB within [0, 1] without NaN")
    return img


def _jnr_landmark_fit(
    fitted, size, focal, config: FitPhotoConfig, rig: JointRig, neural, progress, layout, points3d=None
):
    """JNR's own landmark fit (its rig state, the landmark term's fast path, its priors) and the state the
    photometric stages go on with: ``(LandmarkFit, PhotoState)``."""
    if not config.landmarks.use_neural:
        neural = None
    elif neural is None:
        neural, _ = load_neural(rig)
    width, height = size
    lfit = fit_landmarks(
        fitted,
        width,
        height,
        focal=focal,
        config=config.landmarks,
        rig=rig,
        neural=neural,
        progress=progress,
        layout=layout,
        points3d=points3d,
    )
    dtype = rig.template.dtype
    state = PhotoState(rig, neural, ExpressionModel(rig.asset, dtype=dtype), lfit.rotation, lfit.translation)
    state.load(lfit.theta, lfit.z, lfit.expressions)
    state.identity_prior = lfit.identity
    return lfit, state


def _model_landmark_fit(
    fitted, size, focal, config: FitPhotoConfig, rig: JointRig, neural, progress, layout, points3d=None
):
    """Any registered head model's landmark fit (:mod:`pipeline.photo.model_fit`): ``(LandmarkFit,
    ModelPhotoState)``; ``points3d`` is not read (the identity regressor maps to JNR's joints)."""
    model = create(config.model, asset=rig.asset)
    lfit = fit_model_landmarks(
        fitted, *size, model, focal=focal, config=config.landmarks, progress=progress, layout=layout
    )
    return lfit, ModelPhotoState(model, lfit.rotation, lfit.translation, params=lfit.head)


PHOTO_FITS: dict[str, Callable] = {"jnr": _jnr_landmark_fit}
"""The head models with a photo fit of their own, by kind (JNR's: its rig state with the photometric stages'
appearance); every other registered model takes the generic one (:mod:`pipeline.photo.model_fit`), without
photometric stages."""


def _landmark_terms(
    asset,
    dtype: torch.dtype,
    lm: np.ndarray,
    dense: tuple[np.ndarray, LandmarkLayout] | None,
    lfit: LandmarkFit,
    size: tuple[int, int],
    focal: float,
    config: FitPhotoConfig,
) -> tuple[LandmarkTerm, LandmarkTerm]:
    """The term of the ``(68, 2)`` px iBUG landmarks (reported) and the one fitted: ``dense``'s layout, if given."""
    width, height = size
    landmark = config.landmarks
    camera = make_camera(width, height, focal, dtype=dtype, pose=False)
    scale = lfit.losses["face_scale"]  # the landmark fit's unit (pixels of a face 100 px between the eye corners)
    term = LandmarkTerm(
        asset,
        lm,
        camera,
        landmark.huber_delta_px,
        landmark.contour_weight,
        landmark.landmark_weighting,
        scale=scale,
    )
    fit_term = term
    if dense is not None:
        fitted, layout = dense
        fit_term = LandmarkTerm(
            asset,
            fitted,
            camera,
            landmark.huber_delta_px,
            landmark.contour_weight,
            landmark.landmark_weighting,
            layout,
            scale,
        )
    return term, fit_term


def _fitted_points(
    state: PhotoState, term: LandmarkTerm, fit_term: LandmarkTerm, dense: tuple[np.ndarray, LandmarkLayout] | None
) -> tuple:
    """Fitted ``(V, 3)`` rig head, ``(68, 2)`` px landmarks, their and the dense points' camera 3D, translation, mm."""
    with torch.no_grad():
        v = state.rig_vertices()
        projected = term.project(state, v)
        landmarks3d_camera = state.to_camera(term.points3d(state, v)).double().numpy()
        dense3d_camera = None if dense is None else state.to_camera(fit_term.points3d(state, v)).double().numpy()
        translation = state.translation.double().numpy()
    return v, projected, landmarks3d_camera, dense3d_camera, translation


def fit_photo(
    image,
    landmarks2d,
    *,
    focal: float | None = None,
    config: FitPhotoConfig | None = None,
    rig: JointRig | None = None,
    neural: NeuralSkinning | None = None,
    progress: Progress | None = None,
    dense: tuple[np.ndarray, LandmarkLayout] | None = None,
    points3d: np.ndarray | None = None,
) -> PhotoFit:
    """Reconstruct the head in one photo (module docstring).

    Args:
        image: ``(H, W, 3)`` uint8 sRGB (as :func:`landmarks.images.load_image` returns) or float32
            linear RGB in [0, 1].
        landmarks2d: ``(68, 2)`` pixels (OpenCV, 0-based), iBUG-68 order: the fit's landmarks, or with
            ``dense`` only those the outputs and the error report (e.g. a dense detector's 68 points).
        focal: focal length in pixels (default :func:`pipeline.camera.default_focal`).
        config: settings and schedules (default :class:`FitPhotoConfig`).
        rig, neural: the models (default: the committed rig, float32, and its learned skinning).
        progress: :data:`rig.optim.Progress`, called after every step of both fits.
        dense: ``(points (N, 2) pixels, layout)``: fit these landmarks of another layout instead
            (:class:`landmarks.layout.LandmarkLayout`, e.g. MediaPipe's 478 points); ``landmarks2d`` is then
            only reported.
        points3d: ``(478, 3)`` the detector's 3D points (MediaPipe's pixels and relative depth): the identity
            regressor reads them when ``config.landmarks.regression.enabled``
            (:class:`pipeline.photo.landmark_fit.IdentityRegressionConfig`).

    Returns:
        :class:`PhotoFit`.

    Raises:
        ValueError: bad image or landmarks, a bad focal, or a fit that diverges.
        render.backend.LLVMError: no usable libLLVM for the renderer (CPU).
    """
    t0 = time.perf_counter()
    config = config or FitPhotoConfig()
    photo = check_photo(image)
    lm = check_landmarks_2d_shape(landmarks2d)
    height, width = photo.shape[:2]
    focal = default_focal(width, height) if focal is None else check_focal(focal, width, height)
    rig = rig or JointRig()
    fitted, layout = (lm, None) if dense is None else dense
    if config.model not in PHOTO_FITS and config.photometric.enabled:
        own = ", ".join(PHOTO_FITS)
        raise InputError(
            f"the photometric stages fit a model with a photo fit of its own ({own}), not {config.model!r}"
        )
    fit = PHOTO_FITS.get(config.model, _model_landmark_fit)
    lfit, state = fit(fitted, (width, height), focal, config, rig, neural, progress, layout, points3d)
    t_landmarks = time.perf_counter() - t0

    term, fit_term = _landmark_terms(rig.asset, state.dtype, lm, dense, lfit, (width, height), focal, config)
    t1 = time.perf_counter()
    noise_px = config.landmarks.noise_for(fit_term.layout.name)
    appearance, stages, crop = fit_appearance(photo, lm, focal, state, fit_term, config.photometric, progress, noise_px)
    t_photo = time.perf_counter() - t1

    v, projected, landmarks3d_camera, dense3d_camera, translation = _fitted_points(state, term, fit_term, dense)
    rotation = state.arrays()["rotation"]
    error, nme = landmark_errors(projected, lm)
    light = appearance["light_camera"]
    return PhotoFit(
        head=state.head_params(),
        rotation=rotation,
        translation=translation,
        focal=focal,
        width=width,
        height=height,
        camera=make_camera(width, height, focal, rotation=rotation, translation=translation),
        rig_vertices=v.double().numpy(),
        appearance=PhotoAppearance(
            appearance["albedo"],
            appearance["ambient"],
            appearance["irradiance"],
            light,
            camera_direction_to_rig(light, rotation),
        ),
        landmarks=PhotoLandmarks(
            lm, projected, error, nme, landmarks3d_camera, dense3d_camera, None if layout is None else layout.name
        ),
        landmark_fit=lfit,
        stages=stages,
        crop=crop,
        timings={"landmarks": t_landmarks, "photometric": t_photo, "total": time.perf_counter() - t0},
    )
