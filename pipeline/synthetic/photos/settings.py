"""The distributions of a synthetic photo (:class:`PhotoSettings`) and the photo with its ground truth
(:class:`SyntheticPhoto`); frames and colours: :mod:`pipeline.synthetic.photos`."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from render.reference import ReferenceLight
from rig.errors import InputError


def _check_range(
    value, name: str, *, low: float | None = None, high: float | None = None, strict_low: bool = False
) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"PhotoSettings: {name} must be a (low, high) pair of numbers, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise InputError(f"PhotoSettings: {name} must be a finite (low, high) pair with low <= high, got {value!r}")
    if low is not None and (lo < low or (strict_low and lo <= low)):
        raise InputError(
            f"PhotoSettings: {name} must lie {'above' if strict_low else 'at or above'} {low}, got {value!r}"
        )
    if high is not None and hi > high:
        raise InputError(f"PhotoSettings: {name} must lie at or below {high}, got {value!r}")
    return lo, hi


def _check_number(value, name: str, *, low: float = 0.0, high: float | None = None) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not math.isfinite(float(value))
        or value < low
        or (high is not None and value > high)
    ):
        bound = f"in [{low}, {high}]" if high is not None else f">= {low}"
        raise InputError(f"PhotoSettings: {name} must be a finite number {bound}, got {value!r}")
    return float(value)


def _check_int(value, name: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise InputError(f"PhotoSettings: {name} must be an integer >= {low}, got {value!r}")
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
            to a short tele (:func:`pipeline.camera.default_focal` assumes 1.4).
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
            :mod:`pipeline.camera` (``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation``).
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


def focal_settings(focal_factor: float, base: PhotoSettings | None = None) -> PhotoSettings:
    """``base`` (default :class:`PhotoSettings`) at one focal length over the image side, the camera's distance
    scaled with it so the face keeps the size it has at the default 1.2-1.7 x range and 450-650 mm."""
    base = base or PhotoSettings()
    k = float(focal_factor) / 1.45
    return replace(
        base,
        focal_factor_range=(float(focal_factor), float(focal_factor)),
        distance_mm_range=(base.distance_mm_range[0] * k, base.distance_mm_range[1] * k),
    )


def _as_generator(rng, func: str) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and rng >= 0:
        return np.random.default_rng(int(rng))
    raise InputError(f"{func}: rng must be a numpy Generator or a non-negative integer seed, got {rng!r}")


__all__ = ["PhotoSettings", "SyntheticPhoto", "focal_settings"]
