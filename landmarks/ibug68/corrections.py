"""The committed corrections of the geometric placement, fitted to dlib's detections on renders of the
template by ``benchmarks/bench_landmark_offsets.py`` (``--fit --write`` rewrites the two tables here)."""

from __future__ import annotations

LANDMARK_CORRECTIONS_MM: dict[int, tuple[float, float, float]] = {
    8: (0.0, 1.5, 14.8),  # jaw_08
    22: (1.0, -5.8, -0.2),  # left_brow_0
    23: (2.3, -1.0, -0.6),  # left_brow_1
    24: (4.7, 3.2, -2.7),  # left_brow_2
    25: (5.8, 2.0, -6.0),  # left_brow_3
    26: (5.8, -4.1, -7.2),  # left_brow_4
    27: (0.0, -4.2, 0.2),  # nose_bridge_0
    28: (0.0, -2.9, 2.0),  # nose_bridge_1
    29: (0.0, -1.2, 0.8),  # nose_bridge_2
    30: (0.0, 0.0, 0.0),  # nose_bridge_3
    33: (0.0, 1.6, 0.9),  # nose_base_2
    34: (1.1, -0.3, -0.9),  # nose_base_3
    35: (0.2, 0.2, 0.4),  # nose_base_4
    42: (0.2, 1.3, 0.4),  # left_eye_inner
    43: (-1.5, -0.5, -0.1),  # left_eye_upper_0
    44: (-0.8, 0.3, 0.3),  # left_eye_upper_1
    45: (-1.2, 3.0, 2.8),  # left_eye_outer
    46: (1.3, 0.4, -0.6),  # left_eye_lower_0
    47: (-2.7, 0.8, -0.4),  # left_eye_lower_1
    51: (0.0, -2.0, 0.2),  # outer_lip_upper_2
    52: (1.6, -1.1, -0.4),  # outer_lip_upper_3
    53: (1.7, -2.2, -1.4),  # outer_lip_upper_4
    54: (1.3, 0.2, -0.7),  # outer_lip_left_corner
    55: (2.3, 1.9, -0.9),  # outer_lip_lower_0
    56: (2.6, 0.6, -0.1),  # outer_lip_lower_1
    57: (0.0, 0.0, 0.0),  # outer_lip_lower_2
    63: (1.5, 0.0, -0.3),  # inner_lip_upper_2
    64: (-1.7, 0.0, 1.5),  # inner_lip_left_corner
    65: (1.2, 0.1, -0.3),  # inner_lip_lower_0
}
"""Per landmark of the left side and the midline (x >= 0; the right side is their mirror image), a 3D
offset in mm, template space, rounded to 0.1 mm, added to the geometric placement before the point is
snapped back onto the landmark's surface (:func:`~landmarks.ibug68.domains._snap`: its region's faces,
its rim, or the midline).

It moves the geometric placement to where dlib's 68-point predictor (:mod:`landmarks.detect`) puts the
landmark on renders of the template: ``benchmarks/bench_landmark_offsets.py --fit`` photographs the
template in a grid of poses (:func:`pipeline.synthetic.photos.simulate.simulate_photo`), detects, and
for each landmark (with its mirror partner, mirrored) takes the point of its surface whose projections
agree best with the detections over all views (least squares); the row is that point minus the
placement.
Landmarks without a row keep their placement (the lips' midline rim vertices 62 and 66 have no
freedom: the mouth loop crosses the midline at one vertex each). Results: ``docs/landmarks.md``."""

CONTOUR_ANGLES_DEG: tuple[float, ...] = (-0.1, 15.6, 26.6, 43.6, 52.7, 63.6, 75.8, 82.8)
"""The static jaw contour of the left side, landmarks 16, 15, ..., 9: the direction of each point as
seen from the contour centre (x = 0, the outer eye corners' height) in the frontal projection, degrees
below the horizontal; each point is the frontal-outline vertex nearest that direction. Fitted with
:data:`LANDMARK_CORRECTIONS_MM` (the direction sets the line across the cheek on which
:func:`~landmarks.ibug68.contour.contour_landmarks` looks for the silhouette); empty: the geometric
placement (9 equal steps of arc length along the outline from the eye corners' height to the chin)."""

__all__ = ["CONTOUR_ANGLES_DEG", "LANDMARK_CORRECTIONS_MM"]
