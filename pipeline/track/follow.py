"""A face followed through a clip with MediaPipe's models, as its tracker does: the full detector on the
first frame (and whenever the face is lost), then each frame's 468-point mesh on the crop the previous
frame's points give (:func:`landmarks.mediapipe.detector.mesh_rect`), the irises added (478 points).

A frame whose mesh scores a face presence under ``min_presence`` is lost: the detector runs on the next
frame again, and the face it finds nearest to where the face was (the largest, at the start) is followed.

Example:
    >>> follower = FaceFollower()  # doctest: +SKIP
    >>> for index, frame in clip.frames():  # doctest: +SKIP
    ...     seen = follower.step(frame)  # FollowedFrame: (478, 3) points or None
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from landmarks.detector import NoFaceError
from landmarks.mediapipe.detector import DEFAULT_MIN_PRESENCE, MediaPipeDetector, mesh_rect
from landmarks.mediapipe.iris import add_irises
from landmarks.mediapipe.mesh import face_mesh
from rig.errors import InputError


@dataclass(frozen=True)
class FollowedFrame:
    """One frame's face.

    Attributes:
        points: ``(478, 3)`` MediaPipe's points (pixels, OpenCV; ``z`` relative depth), or None: no face.
        presence: the mesh model's face-presence score (0 when nothing was found).
        detected: the points came from a fresh detection (the first frame, or after the face was lost).
        milliseconds: the time this frame took.
    """

    points: np.ndarray | None
    presence: float
    detected: bool
    milliseconds: float


def _centre(points: np.ndarray) -> np.ndarray:
    return np.asarray(points, np.float64)[:, :2].mean(axis=0)


class FaceFollower:
    """Follow one face from frame to frame (module docstring).

    Args:
        face: which face of the first frame with faces to follow: 0 the largest (default), ``k`` the k-th
            by size (as ``jnr fit --face`` numbers them).
        min_presence: the mesh's face presence under which the face counts as lost.
        detector: the MediaPipe detector (default: its full-range model, one thread).
    """

    def __init__(
        self,
        face: int = 0,
        min_presence: float = DEFAULT_MIN_PRESENCE,
        detector: MediaPipeDetector | None = None,
    ) -> None:
        if not (isinstance(face, int) and face >= 0):
            raise InputError(f"face must be an integer >= 0, got {face!r}")
        self.face = face
        self.min_presence = float(min_presence)
        self.detector = detector or MediaPipeDetector()
        self._last: np.ndarray | None = None
        self._where: np.ndarray | None = None  # the face's last centre (pixels), kept while it is lost
        self._started = False
        self.most_faces = 0
        self.found_once = False
        """Whether the chosen face was found in any frame (a reset at a cut keeps it)."""
        """The most faces found in one frame before the chosen one was (a too-large ``face`` shows here)."""

    def reset(self) -> None:
        """Forget the face (a shot cut): the next frame's is found by the detector, the ``face``-th largest."""
        self._last, self._where, self._started = None, None, False

    @property
    def started(self) -> bool:
        """Whether the chosen face has been found in a frame."""
        return self._started

    def _detect(self, frame: np.ndarray) -> np.ndarray | None:
        try:
            faces = self.detector.detect(frame)
        except NoFaceError:
            return None
        if not faces:
            return None
        if not self._started:
            self.most_faces = max(self.most_faces, len(faces))
            by_size = sorted(faces, key=lambda f: -float(np.prod(np.ptp(f.dense[:, :2], axis=0))))
            if self.face >= len(by_size):
                return None
            return np.asarray(by_size[self.face].dense, np.float64)
        if self._where is None:
            return np.asarray(faces[0].dense, np.float64)
        nearest = min(faces, key=lambda f: float(np.linalg.norm(_centre(f.dense) - self._where)))
        return np.asarray(nearest.dense, np.float64)

    def step(self, frame: np.ndarray) -> FollowedFrame:
        """The face in the next frame (``(H, W, 3)`` uint8 RGB)."""
        t0 = time.perf_counter()
        if self._last is not None:
            mesh = face_mesh(frame, mesh_rect(self._last), self.detector.num_threads)
            if mesh.presence >= self.min_presence:
                dense, _ = add_irises(frame, mesh.points, self.detector.refine_eyes, self.detector.num_threads)
                self._last = np.asarray(dense, np.float64)
                self._where = _centre(self._last)
                return FollowedFrame(self._last, float(mesh.presence), False, 1e3 * (time.perf_counter() - t0))
        found = self._detect(frame)
        if found is None:
            self._last = None
            return FollowedFrame(None, 0.0, False, 1e3 * (time.perf_counter() - t0))
        self._started = self.found_once = True
        self._last = found
        self._where = _centre(found)
        return FollowedFrame(found, 1.0, True, 1e3 * (time.perf_counter() - t0))


__all__ = ["FaceFollower", "FollowedFrame"]
