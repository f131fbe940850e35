"""The 68 iBUG landmarks embedded on the template: one face index + three barycentric weights each.

Every landmark is found from the template's own structure (eyelid and lip loops, regions, the
midline, geometric extremes), so it follows the template if the template is regenerated. Landmarks
on the subject's left (+X) are computed and their right-side partners are obtained through the
vertex mirror map, so each pair is an exact mirror image; midline landmarks lie on x = 0.
The order is the standard iBUG-68 order (:data:`IBUG68_NAMES`); a golden test pins the face ids.

===========  ==========================================================================
indices      placement
===========  ==========================================================================
0-16         jaw contour: the face's side outline seen from the front (cheeks, jaw,
             chin regions), from the right ear side (-X, at the outer eye corner's height)
             down to the chin (8, lowest midline chin vertex) and up to the left
17-21/22-26  right brow outer->inner / left brow inner->outer, along the middle of the
             brow band
27-30        nose bridge, on the midline from the top of the upper eyelids to the tip
31-35        lower edge of the nose, right->left (33 = lowest forward midline point)
36-41/42-47  eyelid loops: corners, and the lids at 1/3 and 2/3 of the corner-to-corner width
48-59        outer lip: the boundary of the ``lips`` region (corners = its x extremes)
60-67        inner lip: the mouth loop (corners, and the lids at x = +-half the corner x)
===========  ==========================================================================

:func:`landmark_positions` gathers the posed landmarks with one einsum (differentiable in torch).
:func:`contour_landmarks` replaces the static jaw contour with the silhouette seen from a camera
(for turned heads), as FLAME's dynamic contour does.
"""

from __future__ import annotations

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


def _path_point(vertices: np.ndarray, faces: np.ndarray, path: np.ndarray, x: float, face_ids: np.ndarray
                ) -> tuple[int, np.ndarray]:
    """The point of a vertex path at ``x``: on the edge where consecutive path vertices share one, else the
    interpolated position projected onto ``face_ids``."""
    c = vertices[path, 0] - x
    for k in range(len(path) - 1):
        if c[k] * c[k + 1] <= 0.0 and c[k] != c[k + 1]:
            a, b, t = int(path[k]), int(path[k + 1]), c[k] / (c[k] - c[k + 1])
            if len(_faces_with(faces, a, b)):
                return _edge_point(faces, a, b, t)
            return _closest_point_on_faces(vertices, faces, face_ids, (1 - t) * vertices[a] + t * vertices[b])
    raise RuntimeError(f"ibug68: path never reaches x = {x:.3f}")


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


def _boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Closed boundary loops (vertex ids) of a face patch."""
    edges = np.sort(face_edges(faces), 1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    boundary = uniq[counts == 1]
    nbrs: dict[int, list[int]] = {}
    for a, b in boundary:
        nbrs.setdefault(int(a), []).append(int(b))
        nbrs.setdefault(int(b), []).append(int(a))
    loops, seen = [], set()
    for start in nbrs:
        if start in seen:
            continue
        loop, prev, cur = [start], None, start
        seen.add(start)
        while True:
            nxt = [n for n in nbrs[cur] if n != prev and (n not in seen or (n == start and len(loop) > 2))]
            if not nxt or nxt[0] == start:
                break
            prev, cur = cur, nxt[0]
            loop.append(cur)
            seen.add(cur)
        loops.append(np.array(loop))
    return loops


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


# --- the embedding ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _ContourData:
    vertex_ids: np.ndarray  # (17,) static contour vertices (left half computed, right mirrored)
    directions: np.ndarray  # (17, 2) outward frontal directions (x, y) from the contour centre
    centre: np.ndarray  # (2,) contour centre (x, y)
    candidates: tuple[np.ndarray, ...]  # per contour point: vertex ids front -> back (empty for the chin)


@cached_per_asset
def _contour(asset: RigAsset) -> _ContourData:
    v, mirror = asset.vertices, asset.mirror
    eye_outer = [int(loop[np.argmax(np.abs(v[loop, 0]))]) for loop in asset.eye_loops]
    y_top = float(np.mean(v[eye_outer, 1]))
    chin = np.flatnonzero(asset.region_mask("chin") & (mirror == np.arange(len(v))))
    chin_id = int(chin[np.argmin(v[chin, 1])])
    allowed = np.flatnonzero(asset.region_mask(*_SIDE_REGIONS) & (v[:, 2] > 0.0))
    centre = np.array([0.0, y_top])
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
    # Resample the outline polyline (frontal projection) at 9 equal arc-length steps: 16 (ear side) .. 8 (chin).
    seg = np.linalg.norm(np.diff(v[outline, :2], axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    left_half = []
    for t in np.linspace(0.0, s[-1], 9):
        k = int(np.argmin(np.abs(s - t)))
        left_half.append(int(outline[k]))
    left_half[-1] = chin_id
    # left_half runs 16, 15, ..., 8; the right half is its mirror 0..7.
    left_ids = left_half[::-1]  # 8..16
    ids = np.array([int(mirror[i]) for i in left_ids[:0:-1]] + left_ids, np.int64)
    # Candidate lines: allowed vertices near the plane through the centre spanned by the outward frontal
    # direction and +Z (a slice across the cheek from the front towards the ear), sorted front to back.
    directions = v[ids, :2] - centre
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    cand_pool = allowed
    candidates = []
    for k in range(17):
        if k == CHIN:
            candidates.append(np.zeros(0, np.int64))
            continue
        d = directions[k]
        rel = v[cand_pool, :2] - centre
        along, across = rel @ d, rel @ np.array([-d[1], d[0]])
        near = cand_pool[(np.abs(across) < 3.0) & (along > 0.5 * (v[ids[k], :2] - centre) @ d)]
        line = np.unique(np.concatenate([near, [ids[k]]]))
        candidates.append(line[np.argsort(-v[line, 2])])
    return _ContourData(ids, directions, centre, tuple(candidates))


@cached_per_asset
def _embedding(asset: RigAsset) -> LandmarkEmbedding:
    v, faces, mirror = asset.vertices, asset.faces, asset.mirror
    face_lookup = {tuple(sorted(f.tolist())): i for i, f in enumerate(faces)}
    points: dict[int, tuple[int, np.ndarray]] = {}

    # Jaw contour (static): vertices.
    for k, vid in enumerate(_contour(asset).vertex_ids):
        points[k] = _vertex_point(faces, int(vid))

    # Left eye 42-47 (loop with +X), right eye mirrored.
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

    # Inner lip 60-67: the mouth loop.
    mouth = np.asarray(asset.mouth_loop)
    right_c, left_c = int(mouth[np.argmin(v[mouth, 0])]), int(mouth[np.argmax(v[mouth, 0])])
    upper, lower = _split_loop(v, mouth, right_c, left_c)
    cx = v[left_c, 0]
    points[60] = _vertex_point(faces, right_c)
    points[62] = _crossing(v, faces, upper, 0, 0.0)
    points[63] = _crossing(v, faces, upper, 0, 0.5 * cx)
    points[64] = _vertex_point(faces, left_c)
    points[65] = _crossing(v, faces, lower, 0, 0.5 * cx)
    points[66] = _crossing(v, faces, lower, 0, 0.0)

    # Outer lip 48-59: the outer boundary of the lips region. The lips faces form an upper and a lower
    # patch (split by the mouth loop); the lower patch's boundary runs from corner to corner under the lower
    # lip, the upper patch's top row (boundary minus mouth loop) along the top of the upper lip.
    lips = asset.region_mask("lips")
    loops = _boundary_loops(faces[lips[faces].all(1)])
    lips_ids = np.flatnonzero(lips)
    lowest, highest = int(lips_ids[np.argmin(v[lips_ids, 1])]), int(lips_ids[np.argmax(v[lips_ids, 1])])
    lower_loop = next(lp for lp in loops if lowest in lp)
    upper_loop = next(lp for lp in loops if highest in lp)
    right_c = int(lower_loop[np.argmin(v[lower_loop, 0])])
    left_c = int(lower_loop[np.argmax(v[lower_loop, 0])])
    _, lower = _split_loop(v, lower_loop, right_c, left_c)
    top = np.setdiff1d(upper_loop, mouth)
    upper = np.concatenate([[right_c], top[np.argsort(v[top, 0])], [left_c]])
    near_lips = np.flatnonzero(lips[faces].any(1))
    cx = v[left_c, 0]
    midline = mirror == np.arange(len(v))
    points[51] = _vertex_point(faces, int(upper[np.flatnonzero(midline[upper])[0]]))
    points[52] = _path_point(v, faces, upper, cx / 3.0, near_lips)
    points[53] = _path_point(v, faces, upper, 2.0 * cx / 3.0, near_lips)
    points[54] = _vertex_point(faces, left_c)
    points[55] = _path_point(v, faces, lower, 2.0 * cx / 3.0, near_lips)
    points[56] = _path_point(v, faces, lower, cx / 3.0, near_lips)
    points[57] = _vertex_point(faces, int(lower[np.flatnonzero(midline[lower])[0]]))

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
        near = brows[np.abs(v[brows, 0] - x) < 3.0]
        target = np.array([x, 0.5 * (v[near, 1].min() + v[near, 1].max()), v[near, 2].max()])
        points[k] = _closest_point_on_faces(v, faces, brow_faces, target)

    # Right side: mirror images of the left.
    for i, j in enumerate(IBUG68_MIRROR):
        if i not in points and j in points:
            points[i] = _mirror_point(faces, mirror, *points[j], face_lookup)
    missing = [i for i in range(68) if i not in points]
    if missing:
        raise RuntimeError(f"ibug68: landmarks {missing} were not placed")
    return LandmarkEmbedding(np.array([points[i][0] for i in range(68)], np.int64),
                             np.array([points[i][1] for i in range(68)], np.float64))


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


def ibug68_embedding(asset: RigAsset | None = None) -> LandmarkEmbedding:
    """The iBUG-68 landmarks of the template as faces + barycentric weights (computed once per asset).

    Example:
        >>> emb = ibug68_embedding()
        >>> emb.faces.shape, emb.barycentric.shape
        ((68,), (68, 3))
    """
    return _embedding(load_asset() if asset is None else asset)


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


def contour_candidates(asset: RigAsset | None = None) -> tuple[np.ndarray, ...]:
    """Per jaw-contour landmark, the candidate template vertices (front -> back) of the dynamic contour;
    empty for the chin (8), which stays fixed."""
    return _contour(load_asset() if asset is None else asset).candidates


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
    bounds = tuple((int(a), int(b)) for a, b in zip(sizes[:-1], sizes[1:]))
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


def _contour_lines(asset: RigAsset, faces: np.ndarray) -> _ContourLines:
    """The candidate lines of :func:`contour_candidates` flattened, with their incident faces."""
    if faces.shape == asset.faces.shape and np.array_equal(faces, asset.faces):
        return _asset_lines(asset)
    return _build_lines(_contour(asset), faces)


def contour_landmarks(vertices: torch.Tensor, faces, camera_center, asset: RigAsset | None = None
                      ) -> torch.Tensor:
    """Dynamic jaw contour (landmarks 0-16) as seen from a camera, for turned heads.

    For each contour landmark a precomputed line of template vertices runs across the cheek/jaw from the
    front towards the ear (:func:`contour_candidates`); among those facing the camera, the one closest to
    the silhouette (smallest ``|n . view_dir|``) is picked. The chin (8) stays at its static embedding.
    The choice is discrete; the returned positions are differentiable w.r.t. ``vertices``.

    Args:
        vertices: ``(V, 3)`` posed vertices in rig space, mm.
        faces: ``(F, 3)`` template faces.
        camera_center: ``(3,)`` camera centre in the same frame as ``vertices``, mm.

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
    data = _contour(asset)
    lines = _contour_lines(asset, faces_np)
    v = vertices.detach().cpu().double().numpy()
    # area-weighted normals of the candidate vertices only, from their incident faces (= vertex_normals there)
    tri = v[lines.faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = np.stack([np.bincount(lines.corner_slot, weights=np.repeat(fn[:, c], 3)[lines.corner_keep],
                              minlength=len(lines.vertices)) for c in range(3)], 1)
    n /= np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)
    to_cam = np.asarray(cam.detach().cpu().double().numpy()) - v[lines.vertices]
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True).clip(1e-12)
    facing = (n * to_cam).sum(1)
    score = np.where(facing > 0, facing, np.inf)
    picked = [int(i) for i in data.vertex_ids]  # the chin, and any line that faces away: the static landmark
    for k, (lo, hi) in enumerate(lines.bounds):
        if hi > lo and np.isfinite(score[lo:hi]).any():
            picked[k] = int(lines.vertices[lo + int(np.argmin(score[lo:hi]))])
    out = vertices[torch.as_tensor(picked, device=vertices.device)]
    static = landmark_positions(vertices, ibug68_embedding(asset), faces_np)[0, CHIN]
    return torch.cat([out[:CHIN], static[None], out[CHIN + 1:]])
