"""Writing a triangle mesh as Wavefront OBJ (text) or binary PLY, through ``trimesh``.

* :func:`export_mesh` writes the mesh (optionally with face-varying UVs, vertex colours and, for OBJ,
  a material library and material name).
* :func:`write_mtl` writes a Wavefront material library with one textured material (``map_Kd``).
* :func:`check_mesh_arrays`, :func:`shape_error`, :func:`resolve_format` and :func:`split_uv_seams` are
  the argument checks and the UV-seam split shared with the glTF writer (:mod:`rig.io.gltf`).

Conventions: rig space is right-handed, +Y up, +Z forward out of the face, in millimetres; OBJ and PLY
files hold millimetres, unchanged.

Face-varying texture coordinates (``face_uvs``, one UV per face corner, with a UV seam) cannot be
stored per vertex without splitting the seam vertices. Every file keeps the ``V`` input vertices
first, in their input order, and appends one duplicate per extra (vertex, UV) pair at the end;
faces use the duplicates where needed. The map from every written vertex to its input vertex is
``split_source`` (``split_source[:V] == arange(V)``).

Files are written atomically (:func:`rig.io.atomic.write_bytes_atomic`): the data is encoded in
memory, written to a temporary file beside the destination and moved into place in one step; on any
error the temporary file is removed and an existing destination is left untouched.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from rig.errors import InputError, shape_error
from rig.io.atomic import write_bytes_atomic
from rig.io.ply import binary_ply, position_dtype

__all__ = [
    "OBJ_DIGITS",
    "RIG_SPACE_COMMENT",
    "check_mesh_arrays",
    "export_mesh",
    "resolve_format",
    "split_uv_seams",
    "write_mtl",
]

OBJ_DIGITS = 10
RIG_SPACE_COMMENT = "millimetres, rig space: right-handed, +Y up, +Z out of the face, +X the subject's left"
"""What :func:`export_mesh` states in a file's header by default (``# jnr: ...`` in OBJ, ``comment jnr: ...`` in
PLY); glTF files hold metres (:mod:`rig.io.gltf`)."""
"""Decimal places written for OBJ coordinates (fixed-point; 1e-10 mm for positions)."""


# ----------------------------------------------------------------------------------------------
# argument checks
# ----------------------------------------------------------------------------------------------


def check_mesh_arrays(
    func: str,
    vertices: Any,
    faces: Any,
    face_uvs: Any,
    vertex_colors: Any,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Validate and convert the mesh arguments shared by the writers (:func:`export_mesh`,
    :func:`rig.io.gltf.export_skinned_gltf`).

    Args:
        func: the public function's name, for messages.
        vertices: ``(V, 3)`` real, finite, ``V > 0``.
        faces: ``(F, 3)`` integer indices into ``vertices``, ``F > 0``.
        face_uvs: ``(F, 3, 2)`` finite, or None.
        vertex_colors: ``(V, 3)`` float in [0, 1] or uint8, or None.

    Returns:
        float64 ``(V, 3)`` vertices, int64 ``(F, 3)`` faces, float64 ``(F, 3, 2)`` face UVs or None and
        float64 ``(V, 3)`` colours in [0, 1] or None.

    Raises:
        ValueError: an argument with the wrong shape, dtype or range (message: function, argument,
            expected, got).
    """
    v = np.asarray(vertices)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise shape_error(func, "vertices", "(V, 3) with V > 0", v.shape)
    if not np.issubdtype(v.dtype, np.number) or np.issubdtype(v.dtype, np.complexfloating):
        raise InputError(f"{func}: vertices must be real numbers, got dtype {v.dtype}")
    v = v.astype(np.float64)
    if not np.isfinite(v).all():
        raise InputError(f"{func}: vertices contain NaN or infinite values")
    n_vertices = v.shape[0]

    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise shape_error(func, "faces", "(F, 3) with F > 0", f.shape)
    if not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"{func}: faces must be integer vertex indices, got dtype {f.dtype}")
    f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= n_vertices:
        raise InputError(f"{func}: faces index vertices out of range [0, {n_vertices}): min {f.min()}, max {f.max()}")

    uv = None
    if face_uvs is not None:
        uv = np.asarray(face_uvs)
        if uv.shape != (f.shape[0], 3, 2):
            raise shape_error(func, "face_uvs", f"(F, 3, 2) = ({f.shape[0]}, 3, 2)", uv.shape)
        uv = uv.astype(np.float64) + 0.0  # + 0.0 turns -0.0 into 0.0 so equal UVs compare equal
        if not np.isfinite(uv).all():
            raise InputError(f"{func}: face_uvs contain NaN or infinite values")

    colors = None
    if vertex_colors is not None:
        c = np.asarray(vertex_colors)
        if c.shape != (n_vertices, 3):
            raise shape_error(func, "vertex_colors", f"(V, 3) = ({n_vertices}, 3)", c.shape)
        if c.dtype == np.uint8:
            colors = c.astype(np.float64) / 255.0
        elif np.issubdtype(c.dtype, np.floating):
            colors = c.astype(np.float64)
            if not np.isfinite(colors).all() or colors.min() < -1e-6 or colors.max() > 1 + 1e-6:
                raise InputError(
                    f"{func}: float vertex_colors must lie in [0, 1], got range "
                    f"[{np.nanmin(colors)}, {np.nanmax(colors)}]"
                )
            colors = np.clip(colors, 0.0, 1.0)
        else:
            raise InputError(f"{func}: vertex_colors must be float in [0, 1] or uint8, got dtype {c.dtype}")
    return v, f, uv, colors


def resolve_format(func: str, path: Path, file_format: str | None, allowed: Sequence[str]) -> str:
    """The file format: ``file_format`` if given, else the suffix of ``path`` (lower case, no dot).

    Raises:
        ValueError: the format is not one of ``allowed``.
    """
    if file_format is None:
        fmt = path.suffix.lower().lstrip(".")
        source = f"the suffix of {str(path)!r}"
    else:
        fmt = str(file_format).lower().lstrip(".")
        source = f"file_format={file_format!r}"
    if fmt not in allowed:
        raise InputError(
            f"{func}: unsupported file format {fmt!r} (from {source}); expected one of "
            + ", ".join(repr(a) for a in allowed)
        )
    return fmt


def _colors_uint8(colors: np.ndarray) -> np.ndarray:
    return np.round(np.clip(colors, 0.0, 1.0) * 255.0).astype(np.uint8)


# ----------------------------------------------------------------------------------------------
# UV seams
# ----------------------------------------------------------------------------------------------


def split_uv_seams(
    faces: np.ndarray, face_uvs: np.ndarray, n_vertices: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Turn face-varying UVs into per-vertex UVs by duplicating seam vertices.

    Parameters
    ----------
    faces : (F, 3) int64
    face_uvs : (F, 3, 2) float64
        UV per face corner.
    n_vertices : int
        ``V``.

    Returns
    -------
    split_faces : (F, 3) int64
        Faces into the ``N = V + D`` split vertices.
    uvs : (N, 2) float64
        UV per split vertex; ``(0, 0)`` for vertices no face uses.
    split_source : (N,) int64
        Input vertex of each split vertex; ``split_source[:V] == arange(V)``.

    Notes
    -----
    Each vertex keeps, in its original slot, the UV of its first corner in face order; every other
    distinct UV (exact comparison) of that vertex gets a duplicate appended after the ``V`` input
    vertices, ordered by source vertex, then by first use.
    """
    corner_vertex = faces.reshape(-1)
    corner_uv = face_uvs.reshape(-1, 2)
    keys = np.column_stack([corner_vertex.astype(np.float64), corner_uv])
    _, first_corner, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    group_source = corner_vertex[first_corner]
    order = np.lexsort((first_corner, group_source))  # by source vertex, then first use
    sorted_source = group_source[order]
    is_primary = np.ones(len(order), dtype=bool)
    is_primary[1:] = sorted_source[1:] != sorted_source[:-1]

    group_index = np.empty(len(order), dtype=np.int64)
    group_index[order[is_primary]] = sorted_source[is_primary]
    n_dup = int((~is_primary).sum())
    group_index[order[~is_primary]] = n_vertices + np.arange(n_dup)

    split_source = np.concatenate([np.arange(n_vertices), sorted_source[~is_primary]])
    uvs = np.zeros((n_vertices + n_dup, 2), dtype=np.float64)
    uvs[group_index] = corner_uv[first_corner]
    split_faces = group_index[inverse].reshape(faces.shape)
    return split_faces, uvs, split_source.astype(np.int64)


# ----------------------------------------------------------------------------------------------
# OBJ / PLY
# ----------------------------------------------------------------------------------------------


def _obj_text_trimesh(vertices, faces, uvs, colors, header: str) -> str:
    if uvs is not None:
        visual = trimesh.visual.TextureVisuals(uv=uvs)
    elif colors is not None:
        visual = trimesh.visual.ColorVisuals(vertex_colors=_colors_uint8(colors))
    else:
        visual = None
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, visual=visual, process=False, validate=False)
    text = trimesh.exchange.obj.export_obj(
        mesh,
        include_normals=False,
        include_color=colors is not None,
        include_texture=uvs is not None,
        return_texture=False,
        write_texture=False,
        digits=OBJ_DIGITS,
        header=header,
    )
    # trimesh references a default (empty) material library that we do not write; drop the
    # dangling ``mtllib`` / ``usemtl`` lines (the UVs are kept without them).
    lines = [ln for ln in text.split("\n") if not ln.startswith(("mtllib ", "usemtl "))]
    return "\n".join(lines)


def _obj_text_uv_and_colors(vertices, faces, uvs, colors, header: str) -> str:
    """OBJ text with ``v x y z r g b`` lines and UVs (trimesh's OBJ export holds one or the other)."""
    fmt = f"{{:.{OBJ_DIGITS}f}}"
    v_lines = ["v " + " ".join(fmt.format(x) for x in row) for row in np.column_stack([vertices, colors])]
    vt_lines = ["vt " + " ".join(fmt.format(x) for x in row) for row in uvs]
    f1 = faces + 1
    f_lines = [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in f1]
    return "\n".join([f"# {header}", *v_lines, *vt_lines, *f_lines, "", ""])


def _ply_bytes(vertices, faces, uvs, colors) -> bytes:
    if uvs is not None:
        mesh = trimesh.Trimesh(
            vertices=vertices,
            faces=faces,
            visual=trimesh.visual.TextureVisuals(uv=uvs),
            process=False,
            validate=False,
        )
        if colors is not None:
            # a texture visual holds no colours; write them as the standard uchar properties
            c8 = _colors_uint8(colors)
            for i, channel in enumerate(("red", "green", "blue")):
                mesh.vertex_attributes[channel] = c8[:, i].copy()
    else:
        visual = None
        if colors is not None:
            visual = trimesh.visual.ColorVisuals(vertex_colors=_colors_uint8(colors))
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces, visual=visual, process=False, validate=False)
    return trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=False)


def _check_obj_name(func: str, arg: str, value: str) -> str:
    """A material or file name as one OBJ/MTL token: a non-empty string without whitespace or ``#``."""
    if not isinstance(value, str) or not value or any(ch.isspace() or ch == "#" for ch in value):
        raise InputError(f"{func}: {arg} must be a non-empty name without whitespace or '#', got {value!r}")
    return value


def _with_material(text: str, mtllib: str, material: str) -> str:
    """OBJ text with ``mtllib`` after the leading comment lines and ``usemtl`` before the first face."""
    lines = text.split("\n")
    head = 0
    while head < len(lines) and lines[head].startswith("#"):
        head += 1
    first_face = next((i for i, ln in enumerate(lines) if ln.startswith("f ")), len(lines))
    return "\n".join(
        [*lines[:head], f"mtllib {mtllib}", *lines[head:first_face], f"usemtl {material}", *lines[first_face:]]
    )


def write_mtl(path: str | os.PathLike, material: str, texture: str, *, diffuse=(1.0, 1.0, 1.0)) -> None:
    """Write a Wavefront material library (``.mtl``) with one material whose diffuse colour is a texture.

    Parameters
    ----------
    path : str or os.PathLike
        Destination (written atomically); an OBJ refers to it by ``mtllib <its name>``
        (:func:`export_mesh`'s ``mtllib``).
    material : str
        The material's name (``newmtl``; the OBJ's ``usemtl``), one token.
    texture : str
        The image file of ``map_Kd``, relative to the ``.mtl`` file, one token (no spaces).
    diffuse : 3 floats in [0, 1]
        ``Kd``, which viewers multiply with the texture (white: the texture as it is).

    Raises
    ------
    ValueError
        A name with whitespace or ``#``, or a diffuse colour outside [0, 1].
    """
    func = "write_mtl"
    material = _check_obj_name(func, "material", material)
    texture = _check_obj_name(func, "texture", texture)
    kd = np.asarray(diffuse, dtype=np.float64)
    if kd.shape != (3,) or not np.isfinite(kd).all() or kd.min() < 0 or kd.max() > 1:
        raise InputError(f"{func}: diffuse must be 3 numbers in [0, 1], got {diffuse!r}")
    text = "\n".join(
        [
            "# jnr",
            f"newmtl {material}",
            "Ka 0.000000 0.000000 0.000000",
            "Kd " + " ".join(f"{x:.6f}" for x in kd),
            "Ks 0.000000 0.000000 0.000000",
            "d 1.000000",
            "illum 1",
            f"map_Kd {texture}",
            "",
        ]
    )
    write_bytes_atomic(Path(path), text.encode("utf-8"))


def export_mesh(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    face_uvs: np.ndarray | None = None,
    vertex_colors: np.ndarray | None = None,
    file_format: str | None = None,
    mtllib: str | None = None,
    material: str | None = None,
    comment: str = RIG_SPACE_COMMENT,
) -> None:
    """Write a triangle mesh as Wavefront OBJ (text) or PLY (binary little-endian).

    Written through ``trimesh`` with ``process=False``, so no vertex is merged or reordered: the
    first ``V`` vertices of the file are ``vertices`` in order. When ``face_uvs`` has more than
    one UV for a vertex (a UV seam), duplicates of that vertex are appended after the first ``V``
    and faces use them where needed (see the module docstring); ``trimesh.load(path,
    process=False)`` then returns ``V + D`` vertices whose first ``V`` are the input.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file. Written atomically (:func:`rig.io.atomic.write_bytes_atomic`); its
        directory must exist.
    vertices : (V, 3) float
        Vertex positions in millimetres (written unchanged, in millimetres).
    faces : (F, 3) int
        Triangles as indices into ``vertices`` (counter-clockwise seen from outside).
    face_uvs : (F, 3, 2) float, optional
        Texture coordinates per face corner (face-varying, OBJ/OpenGL convention: v up).
        OBJ: ``vt`` lines; PLY: per-vertex ``s``/``t`` properties.
    vertex_colors : (V, 3) float in [0, 1] or uint8, optional
        Per-vertex RGB. OBJ: ``v x y z r g b`` (floats in [0, 1]); PLY: uchar ``red``/``green``/
        ``blue`` (plus ``alpha`` = 255 when no UVs are given).
    file_format : {"obj", "ply"}, optional
        Overrides the format inferred from the suffix of ``path``.
    mtllib, material : str, optional
        OBJ only, both or neither, and only with ``face_uvs``: the material library's file name
        (relative to the OBJ; written by :func:`write_mtl`) and the material the faces use: an
        ``mtllib`` line after the header comment and ``usemtl`` before the faces.
    comment : str
        The units and frame, stated in the header: OBJ's first line ``# jnr: <comment>``, PLY's
        ``comment jnr: <comment>`` (one line). Default :data:`RIG_SPACE_COMMENT`.

    Raises
    ------
    ValueError
        Unsupported format, an argument with the wrong shape, dtype or range, or a material for a
        PLY file, without UVs, or with a name that is not one token.

    Notes
    -----
    OBJ coordinates are written with ``OBJ_DIGITS`` (10) decimal places. PLY stores positions as
    float32 (about 1e-5 mm resolution at 100 mm), or as float64 where float32 would lose them
    (:func:`rig.io.ply.position_dtype`: a mesh far from the origin). Vertices that no face uses are written, but
    trimesh's OBJ loader drops them on reading.
    """
    func = "export_mesh"
    path = Path(path)
    fmt = resolve_format(func, path, file_format, ("obj", "ply"))
    if not isinstance(comment, str) or "\n" in comment or "\r" in comment:
        raise InputError(f"{func}: comment must be one line of text, got {comment!r}")
    header = f"jnr: {comment}"
    v, f, uv, colors = check_mesh_arrays(func, vertices, faces, face_uvs, vertex_colors)
    if (mtllib is None) != (material is None):
        raise InputError(f"{func}: mtllib and material go together, got mtllib={mtllib!r}, material={material!r}")
    if mtllib is not None:
        if fmt != "obj":
            raise InputError(f"{func}: a material (mtllib, material) is written to OBJ files only, not {fmt!r}")
        if uv is None:
            raise InputError(f"{func}: a textured material needs face_uvs")
        _check_obj_name(func, "mtllib", mtllib)
        _check_obj_name(func, "material", material)

    if uv is not None:
        f, uvs, source = split_uv_seams(f, uv, v.shape[0])
        v = v[source]
        colors = colors[source] if colors is not None else None
    else:
        uvs = None

    if fmt == "obj":
        if uvs is not None and colors is not None:
            text = _obj_text_uv_and_colors(v, f, uvs, colors, header)
        else:
            text = _obj_text_trimesh(v, f, uvs, colors, header)
        if mtllib is not None:
            text = _with_material(text, mtllib, material)
        data = text.encode("utf-8")
    elif position_dtype(v) == "<f8":  # far from the origin: float32 would lose the positions
        data = _ply_bytes_float64(v, f, uvs, colors, header)
    else:
        data = _with_ply_comment(_ply_bytes(v, f, uvs, colors), header)
    write_bytes_atomic(path, data)


def _ply_bytes_float64(vertices, faces, uvs, colors, comment: str) -> bytes:
    """A PLY mesh with float64 ``x y z`` (:func:`rig.io.ply.position_dtype`), the same other properties as
    :func:`_ply_bytes` (``s t`` texture coordinates, ``red green blue``)."""
    fields = [(c, "<f8", vertices[:, i]) for i, c in enumerate("xyz")]
    if uvs is not None:
        fields += [(c, "<f4", uvs[:, i]) for i, c in enumerate("st")]
    if colors is not None:
        c8 = _colors_uint8(colors)
        fields += [(c, "u1", c8[:, i]) for i, c in enumerate(("red", "green", "blue"))]
    return binary_ply(fields, faces, comments=(comment,))


def _with_ply_comment(data: bytes, comment: str) -> bytes:
    """PLY bytes with ``comment <comment>`` after the ``format`` line of the header."""
    end = data.index(b"\n", data.index(b"\nformat ") + 1) + 1
    return data[:end] + b"comment " + comment.encode("ascii", "replace") + b"\n" + data[end:]
