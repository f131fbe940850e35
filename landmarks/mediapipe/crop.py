"""Rotated square crops of an image, as MediaPipe's models see them, and the map back to image pixels.

A :class:`RotatedRect` is a square of side ``size`` pixels centred on ``centre`` (0-based OpenCV pixels:
origin at the centre of the top-left pixel, x right, y down) and turned by ``angle`` radians (clockwise
on screen, as y points down): its x axis is ``(cos angle, sin angle)`` in the image. A point at crop
coordinates ``(u, v)`` in ``[0, 1]`` (MediaPipe's normalised crop coordinates: ``(0, 0)`` the crop's top-left
corner, ``(1, 1)`` its bottom-right one) lies at ``centre + R(angle) @ ((u - 0.5) * size, (v - 0.5) * size)``;
the output pixel ``j`` of an ``n``-pixel crop covers ``u`` in ``[j / n, (j + 1) / n]``.

:func:`warp_crop` samples the crop with ``cv2.warpAffine`` (bilinear) after halving the image with
``cv2.pyrDown`` (a Gaussian low-pass) while the crop is at least twice its output size, so large faces
are not aliased.

Example::

    rect = RotatedRect(np.array([250.0, 180.0]), 300.0, np.deg2rad(10.0))
    crop = warp_crop(image, rect, 192)         # (192, 192, 3) uint8
    crop_to_image(np.array([[0.5, 0.5]]), rect)  # [[250., 180.]]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class RotatedRect:
    """A rotated square region of an image (MediaPipe's ``NormalizedRect``, in pixels)."""

    centre: np.ndarray
    """``(2,)`` float64 ``(x, y)``, 0-based OpenCV pixels."""
    size: float
    """Side, pixels."""
    angle: float
    """Rotation, radians: the crop's x axis is ``(cos angle, sin angle)`` in the image (y down)."""

    def rotation(self) -> np.ndarray:
        """``(2, 2)`` the crop's axes as columns, in image pixels per crop pixel (unit length)."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        return np.array([[c, -s], [s, c]])


def normalize_angle(angle: float) -> float:
    """``angle`` (radians) wrapped into ``[-pi, pi)``."""
    return float(angle - 2.0 * math.pi * math.floor((angle + math.pi) / (2.0 * math.pi)))


def square_rect(centre: np.ndarray, width: float, height: float, angle: float, scale: float) -> RotatedRect:
    """MediaPipe's ``RectTransformationCalculator`` with ``square_long`` and ``scale_x = scale_y = scale``:
    the square of side ``scale * max(width, height)`` around ``centre`` (pixels), turned by ``angle`` (radians).

    Args:
        centre: ``(2,)`` pixels. width, height: the rectangle to grow, pixels. angle: radians. scale: > 0.

    Returns:
        :class:`RotatedRect`.
    """
    side = scale * max(float(width), float(height))
    return RotatedRect(np.asarray(centre, dtype=np.float64).reshape(2), side, normalize_angle(angle))


def crop_matrix(rect: RotatedRect, output_size: int) -> np.ndarray:
    """The affine map from an ``output_size`` x ``output_size`` crop's pixels to the image's.

    Args:
        rect: the crop. output_size: its side in output pixels (the model's input size).

    Returns:
        ``(2, 3)`` float64 ``M``: image pixel ``= M @ (j_x, j_y, 1)`` for output pixel ``(j_x, j_y)``, both
        0-based OpenCV pixels (``cv2.warpAffine`` with ``WARP_INVERSE_MAP``).
    """
    step = rect.size / output_size
    axes = rect.rotation()
    offset = (0.5 / output_size - 0.5) * rect.size  # crop pixel 0's centre, relative to the crop's centre
    return np.hstack([step * axes, (rect.centre + axes @ np.array([offset, offset]))[:, None]])


def warp_crop(image: np.ndarray, rect: RotatedRect, output_size: int, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """Sample the crop ``rect`` of ``image`` at ``output_size`` x ``output_size`` pixels.

    Args:
        image: ``(H, W, C)`` uint8. rect: the crop (may reach outside the image). output_size: pixels.
        border: how pixels outside the image are filled: ``cv2.BORDER_REPLICATE`` (MediaPipe's landmark
            and iris crops) or ``cv2.BORDER_CONSTANT`` (black: the detectors' letterbox).

    Returns:
        ``(output_size, output_size, C)`` uint8.
    """
    matrix = crop_matrix(rect, output_size)
    height, width = image.shape[:2]
    # only the part of the image the crop covers (plus the filter's reach) is low-passed and sampled
    corners = matrix @ np.array([[0, 0, 1], [output_size, 0, 1], [0, output_size, 1], [output_size, output_size, 1]]).T
    margin = 4.0 * max(rect.size / output_size, 1.0)
    x0 = int(np.clip(math.floor(corners[0].min() - margin), 0, width - 1))
    y0 = int(np.clip(math.floor(corners[1].min() - margin), 0, height - 1))
    x1 = int(np.clip(math.ceil(corners[0].max() + margin) + 1, x0 + 1, width))
    y1 = int(np.clip(math.ceil(corners[1].max() + margin) + 1, y0 + 1, height))
    region = image[y0:y1, x0:x1]
    matrix = matrix - np.array([[0.0, 0.0, x0], [0.0, 0.0, y0]])
    step = rect.size / output_size
    while step >= 2.0 and min(region.shape[:2]) >= 2:
        region = cv2.pyrDown(region)  # output pixel i is centred on input pixel 2 i
        matrix = matrix / 2.0
        step /= 2.0
    return cv2.warpAffine(
        region,
        matrix,
        (output_size, output_size),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=border,
        borderValue=0,
    )


def crop_to_image(points: np.ndarray, rect: RotatedRect) -> np.ndarray:
    """Normalised crop coordinates to image pixels (MediaPipe's ``LandmarkProjectionCalculator``).

    Args:
        points: ``(N, 2)`` or ``(N, 3)`` ``(u, v[, w])``: ``u, v`` in crop widths (``[0, 1]`` inside the
            crop), ``w`` a depth in crop widths.
        rect: the crop.

    Returns:
        Same shape, float64: ``(x, y)`` 0-based OpenCV pixels, and ``w`` times ``rect.size`` (pixels).
    """
    points = np.asarray(points, dtype=np.float64)
    out = np.empty_like(points)
    out[:, :2] = rect.centre + ((points[:, :2] - 0.5) * rect.size) @ rect.rotation().T
    if points.shape[1] > 2:
        out[:, 2:] = points[:, 2:] * rect.size
    return out


__all__ = ["RotatedRect", "crop_matrix", "crop_to_image", "normalize_angle", "square_rect", "warp_crop"]
