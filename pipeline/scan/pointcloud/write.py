"""Writing a point cloud as a binary PLY file, with normals, colours and per-point values
(:func:`write_point_cloud_ply`)."""

from __future__ import annotations

import os

import numpy as np

from rig.errors import InputError
from rig.io.atomic import write_bytes_atomic
from rig.io.ply import binary_ply, position_dtype


def write_point_cloud_ply(
    path, points, *, colors=None, normals=None, scalars: dict[str, np.ndarray] | None = None
) -> None:
    """Write a binary little-endian PLY point cloud, atomically (:func:`rig.io.atomic.write_bytes_atomic`).

    Vertex properties, in order: float32 ``x y z`` (float64 far from the origin, where float32 would lose
    them: :func:`rig.io.ply.position_dtype`), float32 ``nx ny nz`` (if ``normals``), uint8
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
        raise InputError(f"{func}: points must have shape (N, 3), got {points.shape}")
    n = len(points)
    fields = [(c, position_dtype(points), points[:, i]) for i, c in enumerate("xyz")]
    if normals is not None:
        normals = np.asarray(normals)
        if normals.shape != (n, 3):
            raise InputError(f"{func}: normals must have shape ({n}, 3), got {normals.shape}")
        fields += [(c, "<f4", normals[:, i]) for i, c in enumerate(("nx", "ny", "nz"))]
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (n, 3):
            raise InputError(f"{func}: colors must have shape ({n}, 3), got {colors.shape}")
        if not np.issubdtype(colors.dtype, np.integer) or colors.min(initial=0) < 0 or colors.max(initial=0) > 255:
            raise InputError(f"{func}: colors must be integers in 0-255 (uint8), got dtype {colors.dtype}")
        fields += [(c, "u1", colors[:, i]) for i, c in enumerate(("red", "green", "blue"))]
    for name, values in (scalars or {}).items():
        values = np.asarray(values)
        if not (isinstance(name, str) and name.isidentifier() and name.isascii()):
            raise InputError(f"{func}: scalar name {name!r} is not a valid PLY property name")
        if name in {f[0] for f in fields}:
            raise InputError(f"{func}: scalar name {name!r} clashes with another vertex property")
        if values.shape != (n,):
            raise InputError(f"{func}: scalars[{name!r}] must have shape ({n},), got {values.shape}")
        fields.append((name, "<f4", values))

    data = binary_ply(fields, comments=("written by jnr (pipeline.scan.pointcloud)",))
    write_bytes_atomic(os.fspath(path), data, make_parents=True)


__all__ = ["write_point_cloud_ply"]
