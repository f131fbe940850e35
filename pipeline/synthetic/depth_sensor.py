"""Time-of-flight sensor model of :func:`pipeline.synthetic.scans.simulate_scan`, applied to a rendered depth image.

Dropout at depth discontinuities and grazing angles, elliptical holes, lateral jitter and axial noise
growing with the square of the depth, and flying pixels / stray points. Arrays are in the OpenCV camera
frame of :mod:`pipeline.synthetic.scans` (mm); images are ``(H, W)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.geometry import face_normals

__all__ = ["HIRES_CAMERA", "DepthCamera", "ScanSettings", "add_outliers", "back_project", "drop_pixels"]


@dataclass(frozen=True)
class DepthCamera:
    """Pinhole depth camera (Azure Kinect NFOV-binned-like), OpenCV convention.

    Attributes:
        width, height: image size, pixels.
        fx, fy: focal lengths, pixels.
        cx, cy: principal point, pixels.
    """

    width: int = 320
    height: int = 288
    fx: float = 252.0
    fy: float = 252.0
    cx: float = 160.0
    cy: float = 144.0

    @property
    def focal(self) -> np.ndarray:
        """``(2,)`` ``(fx, fy)``, pixels (for :func:`pipeline.camera.camera_points_to_pixels`)."""
        return np.array([self.fx, self.fy])

    @property
    def centre(self) -> np.ndarray:
        """``(2,)`` the principal point ``(cx, cy)``, pixels."""
        return np.array([self.cx, self.cy])


HIRES_CAMERA = DepthCamera(640, 576, 504.0, 504.0, 320.0, 288.0)
"""Twice the default resolution (``jnr data scan --hires``: ~15-20k points on a head instead of ~4k)."""


@dataclass(frozen=True)
class ScanSettings:
    """Placement and sensor model of :func:`simulate_scan`.

    Attributes:
        distance_mm: camera to the frontmost point of the head, along world Z, mm.
        yaw_deg_range, pitch_deg_range, roll_deg_range: head rotation ranges (about world Y, X, Z), degrees.
        max_offset_mm: the head's translation is uniform in ``[-max_offset_mm, max_offset_mm]`` per axis.
        noise_mm_at_1m: axial noise sigma at 1 m; sigma(z) = max(noise_mm_at_1m (z / 1000)^2, noise_floor_mm).
        noise_floor_mm: lower bound of the axial noise sigma, mm.
        lateral_jitter_px: sigma of the per-pixel jitter of the ray (pixels).
        hole_fraction: ``(low, high)``: the fraction of the face's pixels dropped by random elliptical holes
            is drawn uniformly from this range.
        edge_dropout: drop pixels next to depth discontinuities (> ``edge_jump_mm``) or the image's empty
            background, and pixels seen at grazing angles (> ``grazing_deg``).
        edge_jump_mm, grazing_deg: thresholds of ``edge_dropout``.
        outlier_fraction: outliers added, as a fraction of the valid points (half flying pixels behind
            valid pixels, half uniform in the head's bounding box grown by 30 mm).
        normals: estimate per-point normals from the depth image.
    """

    distance_mm: float = 600.0
    yaw_deg_range: tuple[float, float] = (-45.0, 45.0)
    pitch_deg_range: tuple[float, float] = (-15.0, 15.0)
    roll_deg_range: tuple[float, float] = (-10.0, 10.0)
    max_offset_mm: float = 300.0
    noise_mm_at_1m: float = 3.0
    noise_floor_mm: float = 0.5
    lateral_jitter_px: float = 0.3
    hole_fraction: tuple[float, float] = (0.05, 0.3)
    edge_dropout: bool = True
    edge_jump_mm: float = 15.0
    grazing_deg: float = 75.0
    outlier_fraction: float = 0.01
    normals: bool = True


def _rays(camera: DepthCamera, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Camera-frame rays with ``z = 1`` through pixel coordinates ``u, v``, ``(..., 3)``."""
    return np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u, dtype=float)], -1)


def _edge_mask(depth: np.ndarray, jump_mm: float) -> np.ndarray:
    """Pixels with a 4-neighbour that is empty or deeper/shallower by more than ``jump_mm``."""
    pad = np.pad(depth, 1, constant_values=np.inf)
    centre = pad[1:-1, 1:-1]
    bad = np.zeros(depth.shape, bool)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        nb = pad[dy : dy + depth.shape[0], dx : dx + depth.shape[1]]
        with np.errstate(invalid="ignore"):
            bad |= ~np.isfinite(nb) | (np.abs(nb - centre) > jump_mm)
    return bad & np.isfinite(depth)


def _holes(valid: np.ndarray, target: float, rng: np.random.Generator) -> np.ndarray:
    """Random elliptical holes over ``valid`` pixels until about ``target`` of them are dropped."""
    holes = np.zeros(valid.shape, bool)
    n_valid = int(valid.sum())
    if target <= 0.0 or n_valid == 0:
        return holes
    vv, uu = np.mgrid[0 : valid.shape[0], 0 : valid.shape[1]]
    ys, xs = np.nonzero(valid)
    for _ in range(40):
        missing = target * n_valid - (holes & valid).sum()
        if missing <= 0.02 * target * n_valid:
            break
        i = rng.integers(len(ys))
        area = missing * rng.uniform(0.4, 1.0)
        ratio = rng.uniform(1.0, 2.5)
        a = np.sqrt(area * ratio / np.pi)
        b = a / ratio
        th = rng.uniform(0.0, np.pi)
        du, dv = uu - xs[i], vv - ys[i]
        p = du * np.cos(th) + dv * np.sin(th)
        q = -du * np.sin(th) + dv * np.cos(th)
        holes |= (p / a) ** 2 + (q / b) ** 2 <= 1.0
    return holes


def _depth_normals(points_img: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per-pixel normals ``(H, W, 3)`` (camera frame) from central (or one-sided) differences of the
    back-projected image, oriented towards the camera; zero where no neighbours are valid."""
    p = np.where(valid[..., None], points_img, np.nan)
    pad = np.pad(p, ((1, 1), (1, 1), (0, 0)), constant_values=np.nan)

    def diff(a, b):
        d = a - b
        return d

    c = pad[1:-1, 1:-1]
    right, left = pad[1:-1, 2:], pad[1:-1, :-2]
    down, up = pad[2:, 1:-1], pad[:-2, 1:-1]
    du = diff(right, left)
    du = np.where(np.isnan(du), diff(right, c), du)
    du = np.where(np.isnan(du), diff(c, left), du)
    dv = diff(down, up)
    dv = np.where(np.isnan(dv), diff(down, c), dv)
    dv = np.where(np.isnan(dv), diff(c, up), dv)
    n = np.cross(du, dv)
    n = np.where(np.isnan(n), 0.0, n)
    flip = (n * np.nan_to_num(c)).sum(-1) > 0  # towards the camera: n . p < 0
    n = np.where(flip[..., None], -n, n)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(norm > 0, n / np.maximum(norm, 1e-12), 0.0)


def drop_pixels(
    cam: np.ndarray,
    f: np.ndarray,
    depth: np.ndarray,
    face_id: np.ndarray,
    camera: DepthCamera,
    s: ScanSettings,
    rng: np.random.Generator,
) -> tuple[np.ndarray, float]:
    """``(H, W)`` pixels kept after edge / grazing dropout and (drawn) random holes, and the holes' share of them."""
    rendered = np.isfinite(depth)
    valid = rendered.copy()
    if s.edge_dropout:
        vv, uu = np.nonzero(rendered)
        n = face_normals(cam, f[face_id[vv, uu]])
        ray = _rays(camera, uu.astype(float), vv.astype(float))
        cosang = np.abs((n * ray).sum(1)) / np.maximum(np.linalg.norm(n, axis=1) * np.linalg.norm(ray, axis=1), 1e-12)
        grazing = np.zeros_like(rendered)
        grazing[vv, uu] = cosang < np.cos(np.radians(s.grazing_deg))
        valid &= ~(grazing | _edge_mask(depth, s.edge_jump_mm))
    lo_h, hi_h = s.hole_fraction
    target = float(rng.uniform(lo_h, hi_h))
    holes = _holes(rendered, target, rng)
    hole_fraction = float((holes & rendered).sum() / max(rendered.sum(), 1))
    valid &= ~holes
    return valid, hole_fraction


def back_project(
    depth: np.ndarray, valid: np.ndarray, camera: DepthCamera, s: ScanSettings, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Ray jitter, then axial noise (drawn in that order): noisy ``(H, W)`` depth, ``(N, 3)`` points and normals, mm."""
    h, w = depth.shape
    vv, uu = np.mgrid[0:h, 0:w].astype(float)
    if s.lateral_jitter_px > 0:
        uu = uu + rng.normal(0.0, s.lateral_jitter_px, size=uu.shape)
        vv = vv + rng.normal(0.0, s.lateral_jitter_px, size=vv.shape)
    z = np.where(valid, depth, np.inf)
    sigma = np.maximum(s.noise_mm_at_1m * (np.where(valid, depth, 0.0) / 1000.0) ** 2, s.noise_floor_mm)
    noise = rng.normal(0.0, 1.0, size=z.shape) * sigma
    z = np.where(valid, z + noise, np.inf)
    points_img = _rays(camera, uu, vv) * np.where(valid, z, 0.0)[..., None]
    points = points_img[valid]
    normals = _depth_normals(points_img, valid)[valid] if s.normals else None
    if normals is not None:
        fallback = np.linalg.norm(normals, axis=1) == 0
        normals[fallback] = -points[fallback] / np.linalg.norm(points[fallback], axis=1, keepdims=True)
    return z, points, normals


def add_outliers(
    points: np.ndarray, normals: np.ndarray | None, head_cam: np.ndarray, s: ScanSettings, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray | None]:
    """Append flying pixels behind points and strays in the head's box (``head_cam`` ``(K, 3)`` mm, grown by 30 mm)."""
    n_out = int(round(s.outlier_fraction * len(points)))
    if n_out:
        n_fly = n_out // 2
        pick = rng.integers(len(points), size=n_fly)
        fly = points[pick] * (1.0 + rng.uniform(0.02, 0.2, size=(n_fly, 1)))
        lo, hi = head_cam.min(axis=0) - 30.0, head_cam.max(axis=0) + 30.0
        stray = rng.uniform(lo, hi, size=(n_out - n_fly, 3))
        extra = np.concatenate([fly, stray])
        points = np.concatenate([points, extra])
        if normals is not None:
            normals = np.concatenate([normals, -extra / np.linalg.norm(extra, axis=1, keepdims=True)])
    return points, normals
