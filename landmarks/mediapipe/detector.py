"""MediaPipe's face detector, face mesh and iris models as a :class:`~landmarks.detector.FaceDetector`
(``"mediapipe"``).

Per image: the full-range face detector (by default; :data:`DETECTION_MODELS`) finds the faces
(:mod:`landmarks.mediapipe.detection`); per face the 468-point mesh runs on a crop turned upright by the
detector's eye keypoints, then once more on the crop MediaPipe's tracker would take from that mesh
(:func:`mesh_rect`); the iris model adds the 10 iris points (:mod:`landmarks.mediapipe.iris`); a fixed
table maps the mesh to the 68 iBUG landmarks (:mod:`landmarks.mediapipe.ibug68_map`). Each
:class:`~landmarks.detector.FaceDetection` carries ``dense``, the ``(478, 3)`` points in MediaPipe's
order, and ``roll_deg``. Models are loaded once, on the first detection; LiteRT runs on one thread by
default.

Why the full-range model by default: it finds small faces the short-range one, made for selfies, misses,
and on a close portrait both find the face and the 68 landmarks mapped from their meshes are about as
accurate (measured in ``docs/landmarks.md``, "MediaPipe's detector and its 68 points"). ``model="both"`` runs
both and merges their boxes (weighted NMS). The detector sees the whole image at 192 x 192: a smaller face
needs a crop, hence the overlapping squares of :func:`detection_tiles` on large images (the time each part
takes: ``docs/landmarks.md``, ``docs/fit_photo.md``).

Example::

    faces = MediaPipeDetector().detect(image)  # (H, W, 3) uint8 RGB -> [FaceDetection]
    faces[0].dense.shape, faces[0].landmarks.shape   # (478, 3), (68, 2)
"""

from __future__ import annotations

import dataclasses
import importlib.util
import logging
import math
import time

import numpy as np

from landmarks.detector import DetectionError, FaceDetection, FallbackDetector
from landmarks.images import check_image
from landmarks.mediapipe.anchors import DETECTOR_OPTIONS, DetectorOptions
from landmarks.mediapipe.crop import RotatedRect, square_rect
from landmarks.mediapipe.detection import BoxDetection, detect_boxes, weighted_nms
from landmarks.mediapipe.ibug68_map import mesh_to_ibug68
from landmarks.mediapipe.iris import EYE_CORNERS, add_irises
from landmarks.mediapipe.mesh import FACE_RECT_SCALE, FaceMesh, eye_line_angle, face_mesh, face_rect
from landmarks.mediapipe.models import INSTALL_RUNTIME, model_dir

_log = logging.getLogger(__name__)

DETECTION_MODELS = ("full", "short", "both")
"""The ``model`` choices: MediaPipe's full-range detector, its short-range one, or both merged."""
DEFAULT_MIN_PRESENCE = 0.5
"""Faces whose mesh model's face-presence score is lower are dropped (a detector box without a face)."""
RETRY_MIN_SCORE = 0.4
"""When no face passes MediaPipe's detector thresholds (0.6 full range, 0.5 short range), :meth:`MediaPipeDetector.
detect` looks once more at the boxes scoring down to this, each kept only when the mesh model confirms a face
(presence >= ``min_presence``). Synthetic renders of clear, frontal faces scored 0.50-0.57 with the full-range
detector and were lost (3 of 10 neutral validation photos, issue 37) while their meshes' presence was 1.0; on 17
scikit-image pictures without a face, the boxes scoring 0.3-0.54 all had presence 0.0."""
TRACKING_ROTATION_POINTS = (33, 133)
"""MediaPipe's tracking crop is turned by the line from mesh point 33 to 133 (the subject's right eye's
corners)."""


def mesh_rect(points: np.ndarray, scale: float = FACE_RECT_SCALE) -> RotatedRect:
    """The crop MediaPipe's tracker takes from a face's mesh for the next frame
    (``FaceLandmarkLandmarksToRoi``): the box of all mesh points grown to a square of 1.5 times its
    longer side, turned by the line from mesh point 33 to 133.

    Args:
        points: ``(468+, 2+)`` mesh points, pixels. scale: side over the box's longer side.

    Returns:
        :class:`~landmarks.mediapipe.crop.RotatedRect`.
    """
    xy = np.asarray(points, dtype=np.float64)[:468, :2]
    low, high = xy.min(axis=0), xy.max(axis=0)
    start, end = TRACKING_ROTATION_POINTS
    angle = eye_line_angle(xy[start], xy[end])
    return square_rect((low + high) / 2.0, high[0] - low[0], high[1] - low[1], angle, scale)


def roll_degrees(points: np.ndarray) -> float:
    """The face's roll: the angle of the line from the subject's right eye to the left eye (the means of
    each eye's two corner points, :data:`~landmarks.mediapipe.iris.EYE_CORNERS`), degrees in
    ``[-180, 180)``, image axes (y down: positive is clockwise on screen); 0 for an upright face.

    Args:
        points: ``(468+, 2+)`` mesh points, pixels.
    """
    xy = np.asarray(points, dtype=np.float64)[:, :2]
    right = xy[list(EYE_CORNERS["right"])].mean(axis=0)
    left = xy[list(EYE_CORNERS["left"])].mean(axis=0)
    return math.degrees(eye_line_angle(right, left))


def _check_number(value, name: str, low: float, high: float) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not low <= float(value) <= high
    ):
        raise DetectionError(f"MediaPipeDetector: {name} must be a number in [{low}, {high}]; got {value!r}")
    return float(value)


def _check_int(value, name: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
        raise DetectionError(f"MediaPipeDetector: {name} must be an integer in [{low}, {high}]; got {value!r}")
    return int(value)


class MediaPipeDetector:
    """MediaPipe's face detector, 468-point mesh and iris models on LiteRT (``"mediapipe"``); a
    :class:`~landmarks.detector.FaceDetector`.

    Args:
        model: the face detector: ``"full"`` (full range, default), ``"short"`` (short range, selfies)
            or ``"both"`` (:data:`DETECTION_MODELS`).
        min_score: detections scoring lower (in ``[0, 1]``) are dropped; ``None``: MediaPipe's thresholds
            (0.6 full range, 0.5 short range).
        min_presence: faces whose mesh scores a lower face presence are dropped (:data:`DEFAULT_MIN_PRESENCE`).
        mesh_passes: 1: the mesh on the detection's crop only; 2 (default): once more on the crop taken
            from that mesh (:func:`mesh_rect`), better centred and turned.
        refine_eyes: let the iris model's eye contours replace the mesh's eye and brow points.
        num_threads: LiteRT's CPU threads per model (1-16).
        tiles: also search overlapping squares of a large or wide image for faces too small in the whole
            image (:func:`detection_tiles`; default True).

    Raises:
        DetectionError: a bad option.
    """

    name = "mediapipe"
    description = "MediaPipe's face detector, face mesh and iris models"

    def __init__(
        self,
        model: str = "full",
        min_score: float | None = None,
        min_presence: float = DEFAULT_MIN_PRESENCE,
        mesh_passes: int = 2,
        refine_eyes: bool = True,
        num_threads: int = 1,
        tiles: bool = True,
    ):
        if model not in DETECTION_MODELS:
            raise DetectionError(
                f"MediaPipeDetector: model must be one of {', '.join(DETECTION_MODELS)}; got {model!r}"
            )
        self.model = model
        self.min_score = None if min_score is None else _check_number(min_score, "min_score", 0.0, 1.0)
        self.min_presence = _check_number(min_presence, "min_presence", 0.0, 1.0)
        self.mesh_passes = _check_int(mesh_passes, "mesh_passes", 1, 2)
        self.refine_eyes = bool(refine_eyes)
        self.num_threads = _check_int(num_threads, "num_threads", 1, 16)
        self.tiles = bool(tiles)
        self.last_timings_ms: dict[str, float] = {}
        """Milliseconds of each stage of the last :meth:`detect` (``detection``, ``mesh``, ``iris``,
        summed over its faces)."""

    def _options(self) -> list[DetectorOptions]:
        names = ("full", "short") if self.model == "both" else (self.model,)
        options = [DETECTOR_OPTIONS[n] for n in names]
        if self.min_score is not None:
            options = [dataclasses.replace(o, min_score=self.min_score) for o in options]
        return options

    def detect_boxes(self, image: np.ndarray, min_score: float | None = None) -> list[BoxDetection]:
        """The face detector's boxes and 6 keypoints, best first (no mesh), pixels; ``min_score``: this threshold
        instead of the detector's.

        Raises:
            DetectionError: a bad image, or the runtime or a model file is missing.
        """
        image = check_image(image, "MediaPipeDetector.detect_boxes")
        options = self._options()
        if min_score is not None:
            options = [
                dataclasses.replace(o, min_score=_check_number(min_score, "min_score", 0.0, 1.0)) for o in options
            ]
        found = []
        for o in options:
            tiles = detection_tiles(*image.shape[:2], o.anchors.input_size) if self.tiles else [(0, 0, 0)]
            for left, top, side in tiles:
                tile = image if side == 0 else np.ascontiguousarray(image[top : top + side, left : left + side])
                shift = np.array([left, top], dtype=np.float64)
                for face in detect_boxes(tile, o, self.num_threads):
                    box = np.asarray(face.box, np.float64) + np.tile(shift, 2)
                    found.append(BoxDetection(box, np.asarray(face.keypoints, np.float64) + shift, face.score))
        if len(found) < 2:
            return found
        boxes = np.array([f.box for f in found])
        merged = weighted_nms(
            boxes, np.array([f.keypoints for f in found]), np.array([f.score for f in found]), options[0].nms_iou
        )
        return [BoxDetection(box, points, score) for box, points, score in merged]

    def mesh(self, image: np.ndarray, face: BoxDetection) -> FaceMesh:
        """The 468-point mesh of one detected face (``mesh_passes`` crops), pixels.

        Raises:
            DetectionError: the runtime or the model file is missing.
        """
        mesh = face_mesh(image, face_rect(face.box, face.keypoints), self.num_threads)
        if self.mesh_passes == 2 and mesh.presence >= self.min_presence:
            mesh = face_mesh(image, mesh_rect(mesh.points), self.num_threads)
        return mesh

    def detect(self, image: np.ndarray) -> list[FaceDetection]:
        """Every face the detector finds whose mesh confirms it, with its 68 landmarks, its ``(478, 3)``
        ``dense`` points and ``roll_deg``, best detector score first. When none is found with MediaPipe's
        thresholds (and ``min_score`` was not given), the boxes scoring down to :data:`RETRY_MIN_SCORE` are
        tried, each kept only when its mesh confirms a face.

        Raises:
            DetectionError: a bad image, or the runtime or a model file is missing.
        """
        image = check_image(image, "MediaPipeDetector.detect")
        timings = {"detection": 0.0, "mesh": 0.0, "iris": 0.0}
        start = time.perf_counter()
        boxes = self.detect_boxes(image)
        timings["detection"] = 1e3 * (time.perf_counter() - start)
        faces = self._confirmed(image, boxes, timings)
        if not faces and self.min_score is None:
            start = time.perf_counter()
            weak = self.detect_boxes(image, RETRY_MIN_SCORE)  # those that passed are rejected again, cheaply
            timings["detection"] += 1e3 * (time.perf_counter() - start)
            faces = self._confirmed(image, weak, timings)
            if faces:
                _log.info(
                    "MediaPipe: face found at detector score %.2f (below its threshold), confirmed by the mesh",
                    faces[0].score,
                )
        self.last_timings_ms = timings
        return faces

    def _confirmed(self, image: np.ndarray, boxes: list[BoxDetection], timings: dict) -> list[FaceDetection]:
        """The faces of ``boxes`` whose mesh confirms them (presence >= ``min_presence``), one per face."""
        faces, meshes = [], []
        for box in boxes:
            start = time.perf_counter()
            mesh = self.mesh(image, box)
            timings["mesh"] += 1e3 * (time.perf_counter() - start)
            if mesh.presence < self.min_presence:
                continue
            # a face seen whole and in part (the image and a tile) ends on one mesh: keep the first, best box
            extent = np.r_[mesh.points[:, :2].min(0), mesh.points[:, :2].max(0)]
            if any(_overlap(extent, other) > DUPLICATE_IOU for other in meshes):
                continue
            meshes.append(extent)
            start = time.perf_counter()
            dense, _ = add_irises(image, mesh.points, self.refine_eyes, self.num_threads)
            timings["iris"] += 1e3 * (time.perf_counter() - start)
            landmarks = mesh_to_ibug68(dense[:, :2])
            box_pixels = np.array(box.box, dtype=np.float64)
            for array in (dense, landmarks, box_pixels):
                array.flags.writeable = False
            faces.append(
                FaceDetection(
                    box=box_pixels,
                    score=float(box.score),
                    landmarks=landmarks,
                    detector=self.name,
                    dense=dense,
                    roll_deg=roll_degrees(dense),
                )
            )
        return faces

    def __repr__(self) -> str:
        return (
            f"MediaPipeDetector(model={self.model!r}, min_score={self.min_score}, min_presence={self.min_presence}, "
            f"mesh_passes={self.mesh_passes}, refine_eyes={self.refine_eyes}, num_threads={self.num_threads}, "
            f"tiles={self.tiles})"
        )


DUPLICATE_IOU = 0.5
"""Two faces whose meshes' boxes overlap by more than this (intersection over union) are one face."""


def detection_tiles(height: int, width: int, input_size: int) -> list[tuple[int, int, int]]:
    """Where the face detector looks: ``(left, top, side)`` squares of the image, the first ``(0, 0, 0)`` the
    whole image (letterboxed to the detector's ``input_size``).

    The detector sees the whole image at ``input_size`` pixels, so a small face in a large or wide image
    shrinks below what it finds (about 15 px of its input). When the longer side exceeds twice
    ``input_size``, overlapping squares of side ``min(shorter side, max(2 * input_size, longer side / 2))``
    (half a side apart, covering the image) are searched too: a 448 x 256 image adds two 256-px squares
    (faces 1.75x larger to the detector), a 1920 x 1080 photo six 960-px ones (2x). Their boxes are merged
    with the whole image's by weighted non-maximum suppression, and faces that end on the same mesh are
    kept once (:data:`DUPLICATE_IOU`).
    """
    tiles = [(0, 0, 0)]
    longer, shorter = max(height, width), min(height, width)
    if longer <= 2 * input_size:
        return tiles
    side = int(min(shorter, max(2 * input_size, longer // 2)))

    def starts(extent: int) -> list[int]:
        if extent <= side:
            return [0]
        count = math.ceil((extent - side) / (side / 2)) + 1
        return [round(i * (extent - side) / (count - 1)) for i in range(count)]

    tiles += [(left, top, side) for top in starts(height) for left in starts(width)]
    return tiles


def _overlap(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two ``[left, top, right, bottom]`` boxes."""
    inter = max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


def auto_detector() -> FallbackDetector:
    """``"auto"``, ``jnr fit``'s default: :class:`MediaPipeDetector`, and dlib's detectors (HOG, then the CNN:
    :func:`landmarks.dlib_detector.dlib_detector`) only when it finds no face. MediaPipe first because on
    the synthetic validation and benchmark photos its 478 points fit better than dlib's 68 and it found more
    faces (docs/fit_photo.md, "Dense landmarks"). Without LiteRT or MediaPipe's model files ``auto`` refuses in
    one line saying what to install (or to pass ``--detector dlib``): it never switches to another detector
    silently (issue 38), since the fit's accuracy depends on which points it gets.

    Raises:
        DetectionError: LiteRT or the model files are missing."""
    from landmarks.dlib_detector import dlib_detector

    if importlib.util.find_spec("ai_edge_litert") is None:
        raise DetectionError(f"--detector auto needs MediaPipe's runtime: {INSTALL_RUNTIME}; or pass --detector dlib")
    try:
        model_dir()
    except DetectionError as exc:
        raise DetectionError(f"--detector auto: {exc}; or pass --detector dlib") from None
    dlib = dlib_detector()
    return FallbackDetector(
        "auto", (MediaPipeDetector(), *dlib.detectors), "MediaPipe's models, then dlib's HOG and CNN detectors"
    )


__all__ = [
    "DEFAULT_MIN_PRESENCE",
    "DETECTION_MODELS",
    "DUPLICATE_IOU",
    "TRACKING_ROTATION_POINTS",
    "MediaPipeDetector",
    "auto_detector",
    "detection_tiles",
    "mesh_rect",
    "roll_degrees",
]
