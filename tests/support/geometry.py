"""Naive references for :mod:`rig.geometry`: one point at a time against every triangle, one face at a time
for the normals, with formulas independent of the package's (plane projection, then the three edges), mm."""

from __future__ import annotations

import numpy as np


def _closest_on_segments(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
    return a + t[..., None] * ab


def closest_points_on_each_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``(T, 3)``: the closest point to one point ``p (3,)`` on each triangle ``(a, b, c)`` (each ``(T, 3)``):
    the projection of ``p`` onto the triangle's plane where it falls inside (the signed areas of its three
    sub-triangles all >= 0), else the closest of the closest points on the three edges."""
    n = np.cross(b - a, c - a)
    q = p - (((p - a) * n).sum(-1) / (n * n).sum(-1))[:, None] * n
    inside = np.ones(len(a), bool)
    for y, z in ((b, c), (c, a), (a, b)):
        inside &= (np.cross(y - q, z - q) * n).sum(-1) >= 0
    edges = np.stack([_closest_on_segments(p, y, z) for y, z in ((a, b), (b, c), (c, a))])  # (3, T, 3)
    nearest_edge = edges[((edges - p) ** 2).sum(-1).argmin(0), np.arange(len(a))]
    return np.where(inside[:, None], q, nearest_edge)


def brute_force_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(N,)`` mm: each point's distance to the mesh, the minimum over every triangle, one point at a time."""
    v = np.asarray(vertices, float)
    tri = v[np.asarray(faces)]
    out = np.empty(len(points))
    for i, p in enumerate(np.asarray(points, float)):
        q = closest_points_on_each_triangle(p, tri[:, 0], tri[:, 1], tri[:, 2])
        out[i] = np.sqrt(((q - p) ** 2).sum(-1).min())
    return out


def loop_vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V, 3)``: each face's cross product (twice its area, outward for counter-clockwise faces) added to its
    three corners, one face at a time, then normalised."""
    v = np.asarray(vertices, float)
    n = np.zeros_like(v)
    for a, b, c in np.asarray(faces):
        face_normal = np.cross(v[b] - v[a], v[c] - v[a])
        for corner in (a, b, c):
            n[corner] += face_normal
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)
