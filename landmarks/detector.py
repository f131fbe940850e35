"""The face detector interface: what a detector returns, the protocol it implements and the registry of them.

A detector finds faces in an ``(H, W, 3)`` uint8 RGB image and gives each one a :class:`FaceDetection`: a
box, a score and the 68 iBUG landmarks, all in **0-based OpenCV pixel coordinates** (origin at the centre
of the top-left pixel, x right, y down), the convention of :mod:`landmarks.formats`. Detectors are made by
name from a registry (:func:`create_detector`), so ``jnr fit --detector NAME`` and the library take any
registered one; :func:`landmarks.detect.detect_faces` is the front that checks the image and the faces
and sorts them largest first.

Built in: dlib's HOG and CNN detectors (:mod:`landmarks.dlib_detector`), ``dlib`` (HOG, and the CNN
only when HOG finds nothing), ``mediapipe`` (:mod:`landmarks.mediapipe.detector`: MediaPipe's models,
which also fill :attr:`FaceDetection.dense` and :attr:`FaceDetection.roll_deg`) and ``auto``, the default
(``mediapipe``, and ``dlib`` only when it finds nothing; without MediaPipe's runtime or models it refuses
rather than run ``dlib`` alone). Adding one is a module
with a class that implements :class:`FaceDetector` and one :func:`register_detector` call: in the new
module (imported before use), or below in this module's :func:`_register_builtin` for one jnr ships
(importing the implementation lazily, in its factory, so that this module, which ``jnr fit --help``
reads the names from, stays free of numpy and the detector's libraries).

Example::

    class Fixed:                                   # a detector: a name, a description, detect()
        name, description = "fixed", "the same landmarks every time"
        def detect(self, image):
            return [FaceDetection(box, 1.0, points, "fixed")]

    register_detector("fixed", lambda: Fixed(), summary="the same landmarks every time")
    create_detector("fixed").detect(image)         # -> [FaceDetection]
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from rig.errors import InputError

if TYPE_CHECKING:
    import numpy as np

NUM_LANDMARKS = 68
"""Landmarks per face, in iBUG-68 order (:data:`landmarks.ibug68.names.IBUG68_NAMES`)."""
DEFAULT_DETECTOR = "auto"
"""The detector ``jnr fit`` uses unless ``--detector`` names another."""


class DetectionError(InputError):
    """No face found, or bad arguments to a detector (an unknown name, a bad image array or option)."""


class NoFaceError(DetectionError):
    """The detector found no face in the image (a photo that was read, unlike an unreadable one)."""


@dataclass(frozen=True)
class FaceDetection:
    """One detected face. The arrays are read-only for the built-in detectors."""

    box: np.ndarray
    """``(4,)`` float64 ``[left, top, right, bottom]`` in pixels, 0-based OpenCV (x right, y down); dlib's
    rectangles have inclusive corners."""
    score: float
    """The detector's confidence (higher is more confident), on the detector's own scale: dlib's HOG score
    (may be slightly negative; a clear face above 1), its CNN's (MMOD) confidence (a clear face about 1) or
    MediaPipe's detection probability (0 to 1)."""
    landmarks: np.ndarray
    """``(68, 2)`` float64 0-based OpenCV pixel coordinates (x right, y down), iBUG-68 order."""
    detector: str
    """The registered name of the detector that found the face (for ``auto``: ``"mediapipe"``, ``"hog"`` or
    ``"cnn"``)."""
    dense: np.ndarray | None = None
    """``(478, 3)`` float64 dense points, or None (dlib's detectors): MediaPipe's 468 face-mesh points and
    the subject's right (468-472) and left (473-477) iris, centre first, in MediaPipe's order; ``x, y`` in
    0-based OpenCV pixels like ``landmarks``, ``z`` MediaPipe's relative depth in the same pixel scale
    (negative towards the camera)."""
    roll_deg: float | None = None
    """The face's in-plane rotation, or None: the angle of the line from the subject's right eye to the
    left eye, degrees, image axes (y down: positive is clockwise on screen); 0 for an upright face."""

    @property
    def area(self) -> float:
        """Box area in square pixels."""
        left, top, right, bottom = (float(v) for v in self.box)
        return max(right - left, 0.0) * max(bottom - top, 0.0)


@runtime_checkable
class FaceDetector(Protocol):
    """What a face detector implements: made by :func:`create_detector`, used through
    :func:`landmarks.detect.detect_faces`."""

    name: str
    """The name it is registered under (``jnr fit --detector NAME``); recorded in ``report.json``."""
    description: str
    """Which detector it is, for messages and ``report.json`` (e.g. ``"dlib's HOG detector"``)."""

    def detect(self, image: np.ndarray) -> list[FaceDetection]:
        """Every face in ``image`` (``(H, W, 3)`` uint8 RGB), in any order; empty when there is none.

        Raises:
            DetectionError: ``image`` is not an ``(H, W, 3)`` uint8 array, or is empty.
        """
        ...


class FallbackDetector:
    """Runs detectors in turn and returns the faces of the first that finds any. Implements :class:`FaceDetector`.

    The built-in ``dlib`` (:func:`landmarks.dlib_detector.dlib_detector`) is one: dlib's HOG detector, then its
    slower CNN only when HOG finds nothing. So is ``auto`` (:func:`landmarks.mediapipe.detector.auto_detector`):
    MediaPipe's models, then dlib's HOG and CNN only when MediaPipe finds no face. ``auto`` is not made at all
    without MediaPipe's runtime or model files: it refuses, saying what to install, and never runs dlib's
    detectors alone in their place.

    Args:
        name: the registered name. detectors: tried in this order. description: for messages.
    """

    def __init__(self, name: str, detectors: tuple[FaceDetector, ...], description: str):
        if not detectors:
            raise DetectionError(f"FallbackDetector {name!r}: detectors must not be empty")
        self.name = name
        self.detectors = tuple(detectors)
        self.description = description

    def detect(self, image: np.ndarray) -> list[FaceDetection]:
        """The faces of the first detector that finds any; empty if none does."""
        faces: list[FaceDetection] = []
        for detector in self.detectors:
            faces = detector.detect(image)
            if faces:
                break
        return faces

    def __repr__(self) -> str:
        return f"FallbackDetector({self.name!r}, {[d.name for d in self.detectors]})"


# ------------------------------------------------------------------------------------------ registry


@dataclass(frozen=True)
class _Registration:
    factory: Callable[..., FaceDetector]
    summary: str


_REGISTRY: dict[str, _Registration] = {}
_NAME = re.compile(r"[a-z][a-z0-9_-]*")


def register_detector(
    name: str, factory: Callable[..., FaceDetector], *, summary: str = "", replace: bool = False
) -> None:
    """Register a detector under ``name``: ``factory(**options)`` makes it (:func:`create_detector`).

    Args:
        name: lower-case letters, digits, ``_`` and ``-``, starting with a letter (a ``--detector`` choice).
        factory: returns a :class:`FaceDetector`; called for every :func:`create_detector`, so it should
            be cheap (load models lazily and once, on the first :meth:`~FaceDetector.detect`), and it
            imports the implementation itself when that pulls in heavy libraries.
        summary: one line for ``jnr fit --help`` (what it finds, how fast).
        replace: allow replacing a registered detector of the same name.

    Raises:
        DetectionError: a malformed name, a factory that is not callable, or a name already registered
            (without ``replace``).
    """
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise DetectionError(
            f"register_detector: name must be lower-case letters, digits, '_' or '-', starting with a letter; "
            f"got {name!r}"
        )
    if not callable(factory):
        raise DetectionError(f"register_detector: factory must be callable; got {type(factory).__name__}")
    if name in _REGISTRY and not replace:
        raise DetectionError(f"register_detector: a detector named {name!r} is registered already (replace=True)")
    _REGISTRY[name] = _Registration(factory, str(summary))


def unregister_detector(name: str) -> None:
    """Remove a registered detector (e.g. one a test added).

    Raises:
        DetectionError: ``name`` is not registered.
    """
    _registration(name, "unregister_detector")
    del _REGISTRY[name]


def detector_names() -> tuple[str, ...]:
    """The registered detectors' names, in the order they were registered."""
    return tuple(_REGISTRY)


def detector_summary(name: str) -> str:
    """The one-line summary ``name`` was registered with (for ``--help``)."""
    return _registration(name, "detector_summary").summary


def check_detector_name(name: str, function: str = "create_detector") -> str:
    """``name`` if a detector is registered under it.

    Raises:
        DetectionError: it is not (the message lists the registered names).
    """
    _registration(name, function)
    return name


def create_detector(name: str, /, **options) -> FaceDetector:
    """A new detector of the registered kind ``name``, made by its factory with ``options`` (e.g. dlib's
    ``upsample``, ``min_score``; see :mod:`landmarks.dlib_detector`).

    Raises:
        DetectionError: ``name`` is not registered (the message lists the names), a bad option value,
            or the factory did not return a :class:`FaceDetector`.
        TypeError: an option the detector does not take.
    """
    detector = _registration(name, "create_detector").factory(**options)
    if not isinstance(detector, FaceDetector):
        raise DetectionError(
            f"create_detector: the factory of {name!r} returned {type(detector).__name__}, which lacks the "
            "FaceDetector attributes name, description and detect()"
        )
    return detector


def _registration(name: str, function: str) -> _Registration:
    registration = _REGISTRY.get(name) if isinstance(name, str) else None
    if registration is None:
        raise DetectionError(
            f"{function}: unknown face detector {name!r}; the detectors are {', '.join(_REGISTRY)} "
            "(landmarks.detector.register_detector adds one)"
        )
    return registration


def lazy_factory(target: str) -> Callable[..., FaceDetector]:
    """A factory that imports ``"package.module:attribute"`` when it is first called and calls that with the
    options: a detector's module (numpy, dlib, a model runtime) is loaded only when one is made, so that
    listing the names (``jnr fit --help``) stays light."""
    module_name, _, attribute = target.partition(":")
    if not module_name or not attribute:
        raise DetectionError(f"lazy_factory: expected 'package.module:attribute', got {target!r}")

    def factory(**options) -> FaceDetector:
        return getattr(importlib.import_module(module_name), attribute)(**options)

    factory.__qualname__ = f"lazy_factory({target!r})"
    return factory


def _register_builtin() -> None:
    """dlib's detectors (:mod:`landmarks.dlib_detector`) and MediaPipe's (:mod:`landmarks.mediapipe.detector`),
    each imported when one is made."""
    register_detector(
        "hog", lazy_factory("landmarks.dlib_detector:HogDetector"), summary="dlib's HOG detector: fast, frontal faces"
    )
    register_detector(
        "cnn",
        lazy_factory("landmarks.dlib_detector:CnnDetector"),
        summary="dlib's CNN detector: finds turned, tilted and low-contrast faces; about 5 s for a "
        "512 x 512 photo on 2 cores",
    )
    register_detector(
        "dlib",
        lazy_factory("landmarks.dlib_detector:dlib_detector"),
        summary="hog, and cnn only when hog finds no face",
    )
    register_detector(
        "mediapipe",
        lazy_factory("landmarks.mediapipe.detector:MediaPipeDetector"),
        summary="MediaPipe's face detector, 478-point mesh and irises (ai-edge-litert): finds small, turned and "
        "tilted faces; about 30 ms for a 512 x 512 photo on 1 core",
    )
    register_detector(
        "auto",
        lazy_factory("landmarks.mediapipe.detector:auto_detector"),
        summary="mediapipe, and dlib only when mediapipe finds no face",
    )


_register_builtin()

__all__ = [
    "DEFAULT_DETECTOR",
    "lazy_factory",
    "NUM_LANDMARKS",
    "DetectionError",
    "FaceDetection",
    "FaceDetector",
    "FallbackDetector",
    "NoFaceError",
    "check_detector_name",
    "create_detector",
    "detector_names",
    "detector_summary",
    "register_detector",
    "unregister_detector",
]
