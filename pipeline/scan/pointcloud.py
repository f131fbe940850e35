"""Point clouds for ``jnr fit-scan CLOUD``: read, validate, estimate normals, find the scan border, write.

Every cloud that leaves this module is in rig space: millimetres, right-handed, +Y up, +Z out of the face
(``N`` points, shapes ``(N, 3)``). Files may be in millimetres, centimetres or metres (detected from the
cloud's size, or given with ``units``) and in the rig frame (``frame="y-up"``) or in OpenCV camera
coordinates (``frame="opencv"``: x right, y down, z forward, as depth cameras write them).

Supported files (extension, case-insensitive): ``.ply`` (ASCII or binary, point cloud or mesh),
``.obj``, ``.xyz`` / ``.txt`` / ``.csv`` (3 or 6 columns) and ``.npy`` (``(N, 3)`` or ``(N, 6)``).

Large clouds are reduced as soon as they are checked: :func:`validate_points` (so also
:func:`read_point_cloud`) keeps a cloud of at most :data:`LARGE_CLOUD_POINTS` (200 000) points exactly as
given, and replaces a larger one by a seeded uniform random subsample of :data:`SUBSAMPLE_POINTS`
(50 000) of its points, in file order (its units are still detected on all points). The fit draws its
8 000 points (``FitScanConfig.correspondences.max_cloud_points``) uniformly at random anyway, so the reduced cloud has the
statistics the fit would have seen (the pre-alignment's inlier fraction, which decides "not a head", the
share of outliers), while everything after reading (normals, the scan border, the error map,
``cloud_error.ply``, the report) costs what a 50k-point scan costs. :class:`PointCloud` records the
input's point count. (Merging on a voxel grid was measured and not used: it weights every occupied cube
alike, so isolated outliers in a dense scan count 30x more; with 1 % of them in a 1 M-point scan the
inlier fraction fell from 0.90 to 0.65-0.71, next to the 0.6 rejection threshold.)
"""

from __future__ import annotations

import io
import json
import math
import os
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from rig.errors import InputError
from rig.io.atomic import write_bytes_atomic

SUPPORTED_EXTENSIONS = (".ply", ".obj", ".xyz", ".txt", ".csv", ".npy")
UNITS = ("auto", "mm", "cm", "m")
FRAMES = ("y-up", "opencv")
UNIT_SCALE_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
HEAD_EXTENT_MM = (80.0, 450.0)
"""Largest side (mm) of the 1st-99th percentile bounding box of a head or face scan; used by ``units="auto"``."""
EXPLICIT_EXTENT_MM = (30.0, 1000.0)
"""Accepted largest side (mm) after scaling with explicit ``units`` (looser than the auto range)."""
NAN_GREY = (128, 128, 128)
LARGE_CLOUD_POINTS = 200_000
"""Clouds with more points than this are subsampled by :func:`validate_points`; smaller ones are kept
exactly as given (a simulated 640x576 Kinect-like scan of a head has 14-20k points, a 320x288 one 3-5k)."""
SUBSAMPLE_POINTS = 50_000
"""Points kept of a larger cloud: 2.5x the densest simulated Kinect scan (20k) and 6x the fit's own
subsample (``FitScanConfig.correspondences.max_cloud_points``, 8000)."""
SUBSAMPLE_SEED = 0
"""Seed of that subsample (the same file always gives the same cloud)."""


class CloudError(InputError):
    """Bad point-cloud input (message says what and how to fix)."""


@dataclass(frozen=True)
class PointCloud:
    """A validated point cloud in rig space."""

    points: np.ndarray
    """``(N, 3)`` float64 positions in mm, rig frame (+Y up, +Z out of the face)."""
    normals: np.ndarray | None
    """``(N, 3)`` float64 unit normals in the rig frame, or None when the source had none."""
    path: str
    """The source file ('' when built in memory)."""
    units: str
    """The units the source was in: 'mm', 'cm' or 'm'."""
    scale_to_mm: float
    """The factor that was applied to reach mm (1, 10 or 1000)."""
    input_points: int | None = None
    """Points in the source; more than ``len(points)`` only when the cloud was larger than
    :data:`LARGE_CLOUD_POINTS` and ``points`` is a random subsample of it (None given: ``len(points)``)."""

    def __post_init__(self) -> None:
        if self.input_points is None:
            object.__setattr__(self, "input_points", len(self.points))


# ----------------------------------------------------------------------------------------------- reading


def read_point_cloud(path, *, units: str = "auto", frame: str = "y-up", min_points: int = 500,
                     large_cloud_points: int = LARGE_CLOUD_POINTS,
                     subsample_points: int = SUBSAMPLE_POINTS) -> PointCloud:
    """Read a point cloud file and return it validated, in mm and in the rig frame (reduced if large).

    Args:
        path: a ``.ply``, ``.obj``, ``.xyz``, ``.txt``, ``.csv`` or ``.npy`` file (see the module docstring).
            PLY/OBJ meshes are fine: their vertices are used, and their vertex normals only if stored.
        units: ``"auto"`` (detect mm, cm or m from the cloud's size), ``"mm"``, ``"cm"`` or ``"m"``.
        frame: ``"y-up"`` (the file is in the rig frame) or ``"opencv"`` (x right, y down, z forward).
        min_points: fewest distinct points accepted.
        large_cloud_points, subsample_points: clouds of more points than the first are replaced by a
            random subsample of the second (:func:`validate_points`).

    Returns:
        A :class:`PointCloud` with ``(N, 3)`` float64 points in mm and ``(N, 3)`` unit normals or None.

    Raises:
        FileNotFoundError: the file does not exist.
        CloudError: unknown extension, unparseable file or a cloud that fails :func:`validate_points`.

    Example:
        >>> cloud = read_point_cloud("scan.ply", units="auto")  # doctest: +SKIP
        >>> cloud.points.shape, cloud.units  # doctest: +SKIP
        ((48213, 3), 'm')
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in SUPPORTED_EXTENSIONS:
        raise CloudError(f"{path}: unknown point-cloud extension {ext or '(none)'!r}; "
                         f"supported: {', '.join(SUPPORTED_EXTENSIONS)}")
    if not os.path.exists(path):
        raise FileNotFoundError(f"point cloud not found: {path}")
    if os.path.isdir(path):
        raise CloudError(f"{path}: is a folder, expected a point-cloud file")
    reader = {".ply": _read_ply, ".obj": _read_obj, ".npy": _read_npy}.get(ext, _read_table)
    try:
        points, normals = reader(path)
    except CloudError:
        raise
    except (ValueError, TypeError, KeyError, IndexError, EOFError) as exc:  # parser errors, not I/O errors
        raise CloudError(f"{path}: cannot parse this {ext} file ({type(exc).__name__}: {exc}); "
                         f"is it a valid, complete {ext} file?") from exc
    return validate_points(points, normals, units=units, frame=frame, min_points=min_points, path=path,
                           large_cloud_points=large_cloud_points, subsample_points=subsample_points)


def _read_ply(path: str) -> tuple[np.ndarray, np.ndarray | None]:
    # trimesh parses both encodings; for a point cloud it returns normals only in the raw vertex data
    # (metadata['_ply_raw']), so take x y z and nx ny nz from there, which also works for meshes.
    from trimesh.exchange.ply import load_ply

    with open(path, "rb") as fh:
        loaded = load_ply(fh)
    raw = loaded.get("metadata", {}).get("_ply_raw", {}).get("vertex")
    if raw is None:
        vertices = loaded.get("vertices")
        if vertices is None:
            raise CloudError(f"{path}: the PLY file has no 'vertex' element; is it a point cloud or mesh?")
        return np.asarray(vertices, dtype=np.float64), None
    data = raw["data"]
    names = set(data.keys()) if isinstance(data, dict) else set(data.dtype.names or ())
    if not {"x", "y", "z"} <= names:
        raise CloudError(f"{path}: the PLY vertices have no x y z properties (found {sorted(names)})")
    points = _columns(data, ("x", "y", "z"))
    normals = _columns(data, ("nx", "ny", "nz")) if {"nx", "ny", "nz"} <= names else None
    return points, normals


def _columns(data, names: tuple[str, str, str]) -> np.ndarray:
    """``(N, 3)`` float64 from three named fields, filled in place rather than stacked from three float64
    copies (reading 10 M points with normals: 0.29-0.30 s, was 0.36-1.43 s)."""
    first = np.asarray(data[names[0]]).reshape(-1)
    out = np.empty((len(first), 3), dtype=np.float64)
    for i, name in enumerate(names):
        out[:, i] = np.asarray(data[name]).reshape(-1)
    return out


def _read_obj(path: str) -> tuple[np.ndarray, np.ndarray | None]:
    # A line scan is enough: trimesh re-indexes OBJ vertices by face corners, which would break the
    # one-normal-per-vertex pairing we need, and drops vertices of point-only OBJ files.
    vertices, vertex_normals = [], []
    with open(path, encoding="utf-8") as fh:
        for number, line in enumerate(fh, 1):
            tokens = line.split()
            if not tokens or tokens[0] not in ("v", "vn"):
                continue
            if len(tokens) < 4:
                raise CloudError(f"{path}: line {number}: {tokens[0]!r} needs 3 numbers, got {line.strip()!r}")
            try:
                xyz = (float(tokens[1]), float(tokens[2]), float(tokens[3]))
            except ValueError as exc:
                raise CloudError(f"{path}: line {number}: not a number in {line.strip()!r}") from exc
            (vertices if tokens[0] == "v" else vertex_normals).append(xyz)
    points = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    if vertex_normals and len(vertex_normals) != len(vertices):
        # vn indexed per face corner cannot be paired with vertices; estimate normals later instead.
        return points, None
    return points, (np.array(vertex_normals, dtype=np.float64).reshape(-1, 3) if vertex_normals else None)


def _read_table(path: str) -> tuple[np.ndarray, np.ndarray | None]:
    with open(path, encoding="utf-8") as fh:
        lines = [line for line in fh.read().splitlines() if line.strip() and not line.lstrip().startswith("#")]
    if lines and not _is_numeric_row(lines[0]):
        lines = lines[1:]  # a single header line (e.g. "x,y,z,nx,ny,nz")
    if not lines:
        return np.zeros((0, 3)), None
    table = np.loadtxt(io.StringIO("\n".join(lines).replace(",", " ")), dtype=np.float64, comments="#", ndmin=2)
    return _split_columns(table, path)


def _is_numeric_row(line: str) -> bool:
    try:
        [float(token) for token in line.replace(",", " ").split()]
    except ValueError:
        return False
    return True


def _read_npy(path: str) -> tuple[np.ndarray, np.ndarray | None]:
    array = np.load(path, allow_pickle=False)
    if not isinstance(array, np.ndarray) or not (np.issubdtype(array.dtype, np.integer)
                                                 or np.issubdtype(array.dtype, np.floating)):
        raise CloudError(f"{path}: expected a numeric (N, 3) or (N, 6) array, got dtype {array.dtype}")
    return _split_columns(array.astype(np.float64), path)


def _split_columns(table: np.ndarray, path: str) -> tuple[np.ndarray, np.ndarray | None]:
    if table.ndim != 2 or table.shape[1] not in (3, 6):
        raise CloudError(f"{path}: expected 3 columns (x y z) or 6 (x y z nx ny nz), got shape {table.shape}")
    return table[:, :3], (table[:, 3:] if table.shape[1] == 6 else None)


# -------------------------------------------------------------------------------------------- validation


def validate_points(points, normals=None, *, units: str = "auto", frame: str = "y-up", min_points: int = 500,
                    path: str = "", large_cloud_points: int = LARGE_CLOUD_POINTS,
                    subsample_points: int = SUBSAMPLE_POINTS) -> PointCloud:
    """Check a cloud, bring it to mm and the rig frame, subsample it if large, and wrap it in a :class:`PointCloud`.

    Non-finite rows reject the cloud (it is never cleaned silently). Zero-length normals drop all
    normals with a warning; the others are normalised to unit length. A cloud of more than
    ``large_cloud_points`` points is replaced by a uniform random subsample of ``subsample_points`` of
    them (seed :data:`SUBSAMPLE_SEED`, file order kept, with a warning that gives both counts) once its
    rows, normals and units are checked on all points; a smaller one is kept as given.

    Args:
        points: ``(N, 3)`` positions in ``units`` and ``frame``.
        normals: ``(N, 3)`` normals in ``frame`` (any positive length), or None.
        units: ``"auto"``, ``"mm"``, ``"cm"`` or ``"m"``. Auto accepts a cloud whose largest side (1st-99th
            percentile box) is 80-450 mm, 8-45 cm or 0.08-0.45 m, and warns when it converts cm or m.
            Explicit units are applied and the result must be 30-1000 mm across.
        frame: ``"y-up"`` (rig frame) or ``"opencv"`` (x right, y down, z forward; converted by ``(x, -y, -z)``).
        min_points: fewest distinct points accepted (in the subsample, for a large cloud).
        path: source file, used in messages and stored in the result.
        large_cloud_points: clouds with more points are subsampled (:data:`LARGE_CLOUD_POINTS`).
        subsample_points: points kept of such a cloud (:data:`SUBSAMPLE_POINTS`).

    Returns:
        A :class:`PointCloud` (points in mm, rig frame; float64 copies) with ``input_points = N``.

    Raises:
        CloudError: wrong shape, empty, non-finite, too few points, bad normals, unknown units/frame,
            or a cloud that is not head-sized.

    Example:
        >>> cloud = validate_points(np.random.default_rng(0).uniform(-0.1, 0.1, (1000, 3)))  # metres: warns
        >>> cloud.units, cloud.scale_to_mm, cloud.input_points
        ('m', 1000.0, 1000)
    """
    where = f"{path}: " if path else "validate_points: "
    if units not in UNITS:
        raise CloudError(f"{where}units must be one of {', '.join(UNITS)}, got {units!r}")
    if frame not in FRAMES:
        raise CloudError(f"{where}frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    try:
        points = np.asarray(points, dtype=np.float64)  # copied below (scaled), never changed in place
    except (TypeError, ValueError) as exc:
        raise CloudError(f"{where}points must be a numeric (N, 3) array ({exc})") from exc
    if points.size == 0:
        raise CloudError(f"{where}the cloud is empty (no points)")
    if points.ndim != 2 or points.shape[1] != 3:
        raise CloudError(f"{where}points must have shape (N, 3), got {points.shape}")
    bad_rows = int((~np.isfinite(points).all(axis=1)).sum())
    if bad_rows:
        raise CloudError(f"{where}{bad_rows} of {len(points)} points have NaN or infinite coordinates; "
                         f"remove them before fitting (the cloud is not cleaned automatically)")
    input_points = len(points)
    keep = None
    if input_points > large_cloud_points:
        if not 1 <= subsample_points <= input_points:
            raise CloudError(f"{where}subsample_points must be in 1..{input_points}, got {subsample_points}")
        keep = np.sort(np.random.default_rng(SUBSAMPLE_SEED).choice(input_points, subsample_points, replace=False))
        # distinct points are counted in the subsample (np.unique over millions of rows is slow)
        _check_distinct(count_distinct(points[keep]), min_points, where,
                        f" among {subsample_points} drawn at random from its {input_points}")
    else:
        _check_distinct(count_distinct(points), min_points, where)
    if normals is not None:
        normals = _checked_normals(normals, points.shape, where)

    unit, scale = _detect_units(points, units, where)
    if keep is not None:
        points, normals = points[keep], (None if normals is None else normals[keep])
        warnings.warn(f"{where}{input_points} points: kept a random {len(points)} of them (clouds of more than "
                      f"{large_cloud_points} points are subsampled; the fit draws its points at random anyway)",
                      stacklevel=2)
    points = points * scale
    points, normals = to_rig_frame(points, frame), (None if normals is None else to_rig_frame(normals, frame))
    return PointCloud(points=points, normals=normals, path=path, units=unit, scale_to_mm=scale,
                      input_points=input_points)


def _check_distinct(distinct: int, min_points: int, where: str, how: str = "") -> None:
    if distinct < min_points:
        raise CloudError(f"{where}the cloud has {distinct} distinct points{how}, at least {min_points} are "
                         f"needed; is it a sparse landmark file rather than a scan?")


def count_distinct(points: np.ndarray) -> int:
    """Number of distinct rows of ``(N, 3)`` float64 points (``len(np.unique(points, axis=0))``, faster).

    Rows are compared by value (``-0.0 == 0.0``): a lexicographic sort, then a count of the rows that
    differ from their predecessor.

    Example:
        >>> count_distinct(np.array([[0.0, 1.0, 2.0], [-0.0, 1.0, 2.0], [0.0, 1.0, 3.0]]))
        2
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return len(points)
    rows = points[np.lexsort(points.T[::-1])]
    return 1 + int(np.any(rows[1:] != rows[:-1], axis=1).sum())


def _checked_normals(normals, shape: tuple[int, ...], where: str) -> np.ndarray | None:
    try:
        normals = np.array(normals, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CloudError(f"{where}normals must be a numeric {shape} array ({exc})") from exc
    if normals.shape != shape:
        raise CloudError(f"{where}normals must have the points' shape {shape}, got {normals.shape}")
    bad_rows = int((~np.isfinite(normals).all(axis=1)).sum())
    if bad_rows:
        raise CloudError(f"{where}{bad_rows} normals have NaN or infinite components; fix or drop the normals")
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    zero = int((length[:, 0] < 1e-12).sum())
    if zero:
        warnings.warn(f"{where}{zero} normals have zero length; ignoring all normals of this cloud "
                      f"(they will be estimated from the points)", stacklevel=3)
        return None
    return normals / length


def _detect_units(points: np.ndarray, units: str, where: str) -> tuple[str, float]:
    low, high = np.percentile(points, [1.0, 99.0], axis=0)
    extent = float((high - low).max())
    if units != "auto":
        scale = UNIT_SCALE_TO_MM[units]
        size = extent * scale
        if not EXPLICIT_EXTENT_MM[0] <= size <= EXPLICIT_EXTENT_MM[1]:
            raise CloudError(f"{where}with units={units!r} the cloud is {size:.4g} mm across, outside "
                             f"{EXPLICIT_EXTENT_MM[0]:g}-{EXPLICIT_EXTENT_MM[1]:g} mm; check --units")
        return units, scale
    lo, hi = HEAD_EXTENT_MM
    for unit in ("mm", "m", "cm"):
        scale = UNIT_SCALE_TO_MM[unit]
        if lo <= extent * scale <= hi:
            if unit != "mm":
                warnings.warn(f"{where}the cloud is {extent:.4g} across, so it looks like {unit}; converted to "
                              f"mm (x{scale:g}). Pass --units to override", stacklevel=3)
            return unit, scale
    raise CloudError(f"{where}the cloud is {extent:.4g} across, which is not head-sized in mm, cm or m; is it "
                     f"a head? pass --units if the units are unusual (a head scan is {lo:g}-{hi:g} mm across)")


def to_rig_frame(xyz: np.ndarray, frame: str) -> np.ndarray:
    """Convert points or normals from a cloud's ``frame`` to the rig frame (the only place this is done).

    Args:
        xyz: ``(*, 3)`` points or normals.
        frame: ``"y-up"`` (returned unchanged, as a copy) or ``"opencv"`` (x right, y down, z forward →
            ``(x, -y, -z)``).

    Returns:
        ``(*, 3)`` float64 array in the rig frame (+Y up, +Z out of the face). Use it for 3D landmarks
        given in the same frame as their cloud.

    Example:
        >>> to_rig_frame(np.array([1.0, 2.0, 3.0]), "opencv")
        array([ 1., -2., -3.])
    """
    if frame not in FRAMES:
        raise CloudError(f"to_rig_frame: frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    xyz = np.array(xyz, dtype=np.float64)
    if xyz.shape[-1:] != (3,):
        raise CloudError(f"to_rig_frame: xyz must have shape (*, 3), got {xyz.shape}")
    if frame == "opencv":
        xyz[..., 1:] *= -1.0
    return xyz


# ------------------------------------------------------------------------------------ normals and border


def _check_cloud_array(points: np.ndarray, func: str, k: int) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise CloudError(f"{func}: points must have shape (N, 3), got {points.shape}")
    if k < 3:
        raise CloudError(f"{func}: k must be at least 3, got {k}")
    if len(points) < 4:
        raise CloudError(f"{func}: need at least 4 points, got {len(points)}")
    if not np.isfinite(points).all():
        raise CloudError(f"{func}: points contain NaN or infinite values")
    return points


def _neighbourhoods(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(N, k)`` distances and indices of each point's k nearest other points (self excluded)."""
    k = min(k, len(points) - 1)
    distances, index = cKDTree(points).query(points, k=k + 1, workers=-1)
    return distances[:, 1:], index[:, 1:]


def _pca_normals(points: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``(N, 3)`` unit normals (smallest principal axis) of each point plus its ``(N, k)`` neighbours."""
    patch = np.concatenate([points[:, None, :], points[index]], axis=1)
    centred = patch - patch.mean(axis=1, keepdims=True)
    covariance = np.einsum("nki,nkj->nij", centred, centred)
    _, vectors = np.linalg.eigh(covariance)  # ascending eigenvalues
    return vectors[:, :, 0]


def estimate_normals(points: np.ndarray, k: int = 16, viewpoint: np.ndarray | None = None) -> np.ndarray:
    """Unit normals by PCA over each point's ``k`` nearest neighbours.

    Args:
        points: ``(N, 3)`` positions (any unit), ``N >= 4``.
        k: neighbours per point (capped at ``N - 1``), at least 3.
        viewpoint: ``(3,)`` position the normals should face (e.g. the scanner), or None to orient them
            away from the cloud's centroid (right for a closed or convex-ish head).

    Returns:
        ``(N, 3)`` float64 unit normals.

    Example:
        >>> sphere = np.random.default_rng(0).normal(size=(2000, 3))
        >>> sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
        >>> bool((np.einsum("ni,ni->n", estimate_normals(sphere), sphere) > 0.9).all())
        True
    """
    points = _check_cloud_array(points, "estimate_normals", k)
    _, index = _neighbourhoods(points, k)
    normals = _pca_normals(points, index)
    if viewpoint is None:
        towards = points - points.mean(axis=0)
    else:
        viewpoint = np.asarray(viewpoint, dtype=np.float64)
        if viewpoint.shape != (3,):
            raise CloudError(f"estimate_normals: viewpoint must have shape (3,), got {viewpoint.shape}")
        towards = viewpoint - points
    flip = np.einsum("ni,ni->n", normals, towards) < 0
    normals[flip] *= -1.0
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def boundary_mask(points: np.ndarray, k: int = 16, threshold: float = 0.35) -> np.ndarray:
    """Points on the border of the scanned surface (the edge of a depth scan or of a hole).

    A point is on the border when the centroid of its ``k`` neighbours, projected onto the local tangent
    plane, is more than ``threshold`` × the mean neighbour distance away from it (inside a surface the
    neighbours surround the point; on a border they all lie on one side). Assumes a roughly even sampling
    (a depth-camera grid, a remeshed scan): on randomly (Poisson) sampled points the neighbour centroid is
    noisy and ``k=16`` flags about 17 % of interior points; use ``k=32`` (about 3 %) or more there.

    Args:
        points: ``(N, 3)`` positions (any unit), ``N >= 4``.
        k: neighbours per point (capped at ``N - 1``), at least 3.
        threshold: offset ratio above which a point is a border point (about 0.6 on a straight edge, 0 inside).

    Returns:
        ``(N,)`` bool mask, True on the border.

    Example:
        >>> u, v = np.meshgrid(np.arange(30.0), np.arange(30.0))
        >>> grid = np.stack([u.ravel(), v.ravel(), np.zeros(900)], axis=1)
        >>> rim = (u == 0) | (u == 29) | (v == 0) | (v == 29)
        >>> mask = boundary_mask(grid)
        >>> int(mask[rim.ravel()].sum()), int(mask[~rim.ravel()].sum())  # all 116 rim points, 4 next to corners
        (116, 4)
    """
    points = _check_cloud_array(points, "boundary_mask", k)
    distances, index = _neighbourhoods(points, k)
    normals = _pca_normals(points, index)
    offset = points[index].mean(axis=1) - points
    tangential = offset - np.einsum("ni,ni->n", offset, normals)[:, None] * normals
    return np.linalg.norm(tangential, axis=1) > threshold * distances.mean(axis=1)


# --------------------------------------------------------------------------------------------- writing


def write_point_cloud_ply(path, points, *, colors=None, normals=None,
                          scalars: dict[str, np.ndarray] | None = None) -> None:
    """Write a binary little-endian PLY point cloud, atomically (:func:`rig.io.atomic.write_bytes_atomic`).

    Vertex properties, in order: float32 ``x y z``, float32 ``nx ny nz`` (if ``normals``), uint8
    ``red green blue`` (if ``colors``), then one float32 property per entry of ``scalars``.

    Args:
        path: output file; its folder must exist.
        points: ``(N, 3)`` positions (mm in rig space by convention).
        colors: ``(N, 3)`` integer colours in 0-255 (e.g. from :func:`error_colors`), or None.
        normals: ``(N, 3)`` normals, or None.
        scalars: per-vertex values, name → ``(N,)`` array, e.g. ``{"error_mm": distances}``. Names must be
            PLY identifiers (letters, digits, underscore) not already used above.

    Raises:
        ValueError: wrong shapes or lengths, colours outside 0-255, bad scalar names.

    Example:
        >>> d = np.linalg.norm(fitted - cloud.points, axis=1)  # doctest: +SKIP
        >>> write_point_cloud_ply("e.ply", cloud.points, colors=error_colors(d),
        ...                       scalars={"error_mm": d})  # doctest: +SKIP
    """
    func = "write_point_cloud_ply"
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{func}: points must have shape (N, 3), got {points.shape}")
    n = len(points)
    fields = [(c, "<f4", points[:, i]) for i, c in enumerate("xyz")]
    if normals is not None:
        normals = np.asarray(normals)
        if normals.shape != (n, 3):
            raise ValueError(f"{func}: normals must have shape ({n}, 3), got {normals.shape}")
        fields += [(c, "<f4", normals[:, i]) for i, c in enumerate(("nx", "ny", "nz"))]
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (n, 3):
            raise ValueError(f"{func}: colors must have shape ({n}, 3), got {colors.shape}")
        if not np.issubdtype(colors.dtype, np.integer) or colors.min(initial=0) < 0 or colors.max(initial=0) > 255:
            raise ValueError(f"{func}: colors must be integers in 0-255 (uint8), got dtype {colors.dtype}")
        fields += [(c, "u1", colors[:, i]) for i, c in enumerate(("red", "green", "blue"))]
    for name, values in (scalars or {}).items():
        values = np.asarray(values)
        if not (isinstance(name, str) and name.isidentifier() and name.isascii()):
            raise ValueError(f"{func}: scalar name {name!r} is not a valid PLY property name")
        if name in {f[0] for f in fields}:
            raise ValueError(f"{func}: scalar name {name!r} clashes with another vertex property")
        if values.shape != (n,):
            raise ValueError(f"{func}: scalars[{name!r}] must have shape ({n},), got {values.shape}")
        fields.append((name, "<f4", values))

    vertex = np.empty(n, dtype=[(name, dtype) for name, dtype, _ in fields])
    for name, _, values in fields:
        vertex[name] = values
    ply_type = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", "comment written by jnr (pipeline.scan.pointcloud)",
              f"element vertex {n}"] + [f"property {ply_type[dtype]} {name}" for name, dtype, _ in fields]
    header = ("\n".join(header + ["end_header"]) + "\n").encode("ascii")
    write_bytes_atomic(os.fspath(path), header + vertex.tobytes(), make_parents=True)


# Blue → light blue → pale yellow → orange → red (ColorBrewer RdYlBu, reversed): even lightness steps
# towards the middle, readable by the colour-blind, and no matplotlib needed.
_ERROR_STOPS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
_ERROR_COLOURS = np.array([[44, 123, 182], [171, 217, 233], [255, 255, 191], [253, 174, 97], [215, 25, 28]],
                          dtype=np.float64)


def error_colors(distances_mm: np.ndarray, vmax_mm: float | None = None) -> np.ndarray:
    """Colours for per-point errors: blue (0) → yellow → red (``>= vmax_mm``), grey for NaN.

    Args:
        distances_mm: ``(N,)`` distances in mm (negative values are shown as 0).
        vmax_mm: distance shown as full red; default the 95th percentile of the finite distances
            (at least 1e-6).

    Returns:
        ``(N, 3)`` uint8 RGB colours.

    Example:
        >>> error_colors(np.array([0.0, 1.0, np.nan]), vmax_mm=1.0)
        array([[ 44, 123, 182],
               [215,  25,  28],
               [128, 128, 128]], dtype=uint8)
    """
    distances = np.asarray(distances_mm, dtype=np.float64)
    if distances.ndim != 1:
        raise ValueError(f"error_colors: distances_mm must have shape (N,), got {distances.shape}")
    finite = distances[np.isfinite(distances)]
    if vmax_mm is None:
        vmax_mm = max(float(np.percentile(finite, 95.0)) if finite.size else 0.0, 1e-6)
    elif not (math.isfinite(vmax_mm) and vmax_mm > 0):
        raise ValueError(f"error_colors: vmax_mm must be a positive number, got {vmax_mm}")
    t = np.clip(np.nan_to_num(distances, nan=0.0) / vmax_mm, 0.0, 1.0)
    rgb = np.stack([np.interp(t, _ERROR_STOPS, _ERROR_COLOURS[:, c]) for c in range(3)], axis=1)
    rgb = np.rint(rgb).astype(np.uint8)
    rgb[np.isnan(distances)] = NAN_GREY
    return rgb


# ------------------------------------------------------------------------------------------- landmarks


def read_landmarks3d(path) -> dict[str, np.ndarray]:
    """Read named 3D landmarks from JSON.

    The file is ``{"landmarks": {"nose_tip": [x, y, z], ...}}`` or the bare mapping ``{"nose_tip": [x, y, z]}``.
    Coordinates are in the same units and frame as the cloud they belong to and are returned unchanged:
    scale them by the cloud's ``scale_to_mm`` and apply :func:`to_rig_frame` as for the cloud. Names are
    not checked here (the model checks them).

    Args:
        path: the JSON file.

    Returns:
        name → ``(3,)`` float64 position, in file order.

    Raises:
        FileNotFoundError: the file does not exist.
        CloudError: bad JSON, no landmarks, or an entry that is not 3 finite numbers.

    Example:
        >>> read_landmarks3d("scan_landmarks.json")["nose_tip"]  # doctest: +SKIP
        array([  1.2,  10.5, 112. ])
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"landmark file not found: {path}")
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CloudError(f"{path}: not valid JSON ({exc})") from exc
    if isinstance(data, dict) and isinstance(data.get("landmarks"), dict):
        data = data["landmarks"]
    if not isinstance(data, dict) or not data:
        raise CloudError(f"{path}: expected {{\"landmarks\": {{name: [x, y, z], ...}}}} or {{name: [x, y, z]}}, "
                         f"got {type(data).__name__ if data else 'no landmarks'}")
    landmarks = {}
    for name, value in data.items():
        is_vector = isinstance(value, list) and len(value) == 3 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        if not is_vector:
            raise CloudError(f"{path}: landmark {name!r} must be a list of 3 numbers [x, y, z], got {value!r}")
        xyz = np.array(value, dtype=np.float64)
        if not np.isfinite(xyz).all():
            raise CloudError(f"{path}: landmark {name!r} has a non-finite coordinate: {value!r}")
        landmarks[name] = xyz
    return landmarks


__all__ = [
    "EXPLICIT_EXTENT_MM",
    "HEAD_EXTENT_MM",
    "LARGE_CLOUD_POINTS",
    "SUBSAMPLE_POINTS",
    "SUBSAMPLE_SEED",
    "SUPPORTED_EXTENSIONS",
    "CloudError",
    "PointCloud",
    "boundary_mask",
    "count_distinct",
    "error_colors",
    "estimate_normals",
    "read_landmarks3d",
    "read_point_cloud",
    "to_rig_frame",
    "validate_points",
    "write_point_cloud_ply",
]
