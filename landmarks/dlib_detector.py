"""dlib's face detectors with its 68-point shape predictor, as :class:`~landmarks.detector.FaceDetector`\\ s.

* :class:`HogDetector` (``"hog"``): dlib's HOG frontal face detector: fast, frontal faces.
* :class:`CnnDetector` (``"cnn"``): dlib's CNN (MMOD) detector (``mmod_human_face_detector.dat`` from
  ``face-recognition-models``): finds turned, tilted and low-contrast faces HOG misses, at many times HOG's
  time (both timed in ``docs/fit_photo.md``, "How it works").
* :func:`dlib_detector` (``"dlib"``): HOG, and the CNN only when HOG finds nothing (``"auto"``, the
  default, tries MediaPipe's first: :func:`landmarks.mediapipe.detector.auto_detector`).

Both give each face the 68 iBUG landmarks of dlib's shape predictor (``shape_predictor_68_face_landmarks.dat``
from ``face-recognition-models``), in 0-based OpenCV pixels (dlib's part coordinates are integer pixel
indices). dlib is imported, and each model file loaded, once, on the first detection that needs it;
detection is deterministic. The registry (:mod:`landmarks.detector`) imports this module when one of
them is made.

Example::

    faces = HogDetector().detect(image)        # (H, W, 3) uint8 RGB -> [FaceDetection], any order
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

import numpy as np

from landmarks.detector import DetectionError, FaceDetection, FallbackDetector
from landmarks.images import check_image

PREDICTOR_FILE = "shape_predictor_68_face_landmarks.dat"
CNN_DETECTOR_FILE = "mmod_human_face_detector.dat"
DEFAULT_MIN_SCORE = 0.5
"""HOG detections with a lower score are dropped (dlib's own default threshold is 0).

Why 0.5: on ``skimage.data.astronaut()`` the real face scores about 1.1-1.5, while a false positive on the
suit scores 0.12 with a box as large as the face's (so sorting by area alone could pick it); real frontal
faces usually score above 1. Lower it (e.g. 0 or -0.2) for hard photos, at the cost of false positives."""
CNN_MIN_CONFIDENCE = 0.3
"""CNN detections with a lower confidence are dropped (dlib's default keeps everything above 0; on
``skimage.data.astronaut()`` upright and rotated by 25-45 degrees the face scores 1.07-1.08)."""


def _model_path(filename: str, what: str, function: str) -> Path:
    """Path of one of dlib's model files that ``face-recognition-models`` ships, found without importing the
    package (its ``__init__`` needs ``pkg_resources``). Raises :class:`DetectionError` when it is missing."""
    hint = f"pip install face-recognition-models (it ships dlib's {what})"
    spec = importlib.util.find_spec("face_recognition_models")
    if spec is None or not spec.submodule_search_locations:
        raise DetectionError(f"{function}: package face_recognition_models not found; {hint}")
    for folder in spec.submodule_search_locations:
        path = Path(folder) / "models" / filename
        if path.is_file():
            return path
    raise DetectionError(f"{function}: {filename} not found in face_recognition_models; {hint}")


def shape_predictor_path() -> Path:
    """Path of dlib's 68-point ``shape_predictor_68_face_landmarks.dat`` from ``face-recognition-models``.

    Raises:
        DetectionError: the package or the file is missing.
    """
    return _model_path(PREDICTOR_FILE, "68-landmark shape predictor", "shape_predictor_path")


def cnn_detector_path() -> Path:
    """Path of dlib's CNN face detector ``mmod_human_face_detector.dat`` from ``face-recognition-models``.

    Raises:
        DetectionError: the package or the file is missing.
    """
    return _model_path(CNN_DETECTOR_FILE, "CNN face detector", "cnn_detector_path")


def _import_dlib():
    try:
        import dlib
    except ImportError:
        raise DetectionError("face detection needs dlib: pip install dlib-bin (or dlib)") from None
    return dlib


@functools.lru_cache(maxsize=1)
def _hog_model():
    """dlib's HOG frontal face detector, created once."""
    return _import_dlib().get_frontal_face_detector()


@functools.lru_cache(maxsize=1)
def _cnn_model():
    """dlib's CNN (MMOD) face detector, loaded once."""
    return _import_dlib().cnn_face_detection_model_v1(str(cnn_detector_path()))


@functools.lru_cache(maxsize=1)
def _predictor():
    """dlib's 68-point shape predictor, loaded once (about 100 MB)."""
    return _import_dlib().shape_predictor(str(shape_predictor_path()))


def _check_upsample(upsample: int, function: str) -> int:
    if isinstance(upsample, bool) or not isinstance(upsample, (int, np.integer)) or upsample < 0:
        raise DetectionError(f"{function}: upsample must be an integer >= 0; got {upsample!r}")
    return int(upsample)


def _check_threshold(value: float, name: str, function: str) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not np.isfinite(value)
    ):
        raise DetectionError(f"{function}: {name} must be a finite number; got {value!r}")
    return float(value)


def _with_landmarks(image: np.ndarray, boxes: list[tuple[object, float]], detector: str) -> list[FaceDetection]:
    """A :class:`FaceDetection` per ``(dlib rectangle, score)``, with the shape predictor's 68 points."""
    predictor = _predictor()
    faces = []
    for rect, score in boxes:
        shape = predictor(image, rect)
        # dlib's part coordinates are integer pixel indices, i.e. already 0-based OpenCV pixels.
        points = np.array([(shape.part(i).x, shape.part(i).y) for i in range(shape.num_parts)], dtype=np.float64)
        box = np.array([rect.left(), rect.top(), rect.right(), rect.bottom()], dtype=np.float64)
        box.flags.writeable = False
        points.flags.writeable = False
        faces.append(FaceDetection(box=box, score=score, landmarks=points, detector=detector))
    return faces


class HogDetector:
    """dlib's HOG frontal face detector and 68-point shape predictor (``"hog"``); a
    :class:`~landmarks.detector.FaceDetector`.

    Args:
        upsample: how many times dlib doubles the image before detecting (finds faces down to about
            80 / 2**upsample pixels wide; each step costs about 4x the time). Must be >= 0.
        min_score: detections scoring below this are dropped (:data:`DEFAULT_MIN_SCORE`).

    Raises:
        DetectionError: a bad ``upsample`` or ``min_score``.
    """

    name = "hog"
    description = "dlib's HOG detector"

    def __init__(self, upsample: int = 1, min_score: float = DEFAULT_MIN_SCORE):
        self.upsample = _check_upsample(upsample, "HogDetector")
        self.min_score = _check_threshold(min_score, "min_score", "HogDetector")

    def detect(self, image: np.ndarray) -> list[FaceDetection]:
        """Every face scoring at least ``min_score``, with its landmarks (in dlib's order)."""
        image = check_image(image, "HogDetector.detect")
        rects, scores, _ = _hog_model().run(image, self.upsample, self.min_score)
        # keep the documented contract whatever dlib does at the boundary
        boxes = [(r, float(s)) for r, s in zip(rects, scores) if s >= self.min_score]
        return _with_landmarks(image, boxes, self.name)


class CnnDetector:
    """dlib's CNN (MMOD) face detector and 68-point shape predictor (``"cnn"``); a
    :class:`~landmarks.detector.FaceDetector`.

    Args:
        upsample: as :class:`HogDetector`.
        min_confidence: detections less confident are dropped (:data:`CNN_MIN_CONFIDENCE`).

    Raises:
        DetectionError: a bad ``upsample`` or ``min_confidence``.
    """

    name = "cnn"
    description = "dlib's CNN detector"

    def __init__(self, upsample: int = 1, min_confidence: float = CNN_MIN_CONFIDENCE):
        self.upsample = _check_upsample(upsample, "CnnDetector")
        self.min_confidence = _check_threshold(min_confidence, "min_confidence", "CnnDetector")

    def detect(self, image: np.ndarray) -> list[FaceDetection]:
        """Every face at least ``min_confidence`` confident, with its landmarks (in dlib's order)."""
        image = check_image(image, "CnnDetector.detect")
        found = _cnn_model()(image, self.upsample)
        boxes = [(d.rect, float(d.confidence)) for d in found if d.confidence >= self.min_confidence]
        return _with_landmarks(image, boxes, self.name)


def dlib_detector(upsample: int = 1, min_score: float = DEFAULT_MIN_SCORE, name: str = "dlib") -> FallbackDetector:
    """``"dlib"``: :class:`HogDetector` (``upsample``, ``min_score``), and :class:`CnnDetector` (``upsample``,
    :data:`CNN_MIN_CONFIDENCE`) only when HOG finds no face (the CNN model is loaded only then)."""
    return FallbackDetector(
        name, (HogDetector(upsample, min_score), CnnDetector(upsample)), "dlib's HOG and CNN detectors"
    )


__all__ = [
    "CNN_DETECTOR_FILE",
    "CNN_MIN_CONFIDENCE",
    "DEFAULT_MIN_SCORE",
    "PREDICTOR_FILE",
    "CnnDetector",
    "HogDetector",
    "dlib_detector",
    "cnn_detector_path",
    "shape_predictor_path",
]
