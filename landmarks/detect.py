"""Detect faces and their 68 iBUG landmarks in a photo with dlib (HOG detector + shape predictor).

Images are ``(H, W, 3)`` uint8 RGB arrays. Boxes are ``(4,)`` float64 ``[left, top, right, bottom]``
in pixels; landmarks are ``(68, 2)`` float64 **0-based OpenCV pixel coordinates** (origin at the centre
of the top-left pixel, x right, y down) in iBUG-68 order (:data:`landmarks.ibug68.IBUG68_NAMES`), the
same convention as :mod:`landmarks.formats`.

dlib and the predictor file (package ``face-recognition-models``) are imported lazily, so
``import landmarks`` works without them; the detector and predictor are created once and cached.
Detection is deterministic (dlib's HOG detector has no randomness).

Example::

    image = load_image("photo.jpg")            # (H, W, 3) uint8 RGB
    face = detect_landmarks(image)             # largest face
    face.landmarks.shape                       # (68, 2)
"""

from __future__ import annotations

import functools
import importlib.util
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.errors import InputError

NUM_LANDMARKS = 68
PREDICTOR_FILE = "shape_predictor_68_face_landmarks.dat"
CNN_DETECTOR_FILE = "mmod_human_face_detector.dat"
DEFAULT_MIN_SCORE = 0.5
"""Detections with a lower dlib HOG score are dropped (dlib's own default threshold is 0).

Why 0.5: on ``skimage.data.astronaut()`` the real face scores about 1.1-1.5, while a false positive on the
suit scores 0.12 with a box as large as the face's (so sorting by area alone could pick it); real frontal
faces usually score above 1. Lower it (e.g. 0 or -0.2) for hard photos, at the cost of false positives."""


class DetectionError(InputError):
    """No face found, an unreadable image, or bad arguments to the detector."""


class NoFaceError(DetectionError):
    """The detector found no face in the image (a photo that was read, unlike an unreadable one)."""


@dataclass(frozen=True)
class FaceDetection:
    """One detected face."""

    box: np.ndarray
    """``(4,)`` float64 ``[left, top, right, bottom]`` in pixels (dlib's rectangle, inclusive corners)."""
    score: float
    """The detector's confidence (higher is more confident): dlib's HOG score (may be slightly negative)
    or the CNN's (MMOD) confidence, on another scale (a clear face about 1)."""
    landmarks: np.ndarray
    """``(68, 2)`` float64 0-based OpenCV pixel coordinates (x right, y down), iBUG-68 order."""
    detector: str = "hog"
    """Which detector found the face: ``"hog"`` or ``"cnn"``."""

    @property
    def area(self) -> float:
        """Box area in square pixels."""
        left, top, right, bottom = self.box
        return float(max(right - left, 0.0) * max(bottom - top, 0.0))


DETECTORS = ("hog", "cnn", "auto")
"""Face detectors: dlib's HOG frontal face detector (fast, frontal faces), dlib's CNN (MMOD) detector
(``mmod_human_face_detector.dat`` from ``face-recognition-models``; finds turned, tilted and low-contrast
faces HOG misses, at about 5 s for a 512 x 512 photo on 2 CPU cores), or ``auto``: HOG, and the CNN only
when HOG finds nothing."""
CNN_MIN_CONFIDENCE = 0.3
"""CNN detections with a lower confidence are dropped (dlib's default keeps everything above 0; on
``skimage.data.astronaut()`` upright and rotated by 25-45 degrees the face scores 1.07-1.08)."""

MAX_IMAGE_PIXELS = 120_000_000
"""Larger images (width x height) are refused with one line before they are decoded (a 10000 x 12000
photo is accepted). Pillow's own guard would raise a multi-line ``DecompressionBombError``."""
WORKING_MAX_SIDE = 2048
"""Photos whose longer side exceeds this are fitted at a reduced size: decoded shrunk by a power of two
``k`` (JPEG: by the decoder itself, ``Image.draft``, so a 10000 x 10000 JPEG never exists in memory at
full size), so that the longer side is at most this (and at least half of it). dlib's detector and
68-point model work on faces from about 80 px across; at 1024-2048 px a face that fills a fifth of
the frame is still 200-400 px wide, so nothing the fit uses is lost."""


@dataclass(frozen=True)
class LoadedImage:
    """A photo as the fit sees it: possibly reduced by an integer factor ``k`` from the file.

    Working pixel ``(x, y)`` (0-based, OpenCV) covers the file's ``k x k`` block whose centre is
    ``(k x + (k - 1) / 2, k y + (k - 1) / 2)`` in the file's 0-based pixels (:meth:`to_original`)."""

    image: np.ndarray
    """``(h, w, 3)`` uint8 RGB, upright (EXIF orientation applied)."""
    factor: int
    """``k``: 1 when the photo is used at its own size."""
    original_size: tuple[int, int]
    """``(W, H)`` of the upright photo in the file, pixels."""

    def to_original(self, points: np.ndarray) -> np.ndarray:
        """``(*, 2)`` working pixels -> the file's pixels (0-based OpenCV)."""
        return np.asarray(points, float) * self.factor + (self.factor - 1) / 2.0

    def to_working(self, points: np.ndarray) -> np.ndarray:
        """``(*, 2)`` the file's pixels -> working pixels (0-based OpenCV)."""
        return (np.asarray(points, float) - (self.factor - 1) / 2.0) / self.factor


def _reason(exc: Exception) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text.replace("cannot identify image file", "not an image file or a corrupt one")


@contextmanager
def _open_unguarded(path: Path):
    """``Image.open`` without Pillow's decompression-bomb guard (:data:`MAX_IMAGE_PIXELS` is checked
    instead, in one line); the guard is restored at once, only the lazy header read runs without it."""
    import warnings

    from PIL import Image

    saved, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(path)
    finally:
        Image.MAX_IMAGE_PIXELS = saved
    with img:
        yield img


def load_working_image(path: str | Path, max_side: int = WORKING_MAX_SIDE,
                       max_pixels: int = MAX_IMAGE_PIXELS) -> LoadedImage:
    """Read a photo for fitting: upright RGB, reduced by a power of two when its longer side exceeds
    ``max_side`` (see :data:`WORKING_MAX_SIDE`), refused above ``max_pixels``.

    Grayscale, palette, CMYK, 16-bit and RGBA images are converted to RGB (alpha dropped); an animated
    image gives its first frame.

    Returns:
        :class:`LoadedImage`.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        DetectionError: not a readable image, or more than ``max_pixels`` pixels (one line).

    Example:
        >>> photo = load_working_image("big.jpg")  # doctest: +SKIP
        >>> photo.image.shape, photo.factor, photo.original_size  # doctest: +SKIP
        ((1250, 1250, 3), 8, (10000, 10000))
    """
    from PIL import ImageOps, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image file not found: {path}")
    try:
        with _open_unguarded(path) as img:
            width, height = img.size
            if width * height > max_pixels:
                raise DetectionError(
                    f"image {path} is {width} x {height} = {width * height / 1e6:.0f} megapixels; jnr reads photos "
                    f"up to {max_pixels / 1e6:.0f} megapixels: downscale it first")
            k = 1
            while max(width, height) > max_side * k:
                k *= 2
            if k > 1 and img.format == "JPEG":
                img.draft("RGB", (-(-width // k), -(-height // k)))  # decoder-side 1/2, 1/4, 1/8 scaling
            done = max(1, round(width / img.size[0]))  # what the decoder already reduced
            img = img.convert("RGB") if img.mode != "RGB" else img
            img.load()
            rotated = img.getexif().get(0x0112, 1) in (5, 6, 7, 8)  # after load: PNG keeps EXIF after IDAT
            if k > done:
                img = img.reduce(k // done)
            img = ImageOps.exif_transpose(img)
            rgb = np.asarray(img, dtype=np.uint8)
    except DetectionError:
        raise
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, EOFError) as exc:
        raise DetectionError(f"cannot read image {path}: {_reason(exc)}") from None
    except MemoryError:
        raise DetectionError(f"image {path} is too large to decode in the available memory") from None
    original = (height, width) if rotated else (width, height)
    if rgb.ndim != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise DetectionError(f"cannot read image {path}: it has no pixels")
    return LoadedImage(image=np.ascontiguousarray(rgb), factor=k, original_size=original)


def load_image(path: str | Path) -> np.ndarray:
    """Read an image file at its full size as an ``(H, W, 3)`` uint8 RGB array.

    The EXIF orientation is applied (``ImageOps.exif_transpose``), so the array is upright as a viewer
    shows it; grayscale, palette, CMYK and RGBA images are converted to RGB (alpha is dropped). For
    fitting, :func:`load_working_image` reads large photos at a reduced size.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        DetectionError: the file cannot be decoded as an image, or has more than
            :data:`MAX_IMAGE_PIXELS` pixels.
    """
    return load_working_image(path, max_side=1 << 30).image


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
def _detector():
    """dlib's HOG frontal face detector, created once."""
    return _import_dlib().get_frontal_face_detector()


@functools.lru_cache(maxsize=1)
def _cnn_detector():
    """dlib's CNN (MMOD) face detector, loaded once."""
    return _import_dlib().cnn_face_detection_model_v1(str(cnn_detector_path()))


@functools.lru_cache(maxsize=1)
def _predictor():
    """dlib's 68-point shape predictor, loaded once (about 100 MB)."""
    return _import_dlib().shape_predictor(str(shape_predictor_path()))


def _check_image(image: np.ndarray, function: str) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise DetectionError(
            f"{function}: image must be an (H, W, 3) uint8 RGB array; got shape {image.shape}, dtype {image.dtype}"
        )
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise DetectionError(f"{function}: image is empty; got shape {image.shape}")
    return np.ascontiguousarray(image)


def _boxes(image: np.ndarray, upsample: int, min_score: float, detector: str) -> list[tuple[object, float]]:
    """``[(dlib rectangle, score)]`` of one detector (``"hog"`` or ``"cnn"``) above its threshold."""
    if detector == "hog":
        rects, scores, _ = _detector().run(image, int(upsample), float(min_score))
        # keep the documented contract whatever dlib does at the boundary
        return [(r, float(s)) for r, s in zip(rects, scores) if s >= min_score]
    found = _cnn_detector()(image, int(upsample))
    return [(d.rect, float(d.confidence)) for d in found if d.confidence >= CNN_MIN_CONFIDENCE]


def detect_faces(image: np.ndarray, upsample: int = 1, min_score: float = DEFAULT_MIN_SCORE,
                 detector: str = "hog") -> list[FaceDetection]:
    """Detect all faces in an image and their 68 landmarks.

    Args:
        image: ``(H, W, 3)`` uint8 RGB.
        upsample: how many times dlib doubles the image before detecting (finds faces down to about
            80 / 2**upsample pixels wide; each step costs about 4x the time). Must be >= 0.
        min_score: HOG detections scoring below this are dropped (see :data:`DEFAULT_MIN_SCORE`); the CNN
            uses :data:`CNN_MIN_CONFIDENCE`.
        detector: one of :data:`DETECTORS` (``"auto"``: HOG, then the CNN if HOG found nothing).

    Returns:
        The faces, sorted by box area, largest first (ties: higher score, then left-most, top-most);
        empty if none was found. Each records the detector that found it.
    """
    image = _check_image(image, "detect_faces")
    if isinstance(upsample, bool) or not isinstance(upsample, (int, np.integer)) or upsample < 0:
        raise DetectionError(f"detect_faces: upsample must be an integer >= 0; got {upsample!r}")
    if isinstance(min_score, bool) or not isinstance(min_score, (int, float, np.integer, np.floating)) \
            or not np.isfinite(min_score):
        raise DetectionError(f"detect_faces: min_score must be a finite number; got {min_score!r}")
    if detector not in DETECTORS:
        raise DetectionError(f"detect_faces: detector must be one of {list(DETECTORS)}; got {detector!r}")
    used = "cnn" if detector == "cnn" else "hog"
    boxes = _boxes(image, upsample, min_score, used)
    if not boxes and detector == "auto":
        used, boxes = "cnn", _boxes(image, upsample, min_score, "cnn")
    predictor = _predictor()
    faces = []
    for rect, score in boxes:
        shape = predictor(image, rect)
        # dlib's part coordinates are integer pixel indices, i.e. already 0-based OpenCV pixels.
        points = np.array([(shape.part(i).x, shape.part(i).y) for i in range(shape.num_parts)], dtype=np.float64)
        box = np.array([rect.left(), rect.top(), rect.right(), rect.bottom()], dtype=np.float64)
        box.flags.writeable = False
        points.flags.writeable = False
        faces.append(FaceDetection(box=box, score=score, landmarks=points, detector=used))
    faces.sort(key=lambda f: (-f.area, -f.score, f.box[0], f.box[1]))
    return faces


def detect_landmarks(image: np.ndarray, face: int | None = None, upsample: int = 1,
                     min_score: float = DEFAULT_MIN_SCORE, detector: str = "auto") -> FaceDetection:
    """Detect the 68 iBUG landmarks of one face.

    Args:
        image: ``(H, W, 3)`` uint8 RGB.
        face: which face, 0-based in the largest-first order of :func:`detect_faces`; ``None`` (default)
            takes the largest.
        upsample, min_score, detector: passed to :func:`detect_faces` (``detector`` default ``"auto"``: the
            CNN runs only when HOG finds no face).

    Returns:
        The chosen :class:`FaceDetection`; ``landmarks`` is ``(68, 2)`` float64 0-based OpenCV pixels.

    Raises:
        DetectionError: ``face`` is out of range; :class:`NoFaceError` (a DetectionError): no face was found.
    """
    if face is not None and (isinstance(face, bool) or not isinstance(face, (int, np.integer))):
        raise DetectionError(f"detect_landmarks: face must be an integer index or None; got {face!r}")
    faces = detect_faces(image, upsample=upsample, min_score=min_score, detector=detector)
    if not faces:
        raise NoFaceError("no face found in the image; pass --landmarks FILE to give the 68 landmarks yourself")
    index = 0 if face is None else int(face)
    if not 0 <= index < len(faces):
        noun = "face" if len(faces) == 1 else "faces"
        raise DetectionError(f"found {len(faces)} {noun}; --face must be 0..{len(faces) - 1}, got {index}")
    return faces[index]
