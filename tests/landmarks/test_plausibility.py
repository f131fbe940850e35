"""Plausibility of 2D landmarks: synthetic views of the rig accepted, garbage rejected with its reason."""

import dataclasses

import numpy as np
import pytest
import torch

from landmarks.ibug68.contour import contour_landmarks
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.names import IBUG68_MIRROR
from landmarks.ibug68.positions import landmark_positions
from landmarks.plausibility import (
    INNER_LANDMARKS,
    MAX_AFFINE_RESIDUAL,
    MIN_SPREAD_RATIO,
    LandmarkPlausibilityError,
    PlausibilityReport,
    check_landmarks_2d,
    face_affine_fit,
    fit_affine_camera,
    reference_landmarks,
)
from pipeline.camera import RIG_TO_OPENCV, camera_center_in_rig
from pipeline.synthetic.population import population_split
from rig.expressions import (
    EXPRESSION_NAMES,
    ExpressionModel,
    coefficients_from_dict,
    expression_limits,
)
from rig.geometry import head_rotation

W = H = 640
MIRROR = list(IBUG68_MIRROR)
MARGIN = 1.5
"""Required factor between the threshold and the worst accepted pose (and the best rejected negative)."""


class Views:
    """Synthetic 2D landmarks of rig heads: static embedding for 17-67, the silhouette for the jaw contour
    (as :func:`pipeline.synthetic.photos.simulate.simulate_photo`), Gaussian pixel noise."""

    def __init__(self, asset):
        self.asset = asset
        self.embedding = ibug68_embedding(asset)
        rest = landmark_positions(asset.vertices, self.embedding, asset.faces)[0]
        self.interocular_mm = float(np.linalg.norm(rest[45] - rest[36]))
        self.expressions = ExpressionModel(asset, dtype=torch.float64)

    def expressive(self, head: np.ndarray, coefficients) -> np.ndarray:
        c = torch.as_tensor(np.asarray(coefficients, np.float64))[None]
        return head + self.expressions(c)[0].numpy()

    def project(
        self,
        vertices,
        yaw=0.0,
        pitch=0.0,
        roll=0.0,
        distance_mm=None,
        *,
        interocular_px=100.0,
        noise_px=0.0,
        rng=None,
        centre=(W / 2, H / 2),
    ) -> np.ndarray:
        """``(68, 2)`` pixels; ``distance_mm=None`` is orthographic. The frontal inter-ocular distance is
        ``interocular_px`` at the face centre's depth."""
        lm = landmark_positions(vertices, self.embedding, self.asset.faces)[0]
        rotation = head_rotation(yaw, pitch, roll)
        to_cam = RIG_TO_OPENCV @ rotation
        c = to_cam @ lm.mean(axis=0)
        translation = np.array([-c[0], -c[1], 1e6 if distance_mm is None else distance_mm])
        eye = camera_center_in_rig(rotation, translation)
        lm[:17] = contour_landmarks(torch.as_tensor(vertices), self.asset.faces, eye, self.asset).numpy()
        cam = lm @ to_cam.T + translation
        focal = translation[2] * interocular_px / self.interocular_mm
        pts = focal * cam[:, :2] / cam[:, 2:] + np.asarray(centre)
        if noise_px:
            pts = pts + rng.normal(0.0, noise_px, pts.shape)
        return pts


@pytest.fixture(scope="module")
def views(asset):
    return Views(asset)


@pytest.fixture(scope="module")
def sampled(views, asset):
    """400 random views (the sampling of :data:`landmarks.plausibility.MAX_AFFINE_RESIDUAL`, smaller)."""
    rng = np.random.default_rng(20240611)
    heads = population_split("heldout", 0).vertices
    low, high = (t.numpy() for t in expression_limits(torch.float64))
    jaw = EXPRESSION_NAMES.index("jawOpen")
    out = []
    for k in range(400):
        head = heads[rng.integers(len(heads))] if k % 2 else asset.vertices
        c = np.zeros(len(EXPRESSION_NAMES))
        if k % 3 == 1:
            c[jaw] = rng.uniform(0.0, 1.0)
        elif k % 3 == 2:
            c = np.where(rng.random(len(c)) < 0.3, rng.uniform(low, high), 0.0)
        pose = rng.uniform([-60, -30, -180], [60, 30, 180])
        distance = None if rng.random() < 0.4 else rng.uniform(250.0, 2000.0)
        out.append(views.project(views.expressive(head, c), *pose, distance, noise_px=2.0, rng=rng))
    return out


@pytest.fixture(scope="module")
def frontal(views, asset):
    return views.project(asset.vertices)


def _rejected(points, fragment, width=W, height=H):
    with pytest.raises(LandmarkPlausibilityError, match=fragment) as info:
        check_landmarks_2d(points, width, height, source="face.pts")
    message = str(info.value)
    assert message.startswith("face.pts: ") and "\n" not in message
    return message


class TestSmoke:
    def test_report(self, frontal):
        report = check_landmarks_2d(frontal, W, H)
        assert isinstance(report, PlausibilityReport)
        assert report.determinant_sign == 1 and report.fraction_inside == 1.0
        assert report.view_cosine == pytest.approx(1.0, abs=0.01)
        assert report.interocular_px == pytest.approx(100.0, rel=0.05)
        assert 0.0 <= report.affine_residual < 0.03 and report.face_size_px > 2 * report.interocular_px
        with pytest.raises(dataclasses.FrozenInstanceError):
            report.affine_residual = 0.0

    def test_error_is_value_error(self):
        assert issubclass(LandmarkPlausibilityError, ValueError)

    def test_reference(self):
        ref = reference_landmarks()
        assert ref.shape == (68, 3) and not ref.flags.writeable
        assert reference_landmarks() is ref  # computed once
        np.testing.assert_allclose(np.sqrt((ref[:, :2] ** 2).sum(1).mean()), 1.0)
        # the subject's left eye on the image right, the chin down, the nose tip nearer than the ears
        assert ref[45, 0] > ref[36, 0] and ref[8, 1] > ref[27, 1] and ref[30, 2] < ref[0, 2]
        assert len(INNER_LANDMARKS) == 51

    def test_fit_affine_camera_recovers_a_known_map(self):
        rng = np.random.default_rng(0)
        ref = reference_landmarks()
        a, t = rng.normal(size=(2, 3)), rng.normal(size=2)
        fitted, shift, residuals = fit_affine_camera(ref, ref @ a.T + t)
        np.testing.assert_allclose(fitted, a, atol=1e-10)
        np.testing.assert_allclose(shift, t, atol=1e-10)
        assert np.abs(residuals).max() < 1e-10
        with pytest.raises(ValueError, match="fit_affine_camera"):
            fit_affine_camera(ref, ref)


class TestExceptions:
    @pytest.mark.parametrize("shape", [(67, 2), (68, 3), (136,)])
    def test_shape(self, shape):
        _rejected(np.zeros(shape), r"expected 68 landmarks .* got shape")

    def test_dtype(self, frontal):
        _rejected(frontal.astype(object), "real numbers")
        _rejected(frontal.astype(complex), "real numbers")

    @pytest.mark.parametrize("size", [(0, H), (W, -1), (W + 0.5, H), (True, H)])
    def test_image_size(self, frontal, size):
        _rejected(frontal, "positive integer", *size)

    @pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
    def test_non_finite(self, frontal, value):
        pts = frontal.copy()
        pts[30, 1] = value
        assert "landmark 30 (0-based" in _rejected(pts, "non-finite")


class TestAccepted:
    def test_sampled_poses_with_margin(self, sampled):
        """Every sampled pose passes, and the worst one is MARGIN below the threshold."""
        reports = [check_landmarks_2d(p, W, H) for p in sampled]
        worst = max(r.affine_residual for r in reports)
        assert worst < MAX_AFFINE_RESIDUAL / MARGIN, worst
        assert min(r.view_cosine for r in reports) > 0.25
        assert min(r.spread_ratio for r in reports) > MARGIN * MIN_SPREAD_RATIO

    @pytest.mark.parametrize("distance", [None, 300.0])
    @pytest.mark.parametrize("expression", [{}, {"jawOpen": 1.0}, {"mouthSmileLeft": 1.0, "eyeBlinkRight": 1.0}])
    def test_extreme_poses(self, views, asset, distance, expression):
        head = views.expressive(asset.vertices, coefficients_from_dict(expression).numpy())
        rng = np.random.default_rng(1)
        for yaw in (-60, 60):
            for pitch in (-30, 30):
                for roll in (-45, 45):
                    pts = views.project(head, yaw, pitch, roll, distance, noise_px=2.0, rng=rng)
                    report = check_landmarks_2d(pts, W, H)
                    assert report.affine_residual < MAX_AFFINE_RESIDUAL / MARGIN

    @pytest.mark.parametrize("roll", range(0, 360, 30))
    def test_any_in_plane_rotation(self, views, asset, roll):
        """Upside down is not mirrored: rolls all around the clock are accepted."""
        pts = views.project(asset.vertices, 30.0, -15.0, float(roll), 500.0)
        assert check_landmarks_2d(pts, W, H).view_cosine > 0.5

    def test_small_face(self, views, asset):
        pts = views.project(
            asset.vertices, 20.0, 10.0, 0.0, 600.0, interocular_px=20.0, noise_px=0.5, rng=np.random.default_rng(2)
        )
        assert check_landmarks_2d(pts, W, H).interocular_px > 15.0

    def test_partial_face_at_the_border(self, frontal):
        """A face 40 % beyond the left border is legal (a detector extrapolates the hidden points)."""
        pts = frontal - [frontal[:, 0].min() + 0.4 * np.ptp(frontal[:, 0]), 0.0]
        report = check_landmarks_2d(pts, W, H)
        assert 0.5 <= report.fraction_inside < 0.7


class TestRejected:
    def test_shifted_5000_px(self, frontal):
        _rejected(frontal + 5000.0, r"outside the 640x640 image: only 0 of 68")

    @pytest.mark.parametrize("index", [8, 30])
    def test_one_point_far_outside(self, frontal, index):
        """A stray point does not widen its own allowance (the face size is that of the points inside)."""
        pts = frontal.copy()
        pts[index] = [W / 2, H + 2000.0]
        assert f"landmark {index} (0-based) is" in _rejected(pts, "beyond its border")

    def test_coincident(self):
        _rejected(np.full((68, 2), 100.0), r"degenerate \(coincident or collinear\)")

    def test_too_small(self, frontal):
        assert "are 2.00 px apart" in _rejected(0.02 * (frontal - frontal.mean(0)) + frontal.mean(0), "too small")

    def test_collinear(self, frontal):
        on_line = frontal.copy()
        on_line[:, 1] = 0.2 * on_line[:, 0] + 100.0  # the real x positions, projected onto a line
        _rejected(on_line, "coincident or collinear")
        spaced = np.stack([np.linspace(100, 500, 68), np.linspace(200, 300, 68)], 1)
        _rejected(spaced[np.random.default_rng(0).permutation(68)], "coincident or collinear")

    def test_mirrored(self, sampled):
        for pts in sampled[:100]:
            message = _rejected(pts[MIRROR], "mirrored left/right")
            assert "36-41" in message

    def test_horizontally_flipped_coordinates(self, frontal):
        """Flipping x without swapping labels is what a mirrored label file looks like too."""
        _rejected(frontal * [-1.0, 1.0] + [W - 1.0, 0.0], "mirrored left/right")

    def test_random_points_in_the_face_box(self, sampled):
        rng = np.random.default_rng(3)
        residuals = []
        for pts in sampled[:200]:
            fake = rng.uniform(pts.min(0), pts.max(0), (68, 2))
            residuals.append(face_affine_fit(fake)[0])
            _rejected(fake, "do not look like a face")
        assert min(residuals) > MARGIN * MAX_AFFINE_RESIDUAL, min(residuals)

    def test_shuffled_order(self, sampled):
        rng = np.random.default_rng(4)
        residuals = []
        for pts in sampled[:200]:
            shuffled = pts[rng.permutation(68)]
            residuals.append(face_affine_fit(shuffled)[0])
            _rejected(shuffled, "do not look like a face")
        assert min(residuals) > MARGIN * MAX_AFFINE_RESIDUAL, min(residuals)

    def test_swapped_x_y(self, frontal):
        """Points read as (y, x): a transposed image is a reflection."""
        _rejected(frontal[:, ::-1], "mirrored left/right")


@pytest.fixture(scope="module")
def astronaut_landmarks():
    """dlib's landmarks on skimage's astronaut portrait (512 x 512) and on its mirror image."""
    pytest.importorskip("dlib")
    image = np.ascontiguousarray(pytest.importorskip("skimage.data").astronaut())
    from landmarks.detect import detect_landmarks

    return detect_landmarks(image).landmarks, detect_landmarks(np.ascontiguousarray(np.fliplr(image))).landmarks


class TestAstronaut:
    """Real dlib detections: the photo and its mirror image (re-detected) pass, swapped labels do not."""

    @pytest.fixture
    def detected(self, astronaut_landmarks):
        return astronaut_landmarks

    def test_accepted(self, detected):
        for pts in detected:
            report = check_landmarks_2d(pts, 512, 512)
            assert report.fraction_inside == 1.0 and report.view_cosine > 0.8
            assert report.affine_residual < MAX_AFFINE_RESIDUAL / 2

    def test_rotated_upside_down(self, detected):
        pts, _ = detected
        check_landmarks_2d(511.0 - pts, 512, 512)

    def test_label_swapped(self, detected):
        for pts in detected:
            _rejected(pts[MIRROR], "mirrored left/right", 512, 512)

    def test_flipped_coordinates_without_detection(self, detected):
        """Mirroring the coordinates (not re-detecting) keeps wrong labels: rejected."""
        pts, _ = detected
        _rejected(pts * [-1.0, 1.0] + [511.0, 0.0], "mirrored left/right", 512, 512)

    def test_shifted_5000_px(self, detected):
        _rejected(detected[0] + 5000.0, "outside the 512x512 image", 512, 512)


def test_a_dense_file_is_told_what_is_wrong_in_its_own_terms(asset):
    """Issue 38: 478-point files off the image, normalised to [0, 1], reversed or mirrored were refused with
    messages about iBUG-68 indices and "68 points" the user never wrote; each now names the file's points and
    what to do."""
    from landmarks.loss import project_points
    from landmarks.mediapipe.ibug68_map import mesh_to_ibug68
    from landmarks.mediapipe.layout import mediapipe_layout
    from pipeline.camera import default_focal, make_camera

    rotation, translation = head_rotation(15.0, 0.0, 0.0), np.array([0.0, 0.0, 600.0])
    layout = mediapipe_layout(asset)
    v = torch.as_tensor(asset.vertices, dtype=torch.float64)
    points = layout.points3d(v, asset.faces, camera_center_in_rig(rotation, translation))
    camera = make_camera(W, H, default_focal(W, H), rotation=rotation, translation=translation, dtype=torch.float64)
    dense = project_points(points[None], camera)[0].numpy()
    assert dense.shape == (478, 2)

    def check(p):
        return check_landmarks_2d(mesh_to_ibug68(p), W, H, source="f.json", mapped_from=len(p))

    assert check(dense).view_cosine > 0.9  # the good file passes
    mirrored = dense.copy()
    mirrored[:, 0] = W - 1 - mirrored[:, 0]
    cases = [
        (dense / [W, H], "all lie within [0, 1]: normalised coordinates"),
        (dense + [5000.0, 0.0], "the 478 MediaPipe points are not in this image's pixel coordinates"),
        (dense[::-1], "do not look like a face in MediaPipe's Face Mesh order"),
        (mirrored, "the 478 MediaPipe points look mirrored left/right"),
    ]
    for bad, message in cases:
        with pytest.raises(LandmarkPlausibilityError, match=message.replace("[", r"\[").replace("]", r"\]")) as e:
            check(bad)
        assert "iBUG" not in str(e.value) and "36-41" not in str(e.value)
