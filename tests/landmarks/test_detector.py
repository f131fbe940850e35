"""The detector interface (:mod:`landmarks.detector`): the registry, the protocol, the fallback, and the front
(:func:`landmarks.detect.detect_faces`) with a fake detector; no dlib needed."""

import subprocess
import sys

import numpy as np
import pytest

from landmarks.detect import detect_faces, detect_landmarks
from landmarks.detector import (
    DEFAULT_DETECTOR,
    DetectionError,
    FaceDetection,
    FaceDetector,
    FallbackDetector,
    NoFaceError,
    check_detector_name,
    create_detector,
    detector_names,
    detector_summary,
    register_detector,
    unregister_detector,
)


def face_at(left: float, top: float, size: float, score: float = 1.0, name: str = "fake") -> FaceDetection:
    """A face with a square box and 68 landmarks spread over it."""
    t = np.linspace(0.0, 1.0, 68)
    points = np.stack([left + size * t, top + size * (1 - t)], axis=1)
    return FaceDetection(np.array([left, top, left + size, top + size]), score, points, name)


class Fake:
    """A detector that returns the faces it was given and records the images it saw."""

    description = "a fake detector"

    def __init__(self, faces=(), name="fake"):
        self.name = name
        self.faces = list(faces)
        self.seen = []

    def detect(self, image):
        self.seen.append(image.shape)
        return list(self.faces)


@pytest.fixture
def registered():
    """Registers ``fake`` (two faces, the smaller first) and ``empty`` (no face) for one test."""
    faces = [face_at(10, 10, 20, score=2.0), face_at(50, 5, 40, score=0.5)]
    register_detector("fake", lambda **options: Fake(faces, **options), summary="for tests")
    register_detector("empty", lambda: Fake(name="empty"))
    yield faces
    unregister_detector("fake")
    unregister_detector("empty")


class TestRegistry:
    def test_builtin_names(self):
        assert detector_names()[:5] == ("hog", "cnn", "dlib", "mediapipe", "auto") and DEFAULT_DETECTOR == "auto"
        assert "fast" in detector_summary("hog") and "hog finds no face" in detector_summary("dlib")
        assert "dlib only when mediapipe finds no face" in detector_summary("auto")

    def test_register_create_unregister(self, registered):
        assert detector_names()[-2:] == ("fake", "empty") and detector_summary("fake") == "for tests"
        detector = create_detector("fake", name="fake")
        assert isinstance(detector, Fake) and isinstance(detector, FaceDetector)
        assert check_detector_name("empty") == "empty"
        unregister_detector("empty")
        assert "empty" not in detector_names()
        register_detector("empty", lambda: Fake(name="empty"))  # for the fixture's clean-up

    def test_unknown_names_are_refused_with_the_list(self):
        with pytest.raises(
            DetectionError,
            match=r"create_detector: unknown face detector 'yolo'; the detectors are hog, cnn, dlib, mediapipe, auto",
        ):
            create_detector("yolo")
        with pytest.raises(DetectionError, match="fit_photo_file: unknown face detector 'HOG'"):
            check_detector_name("HOG", "fit_photo_file")
        with pytest.raises(DetectionError, match="unknown face detector None"):
            create_detector(None)
        with pytest.raises(DetectionError, match="unregister_detector: unknown face detector 'yolo'"):
            unregister_detector("yolo")

    def test_bad_registrations(self, registered):
        with pytest.raises(DetectionError, match="'fake' is registered already"):
            register_detector("fake", Fake)
        for name in ("", "Fake", "two words", "1st", None):
            with pytest.raises(DetectionError, match="name must be lower-case letters"):
                register_detector(name, Fake)
        with pytest.raises(DetectionError, match="factory must be callable"):
            register_detector("other", "landmarks.dlib_detector:HogDetector")
        register_detector("fake", lambda: Fake(name="fake"), replace=True)
        assert create_detector("fake").faces == []

    def test_a_factory_must_return_a_detector(self):
        register_detector("broken", lambda: object())
        try:
            with pytest.raises(DetectionError, match="returned object, which lacks the FaceDetector attributes"):
                create_detector("broken")
        finally:
            unregister_detector("broken")


class TestFront:
    def test_faces_sorted_largest_first(self, registered):
        faces = detect_faces(np.zeros((60, 100, 3), np.uint8), "fake")
        assert [f.box[0] for f in faces] == [50, 10] and faces[0].area == 1600.0
        assert detect_landmarks(np.zeros((60, 100, 3), np.uint8), face=1, detector="fake") is registered[0]

    def test_ties_by_score_then_position(self):
        faces = [face_at(30, 0, 10, 1.0), face_at(20, 0, 10, 1.0), face_at(40, 0, 10, 3.0)]
        got = detect_faces(np.zeros((20, 60, 3), np.uint8), Fake(faces))
        assert [f.box[0] for f in got] == [40, 20, 30]

    def test_image_is_checked_before_the_detector_runs(self):
        fake = Fake([face_at(0, 0, 5)])
        with pytest.raises(DetectionError, match=r"detect_faces: image must be an \(H, W, 3\) uint8"):
            detect_faces(np.zeros((5, 5, 3), np.float32), fake)
        assert fake.seen == []
        detect_faces(np.zeros((5, 7, 3), np.uint8)[:, ::2], fake)  # a strided view is made contiguous
        assert fake.seen == [(5, 4, 3)]

    def test_no_face(self, registered):
        assert detect_faces(np.zeros((8, 8, 3), np.uint8), "empty") == []
        with pytest.raises(NoFaceError, match="no face found"):
            detect_landmarks(np.zeros((8, 8, 3), np.uint8), detector="empty")

    def test_what_a_detector_returns_is_checked(self):
        bad = FaceDetection(np.zeros(4), 1.0, np.zeros((5, 2)), "bad")
        with pytest.raises(ValueError, match=r"landmarks shape \(5, 2\); expected \(4,\) and \(68, 2\)"):
            detect_faces(np.zeros((8, 8, 3), np.uint8), Fake([bad]))
        with pytest.raises(ValueError, match="must return a list of FaceDetection"):
            detect_faces(np.zeros((8, 8, 3), np.uint8), Fake([(0, 0, 1, 1)]))


class TestFallback:
    def test_the_first_detector_that_finds_a_face_wins(self):
        first, second = Fake(name="first"), Fake([face_at(0, 0, 5, name="second")], name="second")
        fallback = FallbackDetector("both", (first, second), "first, then second")
        assert isinstance(fallback, FaceDetector)
        (face,) = fallback.detect(np.zeros((8, 8, 3), np.uint8))
        assert face.detector == "second" and len(first.seen) == len(second.seen) == 1
        first.faces = [face_at(1, 1, 3, name="first")]
        assert [f.detector for f in fallback.detect(np.zeros((8, 8, 3), np.uint8))] == ["first"]
        assert len(second.seen) == 1  # not run when the first finds a face
        with pytest.raises(DetectionError, match="detectors must not be empty"):
            FallbackDetector("none", (), "")


def test_face_detection_is_frozen():
    face = face_at(0, 0, 4)
    with pytest.raises(AttributeError):
        face.score = 2.0
    assert FaceDetection(np.array([5, 5, 1, 9]), 0.0, face.landmarks, "x").area == 0.0  # an inverted box


def test_the_registry_and_jnr_fit_help_import_nothing_heavy():
    probe = (
        "import sys, landmarks.detector, pipeline.cli; pipeline.cli.build_parser(); "
        "print(sorted(m for m in ('numpy', 'torch', 'dlib', 'cv2', 'PIL') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"
