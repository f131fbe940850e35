"""Points on the template as ``(face, barycentric)``: at a vertex, on an edge, where a vertex path crosses a
coordinate, the closest point on faces, a mirror image; and vertex loops and paths (halves of a loop, the
midline, an edge ring in loop order)."""

from __future__ import annotations

import numpy as np

from rig.geometry import closest_surface_points, face_edges

_HIDDEN_REGIONS = ("eyeballs", "mouth_interior", "teeth", "tongue", "eye_pockets")
"""Template regions behind or inside the head, which no landmark lies on."""


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


def _crossing(
    vertices: np.ndarray, faces: np.ndarray, path: np.ndarray, axis: int, value: float
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


def _mirror_point(
    faces: np.ndarray, mirror: np.ndarray, face: int, bary: np.ndarray, face_lookup: dict
) -> tuple[int, np.ndarray]:
    mverts = mirror[faces[face]]
    g = face_lookup.get(tuple(sorted(mverts.tolist())))
    if g is None:
        raise RuntimeError(f"ibug68: face {face} has no mirror face; the template topology is not symmetric")
    order = [int(np.flatnonzero(mverts == w)[0]) for w in faces[g]]
    return g, bary[order]


def _midline_path(
    vertices: np.ndarray, mirror: np.ndarray, faces: np.ndarray, y_lo: float, y_hi: float, z_min: float
) -> np.ndarray:
    """Midline vertices on the front of the face between two heights, top to bottom."""
    ids = np.flatnonzero(
        (mirror == np.arange(len(vertices)))
        & (vertices[:, 1] >= y_lo)
        & (vertices[:, 1] <= y_hi)
        & (vertices[:, 2] >= z_min)
    )
    return ids[np.argsort(-vertices[ids, 1])]


def _closest_point_on_faces(
    v: np.ndarray, faces: np.ndarray, face_ids: np.ndarray, p: np.ndarray
) -> tuple[int, np.ndarray]:
    """Closest point to ``p`` on the given faces (exact point-triangle distance), as ``(face, barycentric)``."""
    face_ids = np.asarray(face_ids, dtype=np.int64)
    found = closest_surface_points(np.asarray(p, float)[None], v, faces[face_ids])
    return int(face_ids[found.face[0]]), found.barycentric[0]


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
