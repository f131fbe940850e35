"""Simulated single-view depth scans of a head mesh (an Azure Kinect / Kinect-like sensor).

The head (rig space: mm, right-handed, +Y up, +Z out of the face) is placed by a random rigid
transform, a pinhole depth camera is put ``distance_mm`` in front of it looking along world -Z, the
mesh is rasterised with a numpy z-buffer (perspective-correct depth), the valid pixels are
back-projected to 3D and corrupted like a time-of-flight sensor (:mod:`pipeline.synthetic.depth_sensor`):
axial noise growing with the square of the depth, lateral jitter, dropout at depth discontinuities and
grazing angles, elliptical holes and flying pixels / stray points. The points come back in the WORLD frame
(+Y up), the frame of the ground-truth vertices, so they are directly comparable.

Camera frame: OpenCV (x right, y down, z forward), pixel centres at integer coordinates
``(u, v) = (fx x / z + cx, fy y / z + cy)``. World -> camera: ``p_cam = diag(1, -1, -1) (p - c)`` with
``c`` the camera position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.camera import camera_points_to_pixels
from pipeline.files import staged_file
from pipeline.scan.pointcloud.write import write_point_cloud_ply
from pipeline.synthetic.depth_sensor import (
    HIRES_CAMERA,
    DepthCamera,
    ScanSettings,
    add_outliers,
    back_project,
    drop_pixels,
)
from pipeline.synthetic.expressive import expressive_split
from rig.asset import load_asset
from rig.errors import InputError
from rig.geometry import RIG_TO_OPENCV, head_rotation

__all__ = [
    "HIRES_CAMERA",
    "WORLD_TO_CAMERA",
    "DepthCamera",
    "ScanSettings",
    "SyntheticScan",
    "render_depth",
    "simulate_scan",
    "write_heldout_scan",
]

WORLD_TO_CAMERA = RIG_TO_OPENCV
"""Rotation from world axes (+Y up, camera looking along -Z) to the OpenCV camera axes (a proper rotation)."""

_NEAR_MM = 1.0
_CHUNK_PAIRS = 2_000_000


@dataclass(frozen=True)
class SyntheticScan:
    """One simulated depth scan.

    Attributes:
        points: ``(N, 3)`` float64 points, mm, world frame (+Y up, right-handed).
        normals: ``(N, 3)`` unit normals towards the camera, or ``None``.
        gt_vertices: ``(V, 3)`` the true head in the world frame, ``head @ rotation.T + translation``.
        rotation: ``(3, 3)`` head rotation; translation: ``(3,)`` mm.
        visible: ``(V,)`` bool, vertices seen by the camera (before holes and dropout): on a rendered pixel,
            within 3 mm of its z-buffer depth.
        hole_fraction: fraction of the face's (rendered) pixels removed by the holes.
        camera_position: ``(3,)`` mm, world frame.
        depth: ``(H, W)`` the final depth image before outliers (mm, ``inf`` where empty).
    """

    points: np.ndarray
    normals: np.ndarray | None
    gt_vertices: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    visible: np.ndarray
    hole_fraction: float
    camera_position: np.ndarray
    depth: np.ndarray


# ----------------------------------------------------------------------------------------------------
# Rasterisation
# ----------------------------------------------------------------------------------------------------


def _check_mesh(vertices, faces, fn: str) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise InputError(f"{fn}: vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"{fn}: faces must be an integer array of shape (F, 3), got {f.shape} {f.dtype}")
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise InputError(f"{fn}: face indices must be in [0, {len(v)}), got [{f.min()}, {f.max()}]")
    if not np.isfinite(v).all():
        raise InputError(f"{fn}: vertices must be finite")
    return v, f.astype(np.int64)


def render_depth(
    vertices_cam: np.ndarray, faces: np.ndarray, camera: DepthCamera = DepthCamera()
) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer rasterisation of a triangle mesh.

    Each pixel centre (integer ``(u, v)``) gets the nearest triangle that contains it (screen-space
    barycentric test), its depth interpolated perspective-correctly (``1/z`` is linear on screen), so
    the back-projected pixel lies exactly on the triangle. Triangles with a vertex nearer than 1 mm
    are skipped.

    Args:
        vertices_cam: ``(V, 3)`` vertices in camera coordinates (OpenCV: x right, y down, z forward), mm.
        faces: ``(F, 3)`` int triangle indices.
        camera: intrinsics.

    Returns:
        ``depth`` ``(H, W)`` float64 z in mm (``inf`` where empty) and ``face_id`` ``(H, W)`` int64
        (``-1`` where empty).
    """
    v, f = _check_mesh(vertices_cam, faces, "render_depth")
    h, w = int(camera.height), int(camera.width)
    depth = np.full(h * w, np.inf)
    face_id = np.full(h * w, -1, dtype=np.int64)
    z = v[:, 2]
    uv = camera_points_to_pixels(v, camera.focal, camera.centre)
    keep = (z[f] > _NEAR_MM).all(axis=1)
    fid = np.flatnonzero(keep)
    t = uv[f[fid]]  # (F', 3, 2)
    area = (t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1]) - (t[:, 1, 1] - t[:, 0, 1]) * (t[:, 2, 0] - t[:, 0, 0])
    u0 = np.maximum(np.ceil(t[..., 0].min(axis=1)), 0).astype(np.int64)
    u1 = np.minimum(np.floor(t[..., 0].max(axis=1)), w - 1).astype(np.int64)
    v0 = np.maximum(np.ceil(t[..., 1].min(axis=1)), 0).astype(np.int64)
    v1 = np.minimum(np.floor(t[..., 1].max(axis=1)), h - 1).astype(np.int64)
    ok = (u1 >= u0) & (v1 >= v0) & (np.abs(area) > 1e-12)
    fid, t, area, u0, u1, v0, v1 = fid[ok], t[ok], area[ok], u0[ok], u1[ok], v0[ok], v1[ok]
    bw = u1 - u0 + 1
    counts = bw * (v1 - v0 + 1)
    inv_z = 1.0 / z[f[fid]]  # (F', 3)
    bounds = np.searchsorted(np.cumsum(counts), np.arange(_CHUNK_PAIRS, counts.sum() + _CHUNK_PAIRS, _CHUNK_PAIRS))
    start = 0
    for stop in np.unique(np.append(np.minimum(bounds + 1, len(fid)), len(fid))):
        if stop <= start:
            continue
        sl = slice(start, stop)
        start = stop
        c = counts[sl]
        k = np.repeat(np.arange(len(c)), c)
        local = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c)
        pu = u0[sl][k] + local % bw[sl][k]
        pv = v0[sl][k] + local // bw[sl][k]
        tk = t[sl][k]
        a0, a1, a2 = tk[:, 0], tk[:, 1], tk[:, 2]

        def edge(p, q, pu=pu, pv=pv):  # signed area of (p, q, pixel)
            return (q[:, 0] - p[:, 0]) * (pv - p[:, 1]) - (q[:, 1] - p[:, 1]) * (pu - p[:, 0])

        ar = area[sl][k]
        b0, b1, b2 = edge(a1, a2) / ar, edge(a2, a0) / ar, edge(a0, a1) / ar
        inside = (b0 >= -1e-12) & (b1 >= -1e-12) & (b2 >= -1e-12)
        if not inside.any():
            continue
        iz = inv_z[sl][k[inside]]
        d = 1.0 / (b0[inside] * iz[:, 0] + b1[inside] * iz[:, 1] + b2[inside] * iz[:, 2])
        pix = pv[inside] * w + pu[inside]
        ids = fid[sl][k[inside]]
        order = np.lexsort((d, pix))
        pix, d, ids = pix[order], d[order], ids[order]
        first = np.r_[True, pix[1:] != pix[:-1]]
        pix, d, ids = pix[first], d[first], ids[first]
        better = d < depth[pix]
        depth[pix[better]] = d[better]
        face_id[pix[better]] = ids[better]
    return depth.reshape(h, w), face_id.reshape(h, w)


# ----------------------------------------------------------------------------------------------------
# Scan simulation
# ----------------------------------------------------------------------------------------------------


def _angle(value, rng_range, rng: np.random.Generator, name: str) -> float:
    lo, hi = rng_range
    if lo > hi:
        raise InputError(f"simulate_scan: {name} range must be (low, high), got {rng_range}")
    draw = float(rng.uniform(lo, hi))  # always drawn, so the stream does not depend on the overrides
    if value is None:
        return draw
    if not np.isfinite(value):
        raise InputError(f"simulate_scan: {name} must be finite, got {value}")
    return float(value)


def _check_settings(s: ScanSettings) -> None:
    """Reject a hole range, distance, offset or outlier fraction outside its domain (before any draw)."""
    lo_h, hi_h = s.hole_fraction
    if not 0.0 <= lo_h <= hi_h < 1.0:
        raise InputError(f"simulate_scan: hole_fraction must be 0 <= low <= high < 1, got {s.hole_fraction}")
    if s.distance_mm <= 0 or s.max_offset_mm < 0 or s.outlier_fraction < 0:
        raise InputError("simulate_scan: distance_mm must be > 0, max_offset_mm and outlier_fraction >= 0")


def _place_head(
    v: np.ndarray, s: ScanSettings, rng: np.random.Generator, yaw_deg, pitch_deg, roll_deg
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random rigid pose (draws yaw, pitch, roll, then the offset): rotation, ``(3,)`` mm offset, ``(V, 3)`` world."""
    yaw = _angle(yaw_deg, s.yaw_deg_range, rng, "yaw_deg")
    pitch = _angle(pitch_deg, s.pitch_deg_range, rng, "pitch_deg")
    roll = _angle(roll_deg, s.roll_deg_range, rng, "roll_deg")
    rotation = head_rotation(yaw, pitch, roll)
    translation = rng.uniform(-s.max_offset_mm, s.max_offset_mm, size=3)
    return rotation, translation, v @ rotation.T + translation


def _visible_vertices(cam: np.ndarray, used: np.ndarray, depth: np.ndarray, camera: DepthCamera) -> np.ndarray:
    """``(V,)`` vertices (``cam`` mm) seen before dropout: used, on a rendered pixel, within 3 mm of its z-buffer."""
    # A vertex whose pixel is empty lies on the silhouette between pixel centres (a grazing or slightly
    # back-facing vertex): the camera samples no surface there, so it is not seen.
    pu, pv = np.rint(camera_points_to_pixels(cam, camera.focal, camera.centre)).astype(np.int64).T
    inside = (cam[:, 2] > _NEAR_MM) & (pu >= 0) & (pu < camera.width) & (pv >= 0) & (pv < camera.height)
    visible = np.zeros(len(cam), bool)
    zb = depth[pv[inside], pu[inside]]
    visible[inside] = np.isfinite(zb) & (cam[inside, 2] <= zb + 3.0)
    referenced = np.zeros(len(cam), bool)
    referenced[used] = True
    return visible & referenced


def simulate_scan(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    rng: np.random.Generator | int,
    settings: ScanSettings = ScanSettings(),
    camera: DepthCamera = DepthCamera(),
    yaw_deg: float | None = None,
    pitch_deg: float | None = None,
    roll_deg: float | None = None,
) -> SyntheticScan:
    """Simulate one depth scan of a head.

    Args:
        vertices: ``(V, 3)`` head vertices in rig space (mm, +Y up, +Z out of the face).
        faces: ``(F, 3)`` int triangles.
        rng: ``np.random.Generator`` or integer seed (all randomness comes from it).
        settings: placement and sensor model.
        camera: depth camera intrinsics.
        yaw_deg, pitch_deg, roll_deg: fixed head rotation (degrees) instead of a random one.

    Returns:
        :class:`SyntheticScan` with points in the world frame (+Y up), the frame of ``gt_vertices``.

    Raises:
        ValueError: bad mesh, non-finite angles, bad ranges.

    Example:
        >>> from rig.asset import load_asset
        >>> a = load_asset()
        >>> scan = simulate_scan(a.vertices, a.faces, rng=0)
        >>> scan.points.shape[1]
        3
    """
    v, f = _check_mesh(vertices, faces, "simulate_scan")
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    s = settings
    _check_settings(s)
    rotation, translation, world = _place_head(v, s, rng, yaw_deg, pitch_deg, roll_deg)

    used = np.unique(f)
    centre = world[used].mean(axis=0)
    camera_position = np.array([centre[0], centre[1], world[used, 2].max() + s.distance_mm])
    cam = (world - camera_position) @ WORLD_TO_CAMERA.T
    depth, face_id = render_depth(cam, f, camera)
    visible = _visible_vertices(cam, used, depth, camera)
    valid, hole_fraction = drop_pixels(cam, f, depth, face_id, camera, s, rng)
    z, points, normals = back_project(depth, valid, camera, s, rng)
    points, normals = add_outliers(points, normals, cam[used], s, rng)

    points_world = points @ WORLD_TO_CAMERA + camera_position  # WORLD_TO_CAMERA is its own inverse/transpose
    normals_world = None if normals is None else normals @ WORLD_TO_CAMERA
    final_depth = np.where(valid, z, np.inf)
    return SyntheticScan(
        points=points_world,
        normals=normals_world,
        gt_vertices=world,
        rotation=rotation,
        translation=translation,
        visible=visible,
        hole_fraction=hole_fraction,
        camera_position=camera_position,
        depth=final_depth,
    )


def write_heldout_scan(
    out,
    truth,
    *,
    head: int = 0,
    expressive: bool = False,
    camera: DepthCamera = DepthCamera(),
    seed: int = 0,
    population_seed: int = 0,
    force: bool = False,
) -> SyntheticScan:
    """Simulate a scan of a held-out synthetic head and write it (``jnr data scan``), each file atomically.

    Args:
        out: the cloud, a binary PLY with normals (mm, +Y up, the world frame of the scan).
        truth: the true head as a mesh (template topology, the same frame).
        head: the held-out head, ``0 <= head < 100``; expressive: with its random expression
            (:func:`pipeline.synthetic.expressive.expressive_split`) instead of neutral.
        camera: the depth camera (:data:`HIRES_CAMERA` for more points); seed: of the scan (placement,
            noise, holes); population_seed: of the synthetic population.
        force: replace existing files.

    Returns:
        The :class:`SyntheticScan`.

    Raises:
        pipeline.files.OutputError: an output is refused (exists without ``force``) or cannot be written.
    """
    import trimesh

    heads = expressive_split("heldout", seed=population_seed, n=head + 1)
    vertices = heads.vertices[head] if expressive else heads.neutral[head]
    asset = load_asset()
    scan = simulate_scan(vertices, asset.faces, rng=np.random.default_rng(seed), camera=camera)
    with staged_file(out, force) as tmp:
        write_point_cloud_ply(tmp, scan.points, normals=scan.normals)
    with staged_file(truth, force) as tmp:
        trimesh.Trimesh(scan.gt_vertices, asset.faces, process=False).export(tmp)
    return scan
