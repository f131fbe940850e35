"""preview.mp4's encoder (pipeline.track.encode): H.264 that decodes to the frames written, keeps the source's
sound, plays in headless Chromium (issue 38: OpenCV's MPEG-4 Part 2 did not), and fails in one line."""

from __future__ import annotations

import shutil
import subprocess
import tempfile

import numpy as np
import pytest

from pipeline.track.encode import EncoderError, H264Writer, ffmpeg_exe
from tests.conftest import needs_tool

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
SIZE = (96, 64)


def _frames(n: int) -> list[np.ndarray]:
    """Flat colours that change from frame to frame (red rising, blue falling), a white square moving."""
    frames = []
    for k in range(n):
        f = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
        f[..., 0], f[..., 2] = (40 + 20 * k) % 256, (200 - 15 * k) % 256
        x = 5 + (6 * k) % 60
        f[10:30, x : x + 20] = 255
        frames.append(f)
    return frames


def _streams(path) -> str:
    """FFmpeg's description of a file's streams (its ``-i`` output)."""
    run = subprocess.run([ffmpeg_exe(), "-hide_banner", "-i", str(path)], capture_output=True, text=True)
    return run.stderr


def test_h264_frames_decode_back(tmp_path):
    import cv2

    path = tmp_path / "v.mp4"
    frames = _frames(8)
    with H264Writer(path, SIZE, 25.0) as video:
        for f in frames:
            video.write(f)
    assert "Video: h264" in _streams(path) and "yuv420p" in _streams(path)
    capture = cv2.VideoCapture(str(path))
    decoded = []
    while True:
        ok, bgr = capture.read()
        if not ok:
            break
        decoded.append(bgr[..., ::-1])
    capture.release()
    assert len(decoded) == len(frames) and decoded[0].shape == frames[0].shape
    for want, got in zip(frames, decoded, strict=True):
        # flat regions within the codec's error (4:2:0 chroma, crf 23)
        assert np.abs(got[40:60, 40:90].astype(int) - want[40:60, 40:90]).mean() < 6


def test_the_sources_sound_goes_with_the_frames_and_odd_sides_are_padded(tmp_path):
    source = tmp_path / "talk.mp4"
    subprocess.run(
        [ffmpeg_exe(), "-loglevel", "error", "-f", "lavfi", "-i", "color=c=gray:s=64x48:d=2", "-f", "lavfi", "-i"]
        + ["sine=frequency=440:duration=2", "-c:v", "libx264", "-pix_fmt", "yuv420p", "-c:a", "aac", str(source)],
        check=True,
    )
    out = tmp_path / "preview.mp4"
    with H264Writer(out, (95, 63), 25.0, audio_from=source) as video:
        for f in _frames(25):
            video.write(f[:63, :95])
    info = _streams(out)
    assert "Audio: aac" in info and "96x64" in info
    silent = tmp_path / "silent.mp4"  # a source without sound: video only, no error
    with H264Writer(silent, SIZE, 25.0) as video:
        video.write(_frames(1)[0])
    with H264Writer(tmp_path / "none.mp4", SIZE, 25.0, audio_from=silent) as video:
        video.write(_frames(1)[0])
    assert "Audio" not in _streams(tmp_path / "none.mp4")


def test_a_failure_is_one_line_from_ffmpeg(tmp_path):
    with pytest.raises(EncoderError, match="FFmpeg could not write the video: ") as info:
        with H264Writer(tmp_path / "no" / "such" / "folder.mp4", SIZE, 25.0) as video:
            for f in _frames(3):
                video.write(f)
    assert "\n" not in str(info.value)


@needs_tool(CHROMIUM is not None, "chromium is not installed (make browser)")
def test_the_preview_plays_in_chromium(tmp_path):
    """A page loads the video in headless Chromium and reports its size and duration (an MPEG-4 Part 2 file,
    OpenCV's mp4v, gives MEDIA_ERR_SRC_NOT_SUPPORTED there)."""
    assert CHROMIUM is not None
    with H264Writer(tmp_path / "preview.mp4", SIZE, 25.0) as video:
        for f in _frames(10):
            video.write(f)
    page = tmp_path / "page.html"
    page.write_text(
        '<html><body><div id="out">pending</div><script>'
        'const v = document.createElement("video"); v.muted = true; v.src = "preview.mp4";'
        'v.addEventListener("loadeddata", () => { document.getElementById("out").textContent = '
        "`loaded ${v.videoWidth}x${v.videoHeight} ${v.duration.toFixed(2)}s`; });"
        'v.addEventListener("error", () => { document.getElementById("out").textContent = `error ${v.error.code}`; });'
        "document.body.appendChild(v);</script></body></html>"
    )
    with tempfile.TemporaryDirectory(prefix="jnr-chromium-") as profile:
        run = subprocess.run(
            [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={profile}"]
            + ["--allow-file-access-from-files", "--virtual-time-budget=10000", "--dump-dom", page.as_uri()],
            capture_output=True,
            timeout=120,
            check=True,
        )
    dom = run.stdout.decode("utf-8")
    assert f"loaded {SIZE[0]}x{SIZE[1]} 0.40s" in dom, dom[-300:]
