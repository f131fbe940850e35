"""Binary PLY bytes from named per-vertex fields (and triangles), with positions in float64 where float32
would lose them (:func:`position_dtype`: a georeferenced scan fit 1e8 mm from the origin)."""

from __future__ import annotations

import numpy as np

from rig.errors import InputError

PLY_TYPES = {"<f4": "float", "<f8": "double", "u1": "uchar", "<i4": "int"}
"""The PLY property type of each NumPy dtype :func:`binary_ply` writes."""
FLOAT32_TOLERANCE = 1e-6
"""float32 positions are written unless float32's spacing where they lie exceeds this share of their extent."""


def position_dtype(points: np.ndarray) -> str:
    """``"<f4"`` (float32) for positions float32 holds to :data:`FLOAT32_TOLERANCE` of their extent, else
    ``"<f8"`` (float64): a head at the origin is float32 in any unit; the same head 1e8 mm away is not
    (float32's spacing there is 8 mm).

    Args:
        points: ``(N, 3)`` positions in any unit.

    Example:
        >>> position_dtype(np.array([[0.0, 0.0, 0.0], [200.0, 0.0, 0.0]]))
        '<f4'
        >>> position_dtype(np.array([[1e8, 0.0, 0.0], [1e8 + 200.0, 0.0, 0.0]]))
        '<f8'
    """
    p = np.asarray(points, np.float64)
    if p.size == 0:
        return "<f4"
    extent = float(np.ptp(p, axis=0).max()) if len(p) > 1 else 0.0
    spacing = float(np.spacing(np.float32(np.abs(p).max())))
    return "<f8" if spacing > FLOAT32_TOLERANCE * max(extent, 1e-30) else "<f4"


def binary_ply(
    fields: list[tuple[str, str, np.ndarray]], faces: np.ndarray | None = None, comments: tuple[str, ...] = ()
) -> bytes:
    """A binary little-endian PLY file's bytes.

    Args:
        fields: the vertex properties in order, ``(name, dtype, (N,) values)`` with a dtype of
            :data:`PLY_TYPES`.
        faces: ``(F, 3)`` vertex indices (``property list uchar int vertex_indices``), or None.
        comments: header comment lines (one line each, ASCII; other characters become ``?``).

    Raises:
        ValueError: unequal lengths, an unknown dtype, a comment with a line break, bad faces.
    """
    n = len(fields[0][2]) if fields else 0
    for name, dtype, values in fields:
        if dtype not in PLY_TYPES or np.shape(values) != (n,):
            raise InputError(f"binary_ply: field {name!r}: dtype {dtype!r} and shape ({n},) needed")
    if any("\n" in c or "\r" in c for c in comments):
        raise InputError("binary_ply: a comment must be one line")
    vertex = np.empty(n, dtype=[(name, dtype) for name, dtype, _ in fields])
    for name, _, values in fields:
        vertex[name] = values
    header = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments)]
    header += [f"element vertex {n}"] + [f"property {PLY_TYPES[dtype]} {name}" for name, dtype, _ in fields]
    body = vertex.tobytes()
    if faces is not None:
        f = np.asarray(faces)
        if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= n)):
            raise InputError(f"binary_ply: faces must be (F, 3) indices below {n}, got shape {f.shape}")
        rows = np.empty(len(f), dtype=[("count", "u1"), ("indices", "<i4", (3,))])
        rows["count"], rows["indices"] = 3, f
        header += [f"element face {len(f)}", "property list uchar int vertex_indices"]
        body += rows.tobytes()
    return ("\n".join([*header, "end_header"]) + "\n").encode("ascii", "replace") + body


__all__ = ["FLOAT32_TOLERANCE", "PLY_TYPES", "binary_ply", "position_dtype"]
