"""Faces and their 6 keypoints from MediaPipe's SSD face detectors (BlazeFace short and full range).

The steps of MediaPipe's ``FaceDetection`` graph, written for numpy:

1. :func:`letterbox`: the image, scaled to fit the model's square input with its aspect ratio kept
   (black bars on the short side, centred), values in ``[-1, 1]``.
2. The model: ``(1, N, 16)`` regressors and ``(1, N, 1)`` logits, one row per SSD anchor
   (:mod:`landmarks.mediapipe.anchors`).
3. :func:`decode_boxes`: each row's ``[dx, dy, w, h, kx0, ky0, ..., kx5, ky5]`` in input pixels, offsets
   from its anchor's centre; :func:`sigmoid_scores`: clipped logits through the sigmoid; rows below
   the model's ``min_score`` are dropped.
4. :func:`weighted_nms`: MediaPipe's "blending" non-maximum suppression: the best box and every box
   overlapping it by more than the IoU threshold are averaged, weighted by their scores.
5. Back to image pixels through the letterbox.

The keypoints are in MediaPipe's order (:data:`KEYPOINT_NAMES`): the subject's right eye, left eye, nose
tip, mouth centre, right ear tragion, left ear tragion ("right" is the subject's: the image's left for
a face towards the camera).

Example::

    faces = detect_boxes(image, FULL_RANGE)    # [BoxDetection], best first
    faces[0].keypoints[0]                      # the subject's right eye, (x, y) pixels
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from landmarks.detector import DetectionError
from landmarks.mediapipe.anchors import DetectorOptions, ssd_anchors
from landmarks.mediapipe.crop import RotatedRect, crop_to_image, warp_crop
from landmarks.mediapipe.models import model
from rig.errors import InputError

KEYPOINT_NAMES = ("right_eye", "left_eye", "nose_tip", "mouth_centre", "right_ear_tragion", "left_ear_tragion")
"""The detectors' 6 keypoints, in their order (the subject's right and left)."""
NUM_KEYPOINTS = len(KEYPOINT_NAMES)


@dataclass(frozen=True)
class BoxDetection:
    """One face from a MediaPipe detector, in image pixels."""

    box: np.ndarray
    """``(4,)`` float64 ``[left, top, right, bottom]``, 0-based OpenCV pixels (x right, y down)."""
    keypoints: np.ndarray
    """``(6, 2)`` float64 ``(x, y)`` pixels, in the order of :data:`KEYPOINT_NAMES`."""
    score: float
    """The detector's score in ``[0, 1]`` (sigmoid of its logit; of the best of the merged boxes)."""


def letterbox(image: np.ndarray, input_size: int) -> tuple[np.ndarray, RotatedRect]:
    """The image as a detector sees it: fitted into an ``input_size`` square, aspect ratio kept, centred,
    black bars, values in ``[-1, 1]`` (MediaPipe's ``ImageToTensorCalculator``, ``keep_aspect_ratio``).

    Args:
        image: ``(H, W, 3)`` uint8 RGB. input_size: the model's input side, pixels.

    Returns:
        ``(1, input_size, input_size, 3)`` float32 and the square of the image it shows (side
        ``max(H, W)``, centred on the image; :func:`~landmarks.mediapipe.crop.crop_to_image` maps the
        model's normalised coordinates back to pixels).
    """
    height, width = image.shape[:2]
    rect = RotatedRect(np.array([(width - 1) / 2.0, (height - 1) / 2.0]), float(max(width, height)), 0.0)
    square = warp_crop(image, rect, input_size, border=cv2.BORDER_CONSTANT)
    return (square.astype(np.float32) / 127.5 - 1.0)[None], rect


def decode_boxes(raw: np.ndarray, anchors: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Boxes and keypoints from the regressor rows (MediaPipe's ``reverse_output_order``: x before y).

    Args:
        raw: ``(N, 4 + 2 K)`` ``[dx, dy, w, h, kx0, ky0, ...]`` in input pixels, relative to the anchor.
        anchors: ``(N, 4)`` ``[x_centre, y_centre, width, height]`` in input units
            (:func:`~landmarks.mediapipe.anchors.ssd_anchors`).
        scale: input pixels per input unit (the input size).

    Returns:
        ``(N, 4)`` ``[xmin, ymin, xmax, ymax]`` and ``(N, K, 2)`` keypoints ``(x, y)``, float64, input units.

    Raises:
        ValueError: shapes that do not match.
    """
    raw = np.asarray(raw, dtype=np.float64)
    anchors = np.asarray(anchors, dtype=np.float64)
    if raw.ndim != 2 or raw.shape[1] < 4 or raw.shape[1] % 2 or anchors.shape != (raw.shape[0], 4):
        raise InputError(
            f"decode_boxes: expected raw (N, 4 + 2K) and anchors (N, 4); got {raw.shape} and {anchors.shape}"
        )
    centre = anchors[:, :2]
    size = anchors[:, 2:]
    box_centre = raw[:, 0:2] / scale * size + centre
    box_size = raw[:, 2:4] / scale * size
    boxes = np.hstack([box_centre - box_size / 2.0, box_centre + box_size / 2.0])
    keypoints = raw[:, 4:].reshape(raw.shape[0], -1, 2) / scale * size[:, None, :] + centre[:, None, :]
    return boxes, keypoints


def sigmoid_scores(logits: np.ndarray, clip: float = 100.0) -> np.ndarray:
    """``(N,)`` scores in ``[0, 1]`` from ``(N,)`` logits clipped to ``[-clip, clip]`` (MediaPipe's
    ``score_clipping_thresh``, ``sigmoid_score``)."""
    logits = np.clip(np.asarray(logits, dtype=np.float64), -clip, clip)
    return 1.0 / (1.0 + np.exp(-logits))


def box_iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Intersection over union of ``box`` ``(4,)`` with each of ``boxes`` ``(N, 4)``, all
    ``[xmin, ymin, xmax, ymax]`` in one unit; ``(N,)``, 0 where the union is empty."""
    low = np.maximum(box[:2], boxes[:, :2])
    high = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(high - low, 0.0, None), axis=1)
    area = np.prod(np.clip(box[2:] - box[:2], 0.0, None))
    areas = np.prod(np.clip(boxes[:, 2:] - boxes[:, :2], 0.0, None), axis=1)
    union = area + areas - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def weighted_nms(
    boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray, iou_threshold: float
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """MediaPipe's weighted ("blending") non-maximum suppression.

    The highest-scoring remaining box and every remaining box overlapping it by more than
    ``iou_threshold`` (itself included) form a cluster; its boxes and keypoints are averaged weighted
    by their scores, the cluster keeps the best score, and its boxes leave the pool. Repeat until the
    pool is empty.

    Args:
        boxes: ``(N, 4)`` ``[xmin, ymin, xmax, ymax]``. keypoints: ``(N, K, 2)``. scores: ``(N,)`` > 0.
        iou_threshold: in ``[0, 1]``.

    Returns:
        One ``(box (4,), keypoints (K, 2), score)`` per cluster, best first (float64).
    """
    boxes = np.asarray(boxes, dtype=np.float64)
    keypoints = np.asarray(keypoints, dtype=np.float64)
    scores = np.asarray(scores, dtype=np.float64)
    pool = np.argsort(-scores, kind="stable")
    merged = []
    while pool.size:
        overlap = box_iou(boxes[pool[0]], boxes[pool]) > iou_threshold
        overlap[0] = True
        cluster = pool[overlap]
        weights = scores[cluster] / scores[cluster].sum()
        box = weights @ boxes[cluster]
        points = np.tensordot(weights, keypoints[cluster], axes=1)
        merged.append((box, points, float(scores[pool[0]])))
        pool = pool[~overlap]
    return merged


@functools.cache
def _anchors(options: DetectorOptions) -> np.ndarray:
    anchors = ssd_anchors(options.anchors)
    anchors.flags.writeable = False
    return anchors


def detect_boxes(image: np.ndarray, options: DetectorOptions, num_threads: int = 1) -> list[BoxDetection]:
    """The faces one MediaPipe detector finds in ``image``.

    Args:
        image: ``(H, W, 3)`` uint8 RGB (checked by the caller).
        options: the model and its decoding (:data:`~landmarks.mediapipe.anchors.FULL_RANGE` or
            :data:`~landmarks.mediapipe.anchors.SHORT_RANGE`).
        num_threads: LiteRT's CPU threads.

    Returns:
        The faces scoring at least ``options.min_score`` after weighted NMS, best first; boxes and keypoints
        in 0-based OpenCV pixels (they may reach outside the image).

    Raises:
        DetectionError: the runtime or model file is missing, or the model's outputs do not match
            ``options`` (a different model file).
    """
    net = model(options.model, num_threads)
    tensor, rect = letterbox(image, options.anchors.input_size)
    regressors, logits = _split_outputs(net.run(tensor), options)
    scores = sigmoid_scores(logits, options.score_clip)
    keep = np.flatnonzero(scores >= options.min_score)
    if keep.size == 0:
        return []
    boxes, keypoints = decode_boxes(regressors[keep], _anchors(options)[keep], options.box_scale)
    faces = []
    for box, points, score in weighted_nms(boxes, keypoints, scores[keep], options.nms_iou):
        corners = crop_to_image(box.reshape(2, 2), rect)
        pixels = crop_to_image(points, rect)
        corners.flags.writeable = False
        pixels.flags.writeable = False
        faces.append(BoxDetection(corners.reshape(4), pixels, score))
    return faces


def _split_outputs(outputs: list[np.ndarray], options: DetectorOptions) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 16)`` regressors and ``(N,)`` logits from the model's outputs (in either order)."""
    width = 4 + 2 * options.num_keypoints
    by_width = {o.shape[-1]: o for o in outputs if o.ndim == 3 and o.shape[:2] == (1, options.num_boxes)}
    if width not in by_width or 1 not in by_width:
        shapes = [o.shape for o in outputs]
        raise DetectionError(
            f"{options.model}: expected outputs (1, {options.num_boxes}, {width}) and (1, {options.num_boxes}, 1); "
            f"got {shapes}"
        )
    return by_width[width][0], by_width[1][0, :, 0]


__all__ = [
    "KEYPOINT_NAMES",
    "NUM_KEYPOINTS",
    "BoxDetection",
    "box_iou",
    "decode_boxes",
    "detect_boxes",
    "letterbox",
    "sigmoid_scores",
    "weighted_nms",
]
