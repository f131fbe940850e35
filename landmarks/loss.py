"""2D landmark reprojection loss through a kornia ``PinholeCamera`` (OpenCV convention: x right, y down,
z forward; pixel coordinates with the origin at the centre of the top-left pixel).

kornia is imported here only (the ``rig`` package does not need it).
"""

from __future__ import annotations

import torch
from kornia.geometry.camera import PinholeCamera

from landmarks.ibug68.names import CHIN, IBUG68_MIRROR, JAW_CONTOUR
from rig.errors import InputError
from rig.lbs import ShapeError

ROBUST_KINDS = ("huber", "l2")
CONTOUR_WEIGHT = 0.5


DETECTOR_ERROR_PX: tuple[float, ...] = (
    8.25,
    7.88,
    6.50,
    6.19,
    6.72,
    8.15,
    7.38,
    5.75,
    5.00,
    5.31,
    7.37,
    7.26,
    6.28,
    5.72,
    5.86,
    8.64,
    8.07,
    5.81,
    5.16,
    5.35,
    5.12,
    4.68,
    4.69,
    4.93,
    5.17,
    4.96,
    5.43,
    3.33,
    2.57,
    2.34,
    2.16,
    2.32,
    2.36,
    2.04,
    2.49,
    2.50,
    4.57,
    4.23,
    3.82,
    4.57,
    5.18,
    5.49,
    4.57,
    3.66,
    4.03,
    4.32,
    5.56,
    5.22,
    2.48,
    2.16,
    2.02,
    2.03,
    2.08,
    2.32,
    2.60,
    2.33,
    2.27,
    2.27,
    2.40,
    2.44,
    2.75,
    3.02,
    3.24,
    3.00,
    2.70,
    2.87,
    2.99,
    2.76,
)
"""Mean per-view distance between dlib's 68 landmarks and the corrected embedding's projections, per landmark,
at an inter-ocular distance of 100 px: 21 poses (yaw +-30 deg, pitch +-15) x 8 render seeds that the
corrections were not fitted on (``benchmarks/results/landmark_offsets.json``, ``corrected``; ``benchmarks/
bench_landmark_offsets.py``; detections whose landmarks failed, NME > 0.1, left out). The jaw contour is off
by 5-8 px, the brows by ~5, the eyes by ~4.5, the nose and mouth by 2-3."""

DETECTOR_REFERENCE_PX = DETECTOR_ERROR_PX[30]
"""The error that gets weight 1 in :func:`detector_landmark_weights`: the nose tip's (30), among the best
placed with the nose and the mouth (2.16 px on the ICT-shaped template; a round 2.0 on MakeHuman's)."""


def detector_landmark_weights(dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """``(68,)`` inverse-variance weights of dlib's landmarks: ``min(1, (DETECTOR_REFERENCE_PX / e_i)^2)`` with
    ``e_i`` :data:`DETECTOR_ERROR_PX` averaged with its mirror landmark's (so the weights are symmetric),
    at least 0.05. A landmark dlib places twice as badly counts a quarter as much."""
    e = torch.tensor(DETECTOR_ERROR_PX, dtype=torch.float64)
    e = 0.5 * (e + e[list(IBUG68_MIRROR)])
    w = (DETECTOR_REFERENCE_PX / e).square().clamp(0.05, 1.0)
    return w.to(dtype=dtype, device=device)


WEIGHTINGS = ("contour", "detector")
"""The landmark weightings of :func:`landmark_weights`."""


def landmark_weights(
    weighting: str = "contour", contour_weight: float = CONTOUR_WEIGHT, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """``(68,)`` weights of a landmark fit's term.

    ``contour``: 1, ``contour_weight`` for the jaw contour, the chin (8) :data:`CONTOUR_WEIGHT` whatever
    ``contour_weight`` (a static landmark, not a silhouette). ``detector``: :func:`detector_landmark_weights`,
    the contour's (but the chin's) times ``contour_weight / CONTOUR_WEIGHT``.
    """
    if weighting not in WEIGHTINGS:
        raise InputError(f"landmark_weights: weighting must be one of {list(WEIGHTINGS)}, got {weighting!r}")
    if not contour_weight >= 0:
        raise InputError(f"contour_weight must be >= 0, got {contour_weight}")
    contour = [i for i in JAW_CONTOUR if i != CHIN]
    if weighting == "detector":
        w = detector_landmark_weights(dtype).clone()
        w[contour] = w[contour] * (float(contour_weight) / CONTOUR_WEIGHT)
        return w
    w = default_landmark_weights(dtype).clone()
    w[contour] = float(contour_weight)
    return w


def default_landmark_weights(dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """``(68,)`` iBUG-68 weights: 1, and :data:`CONTOUR_WEIGHT` for the jaw contour (0-16), whose template
    points are only approximately where annotators put the face outline."""
    w = torch.ones(68, dtype=dtype, device=device)
    w[list(JAW_CONTOUR)] = CONTOUR_WEIGHT
    return w


def project_points(points: torch.Tensor, camera: PinholeCamera) -> torch.Tensor:
    """Project world points to pixels with kornia's pinhole model.

    Args:
        points: ``(B, N, 3)`` world points, mm (the frame the camera's extrinsics map from).
        camera: ``PinholeCamera`` with batch size ``B`` (or 1, broadcast): ``intrinsics`` ``(B, 4, 4)``,
            ``extrinsics`` ``(B, 4, 4)`` world -> camera, OpenCV convention.

    Returns:
        ``(B, N, 2)`` pixel coordinates ``(u, v)`` (OpenCV, 0-based), same dtype as ``points``.

    Example:
        >>> K = torch.tensor([[[500., 0, 320, 0], [0, 500., 240, 0], [0, 0, 1, 0], [0, 0, 0, 1]]])
        >>> cam = PinholeCamera(K, torch.eye(4)[None], torch.tensor([480.]), torch.tensor([640.]))
        >>> project_points(torch.tensor([[[0., 0., 1000.]]]), cam)
        tensor([[[320., 240.]]])
    """
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ShapeError(f"project_points: points must have shape (B, N, 3), got {tuple(points.shape)}")
    b = camera.intrinsics.shape[0]
    if b not in (1, points.shape[0]):
        raise ShapeError(f"project_points: camera batch must be 1 or {points.shape[0]}, got {b}")
    if b == 1 and points.shape[0] != 1:
        camera = PinholeCamera(
            camera.intrinsics.expand(points.shape[0], 4, 4),
            camera.extrinsics.expand(points.shape[0], 4, 4),
            camera.height.expand(points.shape[0]),
            camera.width.expand(points.shape[0]),
        )
    return camera.project(points)


def landmark_reprojection_loss(
    points3d: torch.Tensor,
    landmarks2d: torch.Tensor,
    camera: PinholeCamera,
    weights: torch.Tensor | None = None,
    robust: str = "huber",
    delta_px: float = 5.0,
) -> torch.Tensor:
    """Weighted mean robust pixel distance between projected 3D landmarks and detected 2D landmarks.

    Per landmark ``r = ||project(X) - x||`` in pixels; ``rho(r) = r^2 / 2`` for ``"l2"``; for ``"huber"``
    ``rho(r) = r^2 / 2`` if ``r <= delta_px`` else ``delta_px * (r - delta_px / 2)`` (quadratic near the
    fit, linear for outliers such as a wrong detection). Loss ``= sum_i w_i rho(r_i) / sum_i w_i``.

    Args:
        points3d: ``(B, L, 3)`` landmarks in world space, mm.
        landmarks2d: ``(B, L, 2)`` target pixels (OpenCV, 0-based).
        camera: ``PinholeCamera`` with batch ``B`` or 1.
        weights: ``(L,)`` non-negative; default :func:`default_landmark_weights` (needs ``L = 68``).
        robust: ``"huber"`` or ``"l2"``.
        delta_px: Huber threshold in pixels.

    Returns:
        ``(B,)`` loss in squared-pixel units (``px^2 / 2`` near zero).
    """
    func = "landmark_reprojection_loss"
    if points3d.ndim != 3 or points3d.shape[-1] != 3:
        raise ShapeError(f"{func}: points3d must have shape (B, L, 3), got {tuple(points3d.shape)}")
    if landmarks2d.shape != (*points3d.shape[:2], 2):
        raise ShapeError(
            f"{func}: landmarks2d must have shape {(*points3d.shape[:2], 2)}, got {tuple(landmarks2d.shape)}"
        )
    if robust not in ROBUST_KINDS:
        raise InputError(f"{func}: robust must be one of {ROBUST_KINDS}, got {robust!r}")
    if not delta_px > 0:
        raise InputError(f"{func}: delta_px must be > 0, got {delta_px}")
    n = points3d.shape[1]
    if weights is None:
        if n != 68:
            raise ShapeError(f"{func}: default weights need 68 landmarks, got {n}; pass weights")
        weights = default_landmark_weights(points3d.dtype, points3d.device)
    weights = torch.as_tensor(weights, dtype=points3d.dtype, device=points3d.device)
    if weights.shape != (n,):
        raise ShapeError(f"{func}: weights must have shape ({n},), got {tuple(weights.shape)}")
    if (weights < 0).any() or weights.sum() <= 0:
        raise InputError(f"{func}: weights must be non-negative with a positive sum")
    residual = project_points(points3d, camera) - landmarks2d.to(points3d.dtype)
    # sqrt has an infinite derivative at 0: take it of a value kept away from 0, and use the squared norm
    # directly where the quadratic branch applies.
    sq = (residual * residual).sum(-1)
    if robust == "l2":
        rho = 0.5 * sq
    else:
        r = torch.sqrt(sq.clamp_min(delta_px * delta_px))
        rho = torch.where(sq <= delta_px * delta_px, 0.5 * sq, delta_px * (r - 0.5 * delta_px))
    return (rho * weights).sum(-1) / weights.sum()
