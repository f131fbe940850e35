"""Normals by PCA over each point's neighbours (:func:`estimate_normals`) and the border of the scanned
surface (:func:`boundary_mask`)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from pipeline.scan.pointcloud.cloud import CloudError


def _check_cloud_array(points: np.ndarray, func: str, k: int) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise CloudError(f"{func}: points must have shape (N, 3), got {points.shape}")
    if k < 3:
        raise CloudError(f"{func}: k must be at least 3, got {k}")
    if len(points) < 4:
        raise CloudError(f"{func}: need at least 4 points, got {len(points)}")
    if not np.isfinite(points).all():
        raise CloudError(f"{func}: points contain NaN or infinite values")
    return points


def _neighbourhoods(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(N, k)`` distances and indices of each point's k nearest other points (self excluded)."""
    k = min(k, len(points) - 1)
    distances, index = cKDTree(points).query(points, k=k + 1, workers=-1)
    return distances[:, 1:], index[:, 1:]


def _pca_normals(points: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``(N, 3)`` unit normals (smallest principal axis) of each point plus its ``(N, k)`` neighbours."""
    patch = np.concatenate([points[:, None, :], points[index]], axis=1)
    centred = patch - patch.mean(axis=1, keepdims=True)
    covariance = np.einsum("nki,nkj->nij", centred, centred)
    _, vectors = np.linalg.eigh(covariance)  # ascending eigenvalues
    return vectors[:, :, 0]


def estimate_normals(points: np.ndarray, k: int = 16, viewpoint: np.ndarray | None = None) -> np.ndarray:
    """Unit normals by PCA over each point's ``k`` nearest neighbours.

    Args:
        points: ``(N, 3)`` positions (any unit), ``N >= 4``.
        k: neighbours per point (capped at ``N - 1``), at least 3.
        viewpoint: ``(3,)`` position the normals should face (e.g. the scanner), or None to orient them
            away from the cloud's centroid (right for a closed or convex-ish head).

    Returns:
        ``(N, 3)`` float64 unit normals.

    Example:
        >>> sphere = np.random.default_rng(0).normal(size=(2000, 3))
        >>> sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
        >>> bool((np.einsum("ni,ni->n", estimate_normals(sphere), sphere) > 0.9).all())
        True
    """
    points = _check_cloud_array(points, "estimate_normals", k)
    _, index = _neighbourhoods(points, k)
    normals = _pca_normals(points, index)
    if viewpoint is None:
        towards = points - points.mean(axis=0)
    else:
        viewpoint = np.asarray(viewpoint, dtype=np.float64)
        if viewpoint.shape != (3,):
            raise CloudError(f"estimate_normals: viewpoint must have shape (3,), got {viewpoint.shape}")
        towards = viewpoint - points
    flip = np.einsum("ni,ni->n", normals, towards) < 0
    normals[flip] *= -1.0
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def boundary_mask(points: np.ndarray, k: int = 16, threshold: float = 0.35) -> np.ndarray:
    """Points on the border of the scanned surface (the edge of a depth scan or of a hole).

    A point is on the border when the centroid of its ``k`` neighbours, projected onto the local tangent
    plane, is more than ``threshold`` × the mean neighbour distance away from it (inside a surface the
    neighbours surround the point; on a border they all lie on one side). Assumes a roughly even sampling
    (a depth-camera grid, a remeshed scan): on randomly (Poisson) sampled points the neighbour centroid is
    noisy and ``k=16`` flags about 17 % of interior points; use ``k=32`` (about 3 %) or more there.

    Args:
        points: ``(N, 3)`` positions (any unit), ``N >= 4``.
        k: neighbours per point (capped at ``N - 1``), at least 3.
        threshold: offset ratio above which a point is a border point (about 0.6 on a straight edge, 0 inside).

    Returns:
        ``(N,)`` bool mask, True on the border.

    Example:
        >>> u, v = np.meshgrid(np.arange(30.0), np.arange(30.0))
        >>> grid = np.stack([u.ravel(), v.ravel(), np.zeros(900)], axis=1)
        >>> rim = (u == 0) | (u == 29) | (v == 0) | (v == 29)
        >>> mask = boundary_mask(grid)
        >>> int(mask[rim.ravel()].sum()), int(mask[~rim.ravel()].sum())  # all 116 rim points, 4 next to corners
        (116, 4)
    """
    points = _check_cloud_array(points, "boundary_mask", k)
    distances, index = _neighbourhoods(points, k)
    normals = _pca_normals(points, index)
    offset = points[index].mean(axis=1) - points
    tangential = offset - np.einsum("ni,ni->n", offset, normals)[:, None] * normals
    return np.linalg.norm(tangential, axis=1) > threshold * distances.mean(axis=1)


__all__ = ["boundary_mask", "estimate_normals"]
