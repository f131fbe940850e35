"""MediaPipe's 468-point face mesh, from a face detection to image pixels.

The steps of MediaPipe's ``FaceDetectionFrontDetectionToRoi`` and ``FaceLandmarkCpu`` graphs:

1. :func:`face_rect`: the detection's box grown to a square of 1.5 times its longer side around the box
   centre, turned so that the line from the subject's right eye keypoint to the left eye keypoint is
   horizontal (MediaPipe's ``DetectionsToRectsCalculator`` with ``rotation_vector_start_keypoint_index 0``,
   ``end 1``, ``target_angle 0``, then ``RectTransformationCalculator`` ``scale 1.5``, ``square_long``).
2. The crop (:func:`~landmarks.mediapipe.crop.warp_crop`, edge pixels replicated) at 192 x 192, values
   in ``[0, 1]`` (:data:`MESH_INPUT_RANGE`, as MediaPipe's ``FaceLandmarkCpu`` graph sets its
   ``output_tensor_float_range``; on the astronaut the model hardly cares: ``[-1, 1]`` moves the points
   by 0.4 px on average, 1.3 px at most).
3. The model: ``(1, 1, 1, 1404)`` = 468 ``(x, y, z)`` in crop pixels (z: relative depth, same scale, smaller
   is nearer the camera) and one face-presence logit (:func:`face_presence`).
4. Back to image pixels: ``(x, y)`` through the crop's rotation, ``z`` scaled like ``x``
   (:func:`~landmarks.mediapipe.crop.crop_to_image`).

Example::

    rect = face_rect(detection.box, detection.keypoints)
    mesh = face_mesh(image, rect)              # FaceMesh: (468, 3) pixels, presence in [0, 1]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from landmarks.mediapipe.crop import RotatedRect, crop_to_image, square_rect, warp_crop
from landmarks.mediapipe.models import model

NUM_MESH_POINTS = 468
MESH_INPUT_SIZE = 192
"""The face-mesh model's input side, pixels."""
MESH_INPUT_RANGE = (0.0, 1.0)
"""The face-mesh model's input values for black and white (MediaPipe's ``output_tensor_float_range``)."""
FACE_RECT_SCALE = 1.5
"""The mesh crop's side over the detection box's longer side (MediaPipe's ``scale_x``, ``scale_y``)."""


@dataclass(frozen=True)
class FaceMesh:
    """The 468 mesh points of one face and the crop they came from."""

    points: np.ndarray
    """``(468, 3)`` float64: ``(x, y)`` 0-based OpenCV pixels, ``z`` relative depth in the same pixel scale
    (MediaPipe's, roughly zero at the face's centre, negative towards the camera)."""
    presence: float
    """The model's face-presence score in ``[0, 1]`` (sigmoid of its logit)."""
    rect: RotatedRect
    """The crop the model saw."""


def eye_line_angle(right_eye: np.ndarray, left_eye: np.ndarray) -> float:
    """The angle (radians, in ``[-pi, pi)``) of the line from the subject's right eye to the left eye in the
    image (y down, so positive is clockwise on screen): 0 for an upright face towards the camera."""
    dx, dy = np.asarray(left_eye, dtype=np.float64) - np.asarray(right_eye, dtype=np.float64)
    return math.atan2(dy, dx)


def face_rect(box: np.ndarray, keypoints: np.ndarray, scale: float = FACE_RECT_SCALE) -> RotatedRect:
    """The mesh crop of a detection (MediaPipe's face-detection-to-ROI conversion).

    Args:
        box: ``(4,)`` ``[left, top, right, bottom]`` pixels. keypoints: ``(6, 2)`` the detector's keypoints
            (pixels, :data:`~landmarks.mediapipe.detection.KEYPOINT_NAMES`). scale: side over the box's
            longer side.

    Returns:
        The square :class:`~landmarks.mediapipe.crop.RotatedRect` around the box centre, turned by the eye
        line's angle.
    """
    box = np.asarray(box, dtype=np.float64)
    keypoints = np.asarray(keypoints, dtype=np.float64)
    centre = (box[:2] + box[2:]) / 2.0
    angle = eye_line_angle(keypoints[0], keypoints[1])
    return square_rect(centre, box[2] - box[0], box[3] - box[1], angle, scale)


def face_presence(logit: float) -> float:
    """The face-presence score in ``[0, 1]`` from the model's logit (MediaPipe's sigmoid activation)."""
    return float(1.0 / (1.0 + math.exp(-float(np.clip(logit, -100.0, 100.0)))))


def mesh_input(image: np.ndarray, rect: RotatedRect) -> np.ndarray:
    """``(1, 192, 192, 3)`` float32 the mesh model's input: the crop ``rect`` of ``(H, W, 3)`` uint8 RGB
    ``image``, values in :data:`MESH_INPUT_RANGE`."""
    low, high = MESH_INPUT_RANGE
    crop = warp_crop(image, rect, MESH_INPUT_SIZE).astype(np.float32)
    return (crop * np.float32((high - low) / 255.0) + np.float32(low))[None]


def face_mesh(image: np.ndarray, rect: RotatedRect, num_threads: int = 1) -> FaceMesh:
    """Run the 468-point mesh model on the crop ``rect`` of ``image``.

    Args:
        image: ``(H, W, 3)`` uint8 RGB. rect: the crop (:func:`face_rect`). num_threads: LiteRT's threads.

    Returns:
        :class:`FaceMesh` in image pixels (read-only points).

    Raises:
        DetectionError: the runtime or the model file is missing.
    """
    net = model("face_landmark", num_threads)
    outputs = net.run(mesh_input(image, rect))
    by_size = {o.size: o for o in outputs}
    raw = by_size[NUM_MESH_POINTS * 3].reshape(NUM_MESH_POINTS, 3).astype(np.float64)
    points = crop_to_image(raw / MESH_INPUT_SIZE, rect)
    points.flags.writeable = False
    return FaceMesh(points, face_presence(by_size[1].item()), rect)


__all__ = [
    "FACE_RECT_SCALE",
    "MESH_INPUT_RANGE",
    "MESH_INPUT_SIZE",
    "NUM_MESH_POINTS",
    "FaceMesh",
    "eye_line_angle",
    "face_mesh",
    "face_presence",
    "face_rect",
    "mesh_input",
]
