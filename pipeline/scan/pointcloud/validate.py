"""Checking a cloud, bringing it to mm and the rig frame, and replacing a large one by a random subsample
(:func:`validate_points`)."""

from __future__ import annotations

import warnings

import numpy as np

from pipeline.scan.pointcloud.cloud import CloudError, PointCloud
from pipeline.scan.pointcloud.units import FRAMES, UNITS, detect_units, to_rig_frame

LARGE_CLOUD_POINTS = 200_000
"""Clouds with more points than this are subsampled by :func:`validate_points`; smaller ones are kept
exactly as given (a simulated 640x576 Kinect-like scan of a head has 14-20k points, a 320x288 one 3-5k)."""
SUBSAMPLE_POINTS = 50_000
"""Points kept of a larger cloud: 2.5x the densest simulated Kinect scan (20k) and 6x the fit's own
subsample (``FitScanConfig.correspondences.max_cloud_points``, 8000)."""
SUBSAMPLE_SEED = 0
"""Seed of that subsample (the same file always gives the same cloud)."""
MAX_RESOLUTION_MM = 0.1
"""The coarsest coordinate resolution accepted (mm): a cloud stored as float32 far from the origin (e.g.
georeferenced, 1e8 mm away: an 8 mm grid) has lost its detail in the file and is refused."""


def validate_points(
    points,
    normals=None,
    *,
    units: str = "auto",
    frame: str = "y-up",
    min_points: int = 500,
    path: str = "",
    large_cloud_points: int = LARGE_CLOUD_POINTS,
    subsample_points: int = SUBSAMPLE_POINTS,
    stored_dtype=None,
) -> PointCloud:
    """Check a cloud, bring it to mm and the rig frame, subsample it if large, and wrap it in a :class:`PointCloud`.

    Non-finite rows reject the cloud (it is never cleaned silently). Zero-length normals drop all
    normals with a warning; the others are normalised to unit length. A cloud of more than
    ``large_cloud_points`` points is replaced by a uniform random subsample of ``subsample_points`` of
    them (seed :data:`SUBSAMPLE_SEED`, file order kept, with a warning that gives both counts) once its
    rows, normals and units are checked on all points; a smaller one is kept as given.

    Args:
        points: ``(N, 3)`` positions in ``units`` and ``frame``.
        normals: ``(N, 3)`` normals in ``frame`` (any positive length), or None.
        units: ``"auto"``, ``"mm"``, ``"cm"``, ``"m"`` or ``"in"``. Auto accepts a cloud whose largest side
            (1st-99th percentile box) is 80-450 mm, 8-45 cm or 0.08-0.45 m, and warns when it converts cm or
            m (inches are never guessed). Explicit units are applied and the result must be 30-1000 mm across.
        frame: ``"y-up"`` (rig frame) or ``"opencv"`` (x right, y down, z forward; converted by ``(x, -y, -z)``).
        min_points: fewest distinct points accepted (in the subsample, for a large cloud).
        path: source file, used in messages and stored in the result.
        large_cloud_points: clouds with more points are subsampled (:data:`LARGE_CLOUD_POINTS`).
        subsample_points: points kept of such a cloud (:data:`SUBSAMPLE_POINTS`).
        stored_dtype: the floating dtype the file stored the coordinates in (e.g. ``np.float32``), or None
            (float64 or text): a cloud whose coordinates it resolves more coarsely than
            :data:`MAX_RESOLUTION_MM` where they lie is refused.

    Returns:
        A :class:`PointCloud` (points in mm, rig frame; float64 copies) with ``input_points = N``.

    Raises:
        CloudError: wrong shape, empty, non-finite, too few points, bad normals, unknown units/frame,
            a cloud that is not head-sized, or coordinates stored too coarsely.

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
    points = _checked_points(points, where)
    input_points = len(points)
    keep = _subsample(points, min_points, where, large_cloud_points, subsample_points)
    if normals is not None:
        normals = _checked_normals(normals, points.shape, where)

    unit, scale = detect_units(points, units, where)
    _check_resolution(points, stored_dtype, scale, where)
    if keep is not None:
        points, normals = points[keep], (None if normals is None else normals[keep])
        warnings.warn(
            f"{where}{input_points} points: kept a random {len(points)} of them (clouds of more than "
            f"{large_cloud_points} points are subsampled; the fit draws its points at random anyway)",
            stacklevel=2,
        )
    points = points * scale
    points, normals = to_rig_frame(points, frame), (None if normals is None else to_rig_frame(normals, frame))
    return PointCloud(
        points=points,
        normals=normals,
        path=path,
        units=unit,
        scale_to_mm=scale,
        input_points=input_points,
        units_detected=units == "auto",
    )


def _check_resolution(points: np.ndarray, stored_dtype, scale: float, where: str) -> None:
    """Refuse a cloud whose stored floating type resolves its coordinates more coarsely than
    :data:`MAX_RESOLUTION_MM` where they lie (float32 keeps 24 bits: 8 mm at 1e8 mm from the origin)."""
    if stored_dtype is None or not np.issubdtype(np.dtype(stored_dtype), np.floating):
        return
    far = float(np.abs(points).max())
    resolution = float(np.spacing(np.asarray(far, dtype=stored_dtype))) * scale
    if resolution > MAX_RESOLUTION_MM:
        raise CloudError(
            f"{where}the coordinates are stored as {np.dtype(stored_dtype).name} up to {far * scale:.3g} mm from "
            f"the origin, where that type resolves only {resolution:.3g} mm (jnr needs {MAX_RESOLUTION_MM:g} mm): "
            f"the file has lost the scan's detail; export it centred near the origin, or as float64"
        )


def _checked_points(points, where: str) -> np.ndarray:
    """``(N, 3)`` float64 points, or CloudError for a non-numeric, empty, misshapen or non-finite cloud."""
    try:
        points = np.asarray(points, dtype=np.float64)  # copied by the caller (scaled), never changed in place
    except (TypeError, ValueError) as exc:
        raise CloudError(f"{where}points must be a numeric (N, 3) array ({exc})") from exc
    if points.size == 0:
        raise CloudError(f"{where}the cloud is empty (no points)")
    if points.ndim != 2 or points.shape[1] != 3:
        raise CloudError(f"{where}points must have shape (N, 3), got {points.shape}")
    bad_rows = int((~np.isfinite(points).all(axis=1)).sum())
    if bad_rows:
        raise CloudError(
            f"{where}{bad_rows} of {len(points)} points have NaN or infinite coordinates; "
            f"remove them before fitting (the cloud is not cleaned automatically)"
        )
    return points


def _subsample(
    points: np.ndarray, min_points: int, where: str, large_cloud_points: int, subsample_points: int
) -> np.ndarray | None:
    """The sorted indices of the random subsample of a cloud larger than ``large_cloud_points`` (None for a
    smaller one), after checking that the points kept have at least ``min_points`` distinct ones."""
    input_points = len(points)
    if input_points <= large_cloud_points:
        _check_distinct(count_distinct(points), min_points, where)
        return None
    if not 1 <= subsample_points <= input_points:
        raise CloudError(f"{where}subsample_points must be in 1..{input_points}, got {subsample_points}")
    keep = np.sort(np.random.default_rng(SUBSAMPLE_SEED).choice(input_points, subsample_points, replace=False))
    # distinct points are counted in the subsample (np.unique over millions of rows is slow)
    _check_distinct(
        count_distinct(points[keep]),
        min_points,
        where,
        f" among {subsample_points} drawn at random from its {input_points}",
    )
    return keep


def _check_distinct(distinct: int, min_points: int, where: str, how: str = "") -> None:
    if distinct < min_points:
        raise CloudError(
            f"{where}the cloud has {distinct} distinct points{how}, at least {min_points} are "
            f"needed; is it a sparse landmark file rather than a scan?"
        )


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
        warnings.warn(
            f"{where}{zero} normals have zero length; ignoring all normals of this cloud "
            f"(they will be estimated from the points)",
            stacklevel=3,
        )
        return None
    return normals / length


__all__ = [
    "LARGE_CLOUD_POINTS",
    "MAX_RESOLUTION_MM",
    "SUBSAMPLE_POINTS",
    "SUBSAMPLE_SEED",
    "count_distinct",
    "validate_points",
]
