"""``preview.mp4`` of a track: each frame of the clip with the fitted head blended over it and the detected
landmarks (green dots), beside the fitted head alone, grey, seen from the clip's camera; bridged frames
(no face) are marked in red.

The grey head is drawn by a small rasteriser (OpenCV polygons, far triangles first, Lambert shading with a
light from the camera's upper left): a few tens of milliseconds a frame, so the preview does not cost more than
the tracking. The video is H.264 in MP4 (:mod:`pipeline.track.encode`: browsers, QuickTime, VLC and every
editor play it; OpenCV's MPEG-4 Part 2 did not play in Chromium or Firefox), with the source video's sound.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.animation.keyframes import posed_frames, static_frames
from pipeline.camera import RIG_TO_OPENCV, camera_points_to_pixels
from pipeline.track.encode import H264Writer
from pipeline.track.tracker import TrackResult
from pipeline.track.video import Clip

LIGHT = np.array([-0.4, -0.5, -0.75])
"""The direction towards the light in the camera frame (OpenCV axes: up, left, towards the camera)."""
CHUNK = 32
"""Frames posed at once."""


def posed_camera_vertices(result: TrackResult, frames: np.ndarray) -> np.ndarray:
    """``(F, V, 3)`` the fitted head of ``frames`` in the camera frame (OpenCV), mm (the identity's joints,
    each frame's coefficients: :func:`pipeline.animation.keyframes.posed_frames`, then the frame's pose)."""
    head = result.head
    if head.model.posable:
        taus = np.repeat(head.tau[None], len(frames), axis=0)
        posed = posed_frames(head, result.coefficients[frames], taus)
    else:
        posed = static_frames(head, result.coefficients[frames])
    rotation = np.einsum("ij,fjk->fik", RIG_TO_OPENCV, result.rotations[frames])
    return np.einsum("fvk,fik->fvi", posed, rotation) + result.translations[frames][:, None, :]


def shade_head(
    camera_vertices: np.ndarray, faces: np.ndarray, focal: float, size: tuple[int, int], grey: float = 0.72
) -> tuple[np.ndarray, np.ndarray]:
    """``(image (H, W, 3) uint8, mask (H, W) bool)``: the mesh ``(V, 3)`` (camera frame, mm) drawn grey with
    Lambert shading, triangles far to near (painter's order), back faces culled."""
    import cv2

    width, height = size
    uv = camera_points_to_pixels(camera_vertices, focal, np.array([(width - 1) / 2.0, (height - 1) / 2.0]))
    tri = camera_vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True).clip(1e-12)
    centre = tri.mean(axis=1)
    facing = (normal * centre).sum(axis=1) < 0.0  # towards the camera (at the origin)
    light = LIGHT / np.linalg.norm(LIGHT)
    shade = 0.25 + 0.75 * np.clip(normal @ light, 0.0, 1.0)
    order = np.flatnonzero(facing)[np.argsort(-centre[facing, 2])]
    image = np.zeros((height, width, 3), np.uint8)
    mask = np.zeros((height, width), np.uint8)
    points = np.round(uv[faces] * 16).astype(np.int32)  # 4 bits of sub-pixel precision
    for f in order:
        value = int(round(255 * grey * shade[f]))
        cv2.fillConvexPoly(image, points[f], (value, value, value), lineType=cv2.LINE_AA, shift=4)
        cv2.fillConvexPoly(mask, points[f], 1, shift=4)
    return image, mask.astype(bool)


def write_preview(path: str | Path, clip: Clip, result: TrackResult, progress=None, alpha: float = 0.55) -> None:
    """Write ``preview.mp4`` (module docstring): the clip's frames again, side by side with the head.

    Raises:
        InputError: the H.264 encoder (imageio-ffmpeg) is not installed.
        EncoderError: FFmpeg failed.
    """
    import cv2

    width, height = clip.size
    audio = None if clip.is_folder else clip.path  # the source's sound, when it has one
    faces = np.asarray(result.head.faces, np.int64)
    start_s = result.first_frame / float(clip.fps)
    with H264Writer(path, (2 * width, height), float(clip.fps), audio_from=audio, audio_start_s=start_s) as writer:
        cached: dict[int, np.ndarray] = {}
        first = result.first_frame  # a shot's frames are the clip's from its first on
        for clip_index, frame in clip.frames(first + result.frames):
            if clip_index < first:
                continue
            index = clip_index - first
            if index not in cached:
                chunk = np.arange(index, min(index + CHUNK, result.frames))
                cached = dict(zip(chunk.tolist(), posed_camera_vertices(result, chunk), strict=True))
            head, mask = shade_head(cached.pop(index), faces, result.focal, clip.size)
            left = frame.copy()
            left[mask] = (alpha * head[mask] + (1 - alpha) * frame[mask]).astype(np.uint8)
            if result.observed[index]:
                for x, y in result.landmarks[index][::3]:
                    cv2.circle(left, (int(round(x)), int(round(y))), 1, (40, 220, 60), -1)
            else:
                cv2.putText(left, "no face: bridged", (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (230, 30, 30), 2)
            writer.write(np.concatenate([left, head], axis=1))
            if progress is not None:
                progress("preview", index + 1, result.frames)


__all__ = ["posed_camera_vertices", "shade_head", "write_preview"]
