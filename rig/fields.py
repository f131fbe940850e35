"""Smooth building blocks of displacement fields on the head: compact bumps, ramps, a smoothed normal
field. Functions of 3D position (mm), so every field built from them is an ambient, smooth field; used by
the synthetic population (:mod:`pipeline.synthetic.population`, :mod:`pipeline.synthetic.expressive`) and the sculpted expression
shapes (:mod:`rig.expressions`)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from rig.asset import RigAsset

__all__ = ["bump", "capsule_bump", "ramp", "smoothed_normals", "unit"]


def bump(p: np.ndarray, center, radii) -> np.ndarray:
    """Compact smooth bump ``(1 - t^2)^3`` of the ellipsoidal distance ``t``; ``(V, 3)`` mm -> ``(V,)``."""
    t2 = (((p - np.asarray(center, float)) / np.asarray(radii, float)) ** 2).sum(axis=-1)
    return np.where(t2 < 1.0, (1.0 - np.minimum(t2, 1.0)) ** 3, 0.0)


def capsule_bump(p: np.ndarray, a, b, radius: float) -> np.ndarray:
    """Compact smooth bump of the distance to the segment ``a``-``b`` (mm), zero beyond ``radius``."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    ab = b - a
    s = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    t2 = (np.linalg.norm(p - a - s[:, None] * ab, axis=1) / radius) ** 2
    return np.where(t2 < 1.0, (1.0 - np.minimum(t2, 1.0)) ** 3, 0.0)


def ramp(x: np.ndarray, e0: float, e1: float) -> np.ndarray:
    """Quintic smootherstep: 0 at ``x = e0``, 1 at ``x = e1`` (``e1 < e0`` ramps the other way). C2."""
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * t * (t * (6.0 * t - 15.0) + 10.0)


def unit(v) -> np.ndarray:
    """``v`` scaled to unit length (a float64 copy)."""
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def smoothed_normals(asset: RigAsset, radius: float = 12.0) -> np.ndarray:
    """A smooth ambient direction field near the skin, evaluated at the vertices, ``(V, 3)``.

    Kernel-weighted (``(1 - (d/radius)^2)^3``, area-weighted) average of the outward normals of the skin
    faces (eyeball and mouth-interior faces excluded), divided by the total weight plus a small constant:
    about unit length on smooth skin, shorter where normals disagree (thin parts) and fading to zero away
    from the skin, so it stays smooth everywhere (the eyeballs and mouth interior get their surroundings'
    direction).
    """
    v, f = asset.vertices, asset.faces
    inner = asset.region_mask("eyeballs", "mouth_interior")
    skin_faces = f[~inner[f].any(axis=1)]
    tri = v[skin_faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # |cross| = 2 * area, outward
    centroids = tri.mean(axis=1)
    dist = cKDTree(v).sparse_distance_matrix(cKDTree(centroids), radius, output_type="coo_matrix")
    k = (1.0 - (dist.data / radius) ** 2) ** 3
    num = np.zeros_like(v)
    for axis in range(3):
        np.add.at(num[:, axis], dist.row, k * cross[dist.col, axis])
    den = np.zeros(len(v))
    np.add.at(den, dist.row, k * np.linalg.norm(cross[dist.col], axis=1))
    return num / (den + 0.05 * np.median(den[den > 0]))[:, None]
