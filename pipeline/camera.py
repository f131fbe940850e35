"""The camera of a single photo: a pinhole in OpenCV axes looking at the head in rig space.

Frames:

- **rig space** (the world here): mm, right-handed, +X the subject's left, +Y up, +Z out of the face.
- **camera** (OpenCV, kornia): x right, y down, z forward (into the scene), pixels with the origin at
  the centre of the top-left pixel.

A head is placed by a **head pose** ``(rotation, translation)``: ``rotation`` ``(3, 3)`` turns the head
in rig axes (identity = the face looks straight into the camera; a yaw is a rotation about rig +Y),
``translation`` ``(3,)`` is where the rig origin lands in camera coordinates (mm; ``(0, 0, 600)`` is a
head 60 cm in front of the lens). The camera-from-rig transform is then

    x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation,

the only place where the axis flip :data:`RIG_TO_OPENCV` is applied (:func:`camera_from_head_pose`);
:func:`solve_pose` returns a head pose in the same convention, so
``make_camera(w, h, f, *solve_pose(...))`` images the head as the photo shows it.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera

from landmarks.ibug68.names import JAW_CONTOUR
from rig.errors import InputError
from rig.geometry import (
    RIG_TO_OPENCV,  # the one definition (rig axes -> OpenCV axes), used here
)
from rig.lbs import ShapeError

DEFAULT_DISTANCE_MM = 600.0
"""Initial camera-to-head distance of the iterative PnP (a portrait at arm's length)."""


FOCAL_RANGE = (0.25, 25.0)
"""Accepted focal lengths, as multiples of the photo's longer side: a horizontal field of view from about
127 degrees (wider than any rectilinear phone or DSLR lens; fisheye photos are not pinhole images) down
to about 2.3 degrees (an 800 mm lens on full frame). A focal outside it is a mistake (``--focal 1`` puts
the head ~150 m away), not a camera."""


def check_focal(focal: float, width: int, height: int) -> float:
    """Check a focal length in pixels against :data:`FOCAL_RANGE` for a ``width x height`` photo.

    Returns:
        ``focal`` as a float.

    Raises:
        rig.errors.InputError: not a finite number in the range (a ValueError); the message gives the
            range in pixels.

    Example:
        >>> check_focal(896.0, 640, 480)
        896.0
    """
    low, high = (r * float(max(width, height)) for r in FOCAL_RANGE)
    try:
        value = float(focal)
    except (TypeError, ValueError):
        raise InputError(f"--focal must be a number of pixels, got {focal!r}") from None
    if not (math.isfinite(value) and low <= value <= high):
        raise InputError(
            f"--focal {focal:g} px is outside {low:g}-{high:g} px, the range jnr accepts for this "
            f"{width} x {height} photo ({FOCAL_RANGE[0]:g}-{FOCAL_RANGE[1]:g} x its longer side; the "
            f"default is 1.4 x)"
        )
    return value


def default_focal(width: int, height: int) -> float:
    """A focal length in pixels for photos whose camera is unknown: ``1.4 * max(width, height)``.

    A 50 mm lens on a 36 mm-wide (full-frame) sensor has ``f / sensor_width = 50 / 36 ~ 1.4``, i.e. a
    horizontal field of view of about 40 degrees; portraits are mostly taken with normal-to-short-tele
    lenses (phones: 26 mm-equivalent main camera, but faces fill the frame from closer, which the
    joints/translation absorb). The value is a prior, not an estimate: with a single photo the focal
    length and the distance to the head are nearly interchangeable.

    Example:
        >>> default_focal(640, 480)
        896.0
    """
    if not (width > 0 and height > 0):
        raise InputError(f"default_focal: width and height must be > 0, got {width} x {height}")
    return 1.4 * float(max(width, height))


def camera_from_head_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """The ``(4, 4)`` world (rig) -> camera (OpenCV) extrinsic matrix of a head pose (module docstring)."""
    rotation = np.asarray(rotation, np.float64)
    translation = np.asarray(translation, np.float64)
    if rotation.shape != (3, 3) or translation.shape != (3,):
        raise ShapeError(
            f"camera_from_head_pose: rotation must be (3, 3) and translation (3,), got "
            f"{rotation.shape} and {translation.shape}"
        )
    extrinsics = np.eye(4)
    extrinsics[:3, :3] = RIG_TO_OPENCV @ rotation
    extrinsics[:3, 3] = translation
    return extrinsics


def make_camera(
    width: int,
    height: int,
    focal: float,
    principal: tuple[float, float] | None = None,
    rotation: np.ndarray | None = None,
    translation: np.ndarray | None = None,
    dtype: torch.dtype = torch.float32,
    *,
    pose: bool = True,
) -> PinholeCamera:
    """A kornia ``PinholeCamera`` (batch 1) looking at rig space.

    Args:
        width, height: image size in pixels.
        focal: focal length in pixels (square pixels, no skew).
        principal: ``(cx, cy)`` pixels; default the image centre ``((width - 1) / 2, (height - 1) / 2)``.
        rotation: ``(3, 3)`` head rotation in rig axes (default identity: facing the camera).
        translation: ``(3,)`` rig origin in camera coordinates, mm (default zeros).
        dtype: of the camera's tensors.
        pose: False: identity extrinsics, for points already in the camera frame (the fits move the head
            into the camera themselves and only project); ``rotation``/``translation`` must then be None.

    Returns:
        ``PinholeCamera`` with ``intrinsics``/``extrinsics`` ``(1, 4, 4)``, ``height``/``width`` ``(1,)``.

    Example:
        >>> cam = make_camera(640, 480, 896.0, translation=np.array([0.0, 0.0, 600.0]))
        >>> cam.project(torch.tensor([[[0.0, 0.0, 0.0]]]))  # the rig origin: the image centre
        tensor([[[319.5000, 239.5000]]])
    """
    if not (width > 0 and height > 0):
        raise InputError(f"make_camera: width and height must be > 0, got {width} x {height}")
    if not (np.isfinite(focal) and focal > 0):
        raise InputError(f"make_camera: focal must be a finite number > 0 (pixels), got {focal}")
    cx, cy = ((width - 1) / 2.0, (height - 1) / 2.0) if principal is None else map(float, principal)
    intrinsics = np.array([[focal, 0.0, cx, 0.0], [0.0, focal, cy, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    if pose:
        extrinsics = camera_from_head_pose(
            np.eye(3) if rotation is None else rotation, np.zeros(3) if translation is None else translation
        )
    elif rotation is None and translation is None:
        extrinsics = np.eye(4)
    else:
        raise InputError("make_camera: pose=False takes no rotation or translation")
    return PinholeCamera(
        torch.as_tensor(intrinsics, dtype=dtype)[None],
        torch.as_tensor(extrinsics, dtype=dtype)[None],
        torch.tensor([float(height)], dtype=dtype),
        torch.tensor([float(width)], dtype=dtype),
    )


_FLIP = torch.tensor(np.array(RIG_TO_OPENCV, np.float64))
""":data:`RIG_TO_OPENCV` as a tensor."""


def head_points_to_pixels(
    points: torch.Tensor, rotation: torch.Tensor, translation: torch.Tensor, focal: torch.Tensor, centre: torch.Tensor
) -> torch.Tensor:
    """Pixels of rig-space points seen under head poses: the batched form of :func:`camera_from_head_pose`
    followed by the pinhole projection, for fits that vary the pose (every fit's landmark pixels go through it).

    Args:
        points: ``(B, N, 3)`` rig space, mm.
        rotation: ``(B, 3, 3)`` head rotations (module docstring). translation: ``(B, 3)`` mm.
        focal: ``(2,)`` or a scalar, pixels. centre: ``(2,)`` the principal point, pixels.

    Returns:
        ``(B, N, 2)`` pixels (OpenCV, 0-based); a point less than 1 mm in front of the camera is projected as
        if at 1 mm (no division by zero or a sign flip behind the lens).

    Example:
        >>> px = head_points_to_pixels(torch.zeros(1, 1, 3), torch.eye(3)[None], torch.tensor([[0.0, 0.0, 600.0]]),
        ...                            torch.tensor([896.0, 896.0]), torch.tensor([319.5, 239.5]))
        >>> px.tolist()
        [[[319.5, 239.5]]]
    """
    flip = _FLIP.to(points.dtype)
    camera = points @ (flip @ rotation).transpose(1, 2) + translation[:, None]
    return camera_points_to_pixels(camera, focal, centre)


def camera_points_to_pixels(camera, focal, centre):
    """The pinhole projection of every fit, preview and texture: ``(..., 3)`` camera-frame points (OpenCV, mm)
    -> ``(..., 2)`` pixels (0-based), torch tensors or numpy arrays alike.

    Args:
        camera: ``(..., 3)`` points in the camera frame, mm. focal: a scalar or ``(2,)`` pixels. centre: ``(2,)``
            the principal point, pixels.

    Returns:
        ``(..., 2)`` pixels; a point less than 1 mm in front of the camera is projected as if at 1 mm (no division
        by zero or a sign flip behind the lens).
    """
    return camera[..., :2] / camera[..., 2:].clip(min=1.0) * focal + centre


def camera_center_in_rig(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """``(3,)`` the camera's optical centre in rig space (mm) for a head pose."""
    extrinsics = camera_from_head_pose(rotation, translation)
    return -extrinsics[:3, :3].T @ extrinsics[:3, 3]


def solve_pose(
    landmarks2d: np.ndarray,
    model_points: np.ndarray,
    width: int,
    height: int,
    focal: float,
    *,
    exclude: tuple[int, ...] = JAW_CONTOUR,
) -> tuple[np.ndarray, np.ndarray]:
    """Head pose from 2D landmarks and their 3D model positions (``cv2.solvePnP``, iterative, started
    from a frontal head :data:`DEFAULT_DISTANCE_MM` in front of the camera).

    Args:
        landmarks2d: ``(N, 2)`` pixels (OpenCV, 0-based), finite.
        model_points: ``(N, 3)`` the same landmarks in rig space, mm.
        width, height, focal: the camera (principal point at the image centre).
        exclude: indices left out (default: the jaw contour 0-16, whose 3D points slide with the view).

    Returns:
        ``(rotation (3, 3), translation (3,))``: the head pose (module docstring), float64.

    Raises:
        ValueError: wrong shapes, non-finite landmarks, model points or focal, fewer than 6 usable points, or
            points so degenerate that PnP fails.
    """
    func = "solve_pose"
    pts2 = np.asarray(landmarks2d, np.float64)
    pts3 = np.asarray(model_points, np.float64)
    if pts2.ndim != 2 or pts2.shape[1] != 2:
        raise ShapeError(f"{func}: landmarks2d must have shape (N, 2), got {pts2.shape}")
    if pts3.shape != (len(pts2), 3):
        raise ShapeError(f"{func}: model_points must have shape ({len(pts2)}, 3), got {pts3.shape}")
    if not np.isfinite(pts2).all():
        raise InputError(
            f"{func}: landmarks2d contain NaN or inf (rows {np.flatnonzero(~np.isfinite(pts2).all(1)).tolist()})"
        )
    if not np.isfinite(pts3).all():
        raise InputError(f"{func}: model_points contain NaN or inf")
    if not (np.isfinite(focal) and focal > 0):
        raise InputError(f"{func}: focal must be a finite number > 0, got {focal}")
    use = np.ones(len(pts2), bool)
    use[[i for i in exclude if i < len(use)]] = False
    if use.sum() < 6:
        raise InputError(
            f"{func}: need at least 6 finite landmarks outside {len(exclude)} excluded ones, got {int(use.sum())}"
        )
    spread = pts2[use].std(0)
    if not (spread > 1e-3).all():
        raise InputError(f"{func}: the landmarks are degenerate (all on a line or a point): spread {spread} px")
    K = np.array([[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    rvec0 = cv2.Rodrigues(RIG_TO_OPENCV)[0]
    tvec0 = np.array([[0.0], [0.0], [DEFAULT_DISTANCE_MM]])
    ok, rvec, tvec = cv2.solvePnP(
        pts3[use], pts2[use], K, None, rvec0.copy(), tvec0.copy(), useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE
    )
    if not ok or not (np.isfinite(rvec).all() and np.isfinite(tvec).all()) or tvec[2, 0] <= 0:
        raise InputError(f"{func}: PnP failed (no pose puts the head in front of the camera)")
    camera_rotation = cv2.Rodrigues(rvec)[0]
    return RIG_TO_OPENCV.T @ camera_rotation, tvec[:, 0].copy()


def camera_direction_to_rig(direction: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """A direction ``(3,)`` in the photo camera's frame (OpenCV) -> the same direction in rig space, for
    a head pose ``rotation`` ``(3, 3)`` (directions ignore the translation). Unit length in, unit out."""
    d = np.asarray(direction, np.float64)
    rotation = np.asarray(rotation, np.float64)
    if d.shape != (3,) or rotation.shape != (3, 3):
        raise ShapeError(
            f"camera_direction_to_rig: direction must be (3,) and rotation (3, 3), got {d.shape} and {rotation.shape}"
        )
    return (RIG_TO_OPENCV @ rotation).T @ d
