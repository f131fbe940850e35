"""The iBUG-68 landmark names in their standard order, the jaw contour and the mirror pairs (no torch)."""

from __future__ import annotations

IBUG68_NAMES: tuple[str, ...] = (
    *(f"jaw_{i:02d}" for i in range(17)),
    *(f"right_brow_{i}" for i in range(5)),
    *(f"left_brow_{i}" for i in range(5)),
    *(f"nose_bridge_{i}" for i in range(4)),
    *(f"nose_base_{i}" for i in range(5)),
    "right_eye_outer",
    "right_eye_upper_0",
    "right_eye_upper_1",
    "right_eye_inner",
    "right_eye_lower_0",
    "right_eye_lower_1",
    "left_eye_inner",
    "left_eye_upper_0",
    "left_eye_upper_1",
    "left_eye_outer",
    "left_eye_lower_0",
    "left_eye_lower_1",
    "outer_lip_right_corner",
    *(f"outer_lip_upper_{i}" for i in range(5)),
    "outer_lip_left_corner",
    *(f"outer_lip_lower_{i}" for i in range(5)),
    "inner_lip_right_corner",
    *(f"inner_lip_upper_{i}" for i in range(3)),
    "inner_lip_left_corner",
    *(f"inner_lip_lower_{i}" for i in range(3)),
)

JAW_CONTOUR = tuple(range(17))
"""Indices of the jaw-contour landmarks (weighted down in the 2D loss, dynamic in
:func:`~landmarks.ibug68.contour.contour_landmarks`)."""
CHIN = 8

IBUG68_MIRROR: tuple[int, ...] = tuple(
    [16 - i for i in range(17)]
    + [26 - i for i in range(5)]
    + [21 - i for i in range(5)]
    + [27, 28, 29, 30]
    + [35, 34, 33, 32, 31]
    + [45, 44, 43, 42, 47, 46]
    + [39, 38, 37, 36, 41, 40]
    + [54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55]
    + [64, 63, 62, 61, 60, 67, 66, 65]
)
"""``IBUG68_MIRROR[i]``: the landmark that is the mirror image (x -> -x) of landmark ``i``."""


__all__ = ["CHIN", "IBUG68_MIRROR", "IBUG68_NAMES", "JAW_CONTOUR"]
