"""Face and 68-landmark detection on a real portrait (skimage's astronaut) with dlib's detectors, through the
detector interface (:mod:`landmarks.detector`): by name, and as the classes of :mod:`landmarks.dlib_detector`."""

import numpy as np
import pytest

dlib = pytest.importorskip("dlib")
skimage_data = pytest.importorskip("skimage.data")

from PIL import Image

from landmarks.detect import detect_faces, detect_landmarks
from landmarks.detector import DetectionError, FaceDetection, FaceDetector, NoFaceError, create_detector
from landmarks.dlib_detector import (
    CNN_MIN_CONFIDENCE,
    DEFAULT_MIN_SCORE,
    CnnDetector,
    HogDetector,
    dlib_detector,
    shape_predictor_path,
)
from landmarks.ibug68.names import IBUG68_MIRROR
from landmarks.images import load_image

RIGHT_EYE = slice(36, 42)  # the subject's right eye: image left for a face towards the camera
LEFT_EYE = slice(42, 48)
MOUTH = slice(48, 68)
NOSE_TIP = 30
CHIN = 8


@pytest.fixture(scope="module")
def astronaut() -> np.ndarray:
    return np.ascontiguousarray(skimage_data.astronaut())  # (512, 512, 3) uint8 RGB


@pytest.fixture(scope="module")
def astronaut_face(astronaut) -> FaceDetection:
    return detect_landmarks(astronaut, detector="dlib")


def _grown_box(box: np.ndarray, factor: float) -> np.ndarray:
    left, top, right, bottom = box
    cx, cy, half_w, half_h = (left + right) / 2, (top + bottom) / 2, (right - left) / 2, (bottom - top) / 2
    return np.array([cx - factor * half_w, cy - factor * half_h, cx + factor * half_w, cy + factor * half_h])


class TestSmoke:
    def test_predictor_file_exists(self):
        path = shape_predictor_path()
        assert path.is_file() and path.name == "shape_predictor_68_face_landmarks.dat"

    def test_types_and_shapes(self, astronaut_face):
        assert isinstance(astronaut_face, FaceDetection)
        assert astronaut_face.box.shape == (4,) and astronaut_face.box.dtype == np.float64
        assert astronaut_face.landmarks.shape == (68, 2) and astronaut_face.landmarks.dtype == np.float64
        assert isinstance(astronaut_face.score, float)

    def test_deterministic(self, astronaut, astronaut_face):
        again = detect_landmarks(astronaut, detector="dlib")
        np.testing.assert_array_equal(again.landmarks, astronaut_face.landmarks)
        np.testing.assert_array_equal(again.box, astronaut_face.box)


class TestAstronaut:
    def test_exactly_one_face(self, astronaut):
        faces = detect_faces(astronaut, detector="dlib")
        assert len(faces) == 1

    def test_landmarks_inside_image_and_face_box(self, astronaut, astronaut_face):
        h, w = astronaut.shape[:2]
        pts = astronaut_face.landmarks
        assert np.all(pts >= 0) and np.all(pts[:, 0] <= w - 1) and np.all(pts[:, 1] <= h - 1)
        left, top, right, bottom = _grown_box(astronaut_face.box, 1.5)
        assert np.all((pts[:, 0] >= left) & (pts[:, 0] <= right) & (pts[:, 1] >= top) & (pts[:, 1] <= bottom))

    def test_anatomical_order(self, astronaut_face):
        pts = astronaut_face.landmarks
        eyes_y = max(pts[RIGHT_EYE, 1].mean(), pts[LEFT_EYE, 1].mean())
        assert eyes_y < pts[NOSE_TIP, 1] < pts[MOUTH, 1].mean() < pts[CHIN, 1]
        assert pts[RIGHT_EYE, 0].max() < pts[LEFT_EYE, 0].min()
        assert np.all(np.diff(pts[0:17, 0]) > 0)

    def test_inter_ocular_distance(self, astronaut_face):
        pts = astronaut_face.landmarks
        iod = np.linalg.norm(pts[RIGHT_EYE].mean(0) - pts[LEFT_EYE].mean(0))
        assert 40 <= iod <= 200

    def test_mirrored_image_mirrors_landmarks(self, astronaut, astronaut_face):
        w = astronaut.shape[1]
        mirrored = detect_landmarks(np.ascontiguousarray(astronaut[:, ::-1]), detector="dlib")
        back = mirrored.landmarks[list(IBUG68_MIRROR)].copy()
        back[:, 0] = (w - 1) - back[:, 0]
        error = np.linalg.norm(back - astronaut_face.landmarks, axis=1)
        assert error.mean() < 3.0, error


@pytest.fixture(scope="module")
def two_faces(astronaut) -> np.ndarray:
    """The astronaut (512x512) with a half-size copy on its right, padded grey to the same height."""
    h, w = astronaut.shape[:2]
    small = np.asarray(Image.fromarray(astronaut).resize((w // 2, h // 2), Image.BILINEAR))
    small = np.pad(small, ((0, h - small.shape[0]), (0, 0), (0, 0)), constant_values=128)
    return np.ascontiguousarray(np.concatenate([astronaut, small], axis=1))


class TestSeveralFaces:
    def test_two_faces_largest_first(self, two_faces, astronaut):
        faces = detect_faces(two_faces, detector="dlib")
        assert len(faces) == 2
        assert faces[0].area > faces[1].area
        w = astronaut.shape[1]
        assert faces[0].landmarks[:, 0].max() < w <= faces[1].landmarks[:, 0].min()

    def test_face_index(self, two_faces):
        faces = detect_faces(two_faces, detector="dlib")
        np.testing.assert_array_equal(detect_landmarks(two_faces, detector="dlib").landmarks, faces[0].landmarks)
        np.testing.assert_array_equal(
            detect_landmarks(two_faces, face=1, detector="dlib").landmarks, faces[1].landmarks
        )

    def test_face_index_out_of_range(self, two_faces):
        with pytest.raises(DetectionError, match=r"found 2 faces; --face must be 0\.\.1"):
            detect_landmarks(two_faces, face=2, detector="dlib")
        with pytest.raises(DetectionError, match=r"0\.\.1"):
            detect_landmarks(two_faces, face=-1, detector="dlib")


@pytest.fixture(scope="module")
def tilted(astronaut):
    """The portrait rotated 45 degrees counter-clockwise: HOG finds nothing in it."""
    return np.asarray(Image.fromarray(astronaut).rotate(45, resample=Image.BILINEAR))


class TestDetectors:
    """dlib's CNN (MMOD) detector, on request or when HOG finds nothing (``detector="dlib"``)."""

    @pytest.mark.slow  # 6 s of the fast suite's 6 minutes: CI's make test-slow runs it
    def test_cnn_finds_the_upright_face_where_hog_does(self, astronaut, astronaut_face):
        (face,) = detect_faces(astronaut, detector="cnn")
        assert face.detector == "cnn" and face.score >= CNN_MIN_CONFIDENCE
        a, b = face.box, astronaut_face.box
        inter = max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
        assert inter / (face.area + astronaut_face.area - inter) > 0.5  # the same face
        assert np.abs(face.landmarks - astronaut_face.landmarks).mean() < 5.0

    @pytest.mark.slow  # 6 s of the fast suite's 6 minutes: CI's make test-slow runs it
    def test_dlib_falls_back_to_the_cnn_when_hog_finds_nothing(self, astronaut, astronaut_face, tilted):
        assert detect_faces(tilted, detector="hog") == []
        face = detect_landmarks(tilted, detector="dlib")
        assert face.detector == "cnn"
        # where the upright face's landmarks go under the same 45 degree rotation about the image centre
        h, w = astronaut.shape[:2]
        c = np.array([(w - 1) / 2, (h - 1) / 2])
        t = np.deg2rad(45.0)
        rot = np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])  # counter-clockwise on screen (y down)
        expected = (astronaut_face.landmarks - c) @ rot.T + c
        assert np.linalg.norm(face.landmarks - expected, axis=1).mean() < 8.0
        assert detect_landmarks(astronaut, detector="dlib").detector == "hog"  # HOG finds it: the CNN is not run

    def test_unknown_detector(self, astronaut):
        with pytest.raises(DetectionError, match="unknown face detector 'yolo'; the detectors are hog, cnn, dlib, "):
            detect_faces(astronaut, detector="yolo")


class TestInterface:
    """dlib's detectors as :class:`~landmarks.detector.FaceDetector` classes: the registry makes them, and
    :func:`detect_faces` by name gives what the class gives, sorted."""

    def test_the_registry_makes_the_dlib_classes(self):
        hog, cnn, dlib, auto = (create_detector(name) for name in ("hog", "cnn", "dlib", "auto"))
        assert isinstance(hog, HogDetector) and isinstance(cnn, CnnDetector)
        assert all(isinstance(d, FaceDetector) for d in (hog, cnn, dlib, auto))
        assert (hog.name, cnn.name, dlib.name, auto.name) == ("hog", "cnn", "dlib", "auto")
        assert [d.name for d in dlib.detectors] == ["hog", "cnn"]
        assert [d.name for d in auto.detectors] == ["mediapipe", "hog", "cnn"]  # LiteRT installed
        assert (hog.upsample, hog.min_score, cnn.min_confidence) == (1, DEFAULT_MIN_SCORE, CNN_MIN_CONFIDENCE)
        assert create_detector("hog", upsample=2, min_score=0.0).min_score == 0.0

    def test_by_name_equals_by_class(self, two_faces, astronaut_face):
        by_class = sorted(HogDetector().detect(two_faces), key=lambda f: -f.area)
        by_name = detect_faces(two_faces, "hog")
        assert len(by_name) == len(by_class) == 2
        for a, b in zip(by_name, by_class):
            np.testing.assert_array_equal(a.landmarks, b.landmarks)
            np.testing.assert_array_equal(a.box, b.box)
            assert a.score == b.score and a.detector == b.detector == "hog"
        (given,) = detect_faces(two_faces[:, :512], HogDetector())  # an instance instead of a name
        np.testing.assert_array_equal(given.landmarks, astronaut_face.landmarks)

    def test_dlib_is_hog_where_hog_finds_a_face(self, astronaut, astronaut_face):
        (face,) = dlib_detector().detect(astronaut)
        assert face.detector == "hog"
        np.testing.assert_array_equal(face.landmarks, astronaut_face.landmarks)
        assert astronaut_face.landmarks.flags.writeable is False and astronaut_face.box.flags.writeable is False

    def test_bad_options(self, astronaut):
        with pytest.raises(DetectionError, match="HogDetector: upsample must be an integer >= 0; got 1.5"):
            create_detector("hog", upsample=1.5)
        with pytest.raises(DetectionError, match="CnnDetector: min_confidence must be a finite number"):
            CnnDetector(min_confidence=float("nan"))
        with pytest.raises(TypeError):
            create_detector("cnn", min_score=0.0)  # the CNN's threshold is min_confidence
        with pytest.raises(DetectionError, match="apply to a detector given by name"):
            detect_faces(astronaut, HogDetector(), upsample=0)
        with pytest.raises(DetectionError, match=r"HogDetector.detect: image must be .*got shape \(4, 4\)"):
            HogDetector().detect(np.zeros((4, 4), np.uint8))


class TestExceptions:
    def test_no_face(self):
        grey = np.full((200, 200, 3), 128, np.uint8)
        assert detect_faces(grey, detector="dlib") == []
        with pytest.raises(NoFaceError, match="no face found"):
            detect_landmarks(grey, detector="dlib")

    @pytest.mark.parametrize(
        "image",
        [
            np.zeros((10, 10), np.uint8),
            np.zeros((10, 10, 3), np.float32),
            np.zeros((10, 10, 4), np.uint8),
            np.zeros((0, 10, 3), np.uint8),
        ],
    )
    def test_bad_image(self, image):
        with pytest.raises(DetectionError, match=r"detect_faces: image .*got shape"):
            detect_faces(image, detector="dlib")

    def test_bad_arguments(self):
        grey = np.full((20, 20, 3), 128, np.uint8)
        with pytest.raises(DetectionError, match="upsample"):
            detect_faces(grey, upsample=-1, detector="dlib")
        with pytest.raises(DetectionError, match="min_score"):
            detect_faces(grey, min_score=float("inf"), detector="dlib")
        with pytest.raises(DetectionError, match="face must be"):
            detect_landmarks(grey, face="0", detector="dlib")


class TestLoadedImage:
    def test_loaded_portrait_detects(self, tmp_path, astronaut, astronaut_face):
        path = tmp_path / "astronaut.png"
        Image.fromarray(astronaut).save(path)
        np.testing.assert_array_equal(
            detect_landmarks(load_image(path), detector="dlib").landmarks, astronaut_face.landmarks
        )
