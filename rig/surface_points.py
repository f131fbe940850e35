"""Closest points on triangles and on triangle meshes, barycentric coordinates, and per-vertex values
interpolated at surface points.

The one implementation of the exact point-to-mesh search, :func:`closest_surface_points` (built on the
point-triangle :func:`closest_points_on_triangles`); :mod:`rig.geometry` re-exports every name here. Numpy;
millimetres in, millimetres out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.errors import InputError, check_faces, check_shape


def closest_points_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points on triangles ``(a, b, c)`` to points ``p``: the point-triangle step of
    :func:`closest_surface_points` (Ericson, *Real-Time Collision Detection*, 5.1.5: by Voronoi region).

    Args:
        p, a, b, c: ``(..., 3)`` mm, broadcast against each other (one point against many triangles:
            ``p[:, None]`` with ``(N, K, 3)`` corners).

    Returns:
        ``(..., 3)`` mm, on the triangle (its interior, an edge or a corner).

    Example:
        >>> a, b, c = np.zeros(3), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
        >>> closest_points_on_triangles(np.array([[0.2, 0.2, 5.0], [2.0, -1.0, 0.0]]), a, b, c)
        array([[0.2, 0.2, 0. ],
               [1. , 0. , 0. ]])
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    tiny = 1e-300
    # Interior (default), then override by edge and vertex regions in increasing priority.
    denom = va + vb + vc
    v_ = vb / np.where(np.abs(denom) > tiny, denom, tiny)
    w_ = vc / np.where(np.abs(denom) > tiny, denom, tiny)
    out = a + ab * v_[..., None] + ac * w_[..., None]
    # Edge BC.
    e_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    t = (d4 - d3) / np.where(((d4 - d3) + (d5 - d6)) > tiny, (d4 - d3) + (d5 - d6), tiny)
    out = np.where(e_bc[..., None], b + (c - b) * t[..., None], out)
    # Edge AC.
    e_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    t = d2 / np.where((d2 - d6) > tiny, d2 - d6, tiny)
    out = np.where(e_ac[..., None], a + ac * t[..., None], out)
    # Edge AB.
    e_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    t = d1 / np.where((d1 - d3) > tiny, d1 - d3, tiny)
    out = np.where(e_ab[..., None], a + ab * t[..., None], out)
    # Vertex regions.
    out = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, out)
    return out


def barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(N, 3)`` of points ``p`` in the planes of triangles ``(a, b, c)`` (each ``(N, 3)``)."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = np.where(np.abs(d00 * d11 - d01 * d01) > 1e-300, d00 * d11 - d01 * d01, 1e-300)
    w1 = (d11 * d20 - d01 * d21) / den
    w2 = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - w1 - w2, w1, w2], 1)


@dataclass(frozen=True)
class SurfacePoints:
    """Closest points on a triangle surface (:func:`closest_surface_points`).

    Attributes:
        face: ``(N,)`` int64 row of the surface's ``faces`` holding the closest point.
        barycentric: ``(N, 3)`` its barycentric coordinates in that triangle (non-negative, summing to 1).
        closest: ``(N, 3)`` the closest points, mm.
        distance: ``(N,)`` unsigned distance to them, mm.
    """

    face: np.ndarray
    barycentric: np.ndarray
    closest: np.ndarray
    distance: np.ndarray


def _finite_points(func: str, arg: str, points) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    check_shape(p.ndim == 2 and p.shape[1] == 3, func, arg, "(N, 3)", p.shape)
    if not np.isfinite(p).all():
        raise InputError(f"{func}: {arg} holds non-finite values")
    return p


def closest_surface_points(
    points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, *, k: int = 8, chunk: int = 400_000
) -> SurfacePoints:
    """Exact closest points on a triangle mesh: scipy KD-trees of the triangles' centroids choose candidates,
    :func:`closest_points_on_triangles` projects onto them.

    The triangles are grouped by their radius (largest centroid-to-corner distance: a few large triangles
    would loosen the bound for all), with one KD-tree per group. In a group, the ``k`` triangles with the
    nearest centroids are tested first; any other is at least ``d_k - r`` away (``d_k``: the k-th centroid
    distance, ``r``: the group's largest radius), so points whose best distance exceeds that bound are
    searched again with ``4 k`` triangles, until none is left. The result equals the brute-force minimum
    over all triangles, and where several are equally close (a point over a shared edge or corner) it is on
    the one with the lowest index, whatever the search order.

    Args:
        points: ``(N, 3)`` mm (N may be 0).
        vertices: ``(V, 3)`` mm; faces: ``(F, 3)`` int, F > 0, the surface (e.g. the head's outer skin).
        k: triangles tested per point and group in the first pass; chunk: points x triangles tested at once.

    Returns:
        :class:`SurfacePoints` (``face`` indexes ``faces``).

    Raises:
        ShapeError: wrong shapes. InputError: non-finite points or vertices, faces outside the vertices.

    Example:
        >>> v = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0]])
        >>> found = closest_surface_points(np.array([[2.0, 3.0, 4.0]]), v, np.array([[0, 1, 2]]))
        >>> found.closest, found.distance, found.barycentric
        (array([[2., 3., 0.]]), array([4.]), array([[0.5, 0.2, 0.3]]))
    """
    from scipy.spatial import cKDTree

    func = "closest_surface_points"
    p = _finite_points(func, "points", points)
    v = _finite_points(func, "vertices", vertices)
    tri = v[check_faces(func, faces, len(v))]  # (F, 3, 3)
    centroids = tri.mean(1)
    radius = np.linalg.norm(tri - centroids[:, None], axis=-1).max(1)
    group = np.searchsorted(np.array([4.0, 8.0, 16.0]) * max(float(np.median(radius)), 1e-9) / 3.0, radius)
    best = np.full(len(p), np.inf)
    face = np.zeros(len(p), np.int64)
    closest = np.zeros_like(p)
    for g in np.unique(group):
        ids = np.flatnonzero(group == g)
        tree, reach = cKDTree(centroids[ids]), float(radius[ids].max())
        todo, kk = np.arange(len(p)), min(max(int(k), 1), len(ids))
        while todo.size:
            unsure = []
            step = max(1, chunk // kk)
            for s in range(0, len(todo), step):
                rows = todo[s : s + step]
                dk, nn = tree.query(p[rows], k=kk)
                dk, nn = dk.reshape(len(rows), kk), ids[nn.reshape(len(rows), kk)]
                t = tri[nn]  # (n, k, 3, 3)
                q = closest_points_on_triangles(p[rows, None], t[..., 0, :], t[..., 1, :], t[..., 2, :])
                d = np.linalg.norm(q - p[rows, None], axis=-1)
                # on a tie (a point over a shared edge or corner) the lowest face id: the result does not
                # depend on the order of the search
                j = np.where(d == d.min(1, keepdims=True), nn, len(tri)).argmin(1)
                i = np.arange(len(rows))
                dj, fj = d[i, j], nn[i, j]
                better = (dj < best[rows]) | ((dj == best[rows]) & (fj < face[rows]))
                best[rows[better]] = dj[better]
                face[rows[better]] = fj[better]
                closest[rows[better]] = q[i, j][better]
                if kk < len(ids):
                    unsure.append(rows[dk[:, -1] - reach < best[rows]])
            todo = np.concatenate(unsure) if unsure else np.zeros(0, np.int64)
            kk = min(4 * kk, len(ids))
    t = tri[face]
    bary = np.clip(barycentric(closest, t[:, 0], t[:, 1], t[:, 2]), 0.0, 1.0)
    bary /= bary.sum(1, keepdims=True)
    return SurfacePoints(face, bary, closest, best)


def surface_values(values: np.ndarray, faces: np.ndarray, anchors: SurfacePoints) -> np.ndarray:
    """Per-vertex values interpolated at surface points: ``sum_c bary_c * values[..., faces[face, c], :]``.

    Args:
        values: ``(..., V, C)`` per-vertex values (weights ``(V, J)``, offsets ``(E, V, 3)``, normals).
        faces: ``(F, 3)`` the surface ``anchors`` refer to.
        anchors: :class:`SurfacePoints` of ``N`` points on that surface.

    Returns:
        ``(..., N, C)``.
    """
    corners = np.asarray(faces)[anchors.face]  # (N, 3)
    return np.einsum("nc,...ncd->...nd", anchors.barycentric, np.asarray(values)[..., corners, :])
