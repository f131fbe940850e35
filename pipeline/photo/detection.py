"""The landmarks of a photo file: read from a landmarks file, or found by a face detector.

* :func:`detect_photo_faces` runs a registered detector (:mod:`landmarks.detector`) on a photo's working
  image and describes every face it finds for ``report.json`` (:class:`DetectedFaces`).
* :func:`photo_landmarks` gives the landmarks one fit uses, from a file (checked) or from the face
  picked among those detected: the 68 iBUG points, and MediaPipe's dense points when the detector or the
  file gives them (468 or 478; their 68 iBUG points are then mapped from the mesh).
* :func:`name_photo` puts the photo's name into a detection error.

Example:
    >>> photo = load_working_image("face.jpg")  # doctest: +SKIP
    >>> points, source, dense = photo_landmarks(photo, None, face=None, detector="mediapipe")  # doctest: +SKIP
    >>> source["detector"], points.shape, dense.shape  # doctest: +SKIP
    ('mediapipe', (68, 2), (478, 2))
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from landmarks.detect import detect_faces
from landmarks.detector import DEFAULT_DETECTOR, DetectionError, FaceDetection, NoFaceError, create_detector
from landmarks.formats import MEDIAPIPE_COUNTS, NUM_LANDMARKS, read_landmarks
from landmarks.images import LoadedImage
from landmarks.mediapipe.ibug68_map import mesh_to_ibug68
from landmarks.plausibility import check_landmarks_2d
from rig.errors import InputError

FACE_ALL = "all"
"""``face=FACE_ALL`` (``jnr fit --face all``): fit every detected face, each into ``face_<k>/``, k in the
detector's order (largest first, as ``--face N`` numbers them)."""


@dataclass(frozen=True)
class DetectedFaces:
    """Every face a detector found in a photo (largest first) and report.json's list of them."""

    faces: list[FaceDetection]
    """As :func:`landmarks.detect.detect_faces` returns them: boxes and landmarks in the working image's pixels."""
    listed: list[dict]
    """report.json's ``faces``: per face ``{"box"`` (``[left, top, right, bottom]`` in the photo file's
    pixels), ``"score"``, ``"detector"}``."""
    detector_option: str
    """The detector asked for (``--detector``), e.g. ``"auto"``."""
    description: str
    """That detector's description (:attr:`landmarks.detector.FaceDetector.description`)."""
    seconds: float
    """The time the detection took."""

    def source(self, index: int) -> tuple[np.ndarray, dict]:
        """``(landmarks (68, 2) in the working image's pixels, report.json's description of their source)``
        of face ``index``."""
        chosen = self.faces[index]
        return chosen.landmarks, {
            "landmarks": self.description,
            "detector": chosen.detector,
            "detector_option": self.detector_option,
            "detection_seconds": round(self.seconds, 3),
            "face_box": self.listed[index]["box"],
            "face_score": chosen.score,
            "face_index": index,
            "faces": self.listed,
        }

    def dense(self, index: int) -> np.ndarray | None:
        """``(478, 3)`` MediaPipe's dense points of face ``index``: ``x, y`` in the working image's pixels, ``z``
        its relative depth in the same scale (:attr:`landmarks.detector.FaceDetection.dense`); or None (a
        detector without them)."""
        points = self.faces[index].dense
        return None if points is None else np.array(points, np.float64)


def dense_fit_points(dense: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """MediaPipe's points of :func:`photo_landmarks` split for the fit: ``(pixels (N, 2), points3d (N, 3) or
    None)``, the second the detector's points with their relative depth (what the identity regressor reads), None
    for a landmarks file's ``(N, 2)``."""
    return dense[:, :2], (dense if dense.shape[1] == 3 else None)


MIN_DETECTION_SIDE = 32
"""Photos with a side shorter than this (pixels) are not given to a detector (dlib's CNN crashes on a
1-2 px side; no detector finds a face in so few pixels)."""


def detect_photo_faces(photo: LoadedImage, detector: str) -> DetectedFaces:
    """Every face in the working image of ``photo``, found by the registered detector ``detector``.

    Raises:
        NoFaceError: there is none (the message names the detector); DetectionError: an unknown detector.
    """
    height, width = photo.image.shape[:2]
    if min(height, width) < MIN_DETECTION_SIDE:
        raise NoFaceError(
            f"the photo is {width}x{height} pixels: too small to find a face in (at least {MIN_DETECTION_SIDE} "
            "a side); pass --landmarks FILE to give the landmarks yourself"
        )
    t0 = time.perf_counter()
    found_by = create_detector(detector)
    faces = detect_faces(photo.image, found_by)
    seconds = time.perf_counter() - t0
    if not faces:
        raise NoFaceError(
            f"no face found in the image ({found_by.description}); pass --landmarks FILE to give the 68 landmarks "
            "yourself"
        )
    listed = [
        {"box": photo.to_original(f.box.reshape(2, 2)).reshape(-1).tolist(), "score": f.score, "detector": f.detector}
        for f in faces
    ]
    return DetectedFaces(faces, listed, detector, found_by.description, seconds)


def photo_landmarks(
    photo: LoadedImage, landmarks_path: Path | None, face: int | None, detector: str = DEFAULT_DETECTOR
) -> tuple[np.ndarray, dict, np.ndarray | None]:
    """``(landmarks (68, 2), report.json's description of their source, dense (N, 2|3) or None)``, points in
    the working image's pixels: read from ``landmarks_path`` (the photo file's pixels; 68 iBUG points, or
    MediaPipe's 468 or 478, whose 68 iBUG points are mapped from the mesh
    (:func:`landmarks.mediapipe.ibug68_map.mesh_to_ibug68`); checked to be a plausible face in or near the
    image), or detected: face ``face`` (0, the largest, when None) of :func:`detect_photo_faces`, the
    description listing every face found (box in the photo's pixels, score, detector); ``dense``:
    MediaPipe's points when the file (``(N, 2)``) or the detector (``(478, 3)``, with its relative depth) gives
    them.

    Raises:
        InputError: a bad landmarks file; DetectionError: no face, or ``face`` out of range.
    """
    width, height = photo.original_size
    if landmarks_path:
        points = read_landmarks(landmarks_path, (NUM_LANDMARKS, *MEDIAPIPE_COUNTS))
        dense = None
        if len(points) != NUM_LANDMARKS:
            dense, points = photo.to_working(points), mesh_to_ibug68(points)
        check_landmarks_2d(
            points, width, height, source=str(landmarks_path), mapped_from=None if dense is None else len(dense)
        )
        count = NUM_LANDMARKS if dense is None else len(dense)
        source = {"landmarks": os.path.abspath(landmarks_path), "landmark_count": count}
        return photo.to_working(points), source, dense
    detected = detect_photo_faces(photo, detector)
    index = 0 if face is None else int(face)
    if not 0 <= index < len(detected.faces):
        n = len(detected.faces)
        raise DetectionError(f"found {n} {'face' if n == 1 else 'faces'}; --face must be 0..{n - 1}, got {index}")
    return (*detected.source(index), detected.dense(index))


def check_face(face: object) -> None:
    """``face`` is None, a face number or :data:`FACE_ALL`.

    Raises:
        InputError: it is not.
    """
    if face is None or face == FACE_ALL:
        return
    if isinstance(face, bool) or not isinstance(face, int):
        raise InputError(f"--face must be a face number (0 = the largest) or '{FACE_ALL}', got {face!r}")


def name_photo(exc: InputError, photo_path: Path) -> InputError:
    """A detection or image error that names the photo (the other InputErrors name their file or option),
    of the same class (so that :class:`~landmarks.detector.NoFaceError` stays one)."""
    message = str(exc)
    return type(exc)(message if str(photo_path) in message else f"{photo_path}: {message}")


__all__ = [
    "FACE_ALL",
    "DetectedFaces",
    "check_face",
    "detect_photo_faces",
    "name_photo",
    "photo_landmarks",
]
