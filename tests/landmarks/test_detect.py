"""Face and 68-landmark detection on a real portrait (skimage's astronaut) with dlib."""

import numpy as np
import pytest

dlib = pytest.importorskip("dlib")
skimage_data = pytest.importorskip("skimage.data")

from PIL import Image

from landmarks.detect import (
    CNN_MIN_CONFIDENCE,
    DetectionError,
    FaceDetection,
    detect_faces,
    detect_landmarks,
    load_image,
    shape_predictor_path,
)

try:
    from landmarks.ibug68 import IBUG68_MIRROR
except ImportError:  # ibug68 needs torch; the permutation is standard iBUG-68
    IBUG68_MIRROR = tuple(
        [16 - i for i in range(17)] + [26 - i for i in range(5)] + [21 - i for i in range(5)]
        + [27, 28, 29, 30] + [35, 34, 33, 32, 31]
        + [45, 44, 43, 42, 47, 46] + [39, 38, 37, 36, 41, 40]
        + [54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55]
        + [64, 63, 62, 61, 60, 67, 66, 65]
    )

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
    return detect_landmarks(astronaut)


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
        again = detect_landmarks(astronaut)
        np.testing.assert_array_equal(again.landmarks, astronaut_face.landmarks)
        np.testing.assert_array_equal(again.box, astronaut_face.box)


class TestAstronaut:
    def test_exactly_one_face(self, astronaut):
        faces = detect_faces(astronaut)
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
        mirrored = detect_landmarks(np.ascontiguousarray(astronaut[:, ::-1]))
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
        faces = detect_faces(two_faces)
        assert len(faces) == 2
        assert faces[0].area > faces[1].area
        w = astronaut.shape[1]
        assert faces[0].landmarks[:, 0].max() < w <= faces[1].landmarks[:, 0].min()

    def test_face_index(self, two_faces):
        faces = detect_faces(two_faces)
        np.testing.assert_array_equal(detect_landmarks(two_faces).landmarks, faces[0].landmarks)
        np.testing.assert_array_equal(detect_landmarks(two_faces, face=1).landmarks, faces[1].landmarks)

    def test_face_index_out_of_range(self, two_faces):
        with pytest.raises(DetectionError, match=r"found 2 faces; --face must be 0\.\.1"):
            detect_landmarks(two_faces, face=2)
        with pytest.raises(DetectionError, match=r"0\.\.1"):
            detect_landmarks(two_faces, face=-1)


@pytest.fixture(scope="module")
def tilted(astronaut):
    """The portrait rotated 45 degrees counter-clockwise: HOG finds nothing in it."""
    return np.asarray(Image.fromarray(astronaut).rotate(45, resample=Image.BILINEAR))


class TestDetectors:
    """dlib's CNN (MMOD) detector, on request or when HOG finds nothing (``detector="auto"``)."""

    def test_cnn_finds_the_upright_face_where_hog_does(self, astronaut, astronaut_face):
        (face,) = detect_faces(astronaut, detector="cnn")
        assert face.detector == "cnn" and face.score >= CNN_MIN_CONFIDENCE
        a, b = face.box, astronaut_face.box
        inter = max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
        assert inter / (face.area + astronaut_face.area - inter) > 0.5  # the same face
        assert np.abs(face.landmarks - astronaut_face.landmarks).mean() < 5.0

    def test_auto_falls_back_to_the_cnn_when_hog_finds_nothing(self, astronaut, astronaut_face, tilted):
        assert detect_faces(tilted, detector="hog") == []
        face = detect_landmarks(tilted)  # auto, the default
        assert face.detector == "cnn"
        # where the upright face's landmarks go under the same 45 degree rotation about the image centre
        h, w = astronaut.shape[:2]
        c = np.array([(w - 1) / 2, (h - 1) / 2])
        t = np.deg2rad(45.0)
        rot = np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])  # counter-clockwise on screen (y down)
        expected = (astronaut_face.landmarks - c) @ rot.T + c
        assert np.linalg.norm(face.landmarks - expected, axis=1).mean() < 8.0
        assert detect_landmarks(astronaut).detector == "hog"  # HOG finds it: the CNN is not run

    def test_unknown_detector(self, astronaut):
        with pytest.raises(DetectionError, match="detector must be one of"):
            detect_faces(astronaut, detector="yolo")


class TestExceptions:
    def test_no_face(self):
        grey = np.full((200, 200, 3), 128, np.uint8)
        assert detect_faces(grey) == []
        with pytest.raises(DetectionError, match="no face found"):
            detect_landmarks(grey)

    @pytest.mark.parametrize("image", [np.zeros((10, 10), np.uint8), np.zeros((10, 10, 3), np.float32),
                                       np.zeros((10, 10, 4), np.uint8), np.zeros((0, 10, 3), np.uint8)])
    def test_bad_image(self, image):
        with pytest.raises(DetectionError, match=r"detect_faces: image .*got shape"):
            detect_faces(image)

    def test_bad_arguments(self):
        grey = np.full((20, 20, 3), 128, np.uint8)
        with pytest.raises(DetectionError, match="upsample"):
            detect_faces(grey, upsample=-1)
        with pytest.raises(DetectionError, match="face must be"):
            detect_landmarks(grey, face="0")

    def test_missing_file(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="nope.png"):
            load_image(tmp_path / "nope.png")

    def test_corrupt_file(self, tmp_path):
        path = tmp_path / "corrupt.png"
        path.write_bytes(np.random.default_rng(0).integers(0, 256, 1000, dtype=np.uint8).tobytes())
        with pytest.raises(DetectionError, match="corrupt.png"):
            load_image(path)


class TestLoadImage:
    @pytest.mark.parametrize("mode", ["L", "RGBA", "RGB", "P"])
    def test_modes_load_as_rgb(self, tmp_path, astronaut, mode):
        path = tmp_path / f"img_{mode}.png"
        Image.fromarray(astronaut[:40, :60]).convert(mode).save(path)
        image = load_image(path)
        assert image.shape == (40, 60, 3) and image.dtype == np.uint8
        if mode == "RGB":
            np.testing.assert_array_equal(image, astronaut[:40, :60])

    def test_exif_orientation_applied(self, tmp_path, astronaut):
        path = tmp_path / "rotated.jpg"
        exif = Image.Exif()
        exif[0x0112] = 6  # stored sideways: the viewer rotates 90 degrees clockwise
        Image.fromarray(astronaut[:40, :60]).save(path, exif=exif)
        assert load_image(path).shape == (60, 40, 3)

    def test_loaded_portrait_detects(self, tmp_path, astronaut, astronaut_face):
        path = tmp_path / "astronaut.png"
        Image.fromarray(astronaut).save(path)
        np.testing.assert_array_equal(detect_landmarks(load_image(path)).landmarks, astronaut_face.landmarks)
