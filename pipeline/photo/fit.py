"""Single-photo reconstruction: the landmark fit, then a joint photometric + landmark fit (JNR 4.3 on a photo).

1. **Landmark fit** (:func:`pipeline.photo.landmark_fit.fit_landmarks`): camera, solvePnP pose, then pose,
   joints, Z and expressions against the 68 iBUG landmarks.
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

Measured on synthetic photos (``benchmarks/bench_fit_photo.py``, README): the photometric stages
leave the face geometry where the landmark fit put it (within +-0.06 mm of its error) and fit albedo and
light; freer geometry in them made the geometry worse, since a photo's light is never exactly this model.

The renderer's world is the OpenCV camera frame of the photo (the model moves rig-space vertices
there, as for the landmarks); the light is reported in rig space as well
(:func:`pipeline.camera.camera_direction_to_rig`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import ClassVar

import cv2
import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera

from pipeline.camera import (
    camera_direction_to_rig,
    check_focal,
    default_focal,
    make_camera,
)
from pipeline.colour import srgb_to_linear
from pipeline.fitting.engine import LearningRates, Loss, Stage, StageLog, run_schedule
from pipeline.fitting.priors import PriorWeights
from pipeline.fitting.state import FREE_GROUPS, PhotoState
from pipeline.fitting.terms import L2, Charbonnier, Inputs, Term, term_values
from pipeline.metrics import landmark_errors
from pipeline.photo.landmark_fit import (
    LandmarkFit,
    LandmarkFitConfig,
    LandmarkTerm,
    check_landmarks_2d_shape,
    fit_landmarks,
)
from pipeline.photo.sh import fit_sh, sh_basis
from render.backend import reproducible
from render.lighting import Lighting
from render.renderer import DifferentiableRenderer
from rig.asset import REGION_NAMES
from rig.expressions import ExpressionModel
from rig.geometry import mesh_edges, vertex_normals
from rig.model import JointRig
from rig.optim import Progress
from rig.skinning.neural import NeuralSkinning, load_neural
from rig.template import FACE_REGIONS

PHOTO_GROUPS = FREE_GROUPS + ("albedo", "light")
LIGHT_MODELS = ("directional", "sh")


PHOTO_LAMBDA_IDENTITY = 0.03
"""Weight of the learned identity prior (:mod:`pipeline.fitting.identity`) in the photo fit, against the
landmark term (mean over the 68 landmarks of half the squared pixel error, Huber); L_m is off.

Chosen on synthetic validation photos (held-out heads 0-5, neutral and expressive, 1 px landmark noise,
true focal; ``benchmarks/bench_fit_photo.py`` scores heads 20 on): NoW-style scan-to-mesh median,
mean over the 12 photos, LM landmark fit: see ``docs/fit_photo.md`` for the table. The previous
prior, L_m = 100 towards the template, scored 0.83 mm (Adam: 0.84) against the template's 0.94 mm."""

PHOTO_PRIOR = PriorWeights(lambda_m=0.0, lambda_identity=PHOTO_LAMBDA_IDENTITY)
"""The rig priors of the photo fit: the identity prior instead of L_m, the other weights as
:class:`~pipeline.fitting.priors.PriorWeights`."""


@dataclass(frozen=True)
class PhotoStage(Stage):
    """One stage of the photometric schedule: ``free`` is a subset of ``pose``, ``joints``, ``latent``,
    ``expressions``, ``albedo``, ``light``."""

    groups: ClassVar[tuple[str, ...]] = PHOTO_GROUPS


def photo_schedule(
    appearance_iterations: int = 25,
    joint_iterations: int = 30,
    latent_iterations: int = 15,
    expression_iterations: int = 25,
    final_joint_iterations: int = 25,
) -> tuple[PhotoStage, ...]:
    """The default photometric schedule (120 steps): albedo + light; then JNR 4.3's alternation
    (pose + joints, Z, pose + expressions, pose + joints), each with albedo and light. 0 leaves a stage out."""
    look = ("albedo", "light")
    stages = (
        PhotoStage("appearance", look, appearance_iterations),
        PhotoStage("photo joints", ("pose", "joints") + look, joint_iterations),
        PhotoStage("photo latent", ("latent",) + look, latent_iterations),
        PhotoStage("photo expressions", ("pose", "expressions") + look, expression_iterations),
        PhotoStage("photo joints 2", ("pose", "joints") + look, final_joint_iterations),
    )
    return tuple(s for s in stages if s.iterations > 0)


@dataclass(frozen=True)
class PhotoLearningRates(LearningRates):
    """Adam steps of the photometric stages (``photometric.lr:`` in YAML): the geometry's groups
    (:class:`pipeline.fitting.engine.LearningRates`) and the appearance."""

    albedo: float = 0.02
    """Per-vertex albedo, linear RGB."""
    light: float = 0.05
    """Ambient and irradiance of the light, linear RGB."""


PHOTO_LEARNING_RATES = PhotoLearningRates(rotation=0.003, translation=0.5, joints=0.004, latent=0.02, expressions=0.02)
"""The photometric stages' steps: smaller than the landmark fit's, which they refine."""


@dataclass(frozen=True)
class AlbedoPrior:
    """Weights of the albedo priors (``photometric.albedo_prior:`` in YAML), each a mean squared difference."""

    smooth: float = 20.0
    """Along mesh edges."""
    symmetry: float = 5.0
    """To the mirror vertex's albedo."""
    mean: float = 0.5
    """To the start colour (the median face colour)."""


@dataclass(frozen=True)
class PhotometricConfig:
    """The photometric stages of :func:`fit_photo` (``photometric:`` in YAML)."""

    enabled: bool = False
    """Run them (``jnr fit --photometric``). Off by default: on synthetic photos rendered with another light
    model they did not improve the geometry over the landmark fit (``docs/fit_photo.md``) and cost ~20 s."""
    stages: tuple[PhotoStage, ...] = field(default_factory=photo_schedule)
    render_size: int = 128
    """Side of the square face crop the photometric loss is computed on, pixels."""
    crop_margin: float = 0.25
    """Margin around the landmarks' bounding box (fraction of its size; the top gets twice as much, for
    the forehead)."""
    spp: int = 2
    """Renderer samples per pixel (interior and silhouette)."""
    lambda_photo: float = 200.0
    """Weight of the photometric term (linear RGB, Charbonnier)."""
    lambda_landmarks: float = 1.0
    """Weight of the landmark term (px^2 of the photo) during the photometric stages."""
    charbonnier_eps: float = 0.01
    """``eps`` of the Charbonnier distance, linear RGB."""
    outlier_mads: float = 3.0
    """Residuals above ``median + outlier_mads * 1.4826 * MAD`` are outliers (re-selected every stage)."""
    face_regions: tuple[str, ...] = FACE_REGIONS
    """Rig regions whose pixels the photometric loss counts (default: no scalp/hair, ears, neck, eyes, mouth)."""
    albedo_prior: AlbedoPrior = field(default_factory=AlbedoPrior)
    lr: PhotoLearningRates = PHOTO_LEARNING_RATES
    prior: PriorWeights = PHOTO_PRIOR
    """The rig priors during the photometric stages (:data:`PHOTO_PRIOR`)."""
    light_model: str = "directional"
    """``directional``: ambient + one directional light (:mod:`render.lighting`), its direction re-picked
    before each stage; ``sh``: second-order spherical harmonics, 9 coefficients per channel on the
    vertex normals (:mod:`pipeline.photo.sh`), least squares before each stage, then optimised."""
    sh_ridge: float = 1e-3
    """Ridge weight of the SH least squares (relative to the design's mean diagonal)."""
    light_directions: int = 64
    """Candidate light directions re-picked before each stage."""
    seed: int = 0
    """Renderer sampling seed."""
    reproducible: bool = True
    """Bit-for-bit repeatable fits: the photometric stages run Dr.Jit (:func:`render.backend.reproducible`)
    and torch on one thread, whose gradient scatter-adds otherwise change order from run to run (two
    runs then differed by up to 0.12 mm); ~1.5x the photometric time here. False: faster, not repeatable."""

    def __post_init__(self) -> None:
        if self.render_size < 16:
            raise ValueError(f"render_size must be >= 16 pixels, got {self.render_size}")
        if self.spp < 1:
            raise ValueError(f"spp must be >= 1, got {self.spp}")
        if not self.crop_margin >= 0:
            raise ValueError(f"crop_margin must be >= 0, got {self.crop_margin}")
        if self.light_model not in LIGHT_MODELS:
            raise ValueError(f"light_model must be one of {list(LIGHT_MODELS)}, got {self.light_model!r}")
        if self.light_directions < 1:
            raise ValueError(f"light_directions must be >= 1, got {self.light_directions}")
        bad = [r for r in self.face_regions if r not in REGION_NAMES]
        if bad or not self.face_regions:
            raise ValueError(
                f"face_regions must be a non-empty subset of {list(REGION_NAMES)}, got {list(self.face_regions)}"
            )


@dataclass(frozen=True)
class FitPhotoConfig:
    """Settings of :func:`fit_photo` (``configs/fit_photo.yaml`` holds the defaults)."""

    landmarks: LandmarkFitConfig = field(default_factory=lambda: LandmarkFitConfig(prior=PHOTO_PRIOR))
    """The landmark fit (Levenberg-Marquardt with the identity prior, :data:`PHOTO_PRIOR`)."""
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    """The photometric stages."""


@dataclass(frozen=True)
class Crop:
    """The square part of the photo the photometric loss sees: photo pixels ``[x0, x0 + side)`` x
    ``[y0, y0 + side)`` (may extend past the photo; those pixels are masked), resampled to ``size``."""

    x0: int
    y0: int
    side: int
    size: int

    @property
    def scale(self) -> float:
        """Crop pixels per photo pixel."""
        return self.size / self.side

    def camera(self, focal: float, width: int, height: int, dtype=torch.float32) -> PinholeCamera:
        """The crop's pinhole (identity extrinsics: points are given in the photo camera's frame)."""
        s = self.scale
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        # pixel centres at integers: continuous coordinate u + 0.5 scales about the crop's corner
        k = torch.tensor(
            [
                [focal * s, 0.0, (cx + 0.5 - self.x0) * s - 0.5, 0.0],
                [0.0, focal * s, (cy + 0.5 - self.y0) * s - 0.5, 0.0],
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
            dtype=dtype,
        )
        return PinholeCamera(
            k[None],
            torch.eye(4, dtype=dtype)[None],
            torch.tensor([float(self.size)], dtype=dtype),
            torch.tensor([float(self.size)], dtype=dtype),
        )

    def cut(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(H, W, C)`` photo -> ``(size, size, C)`` float32 crop (area-averaged) and its ``(size, size)``
        float32 in-photo mask."""
        h, w = image.shape[:2]
        pad = np.zeros((self.side, self.side, image.shape[2]), np.float32)
        inside = np.zeros((self.side, self.side), np.float32)
        xa, ya = max(self.x0, 0), max(self.y0, 0)
        xb, yb = min(self.x0 + self.side, w), min(self.y0 + self.side, h)
        if xb > xa and yb > ya:
            pad[ya - self.y0 : yb - self.y0, xa - self.x0 : xb - self.x0] = image[ya:yb, xa:xb]
            inside[ya - self.y0 : yb - self.y0, xa - self.x0 : xb - self.x0] = 1.0
        interp = cv2.INTER_AREA if self.size < self.side else cv2.INTER_LINEAR
        out = cv2.resize(pad, (self.size, self.size), interpolation=interp)
        mask = cv2.resize(inside, (self.size, self.size), interpolation=interp)
        return out.reshape(self.size, self.size, -1), (mask > 0.999).astype(np.float32)


def face_crop(landmarks2d: np.ndarray, size: int, margin: float) -> Crop:
    """Square crop around the 68 landmarks: their box grown by ``margin`` (twice at the top), squared."""
    lo, hi = landmarks2d.min(0), landmarks2d.max(0)
    extent = hi - lo
    x0, x1 = lo[0] - margin * extent[0], hi[0] + margin * extent[0]
    y0, y1 = lo[1] - 2.0 * margin * extent[1], hi[1] + margin * extent[1]
    side = math.ceil(max(x1 - x0, y1 - y0, 8.0))
    cx, cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    return Crop(math.floor(cx - side / 2.0), math.floor(cy - side / 2.0), side, int(size))


@dataclass(frozen=True)
class PhotoFit:
    """Result of :func:`fit_photo`.

    Attributes:
        theta, z, expressions: joint channels ``(P,)`` (deg, mm, ``scale - 1``), latent ``(50,)``,
            expression coefficients ``(E,)``.
        rotation, translation: head pose, ``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation`` (mm).
        focal, width, height: the pinhole (pixels; principal point at the image centre).
        camera: the fitted ``PinholeCamera`` (world = rig space).
        rig_vertices: ``(V, 3)`` the fitted head in rig space, mm.
        albedo: ``(V, 3)`` linear RGB per vertex (the start colour where never seen).
        ambient, irradiance: ``(3,)`` linear RGB of the light; light_direction_rig / _camera: ``(3,)``
            unit direction the light travels, in rig space and in the camera frame. Without photometric
            stages (the default) these are not fitted: grey albedo 0.5, ambient 0.35, irradiance 2 from the
            camera's upper left, for the pictures.
        landmarks2d: ``(68, 2)`` the input landmarks; landmarks_px: ``(68, 2)`` fitted, pixels;
            error_px ``(68,)``; nme: mean error / outer-eye-corner distance.
        landmarks3d_camera: ``(68, 3)`` the fitted landmarks in 3D, camera frame (OpenCV: x right, y down,
            z forward), mm: the static embedding and the jaw contour as this camera sees it; projected with
            the camera they are ``landmarks_px``.
        landmark_fit: the landmark-only fit it started from.
        stages: one :class:`~pipeline.fitting.engine.StageLog` per photometric stage: every loss term,
            and the metrics ``photo`` (mean Charbonnier residual over the counted face pixels, linear RGB),
            ``landmarks_px2``, ``pixels`` (face pixels counted), ``outlier_fraction`` (of the face pixels,
            rejected at the stage's start), ``light_direction_camera``.
        crop: the photometric crop (None without photometric stages).
        timings: seconds per phase (``landmarks``, ``photometric``, ``total``).
    """

    theta: np.ndarray
    z: np.ndarray
    expressions: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    focal: float
    width: int
    height: int
    camera: PinholeCamera
    rig_vertices: np.ndarray
    albedo: np.ndarray
    ambient: np.ndarray
    irradiance: np.ndarray
    light_direction_rig: np.ndarray
    light_direction_camera: np.ndarray
    landmarks2d: np.ndarray
    landmarks_px: np.ndarray
    error_px: np.ndarray
    nme: float
    landmark_fit: LandmarkFit
    stages: tuple[StageLog, ...]
    crop: Crop | None
    timings: dict
    landmarks3d_camera: np.ndarray | None = None


def check_photo(image) -> np.ndarray:
    """``(H, W, 3)`` float32 linear RGB of a uint8 sRGB or float linear image; ValueError otherwise."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 16 or img.shape[1] < 16:
        raise ValueError(f"fit_photo: image must be (H, W, 3) RGB with H, W >= 16, got {img.shape}")
    if img.dtype == np.uint8:
        return srgb_to_linear(img.astype(np.float32) / 255.0)
    img = img.astype(np.float32)
    if not np.isfinite(img).all() or img.min() < 0 or img.max() > 1:
        raise ValueError("fit_photo: a float image must be linear RGB within [0, 1] without NaN")
    return img


def hemisphere_directions(n: int) -> np.ndarray:
    """``(n, 3)`` light travel directions (camera frame, OpenCV) spread over the cap ``z >= 0.25``: light
    coming from the camera's side of the face."""
    i = np.arange(n) + 0.5
    z = 1.0 - (1.0 - 0.25) * i / n
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def fit_light(
    albedo_img: np.ndarray, normals: np.ndarray, target: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel ``target ~ albedo (ambient + irradiance / pi * max(0, n . -d))``: the best ``d`` of
    ``directions`` and its non-negative ambient/irradiance (linear least squares per channel).

    Args: albedo_img, target ``(N, 3)``; normals ``(N, 3)``; directions ``(D, 3)``.
    Returns: ``(direction (3,), ambient (3,), irradiance (3,))``.
    """
    cos = np.clip(-(normals @ directions.T), 0.0, None) / math.pi  # (N, D)
    best = (math.inf, directions[0], np.full(3, 0.5), np.zeros(3))
    for k in range(len(directions)):
        err, amb, irr = 0.0, np.zeros(3), np.zeros(3)
        for c in range(3):
            a = albedo_img[:, c]
            design = np.stack([a, a * cos[:, k]], 1)
            sol, *_ = np.linalg.lstsq(design, target[:, c], rcond=None)
            sol = np.clip(sol, 0.0, None)
            err += float(np.square(design @ sol - target[:, c]).sum())
            amb[c], irr[c] = sol
        if err < best[0]:
            best = (err, directions[k], amb, irr)
    return best[1], best[2], best[3]


def fit_photo(
    image,
    landmarks2d,
    *,
    focal: float | None = None,
    config: FitPhotoConfig | None = None,
    rig: JointRig | None = None,
    neural: NeuralSkinning | None = None,
    progress: Progress | None = None,
) -> PhotoFit:
    """Reconstruct the head in one photo (module docstring).

    Args:
        image: ``(H, W, 3)`` uint8 sRGB (as :func:`landmarks.images.load_image` returns) or float32
            linear RGB in [0, 1].
        landmarks2d: ``(68, 2)`` pixels (OpenCV, 0-based), iBUG-68 order.
        focal: focal length in pixels (default :func:`pipeline.camera.default_focal`).
        config: settings and schedules (default :class:`FitPhotoConfig`).
        rig, neural: the models (default: the committed rig, float32, and its learned skinning).
        progress: :data:`rig.optim.Progress`, called after every step of both fits.

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
    if not config.landmarks.use_neural:
        neural = None
    elif neural is None:
        neural, _ = load_neural(rig)
    lfit = fit_landmarks(
        lm, width, height, focal=focal, config=config.landmarks, rig=rig, neural=neural, progress=progress
    )
    t_landmarks = time.perf_counter() - t0

    dtype = rig.template.dtype
    state = PhotoState(rig, neural, ExpressionModel(rig.asset, dtype=dtype), lfit.rotation, lfit.translation)
    state.load(lfit.theta, lfit.z, lfit.expressions)
    landmark = config.landmarks
    camera = make_camera(width, height, focal, dtype=dtype, pose=False)
    term = LandmarkTerm(
        rig.asset, lm, camera, landmark.huber_delta_px, landmark.contour_weight, landmark.landmark_weighting
    )
    t1 = time.perf_counter()
    appearance, stages, crop = _appearance(photo, lm, focal, state, term, config.photometric, progress)
    t_photo = time.perf_counter() - t1

    with torch.no_grad():
        v = state.rig_vertices()
        projected = term.project(state, v)
        landmarks3d_camera = state.to_camera(term.points3d(state, v)).double().numpy()
        translation = state.translation.double().numpy()
    values = state.arrays()
    rotation = values["rotation"]
    error, nme = landmark_errors(projected, lm)
    return PhotoFit(
        theta=values["theta"],
        z=values["z"],
        expressions=values["expressions"],
        rotation=rotation,
        translation=translation,
        focal=focal,
        width=width,
        height=height,
        camera=make_camera(width, height, focal, rotation=rotation, translation=translation),
        rig_vertices=v.double().numpy(),
        albedo=appearance["albedo"],
        ambient=appearance["ambient"],
        irradiance=appearance["irradiance"],
        light_direction_camera=appearance["light_camera"],
        light_direction_rig=camera_direction_to_rig(appearance["light_camera"], rotation),
        landmarks2d=lm,
        landmarks_px=projected,
        error_px=error,
        nme=nme,
        landmark_fit=lfit,
        stages=stages,
        crop=crop,
        landmarks3d_camera=landmarks3d_camera,
        timings={"landmarks": t_landmarks, "photometric": t_photo, "total": time.perf_counter() - t0},
    )


def _appearance(
    photo: np.ndarray,
    lm: np.ndarray,
    focal: float,
    state: PhotoState,
    term: LandmarkTerm,
    settings: PhotometricConfig,
    progress: Progress | None,
) -> tuple[dict[str, np.ndarray], tuple[StageLog, ...], Crop | None]:
    """The photometric stages when enabled (updating ``state``): ``({albedo, ambient, irradiance,
    light_camera}, stage logs, crop)``. Without them nothing of the appearance is fitted: a grey albedo and a
    key light from the camera's upper left (travelling right, down and forward) + fill, so that render.png and
    overlay.png show the fitted shape shaded rather than flat."""
    if not (settings.enabled and any(s.iterations > 0 for s in settings.stages)):
        light = np.array([0.3, 0.4, 1.0]) / np.linalg.norm([0.3, 0.4, 1.0])
        grey = np.full((len(state.rig.asset.vertices), 3), 0.5)
        shown = {"albedo": grey, "ambient": np.full(3, 0.35), "irradiance": np.full(3, 2.0), "light_camera": light}
        return shown, (), None
    crop = face_crop(lm, settings.render_size, settings.crop_margin)
    light, stages = _photometric(photo, crop, focal, state, term, settings, progress)
    appearance = {
        "albedo": state.albedo.detach().double().numpy(),
        "ambient": state.ambient.detach().double().numpy(),
        "irradiance": state.irradiance.detach().double().numpy(),
        "light_camera": light,
    }
    return appearance, stages, crop


def _photometric(
    photo: np.ndarray,
    crop: Crop,
    focal: float,
    state: PhotoState,
    term: LandmarkTerm,
    settings: PhotometricConfig,
    progress: Progress | None,
):
    """The photometric stages; updates ``state`` in place. Returns the light direction (camera frame)
    and the stage logs."""
    threads = torch.get_num_threads()
    if settings.reproducible:  # torch's CPU scatter-adds (index backward) are order-dependent on several threads too
        torch.set_num_threads(1)
    try:
        with reproducible(settings.reproducible):
            fit = PhotometricObjective(photo, crop, focal, state, term, settings)
            stages = run_schedule(
                state,
                settings.stages,
                fit,
                settings.lr,
                label="fit_photo",
                progress=progress,
                before_stage=fit.before_stage,
            )
            return np.asarray(fit.direction, float), stages
    finally:
        torch.set_num_threads(threads)


class PhotometricObjective:
    """The loss of the photometric stages (module docstring) and what is re-picked before each stage.

    Builds the renderer of the crop, starts the albedo from the median face colour seen from the
    landmark fit's pose and adds the appearance parameters to ``state``
    (:meth:`~pipeline.fitting.state.PhotoState.add_appearance`).
    """

    def __init__(
        self,
        photo: np.ndarray,
        crop: Crop,
        focal: float,
        state: PhotoState,
        term: LandmarkTerm,
        settings: PhotometricConfig,
    ) -> None:
        self.state, self.term, self.settings = state, term, settings
        asset = state.rig.asset
        height, width = photo.shape[:2]
        dtype = self.dtype = torch.float32
        target_np, inside_np = crop.cut(photo)
        self.target = torch.as_tensor(target_np, dtype=dtype)
        self.inside = torch.as_tensor(inside_np, dtype=dtype)
        self.face_region_ids = torch.as_tensor([asset.region_names.index(r) for r in settings.face_regions])
        with torch.no_grad():
            v_cam0 = state.to_camera(state.rig_vertices()).to(dtype)
        n_vertices = len(asset.vertices)
        self.renderer = DifferentiableRenderer(
            v_cam0,
            asset.faces,
            torch.full((n_vertices, 3), 0.5),
            crop.camera(focal, width, height, dtype=dtype),
            Lighting(torch.full((3,), 1.0), torch.zeros(3), torch.tensor([0.0, 0.0, 1.0])),
            spp=settings.spp,
            seed=settings.seed,
            regions=asset.regions,
        )
        # start colour: the median of the face pixels seen from the landmark fit's pose
        with torch.no_grad():
            first = self.renderer.render(v_cam0, torch.full((n_vertices, 3), 0.5), aovs=True)
            m = self.face_mask(first.region_ids) > 0
            if int(m.sum()) < 50:
                raise ValueError(
                    f"fit_photo: the face covers only {int(m.sum())} pixels of the "
                    f"{crop.size}x{crop.size} crop; the landmarks do not match the head"
                )
            self.start_colour = self.target[m].median(0).values.clamp(0.02, 0.98)
        state.add_appearance(
            self.start_colour.repeat(n_vertices, 1), torch.full((3,), 1.0, dtype=dtype), torch.zeros(3, dtype=dtype)
        )
        self.direction = np.array([0.0, 0.0, 1.0])
        self.faces = torch.as_tensor(np.asarray(asset.faces, np.int64))
        self.edges = torch.as_tensor(mesh_edges(asset.faces))
        self.mirror = torch.as_tensor(np.asarray(asset.mirror, np.int64))
        self.candidates = hemisphere_directions(settings.light_directions)
        self.inlier: torch.Tensor | None = None
        self.stages_started = 0
        self.terms = (
            self.photo_term(),
            term.term(settings.lambda_landmarks, name="landmarks"),
            *state.prior_terms(settings.prior),
            *self.albedo_prior_terms(),
        )

    def face_mask(self, region_ids: torch.Tensor) -> torch.Tensor:
        """``(S, S)`` 1 on face-region pixels inside the photo."""
        return torch.isin(region_ids, self.face_region_ids).to(self.dtype) * self.inside

    def light(self):
        if self.settings.light_model == "sh":  # the shading is in the albedo: the renderer only emits it
            return Lighting(
                torch.ones(3, dtype=self.dtype),
                torch.zeros(3, dtype=self.dtype),
                torch.as_tensor(self.direction, dtype=self.dtype),
            )
        return Lighting(self.state.ambient, self.state.irradiance, torch.as_tensor(self.direction, dtype=self.dtype))

    def shaded_albedo(self, v_cam: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
        """``(V, 3)`` what the renderer is given as albedo: the albedo itself (directional light), or the albedo
        times the SH irradiance of each vertex normal (``sh``; differentiable in vertices, albedo and light)."""
        if self.settings.light_model != "sh":
            return albedo
        irradiance = sh_basis(vertex_normals(v_cam, self.faces)) @ self.state.sh.to(v_cam.dtype)
        return albedo * irradiance.clamp_min(0.0)

    def residual_norm(self, image: torch.Tensor) -> torch.Tensor:
        return (image - self.target).square().sum(-1)

    def before_stage(self, stage: Stage) -> dict:
        """Re-pick the light direction (and, before the first stage, its ambient and irradiance) and the
        outlier pixels from the current state."""
        state, dtype = self.state, self.dtype
        with torch.no_grad():
            v_cam = state.to_camera(state.rig_vertices()).to(dtype)
            albedo = state.albedo.clamp(0, 1)
            flat = self.renderer.render(
                v_cam,
                albedo,
                Lighting(torch.ones(3), torch.zeros(3), torch.as_tensor(self.direction, dtype=dtype)),
                aovs=True,
            )
            m = self.face_mask(flat.region_ids) > 0
            if self.settings.light_model == "sh":
                state.sh.copy_(
                    torch.as_tensor(
                        fit_sh(
                            flat.image[m].double().numpy(),
                            flat.normals[m].double().numpy(),
                            self.target[m].double().numpy(),
                            self.settings.sh_ridge,
                        ),
                        dtype=dtype,
                    )
                )
            else:
                self.direction, amb, irr = fit_light(
                    flat.image[m].double().numpy(),
                    flat.normals[m].double().numpy(),
                    self.target[m].double().numpy(),
                    self.candidates,
                )
                if self.stages_started == 0:
                    state.ambient.copy_(torch.as_tensor(amb, dtype=dtype))
                    state.irradiance.copy_(torch.as_tensor(irr, dtype=dtype))
            self.stages_started += 1
            shaded = self.renderer.render(v_cam, self.shaded_albedo(v_cam, albedo), self.light(), aovs=True)
            m = self.face_mask(shaded.region_ids) > 0
            e = self.residual_norm(shaded.image).sqrt()
            med = e[m].median()
            mad = (e[m] - med).abs().median()
            threshold = float(med + self.settings.outlier_mads * 1.4826 * mad)
            self.inlier = (e <= max(threshold, 0.05)).to(dtype)
            outlier_fraction = float(1.0 - self.inlier[m].mean()) if bool(m.any()) else 0.0
        return {"outlier_fraction": outlier_fraction, "light_direction_camera": tuple(float(x) for x in self.direction)}

    def photo_term(self) -> Term:
        """``photo``: ``lambda_photo`` times the mean Charbonnier distance of the linear-RGB residual over the
        inlier face pixels (inputs ``image (B, S, S, 3)``, ``pixel_weights (S * S,)``)."""
        s = self.settings

        def residual(p: Inputs) -> torch.Tensor:
            image = p["image"]
            return (image - self.target).reshape(image.shape[0], -1, 3)

        return Term(
            "photo",
            s.lambda_photo,
            residual,
            Charbonnier(s.charbonnier_eps),
            normaliser="weights",
            group_weights="pixel_weights",
            min_normaliser=1.0,
        )

    def albedo_prior_terms(self) -> tuple[Term, ...]:
        """``albedo_smooth``, ``albedo_symmetry``, ``albedo_mean``: mean squared differences of the albedo
        (input ``albedo (V, 3)``, the parameter itself: each term reads it as the optimiser sees it) along mesh
        edges, to the mirror vertex and to the start colour."""
        w, edges, mirror = self.settings.albedo_prior, self.edges, self.mirror

        def along_edges(p: Inputs) -> torch.Tensor:
            return (p["albedo"][edges[:, 0]] - p["albedo"][edges[:, 1]])[None]

        def to_mirror(p: Inputs) -> torch.Tensor:
            return (p["albedo"] - p["albedo"][mirror])[None]

        def to_start(p: Inputs) -> torch.Tensor:
            return (p["albedo"] - self.start_colour)[None]

        return (
            Term("albedo_smooth", w.smooth, along_edges, L2(), normaliser="mean"),
            Term("albedo_symmetry", w.symmetry, to_mirror, L2(), normaliser="mean"),
            Term("albedo_mean", w.mean, to_start, L2(), normaliser="mean"),
        )

    def __call__(self, free: tuple[str, ...]) -> Loss:
        """One step's loss: render -> Charbonnier over the inlier face pixels, landmarks, priors."""
        state = self.state
        geometry = tuple(g for g in free if g in FREE_GROUPS)
        v = state.rig_vertices(geometry)
        v_cam = state.to_camera(v, geometry).to(self.dtype)
        out = self.renderer.render(v_cam, self.shaded_albedo(v_cam, state.albedo), self.light(), aovs=True)
        weight = self.face_mask(out.region_ids) * self.inlier
        inputs = state.term_inputs().add(
            {"image": out.image[None], "pixel_weights": weight.reshape(-1)},
            landmarks_px=lambda: self.term.pixels(state, v, geometry),
            albedo=lambda: state.albedo,
        )
        unweighted: dict[str, torch.Tensor] = {}
        terms = term_values(self.terms, inputs, unweighted)
        metrics = {"photo": unweighted["photo"], "landmarks_px2": unweighted["landmarks"], "pixels": int(weight.sum())}
        return Loss(terms, metrics)
