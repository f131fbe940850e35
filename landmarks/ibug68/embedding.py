"""The iBUG-68 embedding: the geometric placement, corrected, the jaw contour and the mirrored right side,
as one face and three barycentric weights per landmark (:func:`ibug68_embedding`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from landmarks.ibug68.corrections import LANDMARK_CORRECTIONS_MM
from landmarks.ibug68.domains import _domains, _snap
from landmarks.ibug68.mesh import _mirror_point, _vertex_point
from landmarks.ibug68.names import CHIN, IBUG68_MIRROR
from landmarks.ibug68.outline import _contour_ids
from landmarks.ibug68.placement import _placement
from rig.asset import RigAsset, cached_per_asset, load_asset


@dataclass(frozen=True)
class LandmarkEmbedding:
    """Landmarks as points on template faces.

    Attributes:
        faces: ``(68,)`` int64 template face index of each landmark.
        barycentric: ``(68, 3)`` float64 weights of that face's three vertices (non-negative, sum 1).
    """

    faces: np.ndarray
    barycentric: np.ndarray


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
    return LandmarkEmbedding(
        np.array([points[i][0] for i in range(68)], np.int64), np.array([points[i][1] for i in range(68)], np.float64)
    )


@cached_per_asset
def _embedding(asset: RigAsset) -> LandmarkEmbedding:
    return _build_embedding(asset, corrected=True)


@cached_per_asset
def _heuristic_embedding(asset: RigAsset) -> LandmarkEmbedding:
    return _build_embedding(asset, corrected=False)


def ibug68_embedding(asset: RigAsset | None = None, *, corrected: bool = True) -> LandmarkEmbedding:
    """The iBUG-68 landmarks of the template as faces + barycentric weights (computed once per asset).

    Args:
        asset: the template (default :func:`rig.asset.load_asset`).
        corrected: False: the geometric placement alone, without
            :data:`~landmarks.ibug68.corrections.LANDMARK_CORRECTIONS_MM` and
            :data:`~landmarks.ibug68.corrections.CONTOUR_ANGLES_DEG` (for the benchmark that fits them).

    Example:
        >>> emb = ibug68_embedding()
        >>> emb.faces.shape, emb.barycentric.shape
        ((68,), (68, 3))
    """
    asset = load_asset() if asset is None else asset
    return _embedding(asset) if corrected else _heuristic_embedding(asset)


__all__ = ["LandmarkEmbedding", "ibug68_embedding"]
