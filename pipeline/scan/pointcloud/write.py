"""Writing a point cloud as a binary PLY file, with normals, colours and per-point values
(:func:`write_point_cloud_ply`)."""

from __future__ import annotations

import os

import numpy as np

from rig.io.atomic import write_bytes_atomic


def write_point_cloud_ply(
    path, points, *, colors=None, normals=None, scalars: dict[str, np.ndarray] | None = None
) -> None:
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
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment written by jnr (pipeline.scan.pointcloud)",
        f"element vertex {n}",
    ] + [f"property {ply_type[dtype]} {name}" for name, dtype, _ in fields]
    header = ("\n".join(header + ["end_header"]) + "\n").encode("ascii")
    write_bytes_atomic(os.fspath(path), header + vertex.tobytes(), make_parents=True)


__all__ = ["write_point_cloud_ply"]
