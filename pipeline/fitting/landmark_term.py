"""The landmark reprojection term of one photo, defined once for both solvers, for any landmark layout.

:class:`LandmarkTerm` is the observation: the target pixels, the camera, each landmark's weight, the Huber
threshold and the layout (:class:`landmarks.layout.LandmarkLayout`: dlib's iBUG-68 by default), whose
contour points are re-picked as the silhouette seen from the camera centre (for iBUG-68 the jaw contour
0-16 but the chin, :func:`landmarks.ibug68.contour.contour_vertex_ids`). Its :meth:`LandmarkTerm.term` is
the :class:`~pipeline.fitting.terms.Term` (``Huber`` on each landmark's pixel error, weighted, normalised by
the weights' sum: :func:`landmarks.loss.landmark_reprojection_loss`) reading the input ``landmarks_px
(B, N, 2)``. Two evaluations give that input:

- the live state (:meth:`LandmarkTerm.pixels`): the full mesh in the state's dtype, the contour re-picked every
  call; the Adam objectives and the results use it;
- :class:`BatchedLandmarks`, for the Levenberg-Marquardt solver: a batch of parameter sets at once, in float64,
  skinning only the vertices the landmarks and the contour's pick read, with the skinning weights of the
  state's latent held fixed and the contour re-picked by :meth:`BatchedLandmarks.prepare` (the first
  :data:`CONTOUR_UPDATES` times).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera
from kornia.geometry.conversions import axis_angle_to_rotation_matrix

from landmarks.layout import LandmarkLayout, ibug68_layout
from landmarks.loss import CONTOUR_WEIGHT, project_points
from pipeline.camera import head_points_to_pixels
from pipeline.fitting.state import PhotoState
from pipeline.fitting.terms import Huber, Inputs, Term
from rig.asset import cached_per_asset
from rig.errors import InputError
from rig.expressions import ExpressionModel
from rig.head_model import jnr_vertices
from rig.lbs import skin_vertices_shared_weights
from rig.model import JointRig

NUM_LANDMARKS = 68
"""The points of the default layout (dlib's iBUG-68)."""

REFERENCE_EYE_DISTANCE_PX = 100.0
"""The unit of the landmark term: pixels of a face imaged with this many pixels between the template's outer eye
corners (where the detectors' scatter was measured, :mod:`landmarks.loss`). A photo's residuals are divided by
:func:`face_scale`, so the weights of the priors, the Huber threshold and the detector's noise mean the same for a
face 60 px or 600 px wide: in raw pixels, a 4x larger photo of the same face weighed its landmarks 16x against the
identity prior and the fit followed the detector's errors (issue 37)."""


@cached_per_asset
def template_eye_distance_mm(asset) -> float:
    """The template's distance between its outer eye corners (iBUG 36 and 45), mm."""
    from landmarks.ibug68.embedding import ibug68_embedding
    from landmarks.ibug68.positions import landmark_positions

    points = landmark_positions(np.asarray(asset.vertices, np.float64), ibug68_embedding(asset), asset.faces)[0]
    return float(np.linalg.norm(points[36] - points[45]))


def face_scale(focal: float, depth_mm: float, asset) -> float:
    """Image pixels per unit of the landmark term (:data:`REFERENCE_EYE_DISTANCE_PX`): the template's outer eye
    corners' distance seen frontally at ``depth_mm`` (the head's distance along the optical axis, mm) with
    ``focal`` (pixels), over 100 px. Taken from the pose, not from the detected eye corners, so a turned face
    keeps its size."""
    if not (np.isfinite(depth_mm) and depth_mm > 0 and np.isfinite(focal) and focal > 0):
        raise InputError(f"face_scale: focal and depth must be finite and > 0, got {focal!r}, {depth_mm!r}")
    return float(focal / depth_mm * template_eye_distance_mm(asset) / REFERENCE_EYE_DISTANCE_PX)


CONTOUR_UPDATES = 4
"""LM iterations per stage that re-pick the jaw contour's silhouette vertices; later ones keep the last
pick. A pick is discrete: re-picked every iteration, neighbouring vertices took turns near the minimum and
the cost cycled (seen on synthetic heads) instead of converging."""


def landmark_pixel_term(
    target: torch.Tensor,
    weights: torch.Tensor,
    huber_delta_px: float,
    weight: float = 1.0,
    scale: float = 1.0,
    name: str = "landmarks_px2",
    key: str = "landmarks_px",
) -> Term:
    """The landmark reprojection term of every fit (photo, views, track): ``weight`` times the weighted mean
    Huber of the pixel errors over ``scale``, ``sum_i w_i huber(|px_i - target_i| / scale) / sum_i w_i``.

    Args:
        target: ``(N, 2)`` or ``(1, N, 2)`` the detected pixels. weights: ``(N,)`` each point's weight (0: unused).
        huber_delta_px: the Huber threshold, in the units of ``(px - target) / scale``.
        weight: the term's weight. scale: image pixels per unit of the term (:func:`face_scale`; 1: pixels).
        name: the term's name in the logs. key: the input holding the fitted pixels, ``(B, N, 2)``.
    """
    target = torch.as_tensor(target).reshape(1, -1, 2)

    def pixel_error(p: Inputs) -> torch.Tensor:
        px = p[key]
        return (px - target.to(px.dtype)) / scale

    return Term(name, weight, pixel_error, Huber(huber_delta_px), normaliser="weights", group_weights=weights)


class LandmarkTerm:
    """The landmark reprojection term of one photo (module docstring).

    Args:
        asset: the rig asset (faces).
        landmarks2d: ``(N, 2)`` target pixels (OpenCV, 0-based), in the layout's order.
        camera: ``PinholeCamera`` with identity extrinsics (the model moves points to camera space).
        huber_delta_px: Huber threshold, pixels.
        contour_weight, weighting: each landmark's weight (:meth:`landmarks.layout.LandmarkLayout.weights`).
        layout: the landmark scheme (default: :func:`landmarks.layout.ibug68_layout` of ``asset``).
        scale: image pixels per unit of the term (:func:`face_scale`; 1: raw pixels). It may be set later
            (:attr:`scale`), before the term is evaluated: the fits take it from the first pose.

    Raises:
        landmarks.layout.LayoutError: ``landmarks2d`` does not have the layout's shape.
    """

    def __init__(
        self,
        asset,
        landmarks2d: np.ndarray,
        camera: PinholeCamera,
        huber_delta_px: float,
        contour_weight: float = CONTOUR_WEIGHT,
        weighting: str = "contour",
        layout: LandmarkLayout | None = None,
        scale: float = 1.0,
    ) -> None:
        self.asset, self.camera, self.delta = asset, camera, float(huber_delta_px)
        self.scale = float(scale)
        self.layout = ibug68_layout(asset) if layout is None else layout
        target = self.layout.check(landmarks2d, "LandmarkTerm")
        self.weights = self.layout.weights(weighting, contour_weight, camera.intrinsics.dtype)
        self.faces = asset.faces
        self.embedding = self.layout.embedding
        self.contour = torch.as_tensor(self.layout.contour, dtype=torch.long)
        self.target = torch.tensor(target, dtype=camera.intrinsics.dtype)[None]  # a copy: detections may be read-only

    def term(self, weight: float = 1.0, name: str = "landmarks_px2", key: str = "landmarks_px") -> Term:
        """The :class:`~pipeline.fitting.terms.Term` of these landmarks: ``weight`` times the weighted mean
        Huber of the pixel errors divided by :attr:`scale` (px^2 of a face 100 px between the eye corners with
        :func:`face_scale`), reading the input ``key`` ``(B, N, 2)``."""

        return landmark_pixel_term(self.target, self.weights, self.delta, weight, self.scale, name, key)

    def points3d(self, model: PhotoState, v: torch.Tensor) -> torch.Tensor:
        """``(N, 3)`` rig space, mm: the static embedding, the contour points as seen from the camera."""
        return self.layout.points3d(v, self.faces, model.camera_center())

    def pixels(self, model: PhotoState, v: torch.Tensor, free: tuple[str, ...] = ()) -> torch.Tensor:
        """``(1, N, 2)`` the landmarks of the state's head ``v (V, 3)`` in the photo, pixels; the pose carries
        gradients if ``pose`` is in ``free``."""
        return project_points(model.to_camera(self.points3d(model, v), free)[None], self.camera)

    def __call__(self, model: PhotoState, v: torch.Tensor, free: tuple[str, ...] = ()) -> torch.Tensor:
        """Scalar loss in the term's units (px^2 / :attr:`scale`^2; the term's value with weight 1)."""
        return self.term().value(Inputs(landmarks_px=lambda: self.pixels(model, v, free)))[0]

    def project(self, model: PhotoState, v: torch.Tensor) -> np.ndarray:
        """``(N, 2)`` float64 pixels of the model's landmarks."""
        with torch.no_grad():
            return self.pixels(model, v)[0].double().numpy()


@cached_per_asset
def expressions64(asset) -> ExpressionModel:
    """The asset's expression model in float64 (made once per asset)."""
    return ExpressionModel(asset, dtype=torch.float64)


class _LayoutBatch:
    """What :class:`BatchedLandmarks` and :class:`ModelLandmarks` share: a layout's points for a batch of parameter
    sets from the vertices they skin (subclasses: :meth:`support_vertices`, :meth:`points`).

    Args:
        term: the landmarks. free: the groups the batch varies.
    """

    def __init__(self, term: LandmarkTerm, free: tuple[str, ...]) -> None:
        f64 = torch.float64
        self.term, self.free = term, free
        cam = term.camera.intrinsics[0].to(f64)
        self.focal = cam[[0, 1], [0, 1]]
        self.centre = cam[[0, 1], [2, 2]]
        emb = term.embedding
        self.static_ids = torch.as_tensor(np.asarray(term.faces)[emb.faces], dtype=torch.long)  # (N, 3)
        self.static_bary = torch.as_tensor(emb.barycentric, dtype=f64)  # (N, 3)
        self.support_ids = torch.as_tensor(term.layout.support, dtype=torch.long)
        self.vertex_count = len(term.asset.vertices)
        self.prepared, self.contour = 0, None

    def support_vertices(self, p: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """``(S, 3)`` float64 the vertices :attr:`support_ids` of batch-1 parameters ``p``, rig space, mm."""
        raise NotImplementedError

    def points(self, p: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """``(B, N, 3)`` the landmarks in rig space, mm, of a batch of parameters ``p``."""
        raise NotImplementedError

    def prepared_ids(self) -> None:
        """Hook: the picked vertices changed (:attr:`vertex_ids`)."""

    def prepare(self, p: Mapping[str, torch.Tensor], camera_center: np.ndarray) -> None:
        """Re-pick the contour points (the first :data:`CONTOUR_UPDATES` calls) from ``camera_center (3,)`` (rig
        space, mm) at the batch-1 parameters ``p``."""
        self.prepared += 1
        if self.prepared <= CONTOUR_UPDATES or self.contour is None:
            with torch.no_grad():  # only the vertices the contour's pick reads are made
                v = torch.zeros(self.vertex_count, 3, dtype=torch.float64)
                v[self.support_ids] = self.support_vertices(p).double()
                self.contour = torch.as_tensor(self.term.layout.pick(v.numpy(), camera_center), dtype=torch.long)
        ids = self.static_ids.clone()
        bary = self.static_bary.clone()
        slots = self.term.contour
        ids[slots] = self.contour[:, None].expand(-1, 3)  # the picked vertex (its weight on the first corner)
        bary[slots] = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
        self.vertex_ids, inverse = torch.unique(ids.reshape(-1), return_inverse=True)
        self.local_ids = inverse.reshape(ids.shape)
        self.bary = bary
        self.prepared_ids()

    def interpolate(self, vertices: torch.Tensor) -> torch.Tensor:
        """``(B, U, 3)`` the vertices :attr:`vertex_ids` -> ``(B, N, 3)`` the landmarks."""
        return (vertices[:, self.local_ids] * self.bary[..., None]).sum(2)

    def pixels(self, p: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """``(B, N, 2)`` pixels of ``p``'s ``rotvec (B, 3)``, ``translation (B, 3)`` and head parameters."""
        return self.to_pixels(self.points(p), p["rotvec"], p["translation"])

    def to_pixels(self, points: torch.Tensor, rotvec: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
        """``(B, N, 2)`` pixels of landmarks ``points (B, N, 3)`` (rig space, mm) seen with head pose
        ``rotvec (B, 3)``, ``translation (B, 3)`` (:mod:`pipeline.camera`)."""
        rotation = axis_angle_to_rotation_matrix(rotvec)  # (B, 3, 3)
        return head_points_to_pixels(points, rotation, translation, self.focal, self.centre)


class BatchedLandmarks(_LayoutBatch):
    """:class:`LandmarkTerm`'s landmark pixels of JNR's head for a batch of parameter sets, for the LM solver
    (module docstring): ``theta (B, P)``, ``c (B, E)``, the skinning weights fixed.

    Args:
        term: the landmarks. rig: the rig (its joint hierarchy). weights: ``(V, K)`` skinning weights, fixed.
        free: the groups the batch varies (``pose``, ``joints``, ``expressions``): what does not vary is
            computed once.
    """

    def __init__(self, term: LandmarkTerm, rig: JointRig, weights: torch.Tensor, free: tuple[str, ...]) -> None:
        super().__init__(term, free)
        self.rig = rig
        self.weights = weights.to(torch.float64)
        self.expressions = expressions64(term.asset)
        self._rest: torch.Tensor | None = None
        self._skinning: torch.Tensor | None = None

    def support_vertices(self, p: Mapping[str, torch.Tensor]) -> torch.Tensor:
        ids = self.support_ids
        return jnr_vertices(self.rig, self.expressions, p["theta"], self.weights, p["c"], ids)[0]

    def prepared_ids(self) -> None:
        self._rest = None
        self.rest_weights = self.weights[self.vertex_ids]

    def points(self, p: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """``(B, N, 3)`` the landmarks in rig space, mm, of ``p``'s ``theta (B, P)`` and ``c (B, E)``."""
        batch = p["theta"].shape[0]
        # groups the stage does not move are the same in every row: computed once per stage (the rest
        # shape once per contour pick, which changes the vertices)
        if "expressions" in self.free:
            rest = self.expressions.template[self.vertex_ids] + self.expressions(p["c"], self.vertex_ids)
        else:
            if self._rest is None:
                self._rest = self.expressions.template[self.vertex_ids] + self.expressions(p["c"][:1], self.vertex_ids)
            rest = self._rest  # (1, U, 3)
        if "joints" in self.free:
            _, skinning = self.rig.joint_transforms(p["theta"])
        else:
            if self._skinning is None:
                self._skinning = self.rig.joint_transforms(p["theta"][:1])[1]
            skinning = self._skinning
        if skinning.shape[0] != batch:
            skinning = skinning.expand(batch, -1, -1, -1)
        if rest.shape[0] != batch:
            rest = rest.expand(batch, -1, -1)
        return self.interpolate(skin_vertices_shared_weights(rest, self.rest_weights, skinning))  # (B, N, 3)


class ModelLandmarks(_LayoutBatch):
    """:class:`LandmarkTerm`'s landmark pixels of any head model (:class:`rig.head_model.HeadModel`) for a batch
    of parameter sets: its groups by name in ``p`` (``(B, n)`` each), the vertices by its
    :meth:`~rig.head_model.HeadModel.vertices`.

    Args:
        term: the landmarks. model: the head model. groups: its group names. free: the groups the batch varies.
    """

    def __init__(self, term: LandmarkTerm, model, groups: tuple[str, ...], free: tuple[str, ...]) -> None:
        super().__init__(term, free)
        self.model, self.groups = model, groups

    def _values(self, p: Mapping[str, torch.Tensor], rows: int | None = None) -> dict[str, torch.Tensor]:
        return {g: p[g] if rows is None else p[g][:rows] for g in self.groups}

    def support_vertices(self, p: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return self.model.vertices(self._values(p, 1), self.support_ids)[0].to(torch.float64)

    def points(self, p: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return self.interpolate(self.model.vertices(self._values(p), self.vertex_ids).to(torch.float64))
