"""Shot cuts in a clip: where the picture changes at once, a new shot (and possibly another person) begins.

A cut is found by the content change between consecutive frames (as scene detectors such as PySceneDetect's
content detector measure it): both frames scaled to :data:`THUMB_WIDTH` pixels wide, in HSV, the mean absolute
difference of hue, saturation and value averaged over the three channels (0-255). A head turning, talking or
moving in front of the camera changes a few tens of pixels; a cut changes the whole picture. A change over
:data:`CUT_THRESHOLD` is a cut unless the last cut is fewer than :data:`MIN_SHOT_FRAMES` frames before it (a
flash or a fast pan is not two shots).

The tracker (:func:`pipeline.track.tracker.track_shots`) starts the face anew at a cut (the mesh tracking of the
frame before would follow whatever face lies where the last one was), fits one identity per shot, and never
bridges a gap across a cut.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.errors import InputError

THUMB_WIDTH = 96
"""Frames are compared at this width (pixels): enough for a change of picture, cheap (``docs/track.md``)."""
CUT_THRESHOLD = 27.0
"""Mean absolute HSV difference (0-255, over the three channels) above which consecutive frames are a cut
(PySceneDetect's default for its content detector; chosen there on real footage)."""
MIN_SHOT_FRAMES = 8
"""A change within this many frames of the last cut is not a new cut (flashes, fast pans)."""


@dataclass(frozen=True)
class Shot:
    """Frames ``start`` (included) to ``end`` (excluded) of a clip, between two cuts (or the clip's ends)."""

    start: int
    end: int

    @property
    def frames(self) -> int:
        return self.end - self.start


def thumbnail(frame: np.ndarray) -> np.ndarray:
    """``(h, THUMB_WIDTH, 3)`` float32 HSV (OpenCV's ranges: hue 0-179, saturation and value 0-255) of an
    ``(H, W, 3)`` uint8 RGB frame."""
    import cv2

    height, width = frame.shape[:2]
    small = cv2.resize(frame, (THUMB_WIDTH, max(1, round(height * THUMB_WIDTH / width))), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_RGB2HSV).astype(np.float32)


def content_change(before: np.ndarray, after: np.ndarray) -> float:
    """The mean absolute difference of two :func:`thumbnail` s, averaged over hue, saturation and value (0-255)."""
    return float(np.abs(after - before).mean())


class CutDetector:
    """Feed frames in order (:meth:`step`); it says which begin a new shot (module docstring)."""

    def __init__(self, threshold: float = CUT_THRESHOLD, min_shot_frames: int = MIN_SHOT_FRAMES) -> None:
        if not threshold > 0:
            raise InputError(f"CutDetector: threshold must be > 0, got {threshold}")
        self.threshold, self.min_shot_frames = float(threshold), int(min_shot_frames)
        self._previous: np.ndarray | None = None
        self._index = -1
        self._last_cut = 0
        self.cuts: list[int] = []
        """The frames that begin a new shot (never 0)."""

    def step(self, frame: np.ndarray) -> bool:
        """Whether ``frame`` (the next ``(H, W, 3)`` uint8 RGB frame) begins a new shot."""
        self._index += 1
        thumb = thumbnail(frame)
        previous, self._previous = self._previous, thumb
        if previous is None or previous.shape != thumb.shape:
            return False
        if content_change(previous, thumb) <= self.threshold or self._index - self._last_cut < self.min_shot_frames:
            return False
        self._last_cut = self._index
        self.cuts.append(self._index)
        return True


def split_shots(count: int, cuts: list[int]) -> list[Shot]:
    """The shots of a clip of ``count`` frames cut at ``cuts`` (frames that begin a shot)."""
    bounds = [0, *sorted(c for c in set(cuts) if 0 < c < count), count]
    return [Shot(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


__all__ = ["CUT_THRESHOLD", "MIN_SHOT_FRAMES", "CutDetector", "Shot", "content_change", "split_shots", "thumbnail"]
