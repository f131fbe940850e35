"""Landmark layouts: a detector's point scheme on the template, as the photo fit needs it (issue 26).

A :class:`LandmarkLayout` says, for one scheme of ``N`` 2D points (iBUG-68, :func:`ibug68_layout`; MediaPipe's
478 dense points, :mod:`landmarks.mediapipe.layout`): where each point lies on the template
(:attr:`~LandmarkLayout.embedding`, one face and three barycentric weights each), which points are *contour*
points that slide on the silhouette seen from the camera (re-picked as template vertices by
:attr:`~LandmarkLayout.pick`), how much each point is trusted (:meth:`~LandmarkLayout.weights`) and which two
points are the outer eye corners (for the normalised mean error).
:class:`pipeline.fitting.landmark_term.LandmarkTerm` takes any layout, so both solvers fit any scheme the same
way.

Example::

    layout = ibug68_layout(load_asset())
    layout.count, layout.contour            # 68, the 16 jaw-contour points (0-16 but the chin)
    ids = layout.pick(vertices, camera_centre)   # (16,) vertex ids on the silhouette
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from landmarks.ibug68.contour import contour_support_ids, contour_vertex_ids
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.names import CHIN, JAW_CONTOUR
from landmarks.ibug68.positions import landmark_positions
from landmarks.loss import CONTOUR_WEIGHT, landmark_weights
from rig.asset import RigAsset, cached_per_asset


class LayoutError(ValueError):
    """Landmarks that do not match a layout (their count), or an unknown layout name."""


@dataclass(frozen=True)
class LandmarkLayout:
    """One landmark scheme on the template (module docstring).

    Attributes:
        name: ``"ibug68"`` or ``"mediapipe"`` (recorded in ``report.json``).
        count: ``N``, the number of 2D points a detection or a file of this layout has.
        embedding: where the points lie: ``.faces (N,)`` template face ids, ``.barycentric (N, 3)``
            (:func:`landmarks.ibug68.positions.landmark_positions` reads it).
        contour: ``(C,)`` int64 indices of the points re-picked on the silhouette (the rest are fixed on the
            surface); their embedding is only a frontal start.
        pick: ``pick(vertices (V, 3) float64 numpy mm, camera_centre (3,) mm) -> (C,)`` int64 template vertex
            ids of the contour points seen from that camera (rig space); reads only :attr:`support`.
        support: ``(S,)`` sorted vertex ids :attr:`pick` reads (a fit that skins only these can pick).
        eye_corners: the indices of the subject's right and left outer eye corners (NME's normaliser).
        point_weights: ``point_weights(weighting, contour_weight) -> (N,)`` float64 numpy weights of the
            fit's reprojection term (:meth:`weights`).
        pose_exclude: the points left out of the first pose estimate (PnP on the template), whose 3D points
            slide with the view: the contour points (iBUG-68: the whole jaw line 0-16, the chin too).
        sees_irises: the points include the irises, which tell the gaze (the photo fit then gives the eyeLook*
            coefficients a weaker prior, ``PriorWeights.lambda_gaze``).
    """

    name: str
    count: int
    embedding: object
    contour: np.ndarray
    pick: Callable[[np.ndarray, np.ndarray], np.ndarray]
    support: np.ndarray
    eye_corners: tuple[int, int]
    point_weights: Callable[[str, float], np.ndarray]
    pose_exclude: tuple[int, ...]
    sees_irises: bool = False

    def weights(
        self, weighting: str = "contour", contour_weight: float = CONTOUR_WEIGHT, dtype: torch.dtype = torch.float32
    ) -> torch.Tensor:
        """``(N,)`` weights of the reprojection term: ``weighting`` ``"contour"`` (1, the contour
        ``contour_weight``) or ``"detector"`` (by the detector's measured error on each point)."""
        return torch.as_tensor(self.point_weights(weighting, float(contour_weight)), dtype=dtype)

    def points3d(self, vertices: torch.Tensor, faces, camera_centre) -> torch.Tensor:
        """``(N, 3)`` the layout's points on a head: the static embedding, the contour points on the silhouette
        seen from ``camera_centre`` (:attr:`pick`).

        Args:
            vertices: ``(V, 3)`` torch tensor, rig space, mm (the result is differentiable w.r.t. it).
            faces: ``(F, 3)`` the template's faces. camera_centre: ``(3,)`` the camera centre in rig space, mm.
        """
        static = landmark_positions(vertices, self.embedding, faces)[0]
        picked = self.pick(vertices.detach().cpu().double().numpy(), np.asarray(camera_centre, np.float64))
        points = static.clone()
        device = vertices.device
        points[torch.as_tensor(self.contour, device=device)] = vertices[torch.as_tensor(picked, device=device)]
        return points

    def check(self, points: np.ndarray, function: str) -> np.ndarray:
        """``points`` as ``(N, 2)`` float64.

        Raises:
            LayoutError: another shape (naming ``function`` and the layout).
        """
        array = np.asarray(points, dtype=np.float64)
        if array.shape != (self.count, 2):
            raise LayoutError(
                f"{function}: the {self.name} layout has {self.count} points (pixels, shape ({self.count}, 2)); "
                f"got shape {array.shape}"
            )
        return array


IBUG68_CONTOUR = np.array([k for k in JAW_CONTOUR if k != CHIN], dtype=np.int64)
"""The 16 jaw-contour points of iBUG-68 re-picked on the silhouette (the chin, 8, stays fixed)."""


@cached_per_asset
def ibug68_layout(asset: RigAsset) -> LandmarkLayout:
    """dlib's iBUG-68 points: the corrected embedding (:func:`landmarks.ibug68.embedding.ibug68_embedding`),
    the jaw contour picked along its candidate lines (:func:`landmarks.ibug68.contour.contour_vertex_ids`),
    weights of :func:`landmarks.loss.landmark_weights`."""

    def pick(vertices: np.ndarray, camera_centre: np.ndarray) -> np.ndarray:
        return np.asarray(contour_vertex_ids(vertices, asset.faces, camera_centre, asset), np.int64)[IBUG68_CONTOUR]

    def point_weights(weighting: str, contour_weight: float) -> np.ndarray:
        return landmark_weights(weighting, contour_weight, torch.float64).numpy()

    return LandmarkLayout(
        name="ibug68",
        count=68,
        embedding=ibug68_embedding(asset),
        contour=IBUG68_CONTOUR,
        pick=pick,
        support=np.asarray(contour_support_ids(asset), np.int64),
        eye_corners=(36, 45),
        point_weights=point_weights,
        pose_exclude=tuple(JAW_CONTOUR),
    )


__all__ = ["IBUG68_CONTOUR", "LandmarkLayout", "LayoutError", "ibug68_layout"]
