"""The frames of a clip: a video file (OpenCV's reader, FFmpeg inside: mp4, avi, mov, webm, mkv as the
installed build decodes them) or a folder of numbered images (``frame_0001.png`` ...; natural order).

Only regular files are opened (a FIFO or a device named like a video is refused before it is read); a
clip that cannot be decoded, holds no frame, or changes its frame size is one :class:`VideoError`.

Example:
    >>> clip = open_clip("clip.mp4")  # doctest: +SKIP
    >>> clip.fps, clip.size, clip.count  # doctest: +SKIP
    (30.0, (640, 480), 300)
    >>> for index, frame in clip.frames():  # (H, W, 3) uint8 RGB  # doctest: +SKIP
    ...     pass
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.errors import InputError
from rig.io.inputs import regular_file

VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".avi", ".webm", ".mkv", ".mpg", ".mpeg", ".wmv")
"""Files read as videos (by name; OpenCV decides whether it can decode one)."""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
"""Files a frames folder is made of."""
DEFAULT_FOLDER_FPS = 30.0
"""The frame rate of a folder of images unless ``--fps`` says otherwise."""
MAX_FRAMES = 108_000
"""The longest clip read (an hour at 30 fps): ``--max-frames`` lowers it; longer clips are cut with a warning."""
MAX_VIDEO_BYTES = 64 << 30
"""The largest video file read (64 GiB)."""
MAX_SIDE = 4096
"""Frames larger than this (either side, pixels) are refused: tracking needs no more."""


class VideoError(InputError):
    """A clip that cannot be read: not a regular file or folder, not decodable, empty, or inconsistent."""


@dataclass(frozen=True)
class Clip:
    """A clip's frames and their timing.

    Attributes:
        path: the video file or the frames folder.
        fps: frames per second (the video's own rate; a folder's is :data:`DEFAULT_FOLDER_FPS` or given).
        size: ``(width, height)`` pixels of every frame.
        count: the number of frames the clip announces (a video's container may be off by a few; the reader
            stops at the last decodable frame).
        files: a folder's image files in order (empty for a video).
    """

    path: Path
    fps: float
    size: tuple[int, int]
    count: int
    files: tuple[Path, ...] = ()

    @property
    def is_folder(self) -> bool:
        return bool(self.files)

    def frames(self, max_frames: int = MAX_FRAMES) -> Iterator[tuple[int, np.ndarray]]:
        """``(index, (H, W, 3) uint8 RGB)`` frame by frame, at most ``max_frames``.

        Raises:
            VideoError: a frame that cannot be decoded (a folder's image), or a frame of another size.
        """
        if self.is_folder:
            yield from self._folder_frames(max_frames)
        else:
            yield from self._video_frames(max_frames)

    def _check_size(self, index: int, frame: np.ndarray) -> np.ndarray:
        height, width = frame.shape[:2]
        if (width, height) != self.size:
            raise VideoError(
                f"{self.path}: frame {index} is {width}x{height}, the clip's first frame {self.size[0]}x{self.size[1]}"
            )
        return frame

    def _folder_frames(self, max_frames: int) -> Iterator[tuple[int, np.ndarray]]:
        for index, path in enumerate(self.files[:max_frames]):
            yield index, self._check_size(index, _read_image(path))

    def _video_frames(self, max_frames: int) -> Iterator[tuple[int, np.ndarray]]:
        capture = _capture(self.path)
        try:
            index = 0
            while index < max_frames:
                ok, frame = capture.read()
                if not ok or frame is None:
                    break
                yield index, self._check_size(index, _bgr_to_rgb(frame))
                index += 1
        finally:
            capture.release()
        expected = min(self.count, max_frames)
        if index < expected - max(2, int(0.01 * expected)):  # containers may announce a frame or two too many
            warnings.warn(
                f"{self.path}: decoding stopped after {index} of the {self.count} frames the file announces "
                "(damaged or truncated?); the frames after it are not tracked",
                stacklevel=2,
            )


def _capture(path: Path):
    """OpenCV's FFmpeg reader of ``path`` with FFmpeg's own log off (its lines came before jnr's one-line error,
    issue 38); what it cannot read is reported by jnr."""
    import cv2

    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET, read when the reader opens
    return cv2.VideoCapture(str(path))


def _bgr_to_rgb(frame: np.ndarray) -> np.ndarray:
    if frame.ndim == 2:
        frame = np.repeat(frame[..., None], 3, axis=2)
    return np.ascontiguousarray(frame[..., 2::-1]) if frame.shape[2] >= 3 else np.repeat(frame[..., :1], 3, axis=2)


def _read_image(path: Path) -> np.ndarray:
    from landmarks.images import ImageError, load_image

    try:
        return load_image(path)
    except ImageError as exc:
        raise VideoError(f"{path}: {exc}") from None


MAX_UNINDEXED_COUNT = 10**8
"""A stated frame count above this (or below 1) is FFmpeg's placeholder for a file without an index."""


def _natural_key(path: Path) -> tuple:
    return tuple(int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name))


def open_clip(path: str | Path, fps: float | None = None) -> Clip:
    """Open a video file or a folder of numbered images and read its first frame (to know it decodes).

    Args:
        path: the video or the folder.
        fps: the frame rate to use (default: the video's own; a folder's :data:`DEFAULT_FOLDER_FPS`).

    Raises:
        VideoError: missing, not a regular file or folder, not decodable, without frames, frames too large.
    """
    path = Path(path)
    if fps is not None and not (np.isfinite(fps) and 0.1 <= fps <= 1000.0):
        raise VideoError(f"--fps must be within [0.1, 1000], got {fps}")
    if path.is_dir():
        files = tuple(
            sorted((p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()), key=_natural_key)
        )
        if not files:
            raise VideoError(f"{path}: a frames folder without images ({', '.join(IMAGE_SUFFIXES)})")
        first = _read_image(files[0])
        size = _frame_size(path, first)
        return Clip(path, float(fps or DEFAULT_FOLDER_FPS), size, len(files), files)
    if not path.exists():
        raise VideoError(f"{path}: no such file or folder")
    try:
        regular_file(path, "video", MAX_VIDEO_BYTES)
    except InputError as exc:
        raise VideoError(str(exc)) from None
    if path.stat().st_size == 0:
        raise VideoError(f"{path}: an empty file, not a video")
    import cv2

    capture = _capture(path)
    try:
        if not capture.isOpened():
            raise VideoError(f"{path}: not a video OpenCV can decode (corrupt, or a format its FFmpeg lacks)")
        ok, frame = capture.read()
        if not ok or frame is None:
            raise VideoError(f"{path}: no frame could be decoded (corrupt or empty video)")
        native = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    finally:
        capture.release()
    size = _frame_size(path, frame)
    indexed = 0 < count <= MAX_UNINDEXED_COUNT  # a raw stream (.h264) or a damaged index states no frame count
    if fps is None:
        if not (np.isfinite(native) and 0.1 <= native <= 1000.0):
            raise VideoError(f"{path}: the video states no usable frame rate ({native}); give --fps")
        if not indexed:
            warnings.warn(
                f"{path}: the file has no frame index (a raw stream, or a damaged container), so its frame rate "
                f"{native:g} fps may be FFmpeg's guess (25 for streams without timing); pass --fps if it is not",
                stacklevel=2,
            )
        fps = native
    return Clip(path, float(fps), size, count if indexed else 1)


def _frame_size(path: Path, frame: np.ndarray) -> tuple[int, int]:
    height, width = frame.shape[:2]
    if max(width, height) > MAX_SIDE:
        raise VideoError(f"{path}: frames of {width}x{height} pixels; at most {MAX_SIDE} a side (scale the clip down)")
    if min(width, height) < 32:
        raise VideoError(f"{path}: frames of {width}x{height} pixels are too small to track a face (at least 32)")
    return int(width), int(height)


__all__ = ["Clip", "DEFAULT_FOLDER_FPS", "MAX_FRAMES", "VideoError", "open_clip"]
