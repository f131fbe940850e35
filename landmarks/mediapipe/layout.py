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

import numpy as np

from landmarks.ibug68.positions import landmark_positions
from landmarks.layout import LandmarkLayout
from landmarks.loss import CONTOUR_WEIGHT
from landmarks.mediapipe.contour import contour_lines, pick_contour
from landmarks.mediapipe.embedding import mediapipe_embedding
from rig.asset import RigAsset, cached_per_asset

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
    embedding = mediapipe_embedding(asset)
    contour = np.flatnonzero(embedding.contour).astype(np.int64)
    frontal = landmark_positions(np.asarray(asset.vertices, np.float64), embedding, asset.faces)[0]
    lines = contour_lines(asset, frontal[contour])
    sigma = np.asarray(embedding.sigma_px, np.float64)
    reference = float(np.quantile(sigma[~embedding.contour], REFERENCE_QUANTILE))

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
            raise ValueError(f"landmark weighting must be 'contour' or 'detector', got {weighting!r}")
        return w

    return LandmarkLayout(
        name="mediapipe",
        count=len(sigma),
        embedding=embedding,
        contour=contour,
        pick=pick,
        support=lines.support,
        eye_corners=EYE_OUTER_CORNERS,
        point_weights=point_weights,
        pose_exclude=tuple(int(i) for i in contour),
    )


__all__ = ["EYE_OUTER_CORNERS", "MIN_WEIGHT", "REFERENCE_QUANTILE", "mediapipe_layout"]
