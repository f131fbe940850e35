"""Photographing a head: random pose, camera, light, albedo and background, the true landmarks, path-traced
(:func:`simulate_photo`), the photo of a held-out head (:func:`synthetic_photo`), and any landmark layout's true
points on a photo (:func:`true_layout_points`)."""

from __future__ import annotations

import logging
import math
import time
import zlib
from dataclasses import dataclass

import numpy as np
import torch

from landmarks.ibug68.contour import contour_landmarks
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.positions import landmark_positions
from landmarks.loss import project_points
from pipeline.camera import RIG_TO_OPENCV, camera_center_in_rig, make_camera
from pipeline.colour import linear_to_srgb
from pipeline.synthetic.expressive import expressive_split
from pipeline.synthetic.photos.albedo import synthesize_albedo
from pipeline.synthetic.photos.background import synthetic_background
from pipeline.synthetic.photos.settings import PhotoSettings, SyntheticPhoto, _as_generator
from pipeline.synthetic.population import SPLIT_SIZES, population_split
from render.reference import ReferenceLight, render_reference
from rig.asset import RigAsset, load_asset
from rig.errors import InputError
from rig.geometry import head_rotation

logger = logging.getLogger(__name__)

_PHOTO_STREAM = zlib.crc32(b"synthetic-photo")


def _to_uint8(srgb: np.ndarray) -> np.ndarray:
    return np.floor(np.clip(srgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _draw(value, bounds, rng: np.random.Generator, name: str) -> float:
    draw = float(rng.uniform(*bounds))  # always drawn, so the stream does not depend on the overrides
    if value is None:
        return draw
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not math.isfinite(float(value))
    ):
        raise InputError(f"simulate_photo: {name} must be a finite number, got {value!r}")
    return float(value)


def _tint(tau: float) -> np.ndarray:
    return np.array([1.0 + tau, 1.0, 1.0 - tau])


def simulate_photo(
    vertices,
    rng: np.random.Generator | int,
    settings: PhotoSettings = PhotoSettings(),
    asset: RigAsset | None = None,
    *,
    yaw_deg: float | None = None,
    pitch_deg: float | None = None,
    roll_deg: float | None = None,
    name: str = "",
    albedo: np.ndarray | None = None,
    render: bool = True,
) -> SyntheticPhoto:
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
    v = _checked_vertices(vertices, asset)
    if not isinstance(settings, PhotoSettings):
        raise TypeError(f"{func}: expected settings a PhotoSettings, got {type(settings).__name__}")
    rng = _as_generator(rng, func)
    width, height = int(settings.width), int(settings.height)
    d = _draws(rng, settings, asset, v.shape, (yaw_deg, pitch_deg, roll_deg), albedo)
    rotation, translation, face_centre, landmarks3d = _pose(v, asset, d)
    camera = make_camera(width, height, d.focal, None, rotation, translation, dtype=torch.float64)
    true2d = _true_landmarks(v, asset, d, rotation, translation, landmarks3d, camera, settings)
    light = _light(d, rotation, translation, face_centre)
    image_linear, image, mask = _images(v, asset, d, camera, light, settings, render)
    return SyntheticPhoto(
        image=image,
        image_linear=image_linear,
        landmarks2d=true2d + d.noise,
        landmarks2d_true=true2d,
        gt_vertices=v,
        rotation=rotation,
        translation=translation,
        focal=d.focal,
        width=width,
        height=height,
        albedo=d.albedo,
        light=light,
        name=str(name),
        yaw_deg=d.yaw,
        pitch_deg=d.pitch,
        roll_deg=d.roll,
        mask=mask,
    )


def true_layout_points(photo: SyntheticPhoto, layout, faces: np.ndarray) -> np.ndarray:
    """``(N, 2)`` float64 pixels (OpenCV) of a landmark layout's points on the true head of ``photo``, projected
    exactly (no noise): each point's embedding on ``photo.gt_vertices``, a sliding outline picked on the silhouette
    seen from the photo's camera (:meth:`landmarks.layout.LandmarkLayout.points3d`, e.g. MediaPipe's 478)."""
    v = torch.as_tensor(photo.gt_vertices, dtype=torch.float64)
    points = layout.points3d(v, faces, camera_center_in_rig(photo.rotation, photo.translation))
    camera = make_camera(
        photo.width, photo.height, photo.focal, rotation=photo.rotation, translation=photo.translation, dtype=v.dtype
    )
    return project_points(points[None], camera)[0].numpy()


def _checked_vertices(vertices, asset: RigAsset) -> np.ndarray:
    """``(V, 3)`` float64 finite vertices in the template's topology, or ValueError."""
    func = "simulate_photo"
    v = np.asarray(vertices.detach().cpu().numpy() if isinstance(vertices, torch.Tensor) else vertices, np.float64)
    if v.shape != asset.vertices.shape:
        raise InputError(
            f"{func}: expected vertices of shape {asset.vertices.shape} (the template's topology), got {v.shape}"
        )
    if not np.isfinite(v).all():
        raise InputError(f"{func}: vertices must be finite")
    return v


@dataclass(frozen=True)
class _Draws:
    """The random draws of one photo (units as in :class:`PhotoSettings`; angles of the light in radians)."""

    yaw: float
    pitch: float
    roll: float
    distance: float
    focal: float
    offset: np.ndarray  # (2,) px
    azimuth: float
    elevation: float
    light_distance: float
    irradiance: float
    key_tint: np.ndarray
    environment: float
    environment_tint: np.ndarray
    albedo: np.ndarray  # (V, 3) the given albedo, else the drawn one
    background: np.ndarray
    render_seed: int
    noise: np.ndarray  # (68, 2) px


def _draws(rng: np.random.Generator, s: PhotoSettings, asset: RigAsset, shape, angles, albedo) -> _Draws:
    """Every random draw of :func:`simulate_photo`, in a fixed order (the fixed ``angles``, yaw/pitch/roll
    or None, and ``albedo`` replace their draws, which are made anyway)."""
    func = "simulate_photo"
    width, height = int(s.width), int(s.height)
    yaw_deg, pitch_deg, roll_deg = angles
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
        if albedo.shape != shape or not np.isfinite(albedo).all() or albedo.min() < 0 or albedo.max() > 1:
            raise InputError(f"{func}: albedo must be {shape} linear RGB within [0, 1], got shape {albedo.shape}")
    background = synthetic_background(rng, width, height)
    render_seed = int(rng.integers(0, 2**31 - 1))
    noise = rng.normal(0.0, 1.0, size=(68, 2)) * s.landmark_noise_px
    return _Draws(
        yaw=yaw,
        pitch=pitch,
        roll=roll,
        distance=distance,
        focal=focal,
        offset=offset,
        azimuth=azimuth,
        elevation=elevation,
        light_distance=light_distance,
        irradiance=irradiance,
        key_tint=key_tint,
        environment=environment,
        environment_tint=environment_tint,
        albedo=albedo,
        background=background,
        render_seed=render_seed,
        noise=noise,
    )


def _pose(v: np.ndarray, asset: RigAsset, d: _Draws) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The head pose that images the face centre (the mean of its 68 static landmarks) at the image centre
    plus the drawn offset: ``(rotation (3, 3), translation (3,) mm, face centre (3,) in camera axes before
    the translation, the static landmarks (68, 3) rig mm)``."""
    rotation = head_rotation(d.yaw, d.pitch, d.roll)
    embedding = ibug68_embedding(asset)
    landmarks3d = landmark_positions(v, embedding, asset.faces)[0]
    face_centre = RIG_TO_OPENCV @ rotation @ landmarks3d.mean(axis=0)  # camera axes, before translation
    depth = face_centre[2] + d.distance
    if depth <= 0:
        raise InputError(f"simulate_photo: distance {d.distance:.1f} mm puts the face centre behind the camera")
    offset, focal = d.offset, d.focal
    translation = np.array(
        [offset[0] * depth / focal - face_centre[0], offset[1] * depth / focal - face_centre[1], d.distance]
    )
    return rotation, translation, face_centre, landmarks3d


def _true_landmarks(
    v: np.ndarray,
    asset: RigAsset,
    d: _Draws,
    rotation: np.ndarray,
    translation: np.ndarray,
    landmarks3d: np.ndarray,
    camera,
    s: PhotoSettings,
) -> np.ndarray:
    """``(68, 2)`` px the exact landmarks: the static embedding 17-67, the jaw contour 0-16 as the camera sees
    it; ValueError when one lies behind the camera or within ``margin_px`` of the image border."""
    func = "simulate_photo"
    width, height = int(s.width), int(s.height)
    centre_rig = camera_center_in_rig(rotation, translation)
    landmarks3d[:17] = contour_landmarks(torch.as_tensor(v), asset.faces, centre_rig, asset).numpy()
    cam_points = landmarks3d @ (RIG_TO_OPENCV @ rotation).T + translation
    if (cam_points[:, 2] <= 1.0).any():
        raise InputError(
            f"{func}: landmarks {np.flatnonzero(cam_points[:, 2] <= 1.0).tolist()} lie behind the "
            f"camera (distance {d.distance:.1f} mm)"
        )
    true2d = camera.project(torch.as_tensor(landmarks3d)[None])[0].numpy().astype(np.float64)
    m = s.margin_px
    outside = (true2d[:, 0] < m) | (true2d[:, 0] > width - 1 - m) | (true2d[:, 1] < m) | (true2d[:, 1] > height - 1 - m)
    if outside.any():
        raise InputError(
            f"{func}: the face does not fit in the {width}x{height} image: "
            f"landmarks {np.flatnonzero(outside).tolist()} "
            f"lie outside it or within {m} px of its border (focal {d.focal:.1f} px, distance {d.distance:.1f} mm, "
            f"offset {np.round(d.offset, 1).tolist()} px, yaw/pitch/roll {d.yaw:.1f}/{d.pitch:.1f}/{d.roll:.1f} deg); "
            f"reduce focal_factor_range or offset_px, or increase distance_mm_range"
        )
    return true2d


def _light(d: _Draws, rotation: np.ndarray, translation: np.ndarray, face_centre: np.ndarray) -> ReferenceLight:
    """The point light in a cone in front of/above the face, relative to the camera; converted to rig space."""
    face_centre_cam = face_centre + translation
    azimuth, elevation = d.azimuth, d.elevation
    direction_cam = np.array(
        [math.sin(azimuth) * math.cos(elevation), -math.sin(elevation), -math.cos(azimuth) * math.cos(elevation)]
    )  # camera axes: y down, z away
    light_cam = face_centre_cam + d.light_distance * direction_cam
    light_rig = rotation.T @ RIG_TO_OPENCV.T @ (light_cam - translation)
    return ReferenceLight(
        position=light_rig,
        intensity=d.irradiance * d.light_distance**2 * d.key_tint,
        environment=d.environment * d.environment_tint,
    )


def _images(
    v: np.ndarray, asset: RigAsset, d: _Draws, camera, light: ReferenceLight, s: PhotoSettings, render: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(image_linear (H, W, 3) float32, image (H, W, 3) uint8 sRGB, mask (H, W) float32)``: path-traced, or
    black with an empty mask when not ``render``."""
    width, height = int(s.width), int(s.height)
    if not render:
        image_linear = np.zeros((height, width, 3), np.float32)
        return image_linear, _to_uint8(image_linear), np.zeros((height, width), np.float32)
    start = time.perf_counter()
    rendered = render_reference(
        v, asset.faces, d.albedo, camera, light, spp=s.spp, seed=d.render_seed, background=d.background
    )
    logger.debug(
        "%s: rendered %dx%d at %d spp in %.2f s", "simulate_photo", width, height, s.spp, time.perf_counter() - start
    )
    return rendered.image, _to_uint8(linear_to_srgb(rendered.image)), rendered.mask


def synthetic_photo(
    index: int, *, expressive: bool = False, seed: int = 0, settings: PhotoSettings = PhotoSettings()
) -> SyntheticPhoto:
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
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"synthetic_photo: seed must be a non-negative integer, got {seed!r}")
    n_heads = SPLIT_SIZES["heldout"]
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < n_heads:
        raise InputError(f"synthetic_photo: index must be an integer in [0, {n_heads - 1}], got {index!r}")
    index = int(index)
    population = population_split("heldout", 0, first=index + 1)  # the same heads, without making all 100
    if expressive:
        vertices = expressive_split("heldout", 0, n=index + 1).vertices[index]
    else:
        vertices = population.vertices[index]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), index, int(bool(expressive)), _PHOTO_STREAM]))
    name = f"{population.names[index]}{'_expr' if expressive else ''}"
    return simulate_photo(vertices, rng, settings, name=name)


__all__ = ["simulate_photo", "synthetic_photo"]
