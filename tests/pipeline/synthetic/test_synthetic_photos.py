"""pipeline.synthetic.photos: synthetic portrait photos of held-out heads with known ground truth.

Small images (96x96) and 4 samples per pixel keep the file to a few seconds on 2 CPU cores.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

pytest.importorskip("mitsuba")
pytest.importorskip("kornia")

from landmarks.formats import read_landmarks
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.positions import landmark_positions
from pipeline.camera import RIG_TO_OPENCV, camera_center_in_rig, make_camera
from pipeline.colour import linear_to_srgb, srgb_to_linear
from pipeline.synthetic.photos.albedo import synthesize_albedo
from pipeline.synthetic.photos.background import synthetic_background
from pipeline.synthetic.photos.settings import PhotoSettings, SyntheticPhoto
from pipeline.synthetic.photos.simulate import simulate_photo, synthetic_photo
from pipeline.synthetic.photos.write import write_synthetic_photo
from pipeline.synthetic.population import population_split
from pipeline.synthetic.scans import DepthCamera, render_depth
from render.reference import ReferenceLight
from rig.geometry import head_rotation, vertex_normals

SMALL = PhotoSettings(width=96, height=96, offset_px=5.0, spp=4)
NOSE_TIP, RIGHT_EYE_OUTER, LEFT_EYE_OUTER = 30, 36, 45


@pytest.fixture(scope="module")
def photo() -> SyntheticPhoto:
    return synthetic_photo(3, seed=1, settings=SMALL)


@pytest.fixture(scope="module")
def head() -> np.ndarray:
    return population_split("heldout", 0).vertices[0]


def _pixels(points: np.ndarray, size: int) -> np.ndarray:
    return np.clip(np.rint(points).astype(int), 0, size - 1)


# -- smoke and cardinality ----------------------------------------------------------------------------
def test_fields_shapes_and_types(photo, asset):
    assert photo.name == "heldout_003"
    assert photo.image.shape == (96, 96, 3) and photo.image.dtype == np.uint8
    assert photo.image_linear.shape == (96, 96, 3) and photo.image_linear.dtype == np.float32
    assert photo.mask.shape == (96, 96) and 0.0 <= photo.mask.min() and photo.mask.max() <= 1.0
    assert photo.landmarks2d.shape == (68, 2) and photo.landmarks2d_true.shape == (68, 2)
    assert photo.gt_vertices.shape == asset.vertices.shape and photo.albedo.shape == asset.vertices.shape
    assert photo.rotation.shape == (3, 3) and photo.translation.shape == (3,)
    np.testing.assert_allclose(photo.rotation, head_rotation(photo.yaw_deg, photo.pitch_deg, photo.roll_deg))
    assert SMALL.yaw_deg_range[0] <= photo.yaw_deg <= SMALL.yaw_deg_range[1]
    assert 450.0 <= photo.translation[2] <= 650.0  # distance to the rig origin along the optical axis
    assert 1.2 * 96 <= photo.focal <= 1.7 * 96
    assert isinstance(photo.light, ReferenceLight)
    assert photo.width == 96 and photo.height == 96
    # the head covers a good part of the image, and the background shows around it
    assert 0.15 < photo.mask.mean() < 0.8
    assert photo.image[photo.mask == 0].std() > 1.0


def test_expressive_photo_name_and_shape():
    expr = synthetic_photo(3, expressive=True, seed=1, settings=SMALL)
    neutral = synthetic_photo(3, expressive=False, seed=1, settings=SMALL)
    assert expr.name == "heldout_003_expr"
    assert np.abs(expr.gt_vertices - neutral.gt_vertices).max() > 1.0


# -- features --------------------------------------------------------------------------------------------
def test_deterministic_given_the_seed(photo):
    again = synthetic_photo(3, seed=1, settings=SMALL)
    np.testing.assert_array_equal(again.image, photo.image)
    np.testing.assert_array_equal(again.landmarks2d, photo.landmarks2d)
    np.testing.assert_array_equal(again.albedo, photo.albedo)
    assert again.light == photo.light
    other = synthetic_photo(3, seed=2, settings=SMALL)
    assert np.abs(other.landmarks2d - photo.landmarks2d).max() > 0.5
    assert np.abs(other.image.astype(int) - photo.image.astype(int)).mean() > 5.0
    np.testing.assert_array_equal(other.gt_vertices, photo.gt_vertices)  # the same head


def test_true_landmarks_are_the_projected_mesh_landmarks(photo, asset):
    camera = make_camera(
        photo.width, photo.height, photo.focal, None, photo.rotation, photo.translation, dtype=torch.float64
    )
    points = landmark_positions(photo.gt_vertices, ibug68_embedding(asset), asset.faces)[0]
    uv = camera.project(torch.as_tensor(points)[None])[0].numpy()
    np.testing.assert_allclose(photo.landmarks2d_true[17:], uv[17:], atol=1e-6)  # contour 0-16: dynamic


def test_true_landmarks_land_on_the_head(photo):
    from scipy.ndimage import maximum_filter

    px = _pixels(photo.landmarks2d_true, 96)
    inner = photo.mask[px[17:, 1], px[17:, 0]]
    assert (inner > 0).all() and (inner == 1.0).mean() > 0.9  # brow ends may sit near the outline
    # the jaw contour lies on the outline: a covered pixel within one pixel
    assert (maximum_filter(photo.mask, 3)[px[:, 1], px[:, 0]] > 0.5).all()


def test_landmark_noise_level():
    for sigma in (1.0, 2.5):
        p = synthetic_photo(
            5, seed=0, settings=PhotoSettings(width=96, height=96, offset_px=5.0, spp=1, landmark_noise_px=sigma)
        )
        std = float((p.landmarks2d - p.landmarks2d_true).std())
        assert 0.6 * sigma <= std <= 1.4 * sigma
    p = synthetic_photo(
        5, seed=0, settings=PhotoSettings(width=96, height=96, offset_px=5.0, spp=1, landmark_noise_px=0.0)
    )
    np.testing.assert_array_equal(p.landmarks2d, p.landmarks2d_true)


def test_visible_vertices_project_into_the_mask(photo, asset):
    """The render's camera is the pose's camera: z-buffer the true mesh with the same pinhole and
    compare with the rendered coverage."""
    from scipy.ndimage import maximum_filter

    camera = make_camera(96, 96, photo.focal, None, photo.rotation, photo.translation, dtype=torch.float64)
    uv = camera.project(torch.as_tensor(photo.gt_vertices)[None])[0].numpy()
    cam_points = photo.gt_vertices @ (RIG_TO_OPENCV @ photo.rotation).T + photo.translation
    depth, _ = render_depth(cam_points, asset.faces, DepthCamera(96, 96, photo.focal, photo.focal, 47.5, 47.5))
    covered = np.isfinite(depth)
    rendered = photo.mask > 0.5
    assert (covered & rendered).sum() / (covered | rendered).sum() > 0.97

    px = np.rint(uv).astype(int)
    inside = (px >= 0).all(1) & (px < 96).all(1)
    z_buffer = np.full(len(px), np.inf)
    z_buffer[inside] = depth[px[inside, 1], px[inside, 0]]
    visible = inside & np.isfinite(z_buffer) & (cam_points[:, 2] <= z_buffer + 1.0)
    assert visible.sum() > 1000
    to_camera = camera_center_in_rig(photo.rotation, photo.translation) - photo.gt_vertices
    to_camera /= np.linalg.norm(to_camera, axis=1, keepdims=True)
    facing = visible & ((vertex_normals(photo.gt_vertices, asset.faces) * to_camera).sum(1) > 0.3)
    mask_at = photo.mask[px[:, 1].clip(0, 95), px[:, 0].clip(0, 95)]
    assert (mask_at[facing] > 0.5).mean() > 0.99
    assert (maximum_filter(photo.mask, 3)[px[visible, 1], px[visible, 0]] > 0).all()


def test_positive_yaw_moves_the_nose_right(head):
    """Positive yaw (about rig +Y) turns the face towards rig +X, the subject's left, which the camera
    (x_cam = x_rig for a frontal head) sees on the image's right: the nose tip moves to larger u."""
    nose_u, relative = {}, {}
    for yaw in (-20.0, 0.0, 20.0):
        p = simulate_photo(head, 5, SMALL, yaw_deg=yaw, pitch_deg=0.0, roll_deg=0.0)
        lm = p.landmarks2d_true
        nose_u[yaw] = lm[NOSE_TIP, 0]
        relative[yaw] = lm[NOSE_TIP, 0] - 0.5 * (lm[RIGHT_EYE_OUTER, 0] + lm[LEFT_EYE_OUTER, 0])
    assert nose_u[20.0] > nose_u[0.0] + 2.0 > nose_u[-20.0] + 4.0
    assert relative[20.0] > 1.0 and relative[-20.0] < -1.0 and abs(relative[0.0]) < 0.5


def test_light_is_in_front_of_and_above_the_face(photo):
    # back in camera coordinates: in front of the face (smaller z than the head) and above it (y < 0 is up)
    light_cam = RIG_TO_OPENCV @ photo.rotation @ np.asarray(photo.light.position) + photo.translation
    assert light_cam[2] < photo.translation[2] - 100.0
    assert light_cam[1] < photo.translation[1]


def test_srgb_round_trip():
    x = np.linspace(0.0, 1.0, 1001)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-9)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-9)
    assert srgb_to_linear(0.5) == pytest.approx(0.214041, abs=1e-6)
    assert linear_to_srgb(0.0031308) == pytest.approx(12.92 * 0.0031308)  # both branches meet
    assert srgb_to_linear(np.float32(0.5)).dtype == np.float32
    np.testing.assert_allclose(linear_to_srgb(np.array([-0.5, 2.0])), [0.0, 1.0], atol=1e-12)  # clipped


def test_image_is_the_srgb_of_the_linear_render(photo):
    expected = np.floor(linear_to_srgb(photo.image_linear) * 255.0 + 0.5)
    np.testing.assert_array_equal(photo.image, expected.astype(np.uint8))


def test_albedo_range_variation_and_regions(asset):
    a = synthesize_albedo(np.random.default_rng(0), asset)
    b = synthesize_albedo(np.random.default_rng(1), asset)
    np.testing.assert_array_equal(a, synthesize_albedo(np.random.default_rng(0), asset))
    for albedo in (a, b):
        assert albedo.shape == asset.vertices.shape and albedo.min() >= 0.0 and albedo.max() <= 1.0
    assert np.abs(a - b).mean() > 0.01
    tones = [synthesize_albedo(seed, asset)[asset.region_mask("cheeks")].mean() for seed in range(12)]
    assert max(tones) > 2.0 * min(tones)  # light to dark skin

    for seed in range(5):
        albedo = synthesize_albedo(seed, asset)
        lips, cheeks = albedo[asset.region_mask("lips")].mean(0), albedo[asset.region_mask("cheeks")].mean(0)
        brows, forehead = albedo[asset.region_mask("brows")].mean(), albedo[asset.region_mask("forehead")].mean()
        assert lips[0] / lips[1] > cheeks[0] / cheeks[1]  # redder lips
        assert lips.mean() < cheeks.mean() and brows < forehead  # darker lips and brows
        asym = np.abs(albedo - albedo[asset.mirror]).mean()
        assert 0.0 < asym < 0.05 * albedo.mean()  # almost, not exactly, symmetric


def test_background_is_textured_and_random():
    bg = synthetic_background(np.random.default_rng(0), 64, 48)
    assert bg.shape == (48, 64, 3) and bg.dtype == np.float32 and bg.min() >= 0.0 and bg.max() <= 1.0
    assert bg.std(axis=(0, 1)).min() > 0.005
    # texture: not just a gradient (second differences are not all ~0)
    assert np.abs(np.diff(bg, n=2, axis=1)).mean() > 1e-5
    np.testing.assert_array_equal(bg, synthetic_background(np.random.default_rng(0), 64, 48))
    assert np.abs(bg - synthetic_background(np.random.default_rng(1), 64, 48)).mean() > 0.01


def test_write_synthetic_photo(photo, tmp_path, asset):
    import trimesh
    from PIL import Image

    out = write_synthetic_photo(photo, tmp_path / "p")
    np.testing.assert_array_equal(np.asarray(Image.open(out / "photo.png")), photo.image)
    np.testing.assert_allclose(read_landmarks(out / "landmarks.pts"), photo.landmarks2d, atol=1e-9)
    mesh = trimesh.load(out / "truth.ply", process=False)
    np.testing.assert_allclose(mesh.vertices, photo.gt_vertices, atol=1e-4)
    np.testing.assert_array_equal(mesh.faces, asset.faces)
    truth = json.loads((out / "truth.json").read_text())
    assert truth["name"] == "heldout_003" and truth["focal"] == pytest.approx(photo.focal)
    np.testing.assert_allclose(truth["rotation"], photo.rotation)
    np.testing.assert_allclose(truth["translation"], photo.translation)
    assert truth["light"]["position"] == list(photo.light.position)
    assert {"yaw_deg", "pitch_deg", "roll_deg", "width", "height"} <= set(truth)


# -- exceptions ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"width": 0}, "width"),
        ({"height": 2.5}, "height"),
        ({"yaw_deg_range": (10.0, -10.0)}, "yaw_deg_range"),
        ({"distance_mm_range": (-5.0, 100.0)}, "distance_mm_range"),
        ({"focal_factor_range": (0.0, 1.0)}, "focal_factor_range"),
        ({"spp": 0}, "spp"),
        ({"landmark_noise_px": -1.0}, "landmark_noise_px"),
        ({"offset_px": float("nan")}, "offset_px"),
        ({"skin_tone_range": (0.0, 1.5)}, "skin_tone_range"),
        ({"light_irradiance_range": "bright"}, "light_irradiance_range"),
    ],
)
def test_bad_settings_raise(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PhotoSettings(**kwargs)


def test_face_outside_the_image_raises(head):
    tele = PhotoSettings(width=96, height=96, spp=1, focal_factor_range=(6.0, 6.0))
    with pytest.raises(ValueError, match="does not fit"):
        simulate_photo(head, 0, tele)


def test_bad_inputs_raise(head):
    with pytest.raises(ValueError, match="template"):
        simulate_photo(head[:-1], 0, SMALL)
    with pytest.raises(ValueError, match="yaw_deg"):
        simulate_photo(head, 0, SMALL, yaw_deg=float("inf"))
    with pytest.raises(ValueError, match="index"):
        synthetic_photo(100, settings=SMALL)
    with pytest.raises(ValueError, match="seed"):
        synthetic_photo(0, seed=-1, settings=SMALL)
    with pytest.raises(ValueError, match="width"):
        synthetic_background(0, 0, 10)
