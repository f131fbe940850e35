"""Detect faces and their 68 iBUG landmarks in an image with any registered detector.

The front of :mod:`landmarks.detector`: :func:`detect_faces` checks the image, makes the detector by name
(or takes one), checks what it returns and sorts the faces largest first; :func:`detect_landmarks` picks
one face. Images are ``(H, W, 3)`` uint8 RGB arrays (:func:`landmarks.images.load_image` reads a file);
boxes are ``(4,)`` float64 ``[left, top, right, bottom]`` and landmarks ``(68, 2)`` float64, both in
**0-based OpenCV pixel coordinates** (origin at the centre of the top-left pixel, x right, y down),
landmarks in iBUG-68 order (:data:`landmarks.ibug68.names.IBUG68_NAMES`), the convention of
:mod:`landmarks.formats`.

Example::

    image = load_image("photo.jpg")            # (H, W, 3) uint8 RGB
    face = detect_landmarks(image)             # the largest face, the "auto" detector (MediaPipe, then dlib)
    face.landmarks.shape                       # (68, 2)
"""

from __future__ import annotations

import numpy as np

from landmarks.detector import (
    DEFAULT_DETECTOR,
    NUM_LANDMARKS,
    DetectionError,
    FaceDetection,
    FaceDetector,
    NoFaceError,
    create_detector,
)
from landmarks.images import check_image
from rig.errors import InputError


def _check_faces(faces: object, detector: FaceDetector) -> list[FaceDetection]:
    """What a detector returned, if it keeps the :class:`~landmarks.detector.FaceDetector` contract
    (a detector's bug, not the user's input: ValueError)."""
    if not isinstance(faces, list) or not all(isinstance(f, FaceDetection) for f in faces):
        raise InputError(f"detect_faces: detector {detector.name!r} must return a list of FaceDetection")
    for f in faces:
        if np.shape(f.box) != (4,) or np.shape(f.landmarks) != (NUM_LANDMARKS, 2):
            raise InputError(
                f"detect_faces: detector {detector.name!r} returned a face with box shape {np.shape(f.box)} and "
                f"landmarks shape {np.shape(f.landmarks)}; expected (4,) and ({NUM_LANDMARKS}, 2)"
            )
    return faces


def detect_faces(image: np.ndarray, detector: str | FaceDetector = "hog", **options) -> list[FaceDetection]:
    """Detect all faces in an image and their 68 landmarks.

    Args:
        image: ``(H, W, 3)`` uint8 RGB.
        detector: a registered name (:func:`landmarks.detector.detector_names`; default ``"hog"``, dlib's
            HOG detector) or a :class:`~landmarks.detector.FaceDetector`.
        options: the detector's options when it is given by name (dlib's: ``upsample``, ``min_score``;
            :mod:`landmarks.dlib_detector`).

    Returns:
        The faces, sorted by box area, largest first (ties: higher score, then left-most, top-most);
        empty if none was found. Each records the detector that found it.

    Raises:
        DetectionError: a bad image, an unknown detector name or a bad option value.
    """
    image = check_image(image, "detect_faces")
    if isinstance(detector, str):
        detector = create_detector(detector, **options)
    elif options:
        raise DetectionError(f"detect_faces: options {sorted(options)} apply to a detector given by name")
    faces = list(_check_faces(detector.detect(image), detector))
    faces.sort(key=lambda f: (-f.area, -f.score, float(f.box[0]), float(f.box[1])))
    return faces


def detect_landmarks(
    image: np.ndarray, face: int | None = None, detector: str | FaceDetector = DEFAULT_DETECTOR, **options
) -> FaceDetection:
    """Detect the 68 iBUG landmarks of one face.

    Args:
        image: ``(H, W, 3)`` uint8 RGB.
        face: which face, 0-based in the largest-first order of :func:`detect_faces`; ``None`` (default)
            takes the largest.
        detector, options: as :func:`detect_faces` (default ``"auto"``: MediaPipe's models, and dlib's HOG
            and CNN detectors only when MediaPipe finds no face; it refuses without MediaPipe's runtime or models).

    Returns:
        The chosen :class:`~landmarks.detector.FaceDetection`; ``landmarks`` is ``(68, 2)`` float64
        0-based OpenCV pixels.

    Raises:
        DetectionError: ``face`` is out of range; :class:`~landmarks.detector.NoFaceError` (a
            DetectionError): no face was found.
    """
    if face is not None and (isinstance(face, bool) or not isinstance(face, (int, np.integer))):
        raise DetectionError(f"detect_landmarks: face must be an integer index or None; got {face!r}")
    faces = detect_faces(image, detector, **options)
    if not faces:
        raise NoFaceError("no face found in the image; pass --landmarks FILE to give the 68 landmarks yourself")
    index = 0 if face is None else int(face)
    if not 0 <= index < len(faces):
        noun = "face" if len(faces) == 1 else "faces"
        raise DetectionError(f"found {len(faces)} {noun}; --face must be 0..{len(faces) - 1}, got {index}")
    return faces[index]


__all__ = ["detect_faces", "detect_landmarks"]
