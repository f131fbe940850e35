"""Synthetic portrait photos of held-out synthetic heads, with known ground truth.

Validates the photo fit on images whose answer is known: a held-out head (never seen in training) gets
a random skin/hair/eye albedo, a random pose and camera, a random point light + environment and a
random background, and is path-traced by :func:`render.reference.render_reference` -- a renderer and a
light model that differ from the fitting renderer's, so a fit is not rewarded for sharing its
approximations (no inverse crime). The 68 iBUG landmarks are projected from the true mesh (jaw contour:
the silhouette seen from the camera, :func:`landmarks.ibug68.contour_landmarks`) and jittered like a
landmark detector's output.

Frames (as :mod:`pipeline.photo.camera`):

- **rig space**: mm, right-handed, +X the subject's left, +Y up, +Z out of the face. The true mesh
  ``gt_vertices`` is unposed, in rig space.
- **head pose** ``(rotation, translation)``: ``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation``,
  with ``x_cam`` in OpenCV camera coordinates (x right, y down, z forward, mm);
  ``rotation = R_z(roll) R_x(pitch) R_y(yaw)`` (:func:`head_rotation`): a positive yaw turns the face
  towards the subject's left, i.e. towards the image's right.
- **pixels**: OpenCV / kornia, 0-based, pixel centres at integer coordinates, principal point at the
  image centre ``((W - 1) / 2, (H - 1) / 2)`` (:func:`pipeline.photo.camera.make_camera`).

Colours: ``*_linear`` arrays and albedos are linear RGB; ``image`` is 8-bit sRGB.
Everything is deterministic given the random generator (or ``(seed, index, expressive)``).
"""

from __future__ import annotations

import json
import logging
import math
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from landmarks.ibug68 import contour_landmarks, ibug68_embedding, landmark_positions
from pipeline.photo.camera import RIG_TO_OPENCV, camera_center_in_rig, make_camera
from pipeline.photo.colour import linear_to_srgb, srgb_to_linear
from render.reference import ReferenceLight, render_reference
from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.geometry import head_rotation

__all__ = [
    "HAIR_COLOURS_SRGB",
    "IRIS_COLOURS_SRGB",
    "SKIN_TONES_SRGB",
    "PhotoSettings",
    "SyntheticPhoto",
    "head_rotation",
    "linear_to_srgb",
    "simulate_photo",
    "srgb_to_linear",
    "synthesize_albedo",
    "synthetic_background",
    "synthetic_photo",
    "write_synthetic_photo",
]

logger = logging.getLogger(__name__)

SKIN_TONES_SRGB: tuple[tuple[int, int, int], ...] = (
    (236, 198, 172),  # very light
    (224, 174, 140),  # light
    (198, 140, 104),  # medium
    (164, 108, 74),   # tan / olive-brown
    (118, 76, 52),    # dark
    (78, 52, 38),     # very dark
)
"""Skin albedos from very light to very dark, 8-bit sRGB (typical diffuse skin colours of photos); a
tone parameter ``t`` in [0, 1] interpolates them piecewise linearly in linear RGB."""

HAIR_COLOURS_SRGB: tuple[tuple[int, int, int], ...] = (
    (28, 24, 22),     # black
    (58, 40, 30),     # dark brown
    (98, 68, 44),     # brown
    (176, 146, 100),  # blond
    (136, 66, 38),    # red
    (150, 146, 140),  # grey
)
"""Hair colours, 8-bit sRGB (scalp and, darkened, eyebrows)."""

IRIS_COLOURS_SRGB: tuple[tuple[int, int, int], ...] = (
    (62, 38, 24),     # dark brown
    (96, 62, 36),     # brown
    (110, 96, 58),    # hazel
    (70, 100, 130),   # blue
    (80, 104, 74),    # green
    (100, 106, 112),  # grey
)
"""Iris colours, 8-bit sRGB."""

_SCLERA_SRGB = (222, 212, 200)
_TEETH_SRGB = (226, 216, 192)
_TONGUE_SRGB = (176, 84, 86)
_MOUTH_INTERIOR_LINEAR = np.array([0.10, 0.025, 0.025])
_IRIS_RADIUS_MM = 5.5
_PHOTO_STREAM = zlib.crc32(b"synthetic-photo")


# ----------------------------------------------------------------------------------------------------
# Settings and results
# ----------------------------------------------------------------------------------------------------

def _check_range(value, name: str, *, low: float | None = None, high: float | None = None,
                 strict_low: bool = False) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in value)
    except (TypeError, ValueError):
        raise ValueError(f"PhotoSettings: {name} must be a (low, high) pair of numbers, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise ValueError(f"PhotoSettings: {name} must be a finite (low, high) pair with low <= high, got {value!r}")
    if low is not None and (lo < low or (strict_low and lo <= low)):
        raise ValueError(f"PhotoSettings: {name} must lie {'above' if strict_low else 'at or above'} {low}, "
                         f"got {value!r}")
    if high is not None and hi > high:
        raise ValueError(f"PhotoSettings: {name} must lie at or below {high}, got {value!r}")
    return lo, hi


def _check_number(value, name: str, *, low: float = 0.0, high: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(value)) or value < low or (high is not None and value > high):
        bound = f"in [{low}, {high}]" if high is not None else f">= {low}"
        raise ValueError(f"PhotoSettings: {name} must be a finite number {bound}, got {value!r}")
    return float(value)


def _check_int(value, name: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"PhotoSettings: {name} must be an integer >= {low}, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class PhotoSettings:
    """Camera, pose, light and albedo distributions of :func:`simulate_photo` (validated on construction:
    a bad value raises ``ValueError``; ranges are ``(low, high)``, drawn uniformly).

    Attributes:
        width, height: image size, pixels.
        yaw_deg_range: head yaw (about rig +Y; positive turns the face towards the image's right), degrees.
        pitch_deg_range: head pitch (about rig +X; positive tips the face down), degrees.
        roll_deg_range: head roll (about rig +Z, the face's own axis), degrees.
        distance_mm_range: camera to the rig origin along the optical axis (``translation[2]``), mm.
        focal_factor_range: focal length over ``max(width, height)``; 1.2-1.7 spans phone portraits
            to a short tele (:func:`pipeline.photo.camera.default_focal` assumes 1.4).
        offset_px: the face centre (mean of its 68 landmarks) is imaged at the image centre plus a shift
            drawn uniformly from ``[-offset_px, offset_px]`` per axis, pixels.
        margin_px: every true landmark must lie at least this far inside the image, pixels (else
            :func:`simulate_photo` raises ``ValueError``).
        spp: path-tracing samples per pixel.
        landmark_noise_px: sigma of the Gaussian noise added to each projected landmark coordinate
            (a detector's error), pixels.
        light_azimuth_deg_range: point light direction seen from the face centre, degrees to the image's
            right of the direction towards the camera (negative: to the left).
        light_elevation_deg_range: degrees above that direction (positive: the light is above the camera).
        light_distance_mm_range: point light to the face centre, mm.
        light_irradiance_range: irradiance of the point light on a surface at the face centre facing it
            (linear; the intensity is ``irradiance * distance^2``). A surface of albedo ``a`` facing the
            light reflects ``a * irradiance / pi``.
        environment_radiance_range: radiance of the constant environment (sky/room fill), linear.
        light_tint: each light's colour is ``(1 + tau, 1, 1 - tau)`` times its level, ``tau`` uniform in
            ``[-light_tint, light_tint]`` (warm to cool), drawn separately for the point light and
            the environment.
        skin_tone_range: the skin tone ``t`` is uniform in this range; ``t = 0`` very light, ``t = 1``
            very dark (:data:`SKIN_TONES_SRGB`).
        albedo_variation: amplitude of the smooth variation of the skin albedo (log-albedo sigma of each
            of ``albedo_bumps`` Gaussian bumps of 15-45 mm radius; also redness, at half that).
        albedo_bumps: number of smooth albedo bumps.
        albedo_asymmetry: fraction of the smooth variation that is not left/right symmetric (0: an
            exactly mirrored albedo; per-vertex fine texture is always asymmetric).
        bald_probability: chance that the scalp has the skin colour instead of a hair colour.
    """

    width: int = 384
    height: int = 384
    yaw_deg_range: tuple[float, float] = (-30.0, 30.0)
    pitch_deg_range: tuple[float, float] = (-10.0, 10.0)
    roll_deg_range: tuple[float, float] = (-5.0, 5.0)
    distance_mm_range: tuple[float, float] = (450.0, 650.0)
    focal_factor_range: tuple[float, float] = (1.2, 1.7)
    offset_px: float = 20.0
    margin_px: float = 2.0
    spp: int = 64
    landmark_noise_px: float = 1.0
    light_azimuth_deg_range: tuple[float, float] = (-50.0, 50.0)
    light_elevation_deg_range: tuple[float, float] = (5.0, 45.0)
    light_distance_mm_range: tuple[float, float] = (700.0, 1500.0)
    light_irradiance_range: tuple[float, float] = (1.2, 2.6)
    environment_radiance_range: tuple[float, float] = (0.12, 0.35)
    light_tint: float = 0.08
    skin_tone_range: tuple[float, float] = (0.0, 1.0)
    albedo_variation: float = 0.08
    albedo_bumps: int = 8
    albedo_asymmetry: float = 0.15
    bald_probability: float = 0.15

    def __post_init__(self):
        _check_int(self.width, "width", 1)
        _check_int(self.height, "height", 1)
        _check_range(self.yaw_deg_range, "yaw_deg_range", low=-90.0, high=90.0)
        _check_range(self.pitch_deg_range, "pitch_deg_range", low=-90.0, high=90.0)
        _check_range(self.roll_deg_range, "roll_deg_range", low=-180.0, high=180.0)
        _check_range(self.distance_mm_range, "distance_mm_range", low=0.0, strict_low=True)
        _check_range(self.focal_factor_range, "focal_factor_range", low=0.0, strict_low=True)
        _check_number(self.offset_px, "offset_px")
        _check_number(self.margin_px, "margin_px")
        _check_int(self.spp, "spp", 1)
        _check_number(self.landmark_noise_px, "landmark_noise_px")
        _check_range(self.light_azimuth_deg_range, "light_azimuth_deg_range", low=-90.0, high=90.0)
        _check_range(self.light_elevation_deg_range, "light_elevation_deg_range", low=-90.0, high=90.0)
        _check_range(self.light_distance_mm_range, "light_distance_mm_range", low=0.0, strict_low=True)
        _check_range(self.light_irradiance_range, "light_irradiance_range", low=0.0)
        _check_range(self.environment_radiance_range, "environment_radiance_range", low=0.0)
        _check_number(self.light_tint, "light_tint", high=0.5)
        _check_range(self.skin_tone_range, "skin_tone_range", low=0.0, high=1.0)
        _check_number(self.albedo_variation, "albedo_variation", high=1.0)
        _check_int(self.albedo_bumps, "albedo_bumps", 0)
        _check_number(self.albedo_asymmetry, "albedo_asymmetry", high=1.0)
        _check_number(self.bald_probability, "bald_probability", high=1.0)


@dataclass(frozen=True)
class SyntheticPhoto:
    """One synthetic photo with its ground truth (``H``, ``W``: image size in pixels; ``V`` vertices).

    Attributes:
        image: ``(H, W, 3)`` uint8 sRGB, the photo.
        image_linear: ``(H, W, 3)`` float32 linear RGB before clipping and quantisation.
        landmarks2d: ``(68, 2)`` float64 iBUG-68 landmarks with detector-like noise, pixels (OpenCV,
            0-based: pixel centres at integer coordinates).
        landmarks2d_true: ``(68, 2)`` float64 the exact projections (jaw contour 0-16: the silhouette
            seen from the camera).
        gt_vertices: ``(V, 3)`` float64 the true head in rig space, mm, unposed.
        rotation: ``(3, 3)`` float64 head rotation; translation: ``(3,)`` float64 mm; the pose of
            :mod:`pipeline.photo.camera` (``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation``).
        focal: focal length, pixels (square pixels; principal point at the image centre).
        width, height: image size, pixels.
        albedo: ``(V, 3)`` float64 linear RGB albedo per vertex, in [0, 1].
        light: :class:`render.reference.ReferenceLight`, position in rig space (the render's world frame).
        name: e.g. ``"heldout_003"`` or ``"heldout_003_expr"``.
        yaw_deg, pitch_deg, roll_deg: the angles of ``rotation`` (:func:`head_rotation`), degrees.
        mask: ``(H, W)`` float32 coverage of the head (fraction of each pixel), in [0, 1].
    """

    image: np.ndarray
    image_linear: np.ndarray
    landmarks2d: np.ndarray
    landmarks2d_true: np.ndarray
    gt_vertices: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    focal: float
    width: int
    height: int
    albedo: np.ndarray
    light: ReferenceLight
    name: str
    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    mask: np.ndarray


# ----------------------------------------------------------------------------------------------------
# Colour
# ----------------------------------------------------------------------------------------------------

def _to_uint8(srgb: np.ndarray) -> np.ndarray:
    return np.floor(np.clip(srgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _palette(colours_srgb) -> np.ndarray:
    return srgb_to_linear(np.asarray(colours_srgb, np.float64) / 255.0)


def _skin_tone(t: float) -> np.ndarray:
    """``(3,)`` linear RGB skin albedo for a tone ``t`` in [0, 1] (0 very light, 1 very dark)."""
    tones = _palette(SKIN_TONES_SRGB)
    pos = float(np.clip(t, 0.0, 1.0)) * (len(tones) - 1)
    k = min(int(pos), len(tones) - 2)
    return tones[k] + (pos - k) * (tones[k + 1] - tones[k])


# ----------------------------------------------------------------------------------------------------
# Albedo
# ----------------------------------------------------------------------------------------------------

@cached_per_asset
def _neighbour_average(asset: RigAsset):
    """Sparse ``(V, V)`` row-stochastic matrix: the mean over each vertex and its mesh neighbours."""
    from scipy import sparse

    f = np.asarray(asset.faces, np.int64)
    n = len(asset.vertices)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0], np.arange(n)])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2], np.arange(n)])
    adjacency = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()
    adjacency.data[:] = 1.0  # duplicate edges (shared by two faces) count once
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    return sparse.diags(1.0 / degree) @ adjacency


def _smooth(field: np.ndarray, asset: RigAsset, iterations: int) -> np.ndarray:
    average = _neighbour_average(asset)
    for _ in range(iterations):
        field = average @ field
    return field


def _mirror_blend(field: np.ndarray, mirror: np.ndarray, asymmetry: float) -> np.ndarray:
    """The field's mirror-symmetric part plus ``asymmetry`` times its antisymmetric part."""
    symmetric = 0.5 * (field + field[mirror])
    return symmetric + asymmetry * (field - symmetric)


def _as_generator(rng, func: str) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and rng >= 0:
        return np.random.default_rng(int(rng))
    raise ValueError(f"{func}: rng must be a numpy Generator or a non-negative integer seed, got {rng!r}")


def synthesize_albedo(rng: np.random.Generator | int, asset: RigAsset | None = None, *,
                      settings: PhotoSettings = PhotoSettings()) -> np.ndarray:
    """A random, plausible per-vertex albedo for the rig's template topology.

    A skin tone from very light to very dark (:data:`SKIN_TONES_SRGB`), smooth low-frequency
    variation (Gaussian bumps over the template's vertex positions, almost left/right symmetric) and a
    faint per-vertex texture; redder, darker lips; eyebrows mixing skin and hair colour; a pinker nose,
    ears and cheeks, darker eyelids; hair colour on the scalp (or skin, for a bald head); eyes with a
    sclera and an iris colour; a dark mouth interior. Region boundaries are blended over a few mesh
    rings.

    Args:
        rng: ``np.random.Generator`` or integer seed; all randomness comes from it.
        asset: the rig template (regions, mirror map, faces); default :func:`rig.asset.load_asset`.
        settings: the albedo fields of :class:`PhotoSettings` are used.

    Returns:
        ``(V, 3)`` float64 linear RGB in [0, 1], deterministic given the generator's state.

    Example:
        >>> albedo = synthesize_albedo(0)
        >>> albedo.shape, bool(albedo.min() >= 0.0 and albedo.max() <= 1.0)
        ((4978, 3), True)
    """
    rng = _as_generator(rng, "synthesize_albedo")
    asset = load_asset() if asset is None else asset
    s = settings
    v = np.asarray(asset.vertices, np.float64)
    n = len(v)
    mirror = np.asarray(asset.mirror, np.int64)

    def region(*names: str) -> np.ndarray:
        present = [name for name in names if name in asset.region_names]
        return asset.region_mask(*present).astype(np.float64) if present else np.zeros(n)

    # Draws in a fixed order (the stream does not depend on the asset's regions).
    tone = float(rng.uniform(*s.skin_tone_range))
    redness, yellowness = rng.uniform(-0.05, 0.05, size=2)
    bump_centres = v[rng.integers(n, size=s.albedo_bumps)]
    bump_radii = rng.uniform(15.0, 45.0, size=s.albedo_bumps)
    bump_lum = rng.normal(0.0, s.albedo_variation, size=s.albedo_bumps)
    bump_red = rng.normal(0.0, 0.5 * s.albedo_variation, size=s.albedo_bumps)
    fine = rng.normal(0.0, 1.0, size=n)
    hair = _palette(HAIR_COLOURS_SRGB)[rng.integers(len(HAIR_COLOURS_SRGB))] * rng.uniform(0.85, 1.15, size=3)
    bald = bool(rng.random() < s.bald_probability)
    brow_mix = float(rng.uniform(0.45, 0.75))
    lip_red = float(rng.uniform(0.5, 0.7))
    lip_dark = float(rng.uniform(0.75, 0.95))
    blush = float(rng.uniform(0.0, 1.0))
    iris = _palette(IRIS_COLOURS_SRGB)[rng.integers(len(IRIS_COLOURS_SRGB))] * rng.uniform(0.8, 1.2)
    sclera = _palette([_SCLERA_SRGB])[0] * rng.uniform(0.85, 1.0)
    mouth = _MOUTH_INTERIOR_LINEAR * rng.uniform(0.7, 1.3)

    skin = _skin_tone(tone) * np.array([1.0 + redness, 1.0 + yellowness, 1.0 - yellowness])
    # Smooth variation: log-luminance and redness fields, mostly mirror-symmetric.
    d2 = ((v[:, None, :] - bump_centres[None]) ** 2).sum(-1)
    gauss = np.exp(-0.5 * d2 / bump_radii[None] ** 2)
    lum = _mirror_blend(gauss @ bump_lum, mirror, s.albedo_asymmetry)
    red = _mirror_blend(gauss @ bump_red, mirror, s.albedo_asymmetry)
    lum = lum + 0.25 * s.albedo_variation * _smooth(fine, asset, 1)  # faint, asymmetric skin texture
    colour = skin[None] * np.exp(lum)[:, None] * np.stack([1.0 + red, np.ones(n), 1.0 - red], axis=1)

    # Regional tints, blended over a few rings of neighbours.
    def tint(weight: np.ndarray, factor) -> np.ndarray:
        return 1.0 + weight[:, None] * (np.asarray(factor, np.float64)[None] - 1.0)

    colour = colour * tint(_smooth(region("cheeks"), asset, 2), (1.0 + 0.06 * blush, 1.0 - 0.03 * blush, 1.0 - 0.03 * blush))
    colour = colour * tint(_smooth(region("nose"), asset, 2), (1.04, 0.97, 0.97))
    colour = colour * tint(_smooth(region("ears"), asset, 2), (0.97, 0.88, 0.88))
    colour = colour * tint(_smooth(region("eyelids"), asset, 2), (0.90, 0.84, 0.86))
    colour = colour * tint(_smooth(region("neck"), asset, 3), (0.96, 0.96, 0.98))
    lips = _smooth(region("lips"), asset, 1)[:, None]
    lip_colour = colour * lip_dark * np.array([1.0, lip_red, lip_red + 0.05])
    colour = colour + lips * (lip_colour - colour)
    brows = _smooth(region("brows"), asset, 1)[:, None]
    # eyebrows are darker than the skin around them, whatever the hair colour (grey, blond)
    brow_colour = (1.0 - brow_mix) * colour + brow_mix * np.minimum(0.7 * hair[None], 0.5 * colour)
    colour = colour + brows * (brow_colour - colour)
    if not bald:
        scalp = _smooth(region("scalp"), asset, 3)[:, None]
        hair_colour = hair[None] * np.exp(0.5 * lum)[:, None]
        colour = colour + scalp * (hair_colour - colour)

    # Eyes and mouth: no blending (separate surfaces).
    eyes = region("eyeballs") > 0
    colour[eyes] = sclera
    for side in (1.0, -1.0):
        ids = np.flatnonzero(eyes & (np.sign(v[:, 0]) == side))
        if len(ids):
            front = v[ids[np.argmax(v[ids, 2])]]
            # a soft-edged disc: the eyeball's vertices are a few mm apart, a hard edge would look jagged
            r = np.linalg.norm(v[ids, :2] - front[None, :2], axis=1)
            weight = np.clip((_IRIS_RADIUS_MM + 1.5 - r) / 3.0, 0.0, 1.0)[:, None]
            colour[ids] = sclera + weight * (iris - sclera)
    colour[region("mouth_interior") > 0] = mouth
    colour[region("eye_pockets") > 0] = 0.5 * mouth  # hidden behind the eyeballs; dark where it shows
    colour[region("teeth") > 0] = _palette([_TEETH_SRGB])[0] * rng.uniform(0.85, 1.0)
    colour[region("tongue") > 0] = _palette([_TONGUE_SRGB])[0] * rng.uniform(0.8, 1.1)
    return np.clip(colour, 0.0, 1.0)


# ----------------------------------------------------------------------------------------------------
# Background
# ----------------------------------------------------------------------------------------------------

def _value_noise(rng: np.random.Generator, width: int, height: int, cells: int) -> np.ndarray:
    """``(H, W)`` smooth noise: a ``cells x cells`` grid of N(0, 1) values, bicubically upsampled."""
    import cv2

    grid = rng.normal(0.0, 1.0, size=(cells + 1, cells + 1)).astype(np.float32)
    return cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC).astype(np.float64)


def synthetic_background(rng: np.random.Generator | int, width: int, height: int) -> np.ndarray:
    """A random photo background: a smooth colour gradient with multi-scale texture and soft blobs.

    Args:
        rng: ``np.random.Generator`` or integer seed.
        width, height: image size, pixels.

    Returns:
        ``(H, W, 3)`` float32 linear RGB in [0, 1], deterministic given the generator's state.

    Raises:
        ValueError: non-positive size.

    Example:
        >>> synthetic_background(0, 64, 48).shape
        (48, 64, 3)
    """
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"synthetic_background: {name} must be an integer >= 1, got {value!r}")
    rng = _as_generator(rng, "synthetic_background")
    width, height = int(width), int(height)
    import colorsys

    hue, saturation, value = rng.uniform(0.0, 1.0), rng.uniform(0.05, 0.45), rng.uniform(0.3, 0.85)
    base = srgb_to_linear(np.array(colorsys.hsv_to_rgb(hue, saturation, value)))
    corners = base[None] * np.exp(rng.normal(0.0, 0.3, size=(4, 3)))  # top-left, top-right, bottom-left, bottom-right
    y = np.linspace(0.0, 1.0, height)[:, None, None]
    x = np.linspace(0.0, 1.0, width)[None, :, None]
    image = ((1 - y) * ((1 - x) * corners[0] + x * corners[1]) + y * ((1 - x) * corners[2] + x * corners[3]))

    texture = np.zeros((height, width))
    for octave, cells in enumerate((3, 7, 15, 31)):
        texture += 0.35 * 0.55 ** octave * _value_noise(rng, width, height, cells)
    colour_texture = 0.08 * np.stack([_value_noise(rng, width, height, 5) for _ in range(3)], axis=-1)
    image = image * np.exp(texture[..., None] + colour_texture)

    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    size = float(max(width, height))
    for _ in range(int(rng.integers(2, 6))):  # soft out-of-focus objects
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        radius = rng.uniform(0.05, 0.25) * size
        blob_colour = srgb_to_linear(rng.uniform(0.1, 0.9, size=3))
        weight = rng.uniform(0.3, 0.8) * np.exp(-0.5 * ((xx - cx) ** 2 + (yy - cy) ** 2) / radius ** 2)
        image = image + weight[..., None] * (blob_colour - image)
    return np.clip(image, 0.0, 1.0).astype(np.float32)


# ----------------------------------------------------------------------------------------------------
# Photos
# ----------------------------------------------------------------------------------------------------

def _draw(value, bounds, rng: np.random.Generator, name: str) -> float:
    draw = float(rng.uniform(*bounds))  # always drawn, so the stream does not depend on the overrides
    if value is None:
        return draw
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(value)):
        raise ValueError(f"simulate_photo: {name} must be a finite number, got {value!r}")
    return float(value)


def _tint(tau: float) -> np.ndarray:
    return np.array([1.0 + tau, 1.0, 1.0 - tau])


def simulate_photo(vertices, rng: np.random.Generator | int, settings: PhotoSettings = PhotoSettings(),
                   asset: RigAsset | None = None, *, yaw_deg: float | None = None, pitch_deg: float | None = None,
                   roll_deg: float | None = None, name: str = "", albedo: np.ndarray | None = None,
                   render: bool = True) -> SyntheticPhoto:
    """Photograph a head: random albedo, pose, camera, light and background, path-traced.

    The head is turned by :func:`head_rotation`, its rig origin put ``distance`` mm in front of the
    camera along the optical axis, and shifted sideways so that its face centre (the mean of its 68
    landmarks) is imaged ``offset`` pixels from the image centre. The point light sits in a cone in
    front of the face (azimuth/elevation relative to the direction from the face to the camera, so the
    light follows the camera, not the head). The render happens in rig space: the camera's extrinsics
    carry the pose.

    Args:
        vertices: ``(V, 3)`` the head in rig space (mm), in the template's vertex order (numpy or torch).
        rng: ``np.random.Generator`` or integer seed; all randomness comes from it, in a fixed order.
        settings: :class:`PhotoSettings`.
        asset: the rig template (faces, regions, landmark embedding); default :func:`rig.asset.load_asset`.
        yaw_deg, pitch_deg, roll_deg: fixed head angles (degrees) instead of random ones (the random
            ones are drawn anyway, so everything else stays the same).
        name: stored in :attr:`SyntheticPhoto.name`.
        albedo: ``(V, 3)`` linear RGB in [0, 1] to use instead of the random one (the random one is drawn
            anyway, so everything else stays the same): several photos of one person
            (:mod:`pipeline.synthetic.multiview`).
        render: False: no path tracing (``image`` and ``image_linear`` are black, ``mask`` zeros); the pose,
            camera and landmarks are the same as with it.

    Returns:
        :class:`SyntheticPhoto`.

    Raises:
        ValueError: ``vertices`` not ``(V, 3)`` with the template's ``V`` or not finite; non-finite
            angles; a pose/camera that puts a landmark behind the camera or less than
            ``settings.margin_px`` from the image border (the face must be fully inside the image).

    Example:
        >>> from pipeline.synthetic.population import population_split
        >>> head = population_split("heldout", 0).vertices[0]
        >>> photo = simulate_photo(head, 0, PhotoSettings(width=96, height=96, offset_px=4.0, spp=4))
        >>> photo.image.shape, photo.landmarks2d.shape
        ((96, 96, 3), (68, 2))
    """
    func = "simulate_photo"
    asset = load_asset() if asset is None else asset
    v = np.asarray(vertices.detach().cpu().numpy() if isinstance(vertices, torch.Tensor) else vertices, np.float64)
    if v.shape != asset.vertices.shape:
        raise ValueError(f"{func}: expected vertices of shape {asset.vertices.shape} (the template's topology), "
                         f"got {v.shape}")
    if not np.isfinite(v).all():
        raise ValueError(f"{func}: vertices must be finite")
    if not isinstance(settings, PhotoSettings):
        raise TypeError(f"{func}: expected settings a PhotoSettings, got {type(settings).__name__}")
    rng = _as_generator(rng, func)
    s = settings
    width, height = int(s.width), int(s.height)

    # Random draws, in a fixed order.
    yaw = _draw(yaw_deg, s.yaw_deg_range, rng, "yaw_deg")
    pitch = _draw(pitch_deg, s.pitch_deg_range, rng, "pitch_deg")
    roll = _draw(roll_deg, s.roll_deg_range, rng, "roll_deg")
    distance = float(rng.uniform(*s.distance_mm_range))
    focal = float(rng.uniform(*s.focal_factor_range)) * max(width, height)
    offset = rng.uniform(-s.offset_px, s.offset_px, size=2)
    azimuth = math.radians(rng.uniform(*s.light_azimuth_deg_range))
    elevation = math.radians(rng.uniform(*s.light_elevation_deg_range))
    light_distance = float(rng.uniform(*s.light_distance_mm_range))
    irradiance = float(rng.uniform(*s.light_irradiance_range))
    key_tint = _tint(rng.uniform(-s.light_tint, s.light_tint))
    environment = float(rng.uniform(*s.environment_radiance_range))
    environment_tint = _tint(rng.uniform(-s.light_tint, s.light_tint))
    drawn_albedo = synthesize_albedo(rng, asset, settings=s)
    if albedo is None:
        albedo = drawn_albedo
    else:
        albedo = np.asarray(albedo, np.float64)
        if albedo.shape != v.shape or not np.isfinite(albedo).all() or albedo.min() < 0 or albedo.max() > 1:
            raise ValueError(f"{func}: albedo must be {v.shape} linear RGB within [0, 1], got shape {albedo.shape}")
    background = synthetic_background(rng, width, height)
    render_seed = int(rng.integers(0, 2**31 - 1))
    noise = rng.normal(0.0, 1.0, size=(68, 2)) * s.landmark_noise_px

    # Pose: the face centre is imaged at the image centre + offset.
    rotation = head_rotation(yaw, pitch, roll)
    embedding = ibug68_embedding(asset)
    landmarks3d = landmark_positions(v, embedding, asset.faces)[0]
    face_centre = RIG_TO_OPENCV @ rotation @ landmarks3d.mean(axis=0)  # camera axes, before translation
    depth = face_centre[2] + distance
    if depth <= 0:
        raise ValueError(f"{func}: distance {distance:.1f} mm puts the face centre behind the camera")
    translation = np.array([offset[0] * depth / focal - face_centre[0], offset[1] * depth / focal - face_centre[1],
                            distance])
    camera = make_camera(width, height, focal, None, rotation, translation, dtype=torch.float64)

    # Landmarks: static embedding 17-67, the jaw contour 0-16 as the camera sees it.
    centre_rig = camera_center_in_rig(rotation, translation)
    landmarks3d[:17] = contour_landmarks(torch.as_tensor(v), asset.faces, centre_rig, asset).numpy()
    cam_points = landmarks3d @ (RIG_TO_OPENCV @ rotation).T + translation
    if (cam_points[:, 2] <= 1.0).any():
        raise ValueError(f"{func}: landmarks {np.flatnonzero(cam_points[:, 2] <= 1.0).tolist()} lie behind the "
                         f"camera (distance {distance:.1f} mm)")
    true2d = camera.project(torch.as_tensor(landmarks3d)[None])[0].numpy().astype(np.float64)
    m = s.margin_px
    outside = (true2d[:, 0] < m) | (true2d[:, 0] > width - 1 - m) | (true2d[:, 1] < m) | (true2d[:, 1] > height - 1 - m)
    if outside.any():
        raise ValueError(
            f"{func}: the face does not fit in the {width}x{height} image: landmarks {np.flatnonzero(outside).tolist()} "
            f"lie outside it or within {m} px of its border (focal {focal:.1f} px, distance {distance:.1f} mm, "
            f"offset {np.round(offset, 1).tolist()} px, yaw/pitch/roll {yaw:.1f}/{pitch:.1f}/{roll:.1f} deg); "
            f"reduce focal_factor_range or offset_px, or increase distance_mm_range")

    # Light: a cone in front of/above the face, relative to the camera; converted to rig space.
    face_centre_cam = face_centre + translation
    direction_cam = np.array([math.sin(azimuth) * math.cos(elevation), -math.sin(elevation),
                              -math.cos(azimuth) * math.cos(elevation)])  # camera axes: y down, z away
    light_cam = face_centre_cam + light_distance * direction_cam
    light_rig = rotation.T @ RIG_TO_OPENCV.T @ (light_cam - translation)
    light = ReferenceLight(position=light_rig, intensity=irradiance * light_distance ** 2 * key_tint,
                           environment=environment * environment_tint)

    if not render:
        image_linear = np.zeros((height, width, 3), np.float32)
        return SyntheticPhoto(
            image=_to_uint8(image_linear), image_linear=image_linear, landmarks2d=true2d + noise,
            landmarks2d_true=true2d, gt_vertices=v, rotation=rotation, translation=translation, focal=focal,
            width=width, height=height, albedo=albedo, light=light, name=str(name), yaw_deg=yaw, pitch_deg=pitch,
            roll_deg=roll, mask=np.zeros((height, width), np.float32))
    start = time.perf_counter()
    rendered = render_reference(v, asset.faces, albedo, camera, light, spp=s.spp, seed=render_seed,
                                background=background)
    logger.debug("%s: rendered %dx%d at %d spp in %.2f s", func, width, height, s.spp, time.perf_counter() - start)
    image_linear = rendered.image
    return SyntheticPhoto(
        image=_to_uint8(linear_to_srgb(image_linear)), image_linear=image_linear, landmarks2d=true2d + noise,
        landmarks2d_true=true2d, gt_vertices=v, rotation=rotation, translation=translation, focal=focal,
        width=width, height=height, albedo=albedo, light=light, name=str(name), yaw_deg=yaw, pitch_deg=pitch,
        roll_deg=roll, mask=rendered.mask)


def synthetic_photo(index: int, *, expressive: bool = False, seed: int = 0,
                    settings: PhotoSettings = PhotoSettings()) -> SyntheticPhoto:
    """A photo of held-out head ``index`` (never used in training).

    Args:
        index: head index in ``pipeline.synthetic.population.population_split("heldout", 0)``, 0..99.
        expressive: photograph the head with its random expression
            (``pipeline.synthetic.expressive.expressive_split("heldout", 0)``) instead of the neutral head.
        seed: photo seed, >= 0; the random generator is seeded from ``(seed, index, expressive)``, so
            each photo has its own stream and does not depend on which other photos are made.
        settings: :class:`PhotoSettings`.

    Returns:
        :class:`SyntheticPhoto` named ``heldout_{index:03d}`` (plus ``_expr`` when expressive).

    Raises:
        ValueError: index out of range, negative seed, or :func:`simulate_photo`'s errors.
    """
    from pipeline.synthetic.population import SPLIT_SIZES, population_split

    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"synthetic_photo: seed must be a non-negative integer, got {seed!r}")
    n_heads = SPLIT_SIZES["heldout"]
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < n_heads:
        raise ValueError(f"synthetic_photo: index must be an integer in [0, {n_heads - 1}], got {index!r}")
    index = int(index)
    population = population_split("heldout", 0, first=index + 1)  # the same heads, without making all 100
    if expressive:
        from pipeline.synthetic.expressive import expressive_split

        vertices = expressive_split("heldout", 0, n=index + 1).vertices[index]
    else:
        vertices = population.vertices[index]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), index, int(bool(expressive)), _PHOTO_STREAM]))
    name = f"{population.names[index]}{'_expr' if expressive else ''}"
    return simulate_photo(vertices, rng, settings, name=name)


def write_synthetic_photo(photo: SyntheticPhoto, out_dir: str | Path, asset: RigAsset | None = None) -> Path:
    """Write a photo and its ground truth into ``out_dir`` (created if needed; files are overwritten).

    Files: ``photo.png`` (the sRGB image), ``landmarks.pts`` (the noisy landmarks, iBUG ``.pts``,
    :func:`landmarks.formats.write_landmarks`), ``truth.ply`` (the true mesh in rig space, mm, with the
    template's faces) and ``truth.json`` (name, image size, focal, principal point, pose, angles, light
    in rig space, the exact landmarks).

    Args:
        photo: :class:`SyntheticPhoto`.
        out_dir: the folder.
        asset: the template whose faces the mesh uses (default :func:`rig.asset.load_asset`).

    Returns:
        ``out_dir`` as a ``Path``.

    Raises:
        ValueError: the photo's mesh does not have the template's vertex count.
    """
    import trimesh
    from PIL import Image

    from landmarks.formats import write_landmarks

    asset = load_asset() if asset is None else asset
    if photo.gt_vertices.shape != asset.vertices.shape:
        raise ValueError(f"write_synthetic_photo: expected gt_vertices of shape {asset.vertices.shape}, "
                         f"got {photo.gt_vertices.shape}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.asarray(photo.image, np.uint8)).save(out / "photo.png")
    write_landmarks(out / "landmarks.pts", photo.landmarks2d)
    mesh = trimesh.Trimesh(vertices=photo.gt_vertices, faces=asset.faces, process=False)
    mesh.export(out / "truth.ply")
    truth = {
        "name": photo.name,
        "width": int(photo.width),
        "height": int(photo.height),
        "focal": float(photo.focal),
        "principal": [(photo.width - 1) / 2.0, (photo.height - 1) / 2.0],
        "pose_convention": "x_cam = diag(1, -1, -1) @ rotation @ x_rig + translation (OpenCV camera, mm)",
        "rotation": np.asarray(photo.rotation, float).tolist(),
        "translation": np.asarray(photo.translation, float).tolist(),
        "yaw_deg": float(photo.yaw_deg),
        "pitch_deg": float(photo.pitch_deg),
        "roll_deg": float(photo.roll_deg),
        "light": {**photo.light.to_dict(), "frame": "rig"},
        "landmarks2d_true": np.asarray(photo.landmarks2d_true, float).tolist(),
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
    return out
