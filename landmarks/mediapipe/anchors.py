"""The SSD anchors of MediaPipe's face detectors, and the options of their two models.

MediaPipe's ``SsdAnchorsCalculator`` lays anchors out layer by layer; consecutive layers with the same
stride share one feature map, whose cells are visited row by row (y, then x), each cell giving all the
anchors of those layers in turn. With ``interpolated_scale_aspect_ratio > 0`` every layer adds one
anchor of the interpolated scale ``sqrt(scale_i * scale_{i+1})`` to its aspect ratios. The face
detectors use ``fixed_anchor_size``: every anchor is ``1 x 1`` (the network regresses box sizes in
input pixels), so only the anchor centres matter.

* short range (128 x 128 input): strides 8, 16, 16, 16 -> 16 x 16 x 2 + 8 x 8 x 6 = 896 anchors.
* full range (192 x 192 input): one layer of stride 4 without the interpolated anchor -> 48 x 48 = 2304.

Example::

    anchors = ssd_anchors(SHORT_RANGE.anchors)    # (896, 4) [x_centre, y_centre, width, height]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rig.errors import InputError


@dataclass(frozen=True)
class AnchorOptions:
    """MediaPipe's ``SsdAnchorsCalculatorOptions`` (the fields the face detectors set)."""

    input_size: int
    """Width and height of the square input tensor, pixels."""
    strides: tuple[int, ...]
    """One stride per layer, pixels of the input tensor per feature-map cell."""
    min_scale: float = 0.1484375
    """Scale of the first layer's anchors (relative to the input size)."""
    max_scale: float = 0.75
    """Scale of the last layer's anchors."""
    anchor_offset: float = 0.5
    """Anchor centre within its cell, in cells (0.5: the cell's centre)."""
    aspect_ratios: tuple[float, ...] = (1.0,)
    """Width / height of the anchors each layer adds."""
    interpolated_scale_aspect_ratio: float = 1.0
    """Aspect ratio of the extra anchor of interpolated scale each layer adds (0: none)."""
    fixed_anchor_size: bool = True
    """Every anchor ``1 x 1`` (the face detectors), instead of its scale and aspect ratio."""


@dataclass(frozen=True)
class DetectorOptions:
    """One face-detection model: its anchors and how its outputs are decoded (MediaPipe's
    ``TensorsToDetectionsCalculatorOptions`` and ``NonMaxSuppressionCalculatorOptions``)."""

    model: str
    """The model's name in :data:`landmarks.mediapipe.models.MODEL_FILES`."""
    anchors: AnchorOptions
    """The SSD anchors of its outputs."""
    num_boxes: int
    """Rows of the model's outputs (= anchors)."""
    box_scale: float
    """Box offsets and sizes are regressed in input pixels: divided by this (the input size) they are in
    units of the input (MediaPipe's ``x_scale = y_scale = w_scale = h_scale``)."""
    min_score: float
    """Detections whose score (sigmoid) is lower are dropped (MediaPipe: 0.5 short range, 0.6 full range)."""
    score_clip: float = 100.0
    """Raw logits are clipped to ``[-score_clip, score_clip]`` before the sigmoid."""
    nms_iou: float = 0.3
    """Weighted non-maximum suppression merges boxes overlapping the best one by more than this IoU."""
    num_keypoints: int = 6
    """Keypoints per box, ``(x, y)`` each, after the 4 box values."""


SHORT_RANGE = DetectorOptions(
    model="face_detection_short_range",
    anchors=AnchorOptions(input_size=128, strides=(8, 16, 16, 16)),
    num_boxes=896,
    box_scale=128.0,
    min_score=0.5,
)
"""MediaPipe's short-range (BlazeFace front camera) detector: faces within about 2 m, 128 x 128 input."""
FULL_RANGE = DetectorOptions(
    model="face_detection_full_range",
    anchors=AnchorOptions(input_size=192, strides=(4,), interpolated_scale_aspect_ratio=0.0),
    num_boxes=2304,
    box_scale=192.0,
    min_score=0.6,
)
"""MediaPipe's full-range detector: faces within about 5 m (small ones too), 192 x 192 input."""
DETECTOR_OPTIONS = {"short": SHORT_RANGE, "full": FULL_RANGE}
"""The detection models by their short names (the ``models`` option of the MediaPipe detector)."""


def _layer_scale(options: AnchorOptions, index: int) -> float:
    count = len(options.strides)
    if count == 1:
        return (options.min_scale + options.max_scale) / 2.0
    return options.min_scale + (options.max_scale - options.min_scale) * index / (count - 1.0)


def ssd_anchors(options: AnchorOptions) -> np.ndarray:
    """MediaPipe's SSD anchors for ``options``.

    Args:
        options: the anchor layout (:data:`SHORT_RANGE`.anchors, :data:`FULL_RANGE`.anchors).

    Returns:
        ``(N, 4)`` float64 ``[x_centre, y_centre, width, height]`` in units of the input tensor (``[0, 1]``,
        x right, y down), in the order of the model's output rows.

    Raises:
        ValueError: no strides, or a stride or input size below 1.
    """
    strides = tuple(int(s) for s in options.strides)
    if not strides or min(strides) < 1 or options.input_size < 1:
        raise InputError(f"ssd_anchors: need strides >= 1 and input_size >= 1, got {options}")
    anchors = []
    layer = 0
    while layer < len(strides):
        sizes: list[tuple[float, float]] = []  # (width, height) of each anchor of one cell
        same = layer
        while same < len(strides) and strides[same] == strides[layer]:
            scale = _layer_scale(options, same)
            for ratio in options.aspect_ratios:
                sizes.append((scale * math.sqrt(ratio), scale / math.sqrt(ratio)))
            if options.interpolated_scale_aspect_ratio > 0.0:
                following = 1.0 if same == len(strides) - 1 else _layer_scale(options, same + 1)
                interpolated = math.sqrt(scale * following)
                ratio = options.interpolated_scale_aspect_ratio
                sizes.append((interpolated * math.sqrt(ratio), interpolated / math.sqrt(ratio)))
            same += 1
        cells = math.ceil(options.input_size / strides[layer])
        centres = (np.arange(cells) + options.anchor_offset) / cells
        cy, cx = np.meshgrid(centres, centres, indexing="ij")  # row by row: y, then x
        size = np.ones((len(sizes), 2)) if options.fixed_anchor_size else np.array(sizes)  # (A, 2)
        block = np.empty((cells, cells, len(sizes), 4))
        block[..., 0] = cx[..., None]
        block[..., 1] = cy[..., None]
        block[..., 2:] = size
        anchors.append(block.reshape(-1, 4))
        layer = same
    return np.concatenate(anchors, axis=0)


__all__ = ["DETECTOR_OPTIONS", "FULL_RANGE", "SHORT_RANGE", "AnchorOptions", "DetectorOptions", "ssd_anchors"]
