"""Writing a video browsers play: H.264 (yuv420p, ``+faststart``) in MP4 by the FFmpeg binary that the
``imageio-ffmpeg`` wheel ships, frames piped in as raw RGB, the source's first audio stream copied over (re-encoded
as AAC) when it has one.

OpenCV's own writer gives MPEG-4 Part 2 (``mp4v``), which Chromium and Firefox refuse (issue 38); FFmpeg builds of
OpenCV differ in which encoders they carry, so the encoder is not left to OpenCV.

Example:
    >>> with H264Writer("preview.mp4", (640, 240), 30.0) as video:  # doctest: +SKIP
    ...     video.write(frame)  # (240, 640, 3) uint8 RGB
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

import numpy as np

from rig.errors import InputError, JnrError

ENCODER_MISSING = (
    "the H.264 encoder (the imageio-ffmpeg package, which ships FFmpeg) is not installed: pip install imageio-ffmpeg, "
    "or pass --no-preview"
)


class EncoderError(JnrError):
    """FFmpeg could not write the video (one line: its last message)."""


def ffmpeg_exe() -> str:
    """The FFmpeg binary of the ``imageio-ffmpeg`` wheel.

    Raises:
        InputError: the package is not installed (:data:`ENCODER_MISSING`).
    """
    try:
        import imageio_ffmpeg
    except ImportError:
        raise InputError(ENCODER_MISSING) from None
    return imageio_ffmpeg.get_ffmpeg_exe()


class H264Writer:
    """An H.264 MP4 written frame by frame (module docstring).

    Args:
        path: the ``.mp4`` to write (MP4 whatever its suffix: a staged temporary name is fine).
        size: ``(width, height)`` of every frame, pixels; an odd side is padded by one black pixel (H.264 in
            yuv420p needs even sides).
        fps: frames per second (> 0).
        audio_from: a video file whose first audio stream, if any, goes with the frames (cut to their length),
            from ``audio_start_s`` seconds on (a shot's start).
        crf: x264's quality (lower is better; 23 is its default).
    """

    def __init__(
        self,
        path: str | Path,
        size: tuple[int, int],
        fps: float,
        *,
        audio_from: str | Path | None = None,
        audio_start_s: float = 0.0,
        crf: int = 23,
    ) -> None:
        if not (fps > 0 and np.isfinite(fps)):
            raise InputError(f"H264Writer: fps must be > 0, got {fps}")
        self.path, self.size = Path(path), (int(size[0]), int(size[1]))
        command = [ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-nostdin", "-y"]
        command += ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{self.size[0]}x{self.size[1]}"]
        command += ["-framerate", f"{float(fps):.6g}", "-i", "pipe:0"]
        if audio_from is not None:
            command += ["-ss", f"{max(0.0, float(audio_start_s)):.6f}", "-i", str(audio_from)]
            command += ["-map", "0:v:0", "-map", "1:a:0?", "-c:a", "aac", "-b:a", "128k"]
            command += ["-shortest"]
        command += ["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-preset", "veryfast"]
        command += ["-crf", str(int(crf)), "-pix_fmt", "yuv420p", "-movflags", "+faststart", "-f", "mp4"]
        command.append(str(self.path))
        # FFmpeg's messages go to a file, not the terminal: on failure one line of them joins jnr's own error
        self._log = tempfile.TemporaryFile(mode="w+b")
        self._process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._log)
        self.frames = 0

    def write(self, frame: np.ndarray) -> None:
        """Append one ``(height, width, 3)`` uint8 RGB frame."""
        frame = np.asarray(frame)
        if frame.shape != (self.size[1], self.size[0], 3) or frame.dtype != np.uint8:
            raise InputError(
                f"H264Writer: frames must be ({self.size[1]}, {self.size[0]}, 3) uint8, got {frame.shape} {frame.dtype}"
            )
        try:
            self._process.stdin.write(np.ascontiguousarray(frame).tobytes())
        except BrokenPipeError:
            self._fail()
        self.frames += 1

    def close(self) -> None:
        """Finish the file.

        Raises:
            EncoderError: FFmpeg failed (its last message)."""
        if self._process.stdin and not self._process.stdin.closed:
            try:
                self._process.stdin.close()
            except BrokenPipeError:
                pass
        if self._process.wait() != 0:
            self._fail()
        self._log.close()

    def abort(self) -> None:
        """Stop FFmpeg without finishing the file (the caller discards it)."""
        if self._process.poll() is None:
            self._process.kill()
            self._process.wait()
        self._log.close()

    def _fail(self) -> None:
        self._process.kill()
        self._process.wait()
        self._log.seek(0)
        lines = [ln.strip() for ln in self._log.read().decode("utf-8", "replace").splitlines() if ln.strip()]
        self._log.close()
        raise EncoderError(f"{self.path}: FFmpeg could not write the video: {lines[-1] if lines else 'no message'}")

    def __enter__(self) -> H264Writer:
        return self

    def __exit__(self, kind, value, traceback) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()


__all__ = ["ENCODER_MISSING", "EncoderError", "H264Writer", "ffmpeg_exe"]
