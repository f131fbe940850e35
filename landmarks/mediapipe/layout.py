"""MediaPipe's 478 points as a landmark layout for the photo fit (:class:`landmarks.layout.LandmarkLayout`).

The points lie where :func:`landmarks.mediapipe.embedding.mediapipe_embedding` puts them on the template
(fitted on renders, ``benchmarks/fit_mediapipe_embedding.py``); its outline points slide on the
silhouette along lines of candidate vertices (:mod:`landmarks.mediapipe.contour`); each point is weighted
by the detector's measured scatter on it (``detector`` weighting: ``min(1, (REFERENCE_PX / sigma_i)^2)``,
at least :data:`MIN_WEIGHT`, symmetric between mirror partners where the table is).

Example::

    layout = mediapipe_layout(load_asset())
    fit_landmarks(face.dense[:, :2], width, height, layout=layout)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from landmarks.ibug68.positions import landmark_positions
from landmarks.layout import LandmarkLayout
from landmarks.loss import CONTOUR_WEIGHT
from landmarks.mediapipe.contour import contour_lines, pick_contour
from landmarks.mediapipe.embedding import mediapipe_embedding
from rig.asset import RigAsset, cached_per_asset
from rig.errors import InputError

MESH_POINTS = 468
"""MediaPipe's face-mesh points (the irises follow, 5 per eye)."""
IRIS_POINTS = 10
EYE_OUTER_CORNERS = (33, 263)
"""MediaPipe's outer eye corners (the subject's right, then left): the NME's normaliser."""
REFERENCE_QUANTILE = 0.25
"""The weight-1 scatter (:data:`REFERENCE_PX` is this quantile of the non-contour points' ``sigma_px``): the
best placed quarter of the points count fully."""
MIN_WEIGHT = 0.05
"""The least weight of a point, however scattered."""


@cached_per_asset
def mediapipe_layout(asset: RigAsset) -> LandmarkLayout:
    """MediaPipe's 478 points (468 mesh points and the two irises) on ``asset``'s template (module docstring).

    Raises:
        landmarks.detector.DetectionError: the committed table does not match the template (the message says
            how to refit it).
    """
    return _layout(asset, MESH_POINTS + IRIS_POINTS)


@cached_per_asset
def mediapipe_mesh_layout(asset: RigAsset) -> LandmarkLayout:
    """MediaPipe's 468 mesh points without the irises (a landmark file of 468 points), as
    :func:`mediapipe_layout` (the same places and weights)."""
    return _layout(asset, MESH_POINTS)


def mediapipe_layout_for(asset: RigAsset, count: int) -> LandmarkLayout:
    """The MediaPipe layout of ``count`` (468 or 478) points.

    Raises:
        ValueError: another count.
    """
    if count == MESH_POINTS + IRIS_POINTS:
        return mediapipe_layout(asset)
    if count == MESH_POINTS:
        return mediapipe_mesh_layout(asset)
    raise InputError(f"MediaPipe's layouts have {MESH_POINTS} or {MESH_POINTS + IRIS_POINTS} points, got {count}")


def _layout(asset: RigAsset, count: int) -> LandmarkLayout:
    full = mediapipe_embedding(asset)
    embedding = replace(
        full,
        faces=full.faces[:count],
        barycentric=full.barycentric[:count],
        contour=full.contour[:count],
        sigma_px=full.sigma_px[:count],
    )
    contour = np.flatnonzero(embedding.contour).astype(np.int64)
    frontal = landmark_positions(np.asarray(asset.vertices, np.float64), embedding, asset.faces)[0]
    lines = contour_lines(asset, frontal[contour])
    sigma = np.asarray(embedding.sigma_px, np.float64)
    # the reference of the full table, so that the 468-point layout weighs each point as the 478-point one
    reference = float(np.quantile(np.asarray(full.sigma_px)[~full.contour], REFERENCE_QUANTILE))

    def pick(vertices: np.ndarray, camera_centre: np.ndarray) -> np.ndarray:
        return pick_contour(lines, vertices, camera_centre)

    def point_weights(weighting: str, contour_weight: float) -> np.ndarray:
        # as iBUG-68's (landmarks.loss.landmark_weights): "contour" 1 and contour_weight on the outline;
        # "detector" by the measured scatter, the outline's times contour_weight / CONTOUR_WEIGHT
        if weighting == "detector":
            w = np.clip((reference / np.maximum(sigma, 1e-9)) ** 2, MIN_WEIGHT, 1.0)
            w[contour] *= contour_weight / CONTOUR_WEIGHT
        elif weighting == "contour":
            w = np.ones(len(sigma))
            w[contour] = contour_weight
        else:
            raise InputError(f"landmark weighting must be 'contour' or 'detector', got {weighting!r}")
        return w

    return LandmarkLayout(
        name="mediapipe" if count == MESH_POINTS + IRIS_POINTS else "mediapipe468",
        count=len(sigma),
        embedding=embedding,
        contour=contour,
        pick=pick,
        support=lines.support,
        eye_corners=EYE_OUTER_CORNERS,
        point_weights=point_weights,
        pose_exclude=tuple(int(i) for i in contour),
        sees_irises=count == MESH_POINTS + IRIS_POINTS,
    )


__all__ = [
    "EYE_OUTER_CORNERS",
    "IRIS_POINTS",
    "MESH_POINTS",
    "MIN_WEIGHT",
    "REFERENCE_QUANTILE",
    "mediapipe_layout",
    "mediapipe_layout_for",
    "mediapipe_mesh_layout",
]
