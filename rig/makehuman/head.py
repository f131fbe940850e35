"""The head cut from MakeHuman's base mesh: the skin of the head parts and a short neck, the eyeballs, the
tongue and the teeth, triangulated mirror-symmetrically (:func:`head_mesh`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from rig.errors import SetupError
from rig.makehuman.base_mesh import face_parts, part_names, read_base_mesh, read_mirror

HEAD_PARTS = ("head", "eye_cavity.L", "eye_cavity.R", "mouth_cavity")
"""Atlas parts of the skin kept (the face and scalp, the eye pockets, the mouth bag)."""
NECK_MIN_Y_MM = 560.0
NECK_MAX_ABS_X_MM = 80.0
"""Body faces wholly above this height and within this distance of the midline (mm, MakeHuman's frame)
are added below the head's cut: a short neck, still one boundary loop."""
PIECES = ("skin", "neck", "eyeballs", "tongue", "teeth")
"""What each face of :class:`HeadMesh` belongs to (``face_piece`` indexes this)."""
_HELPERS = {
    "eyeballs": ("helper-l-eye", "helper-r-eye"),
    "tongue": ("helper-tongue",),
    "teeth": ("helper-upper-teeth", "helper-lower-teeth"),
}


@dataclass(frozen=True)
class HeadMesh:
    """The MakeHuman head as a triangle mesh (issue 13's template before it is placed and rigged).

    Attributes:
        vertices: ``(V, 3)`` float64, mm, rig axes, at MakeHuman's body height.
        faces: ``(F, 3)`` int64, counter-clockwise seen from outside.
        uvs: ``(T, 2)`` texture coordinates; face_uvs: ``(F, 3)`` indices into them (face-varying).
        mirror: ``(V,)`` int64 mirror vertex of each vertex (exact: ``vertices[mirror] = vertices * (-1, 1, 1)``).
        face_piece: ``(F,)`` int64 index into :data:`PIECES`.
        face_part: ``(F,)`` int64 the atlas part under each face (index into :func:`part_names`, -1 none).
        source: ``(V,)`` int64 index of each vertex in MakeHuman's base mesh (targets are defined on it).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    face_uvs: np.ndarray
    mirror: np.ndarray
    face_piece: np.ndarray
    face_part: np.ndarray
    source: np.ndarray


def triangulate(quads: np.ndarray, vertices: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """Split quads ``(Q, 4)`` (vertex ids, a triangle repeats its last corner) into triangles, two per quad
    ``(2Q, 3)`` (degenerate ones dropped later by the caller), along the shorter diagonal; a tie goes to
    the diagonal with the smaller mirror-invariant key, so a quad and its mirror image are split alike
    (the mesh is exactly symmetric, so mirrored diagonals have equal lengths).

    Returns:
        ``(Q,)`` bool: True where the quad is split along ``(0, 2)``, else along ``(1, 3)``.
    """
    q = np.asarray(quads, np.int64)
    v = np.asarray(vertices, np.float64)
    ac = ((v[q[:, 0]] - v[q[:, 2]]) ** 2).sum(1)
    bd = ((v[q[:, 1]] - v[q[:, 3]]) ** 2).sum(1)
    low = np.minimum(q, mirror[q])
    key_ac = np.sort(low[:, [0, 2]], 1)
    key_bd = np.sort(low[:, [1, 3]], 1)
    key_smaller = (key_ac[:, 0] < key_bd[:, 0]) | ((key_ac[:, 0] == key_bd[:, 0]) & (key_ac[:, 1] < key_bd[:, 1]))
    return np.where(ac == bd, key_smaller, ac < bd)


def _triangles(
    quads: np.ndarray, quad_uvs: np.ndarray, along_ac: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two triangles of each quad (same orientation), without degenerate ones: ``(T, 3)`` vertex ids,
    ``(T, 3)`` uv ids and the ``(T,)`` index of the quad each came from."""
    corners = np.where(along_ac[:, None, None], np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0, 1, 3], [1, 2, 3]]))
    rows = np.arange(len(quads))[:, None, None]
    tris, tri_uvs = quads[rows, corners].reshape(-1, 3), quad_uvs[rows, corners].reshape(-1, 3)
    keep = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 2] != tris[:, 0])
    return tris[keep], tri_uvs[keep], np.repeat(np.arange(len(quads)), 2)[keep]


@cache
def head_mesh() -> HeadMesh:
    """The head cut from MakeHuman's base mesh: the skin of the atlas's head parts (:data:`HEAD_PARTS`)
    and a short neck, both full eyeballs, the tongue and the two teeth strips; triangulated by
    :func:`triangulate`, vertices renumbered in base-mesh order."""
    mesh = read_base_mesh()
    mirror = read_mirror(num_vertices=len(mesh.vertices))
    parts, names = face_parts(mesh), part_names()
    corners = mesh.vertices[mesh.faces]
    skin = mesh.group_faces("body") & np.isin(parts, [names.index(n) for n in HEAD_PARTS])
    neck = (
        mesh.group_faces("body")
        & ~skin
        & (corners[:, :, 1] > NECK_MIN_Y_MM).all(1)
        & (np.abs(corners[:, :, 0]) < NECK_MAX_ABS_X_MM).all(1)
    )
    piece = np.full(len(mesh.faces), -1, np.int64)
    piece[skin], piece[neck] = PIECES.index("skin"), PIECES.index("neck")
    for name, groups in _HELPERS.items():
        piece[mesh.group_faces(*groups)] = PIECES.index(name)
    chosen = piece >= 0
    quads, quad_uvs = mesh.faces[chosen], mesh.face_uvs[chosen]
    along_ac = triangulate(quads, mesh.vertices, mirror)
    tris, tri_uvs, from_quad = _triangles(quads, quad_uvs, along_ac)
    tri_piece, tri_part = piece[chosen][from_quad], parts[chosen][from_quad]
    source = np.unique(tris)
    if not np.isin(mirror[source], source).all():
        raise SetupError("the MakeHuman head cut is not closed under the mirror map")
    new = np.full(len(mesh.vertices), -1, np.int64)
    new[source] = np.arange(len(source))
    uv_ids = np.unique(tri_uvs)
    new_uv = np.full(len(mesh.uvs), -1, np.int64)
    new_uv[uv_ids] = np.arange(len(uv_ids))
    return HeadMesh(
        vertices=mesh.vertices[source],
        faces=new[tris],
        uvs=mesh.uvs[uv_ids],
        face_uvs=new_uv[tri_uvs],
        mirror=new[mirror[source]],
        face_piece=tri_piece,
        face_part=tri_part,
        source=source,
    )


__all__ = ["HEAD_PARTS", "NECK_MAX_ABS_X_MM", "NECK_MIN_Y_MM", "PIECES", "HeadMesh", "head_mesh", "triangulate"]
