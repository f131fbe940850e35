"""The 68 iBUG landmarks embedded on the template: one face index + three barycentric weights each.

Every landmark is first placed from the template's own structure (eyelid and lip loops, regions, the
midline, geometric extremes), so it follows the template if the template is regenerated; then the
committed corrections (:data:`LANDMARK_CORRECTIONS_MM`, :data:`CONTOUR_ANGLES_DEG`) move it to where
dlib's 68-point predictor -- the detector the photo fit uses -- puts it on renders of the template
(``benchmarks/bench_landmark_offsets.py``; ``docs/landmarks.md``). No rendering happens at run time:
the embedding is a function of the asset and the two tables. Landmarks on the subject's left (+X) and
on the midline are computed, their right-side partners are obtained through the vertex mirror map, so
each pair is an exact mirror image; midline landmarks lie exactly on x = 0 (midline vertices and edges).
The order is the standard iBUG-68 order (:data:`IBUG68_NAMES`); a golden test pins the face ids.

===========  ==========================================================================
indices      geometric placement (before the corrections)
===========  ==========================================================================
0-16         jaw contour: the face's side outline seen from the front (cheeks, jaw,
             chin regions), from the right ear side (-X, at the outer eye corner's height)
             down to the chin (8, lowest midline chin vertex) and up to the left, in 9
             equal arc-length steps per side
17-21/22-26  right brow outer->inner / left brow inner->outer, along the middle of the
             brow band
27-30        nose bridge, on the midline from the top of the upper eyelids to the tip
31-35        lower edge of the nose, right->left (33 = lowest forward midline point)
36-41/42-47  eyelid loops: corners, and the lids at 1/3 and 2/3 of the corner-to-corner width
48-59        outer lip on the vermilion border (the outermost edge ring around the mouth
             loop inside the ``lips`` region): corners, 51/57 on the midline, 50/52 the
             Cupid's bow peaks, 49/53 halfway to the corners, 55-59 under 53..49
60-67        inner lip on the mouth loop (the lips' rim): corners, midline, and under the
             bow peaks
===========  ==========================================================================

Corrected, every landmark stays on its surface: brows on faces touching the ``brows`` region, the
nose base on ``nose`` faces, the outer lip on ``lips`` faces, eyelid points on the eyelid rims, inner
lip points on the mouth loop, midline landmarks on the midline; the static contour on the frontal
outline (each point's direction from the contour centre: :data:`CONTOUR_ANGLES_DEG`).

:func:`landmark_positions` gathers the posed landmarks with one einsum (differentiable in torch).
:func:`contour_landmarks` replaces the static jaw contour with the silhouette seen from a camera
(for turned heads), as FLAME's dynamic contour does.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch

from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.geometry import barycentric, closest_points_on_triangles, face_edges
from rig.lbs import ShapeError

IBUG68_NAMES: tuple[str, ...] = (
    *(f"jaw_{i:02d}" for i in range(17)),
    *(f"right_brow_{i}" for i in range(5)),
    *(f"left_brow_{i}" for i in range(5)),
    *(f"nose_bridge_{i}" for i in range(4)),
    *(f"nose_base_{i}" for i in range(5)),
    "right_eye_outer", "right_eye_upper_0", "right_eye_upper_1", "right_eye_inner",
    "right_eye_lower_0", "right_eye_lower_1",
    "left_eye_inner", "left_eye_upper_0", "left_eye_upper_1", "left_eye_outer",
    "left_eye_lower_0", "left_eye_lower_1",
    "outer_lip_right_corner", *(f"outer_lip_upper_{i}" for i in range(5)), "outer_lip_left_corner",
    *(f"outer_lip_lower_{i}" for i in range(5)),
    "inner_lip_right_corner", *(f"inner_lip_upper_{i}" for i in range(3)), "inner_lip_left_corner",
    *(f"inner_lip_lower_{i}" for i in range(3)),
)

JAW_CONTOUR = tuple(range(17))
"""Indices of the jaw-contour landmarks (weighted down in the 2D loss, dynamic in :func:`contour_landmarks`)."""
CHIN = 8

IBUG68_MIRROR: tuple[int, ...] = tuple(
    [16 - i for i in range(17)]
    + [26 - i for i in range(5)] + [21 - i for i in range(5)]
    + [27, 28, 29, 30]
    + [35, 34, 33, 32, 31]
    + [45, 44, 43, 42, 47, 46] + [39, 38, 37, 36, 41, 40]
    + [54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55]
    + [64, 63, 62, 61, 60, 67, 66, 65]
)
"""``IBUG68_MIRROR[i]``: the landmark that is the mirror image (x -> -x) of landmark ``i``."""

_SIDE_REGIONS = ("cheeks", "jaw", "chin")


@dataclass(frozen=True)
class LandmarkEmbedding:
    """Landmarks as points on template faces.

    Attributes:
        faces: ``(68,)`` int64 template face index of each landmark.
        barycentric: ``(68, 3)`` float64 weights of that face's three vertices (non-negative, sum 1).
    """

    faces: np.ndarray
    barycentric: np.ndarray


# --- small mesh helpers ----------------------------------------------------------------------------------

def _faces_with(faces: np.ndarray, *vertex_ids: int) -> np.ndarray:
    mask = np.ones(len(faces), bool)
    for v in vertex_ids:
        mask &= (faces == v).any(1)
    return np.flatnonzero(mask)


def _vertex_point(faces: np.ndarray, v: int) -> tuple[int, np.ndarray]:
    f = int(_faces_with(faces, v)[0])
    return f, (faces[f] == v).astype(float)


def _edge_point(faces: np.ndarray, a: int, b: int, t: float) -> tuple[int, np.ndarray]:
    """The point ``(1 - t) * a + t * b`` on edge ``a-b``."""
    if t <= 0.0:
        return _vertex_point(faces, a)
    if t >= 1.0:
        return _vertex_point(faces, b)
    candidates = _faces_with(faces, a, b)
    if len(candidates) == 0:
        raise RuntimeError(f"ibug68: vertices {a} and {b} share no face")
    f = int(candidates[0])
    return f, (faces[f] == a) * (1.0 - t) + (faces[f] == b) * t


def _crossing(vertices: np.ndarray, faces: np.ndarray, path: np.ndarray, axis: int, value: float
              ) -> tuple[int, np.ndarray]:
    """First point along the vertex path whose coordinate ``axis`` equals ``value`` (interpolated on an edge)."""
    c = vertices[path, axis] - value
    for k in range(len(path) - 1):
        if c[k] == 0.0:
            return _vertex_point(faces, int(path[k]))
        if c[k] * c[k + 1] < 0.0 or c[k + 1] == 0.0:
            return _edge_point(faces, int(path[k]), int(path[k + 1]), c[k] / (c[k] - c[k + 1]))
    raise RuntimeError(f"ibug68: path never reaches coordinate {axis} = {value:.3f}")


def _split_loop(vertices: np.ndarray, loop: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """The two halves of a closed vertex loop between loop vertices ``a`` and ``b`` (both include both ends),
    returned ``(upper, lower)`` by mean height, each running from ``a`` to ``b``."""
    loop = np.asarray(loop)
    ia, ib = int(np.flatnonzero(loop == a)[0]), int(np.flatnonzero(loop == b)[0])
    rolled = np.roll(loop, -ia)
    ib = (ib - ia) % len(loop)
    one = rolled[: ib + 1]
    other = np.concatenate([rolled[ib:], rolled[:1]])[::-1]
    if vertices[one, 1].mean() >= vertices[other, 1].mean():
        return one, other
    return other, one


def _mirror_point(faces: np.ndarray, mirror: np.ndarray, face: int, bary: np.ndarray,
                  face_lookup: dict) -> tuple[int, np.ndarray]:
    mverts = mirror[faces[face]]
    g = face_lookup.get(tuple(sorted(mverts.tolist())))
    if g is None:
        raise RuntimeError(f"ibug68: face {face} has no mirror face; the template topology is not symmetric")
    order = [int(np.flatnonzero(mverts == w)[0]) for w in faces[g]]
    return g, bary[order]


def _midline_path(vertices: np.ndarray, mirror: np.ndarray, faces: np.ndarray, y_lo: float, y_hi: float,
                  z_min: float) -> np.ndarray:
    """Midline vertices on the front of the face between two heights, top to bottom."""
    ids = np.flatnonzero((mirror == np.arange(len(vertices))) & (vertices[:, 1] >= y_lo)
                         & (vertices[:, 1] <= y_hi) & (vertices[:, 2] >= z_min))
    return ids[np.argsort(-vertices[ids, 1])]


# --- the committed corrections ---------------------------------------------------------------------------

LANDMARK_CORRECTIONS_MM: dict[int, tuple[float, float, float]] = {
    8: (0.0, 1.6, 14.2),  # jaw_08
    22: (1.4, -6.6, -0.3),  # left_brow_0
    23: (2.3, -2.0, -0.5),  # left_brow_1
    24: (3.3, 2.1, -1.4),  # left_brow_2
    25: (5.9, 1.5, -5.3),  # left_brow_3
    26: (5.0, -4.5, -6.6),  # left_brow_4
    27: (0.0, -3.3, -0.2),  # nose_bridge_0
    28: (0.0, -2.4, 1.4),  # nose_bridge_1
    29: (0.0, -0.1, 0.1),  # nose_bridge_2
    30: (0.0, 1.3, -0.2),  # nose_bridge_3
    33: (0.0, 1.3, 0.6),  # nose_base_2
    34: (0.1, -0.8, -0.2),  # nose_base_3
    35: (0.4, 4.6, 0.8),  # nose_base_4
    42: (0.0, 0.0, 0.0),  # left_eye_inner
    43: (-1.2, -0.2, 0.1),  # left_eye_upper_0
    44: (-0.5, 0.1, 0.2),  # left_eye_upper_1
    45: (-0.5, 2.0, 1.3),  # left_eye_outer
    46: (0.4, 0.1, -0.2),  # left_eye_lower_0
    47: (-0.9, 0.1, -0.1),  # left_eye_lower_1
    51: (0.0, -2.3, -0.3),  # outer_lip_upper_2
    52: (1.1, -1.1, -0.4),  # outer_lip_upper_3
    53: (0.3, -1.7, -0.4),  # outer_lip_upper_4
    54: (-1.8, 0.4, 0.1),  # outer_lip_left_corner
    55: (0.3, 1.1, 0.2),  # outer_lip_lower_0
    56: (1.4, 0.6, 0.0),  # outer_lip_lower_1
    57: (0.0, 0.5, 0.2),  # outer_lip_lower_2
    63: (0.9, -1.3, 0.7),  # inner_lip_upper_2
    64: (-4.3, -0.4, 1.2),  # inner_lip_left_corner
    65: (0.9, 0.1, -0.1),  # inner_lip_lower_0
}
"""Per landmark of the left side and the midline (x >= 0; the right side is their mirror image), a 3D
offset in mm, template space, rounded to 0.1 mm, added to the geometric placement before the point is
snapped back onto the landmark's surface (:func:`_snap`: its region's faces, its rim, or the midline).

It moves the geometric placement to where dlib's 68-point predictor (:mod:`landmarks.detect`) puts the
landmark on renders of the template: ``benchmarks/bench_landmark_offsets.py --fit`` photographs the
template in a grid of poses (:func:`pipeline.synthetic.photos.simulate_photo`), detects, and for each
landmark (with its mirror partner, mirrored) takes the point of its surface whose projections agree
best with the detections over all views (least squares); the row is that point minus the placement.
Landmarks without a row keep their placement (the lips' midline rim vertices 62 and 66 have no
freedom: the mouth loop crosses the midline at one vertex each). Results: ``docs/landmarks.md``."""

CONTOUR_ANGLES_DEG: tuple[float, ...] = (-0.1, 16.0, 27.1, 44.1, 53.4, 63.9, 75.8, 82.9)
"""The static jaw contour of the left side, landmarks 16, 15, ..., 9: the direction of each point as
seen from the contour centre (x = 0, the outer eye corners' height) in the frontal projection, degrees
below the horizontal; each point is the frontal-outline vertex nearest that direction. Fitted with
:data:`LANDMARK_CORRECTIONS_MM` (the direction sets the line across the cheek on which
:func:`contour_landmarks` looks for the silhouette); empty: the geometric placement (9 equal steps of
arc length along the outline from the eye corners' height to the chin)."""

_HIDDEN_REGIONS = ("eyeballs", "mouth_interior", "teeth", "tongue", "eye_pockets")


# --- the jaw contour -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Outline:
    vertex_ids: np.ndarray  # the frontal outline of the left half, from the horizontal down to the chin
    angles: np.ndarray  # each vertex's direction from the centre, degrees below the horizontal (~0 .. 90)
    centre: np.ndarray  # (2,) contour centre (x, y)
    allowed: np.ndarray  # vertex ids the contour may use (cheeks, jaw, chin; front half)
    chin_id: int


@dataclass(frozen=True)
class _ContourData:
    vertex_ids: np.ndarray  # (17,) static contour vertices (left half placed, right mirrored)
    directions: np.ndarray  # (17, 2) outward frontal directions (x, y) from the contour centre
    centre: np.ndarray  # (2,) contour centre (x, y)
    candidates: tuple[np.ndarray, ...]  # per contour point: vertex ids front -> back (empty for the chin)


@cached_per_asset
def _outline(asset: RigAsset) -> _Outline:
    v, mirror = asset.vertices, asset.mirror
    eye_outer = [int(loop[np.argmax(np.abs(v[loop, 0]))]) for loop in asset.eye_loops]
    centre = np.array([0.0, float(np.mean(v[eye_outer, 1]))])
    chin = np.flatnonzero(asset.region_mask("chin") & (mirror == np.arange(len(v))))
    chin_id = int(chin[np.argmin(v[chin, 1])])
    allowed = np.flatnonzero(asset.region_mask(*_SIDE_REGIONS) & (v[:, 2] > 0.0))
    # The frontal outline of the left half: for each angle from horizontal (0) to straight down (-90 deg),
    # the allowed vertex projecting farthest from the centre within a narrow angular sector.
    rel = v[allowed, :2] - centre
    ang = np.arctan2(rel[:, 1], rel[:, 0])
    radius = np.linalg.norm(rel, axis=1)
    outline = []
    for a in np.deg2rad(np.linspace(0.0, -90.0, 91)):
        sector = np.flatnonzero((np.abs(ang - a) < np.deg2rad(2.0)) & (rel[:, 0] >= 0.0))
        if len(sector):
            outline.append(int(allowed[sector[np.argmax(radius[sector])]]))
    outline = [i for k, i in enumerate(outline) if k == 0 or i != outline[k - 1]]
    outline = np.array(outline[:-1] + [chin_id]) if outline[-1] != chin_id else np.array(outline)
    rel = v[outline, :2] - centre
    angles = -np.rad2deg(np.arctan2(rel[:, 1], rel[:, 0]))
    return _Outline(outline, angles, centre, allowed, chin_id)


def _contour_ids(asset: RigAsset, corrected: bool) -> np.ndarray:
    """``(17,)`` the static contour vertices: the left half from the outline, the right half mirrored."""
    o, v = _outline(asset), asset.vertices
    if corrected and CONTOUR_ANGLES_DEG:
        if len(CONTOUR_ANGLES_DEG) != 8:
            raise RuntimeError(f"ibug68: CONTOUR_ANGLES_DEG needs 8 angles (16..9), has {len(CONTOUR_ANGLES_DEG)}")
        left_half = [int(o.vertex_ids[np.argmin(np.abs(o.angles - a))]) for a in CONTOUR_ANGLES_DEG]
    else:
        # 9 equal arc-length steps along the outline (frontal projection): 16 (eye corners' height) .. 8 (chin).
        seg = np.linalg.norm(np.diff(v[o.vertex_ids, :2], axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        left_half = [int(o.vertex_ids[int(np.argmin(np.abs(s - t)))]) for t in np.linspace(0.0, s[-1], 9)][:8]
    left_ids = [o.chin_id] + left_half[::-1]  # 8..16
    return np.array([int(asset.mirror[i]) for i in left_ids[:0:-1]] + left_ids, np.int64)


def _contour_from_ids(asset: RigAsset, ids: np.ndarray) -> _ContourData:
    """The dynamic contour's candidate lines for static contour vertices ``ids`` (17; the chin gets none)."""
    v, o = asset.vertices, _outline(asset)
    centre, cand_pool = o.centre, o.allowed
    # Candidate lines: allowed vertices near the plane through the centre spanned by the outward frontal
    # direction and +Z (a slice across the cheek from the front towards the ear), sorted front to back.
    directions = v[ids, :2] - centre
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    candidates = []
    for k in range(len(ids)):
        if k == CHIN:
            candidates.append(np.zeros(0, np.int64))
            continue
        d = directions[k]
        rel = v[cand_pool, :2] - centre
        along, across = rel @ d, rel @ np.array([-d[1], d[0]])
        near = cand_pool[(np.abs(across) < 3.0) & (along > 0.5 * (v[ids[k], :2] - centre) @ d)]
        line = np.unique(np.concatenate([near, [ids[k]]]))
        candidates.append(line[np.argsort(-v[line, 2])])
    return _ContourData(np.asarray(ids, np.int64), directions, centre, tuple(candidates))


@cached_per_asset
def _contour(asset: RigAsset) -> _ContourData:
    return _contour_from_ids(asset, _contour_ids(asset, corrected=True))


@cached_per_asset
def _contour_heuristic(asset: RigAsset) -> _ContourData:
    return _contour_from_ids(asset, _contour_ids(asset, corrected=False))


# --- where each landmark may lie ---------------------------------------------------------------------------

@dataclass(frozen=True)
class _Domain:
    """The surface a landmark is snapped onto: template faces, or mesh edges (a rim or the midline)."""

    faces: np.ndarray  # (F,) face ids (empty when ``edges`` is used)
    edges: np.ndarray  # (E, 2) vertex ids


_DOMAIN_REGIONS = {  # landmark -> the regions of its domain (left side and midline)
    **{k: ("brows",) for k in range(22, 27)},
    **{k: ("nose", "forehead", "brows", "eyelids") for k in (27, 28, 29, 30)},
    **{k: ("nose",) for k in (33, 34, 35)},
    **{k: ("lips",) for k in range(51, 58)},
    CHIN: ("chin",),
}


@cached_per_asset
def _domains(asset: RigAsset) -> dict[int, _Domain]:
    v, faces, mirror = asset.vertices, np.asarray(asset.faces, np.int64), asset.mirror
    hidden = asset.region_mask(*_HIDDEN_REGIONS)
    skin = np.flatnonzero(~hidden[faces].any(1))
    edges = np.unique(np.sort(face_edges(faces[skin]), 1), axis=0)
    on_mid = mirror == np.arange(len(v))
    midline_edges = edges[on_mid[edges].all(1)]
    empty_f, empty_e = np.zeros(0, np.int64), np.zeros((0, 2), np.int64)

    def loop_edges(loop) -> np.ndarray:
        loop = np.asarray(loop, np.int64)
        return np.stack([loop, np.roll(loop, -1)], 1)

    left_eye = int(np.argmax([v[loop, 0].mean() for loop in asset.eye_loops]))
    out: dict[int, _Domain] = {}
    for k, regions in _DOMAIN_REGIONS.items():
        mask = asset.region_mask(*regions)
        if IBUG68_MIRROR[k] == k:
            out[k] = _Domain(empty_f, midline_edges[mask[midline_edges].any(1)])
        else:
            out[k] = _Domain(skin[mask[faces[skin]].any(1)], empty_e)
    for k in range(42, 48):
        out[k] = _Domain(empty_f, loop_edges(asset.eye_loops[left_eye]))
    for k in (63, 64, 65):
        out[k] = _Domain(empty_f, loop_edges(asset.mouth_loop))
    return out


def _snap(asset: RigAsset, domain: _Domain, p: np.ndarray) -> tuple[int, np.ndarray]:
    """The point of ``domain`` closest to ``p``, as ``(face, barycentric)``."""
    v, faces = asset.vertices, asset.faces
    if len(domain.faces):
        return _closest_point_on_faces(v, faces, domain.faces, p)
    a, b = v[domain.edges[:, 0]], v[domain.edges[:, 1]]
    t = np.clip(((p - a) * (b - a)).sum(1) / ((b - a) ** 2).sum(1), 0.0, 1.0)
    q = a + t[:, None] * (b - a)
    best = int(np.argmin(((q - p) ** 2).sum(1)))
    return _edge_point(faces, int(domain.edges[best, 0]), int(domain.edges[best, 1]), float(t[best]))


def snap_domain_points(asset: RigAsset, k: int, steps: int = 6) -> np.ndarray:
    """``(N, 3)`` sample points (mm) of the surface that landmark ``k`` (left side or midline, 17-67 or the
    chin) is snapped onto after its correction: a barycentric grid of ``steps`` per edge on each face, or
    ``steps`` per edge along a rim / the midline. For fitting :data:`LANDMARK_CORRECTIONS_MM`."""
    domain = _domains(asset).get(int(k))
    if domain is None:
        raise KeyError(f"ibug68: landmark {k} has no correction domain")
    v = asset.vertices
    if len(domain.faces):
        grid = np.array([(i, j, steps - i - j) for i in range(steps + 1) for j in range(steps + 1 - i)], float) / steps
        return np.einsum("gk,fkc->fgc", grid, v[asset.faces[domain.faces]]).reshape(-1, 3)
    t = np.linspace(0.0, 1.0, steps + 1)[None, :, None]
    a, b = v[domain.edges[:, 0]][:, None], v[domain.edges[:, 1]][:, None]
    return (a + t * (b - a)).reshape(-1, 3)


# --- the embedding ---------------------------------------------------------------------------------------

def _ordered_ring(faces: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """The vertices of a closed edge loop in loop order."""
    ring_set = {int(i) for i in ring}
    edges = np.unique(np.sort(face_edges(faces), 1), axis=0)
    edges = edges[np.isin(edges, ring).all(1)]
    nbrs: dict[int, list[int]] = {i: [] for i in ring_set}
    for a, b in edges:
        nbrs[int(a)].append(int(b))
        nbrs[int(b)].append(int(a))
    if any(len(n) != 2 for n in nbrs.values()):
        raise RuntimeError("ibug68: the lip ring is not a simple closed loop")
    start = int(min(ring_set))
    order = [start, nbrs[start][0]]
    while True:
        nxt = next(n for n in nbrs[order[-1]] if n != order[-2])
        if nxt == start:
            break
        order.append(nxt)
    if len(order) != len(ring_set):
        raise RuntimeError("ibug68: the lip ring is not a simple closed loop")
    return np.array(order, np.int64)


def _outer_lip_ring(asset: RigAsset) -> np.ndarray:
    """The vermilion border: of the edge rings around the mouth loop (each one mesh ring further out), the
    outermost that lies wholly in the ``lips`` region; in loop order."""
    v, faces = asset.vertices, np.asarray(asset.faces, np.int64)
    hidden = asset.region_mask(*_HIDDEN_REGIONS)
    lips = asset.region_mask("lips")
    edges = np.unique(np.sort(face_edges(faces), 1), axis=0)
    nbrs: list[list[int]] = [[] for _ in range(len(v))]
    for a, b in edges:
        nbrs[a].append(int(b))
        nbrs[b].append(int(a))
    seen = np.zeros(len(v), bool)
    ring = np.asarray(asset.mouth_loop, np.int64)
    seen[ring] = True
    best = None
    while True:
        nxt = sorted({w for u in ring for w in nbrs[u] if not seen[w] and not hidden[w]})
        if not nxt or not lips[nxt].all():
            break
        seen[nxt] = True
        ring = np.array(nxt, np.int64)
        best = ring
    if best is None:
        raise RuntimeError("ibug68: no ring of lips vertices around the mouth loop")
    return _ordered_ring(faces, best)


def _placement(asset: RigAsset) -> dict[int, tuple[int, np.ndarray]]:
    """The geometric placement of the left side and the midline (17-67; the chin), ``{k: (face, bary)}``."""
    v, faces, mirror = asset.vertices, asset.faces, asset.mirror
    points: dict[int, tuple[int, np.ndarray]] = {CHIN: _vertex_point(faces, _outline(asset).chin_id)}

    # Left eye 42-47 (loop with +X): corners, and the lids at 1/3 and 2/3 of the corner-to-corner width.
    left_eye = int(np.argmax([v[loop, 0].mean() for loop in asset.eye_loops]))
    loop = np.asarray(asset.eye_loops[left_eye])
    inner, outer = int(loop[np.argmin(v[loop, 0])]), int(loop[np.argmax(v[loop, 0])])
    upper, lower = _split_loop(v, loop, inner, outer)
    xi, xo = v[inner, 0], v[outer, 0]
    points[42] = _vertex_point(faces, inner)
    points[43] = _crossing(v, faces, upper, 0, xi + (xo - xi) / 3.0)
    points[44] = _crossing(v, faces, upper, 0, xi + 2.0 * (xo - xi) / 3.0)
    points[45] = _vertex_point(faces, outer)
    points[46] = _crossing(v, faces, lower, 0, xi + 2.0 * (xo - xi) / 3.0)
    points[47] = _crossing(v, faces, lower, 0, xi + (xo - xi) / 3.0)

    # Outer lip 48-59 on the vermilion border: corners (its x extremes), 51/57 on the midline, 52 the
    # Cupid's bow peak (the border's highest point), 53 halfway (in x) from the peak to the corner; the
    # lower lip's 56 and 55 under 52 and 53.
    ring = _outer_lip_ring(asset)
    right_c, left_c = int(ring[np.argmin(v[ring, 0])]), int(ring[np.argmax(v[ring, 0])])
    upper, lower = _split_loop(v, ring, right_c, left_c)
    midline = mirror == np.arange(len(v))
    top = upper[(v[upper, 0] > 0.0) & ~midline[upper]]
    peak = int(top[np.argmax(v[top, 1])])
    x_peak, x_half = float(v[peak, 0]), 0.5 * float(v[peak, 0] + v[left_c, 0])
    points[51] = _vertex_point(faces, int(upper[np.flatnonzero(midline[upper])[0]]))
    points[52] = _vertex_point(faces, peak)
    points[53] = _crossing(v, faces, upper, 0, x_half)
    points[54] = _vertex_point(faces, left_c)
    points[55] = _crossing(v, faces, lower, 0, x_half)
    points[56] = _crossing(v, faces, lower, 0, x_peak)
    points[57] = _vertex_point(faces, int(lower[np.flatnonzero(midline[lower])[0]]))

    # Inner lip 60-67 on the mouth loop (the lips' rim): corners, midline, and under the bow peaks.
    mouth = np.asarray(asset.mouth_loop)
    right_c, left_c = int(mouth[np.argmin(v[mouth, 0])]), int(mouth[np.argmax(v[mouth, 0])])
    upper, lower = _split_loop(v, mouth, right_c, left_c)
    points[62] = _crossing(v, faces, upper, 0, 0.0)
    points[63] = _crossing(v, faces, upper, 0, x_peak)
    points[64] = _vertex_point(faces, left_c)
    points[65] = _crossing(v, faces, lower, 0, x_peak)
    points[66] = _crossing(v, faces, lower, 0, 0.0)

    # Nose: bridge on the midline from the top of the upper eyelids to the tip; base along the lower edge.
    nose = asset.region_mask("nose")
    nose_ids = np.flatnonzero(nose)
    tip = int(nose_ids[np.argmax(v[nose_ids, 2])])
    y_top = float(max(v[np.asarray(lp), 1].max() for lp in asset.eye_loops))
    bridge = _midline_path(v, mirror, faces, v[tip, 1], y_top + 5.0, v[tip, 2] - 40.0)
    bridge = bridge[nose[bridge] | (v[bridge, 1] > y_top)]
    for k, frac in enumerate((0.0, 1.0 / 3.0, 2.0 / 3.0)):
        points[27 + k] = _crossing(v, faces, bridge, 1, y_top + frac * (v[tip, 1] - y_top))
    points[30] = _vertex_point(faces, tip)
    front = nose_ids[(v[nose_ids, 2] > v[tip, 2] - 20.0) & (v[nose_ids, 1] < v[tip, 1])]
    half_width = v[front, 0].max()
    columella = front[mirror[front] == front]
    base = int(columella[np.argmin(v[columella, 1])])
    points[33] = _vertex_point(faces, base)
    for k, frac in ((34, 0.38), (35, 0.75)):
        # The lowest front vertex of the column not below the columella base (the ala's lower edge; the
        # nose region also covers the ala-cheek junction further down).
        gap = np.abs(v[front, 0] - frac * half_width)
        column = front[(gap <= gap.min() + 1.0) & (v[front, 1] >= v[base, 1] - 1.0)]
        points[k] = _vertex_point(faces, int(column[np.argmin(v[column, 1])]))

    # Left brow 22-26: the middle of the brow band at five evenly spaced x, projected onto brow faces.
    brows = np.flatnonzero(asset.region_mask("brows") & (v[:, 0] > 0.0))
    x_in, x_out = v[brows, 0].min() + 2.0, v[brows, 0].max() - 2.0
    brow_faces = np.flatnonzero(asset.region_mask("brows")[faces].all(1)
                                & (v[faces, 0].min(1) > 0.0))
    for k, x in zip(range(22, 27), np.linspace(x_in, x_out, 5)):
        near = brows[np.argsort(np.abs(v[brows, 0] - x), kind="stable")[:6]]  # the band's column at x
        target = np.array([x, 0.5 * (v[near, 1].min() + v[near, 1].max()), v[near, 2].max()])
        points[k] = _closest_point_on_faces(v, faces, brow_faces, target)
    return points


def _build_embedding(asset: RigAsset, corrected: bool) -> LandmarkEmbedding:
    v, faces, mirror = asset.vertices, asset.faces, asset.mirror
    face_lookup = {tuple(sorted(f.tolist())): i for i, f in enumerate(faces)}
    points = _placement(asset)
    if corrected:
        domains = _domains(asset)
        for k, delta in LANDMARK_CORRECTIONS_MM.items():
            if k not in domains:
                raise RuntimeError(f"ibug68: LANDMARK_CORRECTIONS_MM has landmark {k}, which has no domain")
            f, w = points[k]
            points[k] = _snap(asset, domains[k], w @ v[faces[f]] + np.asarray(delta, float))
    # Jaw contour (static), left half: vertices (the chin is placed above; the right half is mirrored below).
    for k, vid in enumerate(_contour_ids(asset, corrected)):
        if k > CHIN:
            points[k] = _vertex_point(faces, int(vid))
    # Right side: mirror images of the left.
    for i, j in enumerate(IBUG68_MIRROR):
        if i not in points and j in points:
            points[i] = _mirror_point(faces, mirror, *points[j], face_lookup)
    missing = [i for i in range(68) if i not in points]
    if missing:
        raise RuntimeError(f"ibug68: landmarks {missing} were not placed")
    return LandmarkEmbedding(np.array([points[i][0] for i in range(68)], np.int64),
                             np.array([points[i][1] for i in range(68)], np.float64))


@cached_per_asset
def _embedding(asset: RigAsset) -> LandmarkEmbedding:
    return _build_embedding(asset, corrected=True)


@cached_per_asset
def _heuristic_embedding(asset: RigAsset) -> LandmarkEmbedding:
    return _build_embedding(asset, corrected=False)


def _closest_point_on_faces(v: np.ndarray, faces: np.ndarray, face_ids: np.ndarray, p: np.ndarray
                            ) -> tuple[int, np.ndarray]:
    """Closest point to ``p`` on the given faces (exact point-triangle distance), as ``(face, barycentric)``."""
    face_ids = np.asarray(face_ids, dtype=np.int64)
    tri = v[faces[face_ids]]  # (n, 3, 3)
    q = closest_points_on_triangles(np.broadcast_to(p, (len(face_ids), 3)), tri[:, 0], tri[:, 1], tri[:, 2])
    best = int(np.argmin(((q - p) ** 2).sum(-1)))
    w = np.clip(barycentric(q[best:best + 1], tri[best:best + 1, 0], tri[best:best + 1, 1],
                            tri[best:best + 1, 2])[0], 0.0, 1.0)
    return int(face_ids[best]), w / w.sum()


def ibug68_embedding(asset: RigAsset | None = None, *, corrected: bool = True) -> LandmarkEmbedding:
    """The iBUG-68 landmarks of the template as faces + barycentric weights (computed once per asset).

    Args:
        asset: the template (default :func:`rig.asset.load_asset`).
        corrected: False: the geometric placement alone, without :data:`LANDMARK_CORRECTIONS_MM` and
            :data:`CONTOUR_ANGLES_DEG` (for the benchmark that fits them).

    Example:
        >>> emb = ibug68_embedding()
        >>> emb.faces.shape, emb.barycentric.shape
        ((68,), (68, 3))
    """
    asset = load_asset() if asset is None else asset
    return _embedding(asset) if corrected else _heuristic_embedding(asset)


# --- posed landmarks -------------------------------------------------------------------------------------

def landmark_positions(vertices, embedding: LandmarkEmbedding, faces):
    """Landmark positions on a posed mesh.

    Args:
        vertices: ``(B, V, 3)`` or ``(V, 3)`` mm, torch tensor or numpy array.
        embedding: :class:`LandmarkEmbedding` (``L`` landmarks).
        faces: ``(F, 3)`` template faces (torch or numpy).

    Returns:
        ``(B, L, 3)`` mm, the same kind (torch/numpy) and dtype as ``vertices`` (a batch of one for
        ``(V, 3)`` input); differentiable w.r.t. ``vertices`` in torch.

    Example:
        >>> a = load_asset(); emb = ibug68_embedding(a)
        >>> landmark_positions(torch.as_tensor(a.vertices), emb, a.faces).shape
        torch.Size([1, 68, 3])
    """
    if vertices.ndim not in (2, 3) or vertices.shape[-1] != 3:
        raise ShapeError(f"landmark_positions: vertices must have shape (B, V, 3) or (V, 3), "
                         f"got {tuple(vertices.shape)}")
    tri = np.asarray(faces.cpu() if isinstance(faces, torch.Tensor) else faces)[embedding.faces]  # (L, 3)
    if isinstance(vertices, torch.Tensor):
        verts = vertices if vertices.ndim == 3 else vertices.unsqueeze(0)
        idx = torch.as_tensor(tri, dtype=torch.long, device=verts.device)
        bary = torch.as_tensor(embedding.barycentric, dtype=verts.dtype, device=verts.device)
        return torch.einsum("blkc,lk->blc", verts[:, idx], bary)
    verts = np.asarray(vertices)
    verts = verts if verts.ndim == 3 else verts[None]
    return np.einsum("blkc,lk->blc", verts[:, tri], embedding.barycentric.astype(verts.dtype))


def contour_candidates(asset: RigAsset | None = None, *, corrected: bool = True) -> tuple[np.ndarray, ...]:
    """Per jaw-contour landmark, the candidate template vertices (front -> back) of the dynamic contour;
    empty for the chin (8), which stays fixed. ``corrected``: as in :func:`ibug68_embedding`."""
    asset = load_asset() if asset is None else asset
    return (_contour(asset) if corrected else _contour_heuristic(asset)).candidates


@dataclass(frozen=True)
class _ContourLines:
    vertices: np.ndarray  # (C,) all candidate vertices, landmark after landmark (front -> back)
    bounds: tuple[tuple[int, int], ...]  # per contour landmark: its slice of ``vertices`` (empty: the chin)
    faces: np.ndarray  # (G, 3) the faces incident to a candidate, in mesh order
    corner_slot: np.ndarray  # slot in ``vertices`` of each kept corner of ``faces`` (raveled)
    corner_keep: np.ndarray  # which raveled corners of ``faces`` are candidates


def _build_lines(data: _ContourData, faces: np.ndarray) -> _ContourLines:
    verts = np.concatenate([np.asarray(c, np.int64) for c in data.candidates])
    sizes = np.cumsum([0] + [len(c) for c in data.candidates])
    bounds = tuple((int(a), int(b)) for a, b in itertools.pairwise(sizes))
    incident = np.flatnonzero(np.isin(faces, verts).any(1))
    sub = faces[incident]
    # a vertex may sit on two lines: every occurrence gets its own slot (with the same normal)
    slot_of: dict[int, list[int]] = {}
    for i, vid in enumerate(verts):
        slot_of.setdefault(int(vid), []).append(i)
    corners, slots = [], []
    for j, vid in enumerate(sub.ravel()):
        for slot in slot_of.get(int(vid), ()):
            corners.append(j)
            slots.append(slot)
    order = np.argsort(np.asarray(slots), kind="stable")  # per slot, its corners in mesh order
    return _ContourLines(verts, bounds, sub, np.asarray(slots, np.int64)[order], np.asarray(corners, np.int64)[order])


@cached_per_asset
def _asset_lines(asset: RigAsset) -> _ContourLines:
    return _build_lines(_contour(asset), np.asarray(asset.faces, np.int64))


@cached_per_asset
def _asset_lines_heuristic(asset: RigAsset) -> _ContourLines:
    return _build_lines(_contour_heuristic(asset), np.asarray(asset.faces, np.int64))


def _contour_lines(asset: RigAsset, faces: np.ndarray, corrected: bool = True) -> _ContourLines:
    """The candidate lines of :func:`contour_candidates` flattened, with their incident faces."""
    if faces.shape == asset.faces.shape and np.array_equal(faces, asset.faces):
        return _asset_lines(asset) if corrected else _asset_lines_heuristic(asset)
    return _build_lines(_contour(asset) if corrected else _contour_heuristic(asset), faces)


def contour_support_ids(asset: RigAsset | None = None, *, corrected: bool = True) -> np.ndarray:
    """``(N,)`` sorted ids of the vertices :func:`contour_vertex_ids` reads (the candidates, their incident
    faces' corners, and the fallback vertices): a fit that only skins these can pick the contour."""
    asset = load_asset() if asset is None else asset
    faces = np.asarray(asset.faces, np.int64)
    lines = _contour_lines(asset, faces, corrected)
    data = _contour(asset) if corrected else _contour_heuristic(asset)
    return np.unique(np.concatenate([np.asarray(lines.faces, np.int64).ravel(), np.asarray(lines.vertices, np.int64),
                                     np.asarray(data.vertex_ids, np.int64)]))


def contour_landmarks(vertices: torch.Tensor, faces, camera_center, asset: RigAsset | None = None, *,
                      corrected: bool = True) -> torch.Tensor:
    """Dynamic jaw contour (landmarks 0-16) as seen from a camera, for turned heads.

    For each contour landmark a precomputed line of template vertices runs across the cheek/jaw from the
    front towards the ear (:func:`contour_candidates`); among those facing the camera, the one closest to
    the silhouette (smallest ``|n . view_dir|``) is picked. The chin (8) stays at its static embedding.
    The choice is discrete; the returned positions are differentiable w.r.t. ``vertices``.

    Args:
        vertices: ``(V, 3)`` posed vertices in rig space, mm.
        faces: ``(F, 3)`` template faces.
        camera_center: ``(3,)`` camera centre in the same frame as ``vertices``, mm.
        corrected: as in :func:`ibug68_embedding` (False: the lines of the geometric contour).

    Returns:
        ``(17, 3)`` contour positions, mm, same dtype as ``vertices``.
    """
    asset = load_asset() if asset is None else asset
    if not isinstance(vertices, torch.Tensor) or vertices.ndim != 2 or vertices.shape[-1] != 3:
        raise ShapeError(f"contour_landmarks: vertices must be a torch tensor of shape (V, 3), "
                         f"got {type(vertices).__name__} {tuple(vertices.shape)}")
    cam = torch.as_tensor(camera_center, dtype=vertices.dtype, device=vertices.device)
    if cam.shape != (3,):
        raise ShapeError(f"contour_landmarks: camera_center must have shape (3,), got {tuple(cam.shape)}")
    faces_np = np.asarray(faces.cpu() if isinstance(faces, torch.Tensor) else faces, dtype=np.int64)
    picked = contour_vertex_ids(vertices, faces_np, cam.detach().cpu().double().numpy(), asset, corrected=corrected)
    out = vertices[torch.as_tensor(picked, device=vertices.device)]
    static = landmark_positions(vertices, ibug68_embedding(asset, corrected=corrected), faces_np)[0, CHIN]
    return torch.cat([out[:CHIN], static[None], out[CHIN + 1:]])


def contour_vertex_ids(vertices, faces, camera_center, asset: RigAsset | None = None, *,
                       corrected: bool = True) -> list[int]:
    """The 17 vertex ids :func:`contour_landmarks` picks for the jaw contour as seen from ``camera_center``
    (``(V, 3)`` torch or numpy vertices, rig space, mm); the chin's entry (8) is the vertex its static
    landmark would start from and is not used by :func:`contour_landmarks`."""
    asset = load_asset() if asset is None else asset
    faces_np = np.asarray(faces.cpu() if isinstance(faces, torch.Tensor) else faces, dtype=np.int64)
    data = _contour(asset) if corrected else _contour_heuristic(asset)
    lines = _contour_lines(asset, faces_np, corrected)
    v = (vertices.detach().cpu().double().numpy() if isinstance(vertices, torch.Tensor)
         else np.asarray(vertices, np.float64))
    cam = np.asarray(camera_center, np.float64)
    # area-weighted normals of the candidate vertices only, from their incident faces (= vertex_normals there)
    tri = v[lines.faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = np.stack([np.bincount(lines.corner_slot, weights=np.repeat(fn[:, c], 3)[lines.corner_keep],
                              minlength=len(lines.vertices)) for c in range(3)], 1)
    n /= np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)
    to_cam = cam - v[lines.vertices]
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True).clip(1e-12)
    facing = (n * to_cam).sum(1)
    score = np.where(facing > 0, facing, np.inf)
    picked = [int(i) for i in data.vertex_ids]  # the chin, and any line that faces away: the static landmark
    for k, (lo, hi) in enumerate(lines.bounds):
        if hi > lo and np.isfinite(score[lo:hi]).any():
            picked[k] = int(lines.vertices[lo + int(np.argmin(score[lo:hi]))])
    return picked
