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
(:func:`pipeline.photo.camera.camera_direction_to_rig`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera

from pipeline.fitting.state import FREE_GROUPS
from pipeline.photo.camera import (
    camera_direction_to_rig,
    check_focal,
    default_focal,
    make_camera,
)
from pipeline.photo.colour import srgb_to_linear
from pipeline.photo.landmark_fit import (
    LandmarkFit,
    LandmarkFitConfig,
    LandmarkTerm,
    PosedRig,
    _check_landmarks,
    fit_landmarks,
    landmark_errors,
    rig_prior,
)
from pipeline.scan.fit import FACE_REGIONS, Stage
from rig.expressions import ExpressionModel
from rig.geometry import mesh_edges
from rig.model import JointRig
from rig.skinning.neural import NeuralSkinning, load_neural

PHOTO_GROUPS = FREE_GROUPS + ("albedo", "light")


PHOTO_LAMBDA_M = 100.0
"""L_m weight of the photo fit (the landmark fit's own default, 0.3, suits heads far from the template).

Measured on synthetic renders of held-out heads 0-5 (neutral and expressive, 1 px landmark noise,
landmark-only fit, NoW-style alignment): true face-vertex error 1.05 / 0.98 / 0.91 / 0.89 mm for
L_m = 10 / 30 / 100 / 300, and 1.46 mm at 0.3; the template itself scores ~0.85 mm. From 68
landmarks with pixel noise, the joints mostly fit the noise: a strong prior keeps the head near the
template unless the landmarks insist. 100 rather than 300 leaves the joints some freedom for faces
farther from the template than the synthetic population."""


@dataclass(frozen=True)
class PhotoStage(Stage):
    """One stage of the photometric schedule: ``free`` is a subset of ``pose``, ``joints``, ``latent``,
    ``expressions``, ``albedo``, ``light``."""

    groups: ClassVar[tuple[str, ...]] = PHOTO_GROUPS


def photo_schedule(appearance_iterations: int = 25, joint_iterations: int = 30, latent_iterations: int = 15,
                   expression_iterations: int = 25, final_joint_iterations: int = 25) -> tuple[PhotoStage, ...]:
    """The default photometric schedule (120 steps): albedo + light; then JNR 4.3's alternation
    (pose + joints, Z, pose + expressions, pose + joints), each with albedo and light. 0 leaves a stage out."""
    look = ("albedo", "light")
    stages = (PhotoStage("appearance", look, appearance_iterations),
              PhotoStage("photo joints", ("pose", "joints") + look, joint_iterations),
              PhotoStage("photo latent", ("latent",) + look, latent_iterations),
              PhotoStage("photo expressions", ("pose", "expressions") + look, expression_iterations),
              PhotoStage("photo joints 2", ("pose", "joints") + look, final_joint_iterations))
    return tuple(s for s in stages if s.iterations > 0)


@dataclass(frozen=True)
class FitPhotoConfig:
    """Settings of :func:`fit_photo` (``configs/fit_photo.yaml`` holds the defaults)."""

    landmarks: LandmarkFitConfig = field(default_factory=lambda: LandmarkFitConfig(lambda_m=PHOTO_LAMBDA_M))
    """The landmark-only fit that starts the photometric one (with a strong joint prior, see
    :data:`PHOTO_LAMBDA_M`)."""
    photometric: bool = True
    """Run the photometric stages (false: landmark fit only)."""
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
    lambda_albedo_smooth: float = 20.0
    """Mean squared albedo difference along mesh edges."""
    lambda_albedo_symmetry: float = 5.0
    """Mean squared difference to the mirror vertex's albedo."""
    lambda_albedo_mean: float = 0.5
    """Mean squared difference to the start colour (the median face colour)."""
    lr_rotation: float = 0.003
    lr_translation: float = 0.5
    lr_joints: float = 0.004
    lr_latent: float = 0.02
    lr_expressions: float = 0.02
    lr_albedo: float = 0.02
    lr_light: float = 0.05
    lambda_m: float = PHOTO_LAMBDA_M
    """L_m (eq. 4) during the photometric stages."""
    lambda_x: float = 3.0
    lambda_z: float = 0.01
    lambda_expressions: float = 0.5
    lambda_symmetry: float = 0.0
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
        if self.light_directions < 1:
            raise ValueError(f"light_directions must be >= 1, got {self.light_directions}")
        from rig.asset import REGION_NAMES

        bad = [r for r in self.face_regions if r not in REGION_NAMES]
        if bad or not self.face_regions:
            raise ValueError(f"face_regions must be a non-empty subset of {list(REGION_NAMES)}, got {list(self.face_regions)}")


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
        k = torch.tensor([[focal * s, 0.0, (cx + 0.5 - self.x0) * s - 0.5, 0.0],
                          [0.0, focal * s, (cy + 0.5 - self.y0) * s - 0.5, 0.0],
                          [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], dtype=dtype)
        return PinholeCamera(k[None], torch.eye(4, dtype=dtype)[None], torch.tensor([float(self.size)], dtype=dtype),
                             torch.tensor([float(self.size)], dtype=dtype))

    def cut(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(H, W, C)`` photo -> ``(size, size, C)`` float32 crop (area-averaged) and its ``(size, size)``
        float32 in-photo mask."""
        import cv2

        h, w = image.shape[:2]
        pad = np.zeros((self.side, self.side, image.shape[2]), np.float32)
        inside = np.zeros((self.side, self.side), np.float32)
        xa, ya = max(self.x0, 0), max(self.y0, 0)
        xb, yb = min(self.x0 + self.side, w), min(self.y0 + self.side, h)
        if xb > xa and yb > ya:
            pad[ya - self.y0:yb - self.y0, xa - self.x0:xb - self.x0] = image[ya:yb, xa:xb]
            inside[ya - self.y0:yb - self.y0, xa - self.x0:xb - self.x0] = 1.0
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
class PhotoStageReport:
    """What one photometric stage did (losses at its end)."""

    name: str
    free: tuple[str, ...]
    iterations: int
    loss_start: float
    loss_end: float
    photo_end: float
    """Mean Charbonnier residual over the counted face pixels (linear RGB)."""
    landmarks_px2_end: float
    pixels: int
    """Face pixels counted at the end of the stage."""
    outlier_fraction: float
    """Fraction of face pixels rejected as outliers at the stage's start."""
    light_direction_camera: tuple[float, float, float]
    seconds: float


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
            unit direction the light travels, in rig space and in the camera frame.
        landmarks2d: ``(68, 2)`` the input landmarks; landmarks_px: ``(68, 2)`` fitted, pixels;
            error_px ``(68,)``; nme: mean error / outer-eye-corner distance.
        landmark_fit: the landmark-only fit it started from.
        stages: one :class:`PhotoStageReport` per photometric stage.
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
    stages: tuple[PhotoStageReport, ...]
    crop: Crop | None
    timings: dict


def _check_image(image) -> np.ndarray:
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


def fit_light(albedo_img: np.ndarray, normals: np.ndarray, target: np.ndarray, directions: np.ndarray
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


def fit_photo(image, landmarks2d, *, focal: float | None = None, config: FitPhotoConfig | None = None,
              rig: JointRig | None = None, neural: NeuralSkinning | None = None,
              progress: Callable[[str, int, int], None] | None = None) -> PhotoFit:
    """Reconstruct the head in one photo (module docstring).

    Args:
        image: ``(H, W, 3)`` uint8 sRGB (as :func:`landmarks.detect.load_image` returns) or float32
            linear RGB in [0, 1].
        landmarks2d: ``(68, 2)`` pixels (OpenCV, 0-based), iBUG-68 order.
        focal: focal length in pixels (default :func:`pipeline.photo.camera.default_focal`).
        config: settings and schedules (default :class:`FitPhotoConfig`).
        rig, neural: the models (default: the committed rig, float32, and its learned skinning).
        progress: called as ``progress(stage_name, iteration, iterations)``.

    Returns:
        :class:`PhotoFit`.

    Raises:
        ValueError: bad image or landmarks, a bad focal, or a fit that diverges.
        render.backend.LLVMError: no usable libLLVM for the renderer (CPU).
    """
    t0 = time.perf_counter()
    config = config or FitPhotoConfig()
    photo = _check_image(image)
    lm = _check_landmarks(landmarks2d)
    height, width = photo.shape[:2]
    focal = default_focal(width, height) if focal is None else check_focal(focal, width, height)
    rig = rig or JointRig()
    if config.landmarks.use_neural and neural is None:
        neural, _ = load_neural(rig)
    if not config.landmarks.use_neural:
        neural = None
    lfit = fit_landmarks(lm, width, height, focal=focal, config=config.landmarks, rig=rig, neural=neural,
                         progress=progress)
    t_landmarks = time.perf_counter() - t0

    dtype = rig.template.dtype
    asset = rig.asset
    model = PosedRig(rig, neural, ExpressionModel(asset, dtype=dtype), lfit.rotation, lfit.translation)
    with torch.no_grad():
        model.theta_n.copy_(torch.as_tensor(lfit.theta, dtype=dtype) / model.span)
        model.z.copy_(torch.as_tensor(lfit.z, dtype=dtype))
        model.c.copy_(torch.as_tensor(lfit.expressions, dtype=dtype))
    full = make_camera(width, height, focal, dtype=dtype)
    term = LandmarkTerm(asset, lm, PinholeCamera(full.intrinsics, torch.eye(4, dtype=dtype)[None], full.height,
                                                 full.width), config.landmarks.huber_delta_px)

    stages: list[PhotoStageReport] = []
    crop = None
    albedo_np = np.full((len(asset.vertices), 3), 0.5)
    light_cam = np.array([0.0, 0.3, 1.0]) / np.linalg.norm([0.0, 0.3, 1.0])
    ambient_np, irradiance_np = np.full(3, 0.6), np.zeros(3)
    t1 = time.perf_counter()
    if config.photometric and any(s.iterations > 0 for s in config.stages):
        crop = face_crop(lm, config.render_size, config.crop_margin)
        result = _photometric(photo, crop, focal, model, term, config, asset, neural, progress)
        albedo_np, ambient_np, irradiance_np, light_cam, stages = result
    t_photo = time.perf_counter() - t1

    with torch.no_grad():
        v = model.rig_vertices()
        projected = term.project(model, v)
        rotation = model.rotation().double().numpy()
        translation = model.translation.double().numpy()
    error, nme = landmark_errors(projected, lm)
    return PhotoFit(theta=model.theta.detach().double().numpy(), z=model.z.detach().double().numpy(),
                    expressions=model.c.detach().double().numpy(), rotation=rotation, translation=translation,
                    focal=focal, width=width, height=height,
                    camera=make_camera(width, height, focal, rotation=rotation, translation=translation),
                    rig_vertices=v.double().numpy(), albedo=albedo_np, ambient=ambient_np,
                    irradiance=irradiance_np, light_direction_camera=light_cam,
                    light_direction_rig=camera_direction_to_rig(light_cam, rotation),
                    landmarks2d=lm, landmarks_px=projected, error_px=error, nme=nme, landmark_fit=lfit,
                    stages=tuple(stages), crop=crop,
                    timings={"landmarks": t_landmarks, "photometric": t_photo,
                             "total": time.perf_counter() - t0})


def _photometric(photo: np.ndarray, crop: Crop, focal: float, model: PosedRig, term: LandmarkTerm,
                 config: FitPhotoConfig, asset, neural, progress):
    """The photometric stages; updates ``model`` in place. Returns albedo, ambient, irradiance, the light
    direction (camera frame) and the stage reports."""
    from render.backend import reproducible

    threads = torch.get_num_threads()
    if config.reproducible:  # torch's CPU scatter-adds (index backward) are order-dependent on several threads too
        torch.set_num_threads(1)
    try:
        with reproducible(config.reproducible):
            return _photometric_stages(photo, crop, focal, model, term, config, asset, neural, progress)
    finally:
        torch.set_num_threads(threads)


def _photometric_stages(photo: np.ndarray, crop: Crop, focal: float, model: PosedRig, term: LandmarkTerm,
                        config: FitPhotoConfig, asset, neural, progress):
    from render.lighting import Lighting
    from render.renderer import DifferentiableRenderer

    height, width = photo.shape[:2]
    dtype = torch.float32
    target_np, inside_np = crop.cut(photo)
    target = torch.as_tensor(target_np, dtype=dtype)
    inside = torch.as_tensor(inside_np, dtype=dtype)
    camera = crop.camera(focal, width, height, dtype=dtype)
    face_region_ids = torch.as_tensor([asset.region_names.index(r) for r in config.face_regions])

    with torch.no_grad():
        v_cam0 = model.to_camera(model.rig_vertices()).to(dtype)
    n_vertices = len(asset.vertices)
    renderer = DifferentiableRenderer(v_cam0, asset.faces, torch.full((n_vertices, 3), 0.5), camera,
                                      Lighting(torch.full((3,), 1.0), torch.zeros(3),
                                               torch.tensor([0.0, 0.0, 1.0])),
                                      spp=config.spp, seed=config.seed, regions=asset.regions)

    def face_mask(region_ids: torch.Tensor) -> torch.Tensor:
        return torch.isin(region_ids, face_region_ids).to(dtype) * inside

    # start colour: the median of the face pixels seen from the landmark fit's pose
    with torch.no_grad():
        first = renderer.render(v_cam0, torch.full((n_vertices, 3), 0.5), aovs=True)
        m = face_mask(first.region_ids) > 0
        if int(m.sum()) < 50:
            raise ValueError(f"fit_photo: the face covers only {int(m.sum())} pixels of the "
                             f"{crop.size}x{crop.size} crop; the landmarks do not match the head")
        start_colour = target[m].median(0).values.clamp(0.02, 0.98)
    albedo = start_colour.repeat(n_vertices, 1).clone().requires_grad_(True)
    ambient = torch.full((3,), 1.0, dtype=dtype, requires_grad=True)
    irradiance = torch.zeros(3, dtype=dtype, requires_grad=True)
    direction = np.array([0.0, 0.0, 1.0])
    edges = torch.as_tensor(mesh_edges(asset.faces))
    mirror = torch.as_tensor(np.asarray(asset.mirror, np.int64))
    candidates = hemisphere_directions(config.light_directions)

    lrs = {"joints": [(model.theta_n, config.lr_joints)], "latent": [(model.z, config.lr_latent)],
           "expressions": [(model.c, config.lr_expressions)],
           "pose": [(model.rotvec, config.lr_rotation), (model.translation, config.lr_translation)],
           "albedo": [(albedo, config.lr_albedo)], "light": [(ambient, config.lr_light), (irradiance, config.lr_light)]}

    def light() -> Lighting:
        return Lighting(ambient, irradiance, torch.as_tensor(direction, dtype=dtype))

    def residual_norm(image: torch.Tensor) -> torch.Tensor:
        return (image - target).square().sum(-1)

    def albedo_prior() -> torch.Tensor:
        smooth = (albedo[edges[:, 0]] - albedo[edges[:, 1]]).square().sum(-1).mean()
        sym = (albedo - albedo[mirror]).square().sum(-1).mean()
        mean = (albedo - start_colour).square().sum(-1).mean()
        return config.lambda_albedo_smooth * smooth + config.lambda_albedo_symmetry * sym \
            + config.lambda_albedo_mean * mean

    reports: list[PhotoStageReport] = []
    if neural is not None:
        for p in neural.decoder.parameters():
            p.requires_grad_(False)
    try:
        for stage in config.stages:
            if stage.iterations == 0:
                continue
            ts = time.perf_counter()
            free = tuple(g for g in stage.free if not (g == "latent" and neural is None))
            geometry = tuple(g for g in free if g in FREE_GROUPS)
            # re-pick the light direction and the outlier pixels from the current state
            with torch.no_grad():
                v_cam = model.to_camera(model.rig_vertices()).to(dtype)
                flat = renderer.render(v_cam, albedo.clamp(0, 1),
                                       Lighting(torch.ones(3), torch.zeros(3), torch.as_tensor(direction, dtype=dtype)),
                                       aovs=True)
                m = face_mask(flat.region_ids) > 0
                direction, amb, irr = fit_light(flat.image[m].double().numpy(), flat.normals[m].double().numpy(),
                                                 target[m].double().numpy(), candidates)
                if stage is config.stages[0] or not reports:
                    ambient.copy_(torch.as_tensor(amb, dtype=dtype))
                    irradiance.copy_(torch.as_tensor(irr, dtype=dtype))
                shaded = renderer.render(v_cam, albedo.clamp(0, 1), light(), aovs=True)
                m = face_mask(shaded.region_ids) > 0
                e = residual_norm(shaded.image).sqrt()
                med = e[m].median()
                mad = (e[m] - med).abs().median()
                threshold = float(med + config.outlier_mads * 1.4826 * mad)
                inlier = (e <= max(threshold, 0.05)).to(dtype)
                outlier_fraction = float(1.0 - inlier[m].mean()) if bool(m.any()) else 0.0

            opt = torch.optim.Adam([{"params": [t], "lr": lr} for g in free for t, lr in lrs[g]])
            loss_start = None
            for it in range(stage.iterations):
                v = model.rig_vertices(geometry)
                v_cam = model.to_camera(v, geometry).to(dtype)
                out = renderer.render(v_cam, albedo, light(), aovs=True)
                weight = face_mask(out.region_ids) * inlier
                count = weight.sum().clamp_min(1.0)
                rho = (residual_norm(out.image) + config.charbonnier_eps ** 2).sqrt() - config.charbonnier_eps
                photo_loss = (rho * weight).sum() / count
                lm_loss = term(model, v, geometry)
                loss = config.lambda_photo * photo_loss + config.lambda_landmarks * lm_loss \
                    + rig_prior(model, config) + albedo_prior()
                if not torch.isfinite(loss):
                    raise FloatingPointError(f"fit_photo diverged in stage {stage.name!r} (non-finite loss)")
                if loss_start is None:
                    loss_start = float(loss.detach())
                opt.zero_grad()
                loss.backward()
                opt.step()
                with torch.no_grad():
                    albedo.clamp_(0.0, 1.0)
                    ambient.clamp_(min=0.0)
                    irradiance.clamp_(min=0.0)
                if "expressions" in free:
                    model.clamp_expressions()
                if "joints" in free:
                    model.clamp_joints()
                if progress is not None:
                    progress(stage.name, it + 1, stage.iterations)
            reports.append(PhotoStageReport(
                name=stage.name, free=tuple(free), iterations=stage.iterations, loss_start=float(loss_start),
                loss_end=float(loss.detach()), photo_end=float(photo_loss.detach()),
                landmarks_px2_end=float(lm_loss.detach()), pixels=int(weight.sum()),
                outlier_fraction=outlier_fraction, light_direction_camera=tuple(float(x) for x in direction),
                seconds=time.perf_counter() - ts))
    finally:
        if neural is not None:
            for p in neural.decoder.parameters():
                p.requires_grad_(True)
    return (albedo.detach().double().numpy(), ambient.detach().double().numpy(),
            irradiance.detach().double().numpy(), np.asarray(direction, float), reports)
