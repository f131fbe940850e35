"""Tests of pipeline/photo/fit.py: the face crop's camera, the light estimate, the configuration."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from kornia.geometry.camera import PinholeCamera

from landmarks.loss import project_points
from pipeline.camera import camera_direction_to_rig, make_camera
from pipeline.colour import linear_to_srgb, srgb_to_linear
from pipeline.config import ConfigError, load_config
from pipeline.fitting.priors import PriorWeights
from pipeline.photo.crop import Crop, face_crop
from pipeline.photo.fit_config import FitPhotoConfig, PhotometricConfig, PhotoStage
from pipeline.photo.multiview_config import MultiViewConfig
from pipeline.photo.photometric import fit_light, hemisphere_directions

ROOT = Path(__file__).resolve().parents[3]


class TestCrop:
    def test_crop_camera_projects_like_the_photo_camera_resampled(self):
        """A point's crop pixel = (photo pixel + 0.5 - corner) * scale - 0.5 (pixel centres at integers)."""
        w, h, f = 640, 480, 900.0
        crop = Crop(x0=200, y0=-30, side=250, size=100)
        points = torch.tensor([[[10.0, -20.0, 600.0], [-40.0, 35.0, 650.0], [0.0, 0.0, 580.0]]], dtype=torch.float64)
        full = make_camera(w, h, f, dtype=torch.float64)
        full = PinholeCamera(full.intrinsics, torch.eye(4, dtype=torch.float64)[None], full.height, full.width)
        uv = project_points(points, full)[0].numpy()
        uv_crop = project_points(points, crop.camera(f, w, h, dtype=torch.float64))[0].numpy()
        expected = (uv + 0.5 - np.array([crop.x0, crop.y0])) * crop.scale - 0.5
        assert np.abs(uv_crop - expected).max() < 1e-9

    def test_cut_resamples_and_masks_outside_pixels(self):
        img = np.zeros((60, 80, 3), np.float32)
        img[:, 40:] = 1.0  # right half white
        crop = Crop(x0=20, y0=-20, side=40, size=20)  # top 20 rows are outside the photo
        out, inside = crop.cut(img)
        assert out.shape == (20, 20, 3) and inside.shape == (20, 20)
        assert inside[:10].sum() == 0 and inside[10:].min() == 1.0
        # columns 20..39 of the photo are black, 40..59 white: the crop's left half black, right half white
        assert out[10:, :10].max() == 0.0 and out[10:, 10:].min() == pytest.approx(1.0)

    def test_face_crop_contains_the_landmarks_with_a_margin(self):
        rng = np.random.default_rng(0)
        lm = rng.uniform([100, 150], [220, 300], size=(68, 2))
        crop = face_crop(lm, 128, 0.25)
        assert crop.size == 128
        assert crop.x0 <= lm[:, 0].min() and crop.x0 + crop.side >= lm[:, 0].max()
        top_margin = lm[:, 1].min() - crop.y0
        assert top_margin >= 2 * 0.25 * np.ptp(lm[:, 1]) - 1  # room for the forehead


class TestLight:
    def test_fit_light_recovers_a_known_direction_and_intensities(self):
        rng = np.random.default_rng(1)
        n = rng.normal(size=(4000, 3))
        n[:, 2] = -np.abs(n[:, 2])  # normals facing the camera (OpenCV: towards -z)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        albedo = rng.uniform(0.2, 0.8, size=(4000, 3))
        candidates = hemisphere_directions(64)
        true_d = candidates[17]
        amb, irr = np.array([0.3, 0.25, 0.2]), np.array([2.0, 1.8, 1.5])
        cos = np.clip(-(n @ true_d), 0, None)[:, None] / np.pi
        target = albedo * (amb + irr * cos)
        d, a, i = fit_light(albedo, n, target, candidates)
        assert np.allclose(d, true_d)
        assert np.allclose(a, amb, atol=1e-6) and np.allclose(i, irr, atol=1e-5)

    def test_hemisphere_directions_come_from_the_camera_side(self):
        d = hemisphere_directions(64)
        assert d.shape == (64, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
        assert d[:, 2].min() >= 0.25 - 1e-9

    def test_camera_direction_to_rig(self):
        # a frontal head: camera +z (into the scene) is rig -z (into the face)
        assert np.allclose(camera_direction_to_rig(np.array([0.0, 0.0, 1.0]), np.eye(3)), [0, 0, -1])
        assert np.allclose(camera_direction_to_rig(np.array([0.0, 1.0, 0.0]), np.eye(3)), [0, -1, 0])


def test_srgb_round_trip():
    x = np.linspace(0, 1, 101, dtype=np.float32)
    assert np.abs(linear_to_srgb(srgb_to_linear(x)) - x).max() < 1e-5
    assert srgb_to_linear(np.array([0.5]))[0] == pytest.approx(0.2140, abs=1e-4)


class TestConfig:
    def test_shipped_yaml_equals_the_typed_defaults(self):
        shipped = load_config(FitPhotoConfig, ROOT / "configs" / "fit_photo.yaml")
        assert shipped == FitPhotoConfig()

    def test_unknown_keys_and_bad_stages_are_errors(self, tmp_path):
        with pytest.raises(ConfigError, match="unknown setting"):
            load_config(FitPhotoConfig, None, {"photometric.render_sise": 64})
        with pytest.raises(ConfigError, match="unknown setting"):
            load_config(FitPhotoConfig, None, {"landmarks.prior.lambda_mm": 1})
        with pytest.raises(ConfigError, match="unknown setting"):
            load_config(FitPhotoConfig, None, {"lr_joints": 0.1})  # the flat names of earlier versions
        bad = tmp_path / "bad.yaml"
        bad.write_text("photometric:\n  stages:\n    - {name: x, free: [joints, hair], iterations: 3}\n")
        with pytest.raises(ConfigError, match="free must be"):
            load_config(FitPhotoConfig, bad)
        with pytest.raises(ValueError, match="render_size"):
            PhotometricConfig(render_size=4)
        with pytest.raises(ValueError, match="face_regions"):
            PhotometricConfig(face_regions=("forehead", "moustache"))
        for spp in (0, 10_000):
            with pytest.raises(ValueError, match="spp_silhouette"):
                PhotometricConfig(spp_silhouette=spp)

    def test_nested_override(self):
        c = load_config(
            FitPhotoConfig, None, {"landmarks.prior.lambda_m": 0.7, "photometric.spp": 3, "photometric.lr.albedo": 0.5}
        )
        assert c.landmarks.prior.lambda_m == 0.7 and c.photometric.spp == 3 and c.photometric.lr.albedo == 0.5
        assert c.landmarks.prior.lambda_x == FitPhotoConfig().landmarks.prior.lambda_x  # the rest keep their defaults
        assert PhotoStage("a", ("albedo",), 2).iterations == 2

    def test_a_nested_override_keeps_the_parents_defaults_not_the_nested_class_defaults(self, tmp_path):
        # the photo fit's landmark prior (PHOTO_PRIOR: the identity prior, no L_m) is not PriorWeights()'s: setting
        # one of its weights must leave the others at the photo fit's values, from --set as from a YAML file
        default = FitPhotoConfig().landmarks.prior
        assert default != PriorWeights()  # otherwise this test could not fail
        want = replace(default, lambda_expressions=0.7)
        by_set = load_config(FitPhotoConfig, None, {"landmarks.prior.lambda_expressions": 0.7})
        partial = tmp_path / "partial.yaml"
        partial.write_text("landmarks:\n  prior:\n    lambda_expressions: 0.7\n")
        by_file = load_config(FitPhotoConfig, partial)
        for c in (by_set, by_file):
            assert c.landmarks.prior == want
            assert c.landmarks == replace(FitPhotoConfig().landmarks, prior=want)
        views = load_config(MultiViewConfig, None, {"landmarks.prior.lambda_identity": 0.1})
        assert views.landmarks.prior == replace(MultiViewConfig().landmarks.prior, lambda_identity=0.1)


# ----------------------------------------------------------------------------------------------------
# a synthetic photo with a known expression, fitted end to end
# ----------------------------------------------------------------------------------------------------

JAW_OPEN = 0.7


@pytest.fixture(scope="module")
def known_photo():
    """A held-out head with the rig's jawOpen blendshape at 0.7, path-traced at 192x192 (a different
    renderer and light model than the fit's), true landmarks + 0.5 px noise."""
    from pipeline.synthetic.photos.settings import PhotoSettings
    from pipeline.synthetic.photos.simulate import simulate_photo
    from pipeline.synthetic.population import population_split
    from rig.asset import load_asset
    from rig.expressions import ExpressionModel, coefficients_from_dict

    asset = load_asset()
    expr = ExpressionModel(asset, dtype=torch.float64)
    c = coefficients_from_dict({"jawOpen": JAW_OPEN}, dtype=torch.float64)[None]
    offsets = (expr.vertices(c)[0] - torch.as_tensor(asset.vertices)).numpy()
    head = population_split("heldout", 0).vertices[7] + offsets
    settings = PhotoSettings(width=192, height=192, spp=16, landmark_noise_px=0.5, offset_px=5)
    return simulate_photo(
        head, np.random.default_rng(3), settings, yaw_deg=15.0, pitch_deg=0.0, roll_deg=0.0, name="known"
    )


def _short_config(**kw):
    from pipeline.photo.fit_config import photo_schedule

    base = FitPhotoConfig()  # the default landmark fit (LM, ~0.3 s), short photometric stages
    return FitPhotoConfig(
        landmarks=base.landmarks,
        photometric=replace(
            base.photometric, enabled=True, stages=photo_schedule(8, 8, 0, 8, 0), render_size=64, **{"spp": 2, **kw}
        ),
    )


@pytest.fixture(scope="module")
def known_fit(known_photo):
    from pipeline.photo.fit import fit_photo

    return fit_photo(known_photo.image, known_photo.landmarks2d, focal=known_photo.focal, config=_short_config())


def test_a_synthetic_render_is_fitted_within_bounds(known_photo, known_fit):
    """The open jaw is recovered by the expression, and the head is closer to the truth than the template."""
    from pipeline.evaluation.photos import face_error
    from rig.asset import load_asset
    from rig.expressions import EXPRESSION_NAMES

    asset = load_asset()
    truth = known_photo.gt_vertices
    fitted = face_error(known_fit.rig_vertices, truth, asset)
    template = face_error(asset.vertices, truth, asset)
    jaw = known_fit.expressions[EXPRESSION_NAMES.index("jawOpen")]
    assert abs(jaw - JAW_OPEN) < 0.3, f"jawOpen {jaw:.2f}, true {JAW_OPEN}"  # measured 0.45 (MakeHuman rig)
    assert fitted["vertex_mean_mm"] < 0.7 * template["vertex_mean_mm"], (fitted, template)  # measured 2.39 vs 3.92
    assert fitted["s2m_median_mm"] < 1.0
    assert known_fit.landmarks.error_px.mean() < 2.0
    # the photometric stages ran, found the light on the camera's side and fit the face pixels
    assert [s.name for s in known_fit.stages] == ["appearance", "photo joints", "photo expressions"]
    assert known_fit.stages[-1].metrics["photo"] < 0.08  # mean residual, linear RGB
    assert known_fit.appearance.light_camera[2] > 0.25 and known_fit.appearance.ambient.min() >= 0
    assert known_fit.appearance.albedo.min() >= 0 and known_fit.appearance.albedo.max() <= 1


def test_a_photometric_fit_frees_its_renderer_without_the_garbage_collector(known_photo):
    """The renderer (its Mitsuba scene) goes when the fit returns, not at the next garbage collection: a scene
    left in a reference cycle stays in Dr.Jit's registry, and every later fit's kernels loop over it (each fit of
    a batch took ~5 s longer than the one before)."""
    import gc

    from pipeline.photo.fit import fit_photo
    from pipeline.photo.fit_config import photo_schedule
    from render.renderer import DifferentiableRenderer

    base = _short_config()
    config = replace(base, photometric=replace(base.photometric, stages=photo_schedule(1, 1, 0, 0, 0), render_size=32))
    gc.collect()
    before = {id(o) for o in gc.get_objects() if isinstance(o, DifferentiableRenderer)}  # other tests' live ones
    gc.disable()
    try:
        for _ in range(3):
            fit = fit_photo(known_photo.image, known_photo.landmarks2d, focal=known_photo.focal, config=config)
            assert len(fit.stages) == 2
            del fit
        left = [o for o in gc.get_objects() if isinstance(o, DifferentiableRenderer) and id(o) not in before]
    finally:
        gc.enable()
    # at most the last one (Dr.Jit may hold the last fit's objects until the next); never one per fit
    assert len(left) <= 1, len(left)


def test_the_photometric_renderer_takes_the_shading_and_silhouette_samples_from_the_config(known_photo, monkeypatch):
    """``spp`` sets the shading's samples per pixel and ``spp_silhouette`` the silhouettes' (Mitsuba's ``sppp``):
    each reaches the renderer the fit builds, neither replaced by the other."""
    import pipeline.photo.photometric as photometric
    from pipeline.photo.fit import fit_photo
    from pipeline.photo.fit_config import photo_schedule

    built = []

    class Recording(photometric.DifferentiableRenderer):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            built.append((self.spp, self.spp_primary))

    monkeypatch.setattr(photometric, "DifferentiableRenderer", Recording)
    base = _short_config(spp=2, spp_silhouette=3)
    config = replace(base, photometric=replace(base.photometric, stages=photo_schedule(1, 1, 0, 0, 0), render_size=32))
    fit_photo(known_photo.image, known_photo.landmarks2d, focal=known_photo.focal, config=config)
    assert built == [(2, 3)]


def test_the_photometric_stages_weigh_dense_points_as_the_landmark_fit_does(known_photo):
    """With the photo term off, a photometric stage of the joints minimises what the landmark fit minimised (the
    landmarks over the detector's error squared, the same priors), so it leaves the head where the landmark fit
    put it. Before, its landmark term ignored MediaPipe's 3 px error and pulled the identity 9x harder onto the
    points (an image term then moved the shape away from the truth even on renders of the fit's own model)."""
    from landmarks.mediapipe.layout import mediapipe_layout
    from pipeline.fitting.state import head_vertices
    from pipeline.photo.fit import fit_photo
    from pipeline.synthetic.photos.simulate import true_layout_points
    from rig.asset import load_asset
    from rig.model import JointRig
    from rig.skinning.neural import load_neural

    asset = load_asset()
    layout = mediapipe_layout(asset)
    points = true_layout_points(known_photo, layout, asset.faces)
    points += np.random.default_rng(5).normal(0.0, 2.0, points.shape)  # a detector's few pixels
    base = _short_config(lambda_photo=0.0)
    stages = (PhotoStage("look", ("albedo", "light"), 2), PhotoStage("joints", ("joints", "albedo", "light"), 25))
    config = replace(base, photometric=replace(base.photometric, stages=stages, render_size=32))
    rig = JointRig()
    neural, _ = load_neural(rig)
    fit = fit_photo(
        known_photo.image,
        known_photo.landmarks2d,
        focal=known_photo.focal,
        config=config,
        rig=rig,
        neural=neural,
        dense=(points, layout),
    )
    lf = fit.landmark_fit
    before = head_vertices(rig, neural, lf.theta, lf.z, lf.expressions)
    moved = np.linalg.norm(np.asarray(fit.rig_vertices) - before, axis=1)
    assert moved.mean() < 0.15, moved.mean()  # mm: 0.07 (Adam's steps about the minimum); 0.65 before


def test_outputs_reload_to_the_same_mesh(known_photo, known_fit, tmp_path):
    import json

    import trimesh

    from pipeline.photo.outputs import (
        mesh_from_photo_params,
        write_photo_outputs,
    )
    from tests.support.gltf_reader import read_skinned_gltf

    out = write_photo_outputs(tmp_path / "fit", known_photo.image, known_fit, config=_short_config(), spp=2)
    from pipeline.files import OUTPUT_MARKER
    from pipeline.head.folders import PHOTO_FOLDER

    assert sorted(p.name for p in out.iterdir()) == sorted((*PHOTO_FOLDER.required, OUTPUT_MARKER))
    assert load_config(FitPhotoConfig, out / "config.yaml") == _short_config()  # the settings used, read back
    assert np.abs(mesh_from_photo_params(out / "params.json") - known_fit.rig_vertices).max() < 1e-3
    # the camera frame: projecting the mesh with the params' camera puts the landmarks where the fit says
    cam_points = mesh_from_photo_params(out / "params.json", frame="camera")
    params = json.loads((out / "params.json").read_text())
    f, (cx, cy) = params["camera"]["focal_px"], params["camera"]["principal_point_px"]
    uv = cam_points[:, :2] / cam_points[:, 2:] * f + np.array([cx, cy])
    assert uv.min() > -50 and uv.max() < known_photo.width + 50 and (cam_points[:, 2] > 0).all()
    # the fitted landmarks: 2D (.pts, 1-based) = the 3D ones (camera frame) projected with the params' camera
    from landmarks.formats import read_landmarks
    from landmarks.ibug68.names import IBUG68_NAMES

    fitted = read_landmarks(out / "landmarks_fitted.pts")
    np.testing.assert_allclose(fitted, known_fit.landmarks.fitted, atol=1e-3)
    l3 = json.loads((out / "landmarks3d.json").read_text())
    assert l3["names"] == list(IBUG68_NAMES) and l3["units"] == "mm"
    p3 = np.asarray(l3["points"])
    np.testing.assert_allclose(p3[:, :2] / p3[:, 2:] * f + np.array([cx, cy]), fitted, atol=1e-3)
    nose_tip = p3[IBUG68_NAMES.index("nose_bridge_3")]
    assert np.linalg.norm(cam_points - nose_tip, axis=1).min() < 4.0  # on the fitted surface (edges ~5 mm)
    header, row = (out / "expressions.csv").read_text().splitlines()
    assert header.split(",")[:2] == ["eyeBlinkLeft", "eyeLookDownLeft"] and len(row.split(",")) == 52
    np.testing.assert_allclose(
        [float(x) for x in row.split(",")], [params["expressions"][n] for n in header.split(",")], atol=1e-6
    )
    ply = trimesh.load(out / "mesh.ply", process=False)
    assert np.abs(np.asarray(ply.vertices)[: len(known_fit.rig_vertices)] - known_fit.rig_vertices).max() < 1e-3
    assert np.asarray(ply.visual.vertex_colors).shape[0] >= len(known_fit.rig_vertices)
    gltf = read_skinned_gltf(out / "mesh.glb")
    assert len(gltf["joint_names"]) == 52
    report = json.loads((out / "report.json").read_text())
    assert report["landmarks"]["nme_inter_ocular"] == pytest.approx(known_fit.landmarks.nme)
    from PIL import Image

    assert Image.open(out / "overlay.png").size == (known_photo.width, known_photo.height)
    with pytest.raises(FileExistsError, match="--force"):
        write_photo_outputs(tmp_path / "fit", known_photo.image, known_fit)


def test_fits_are_bit_for_bit_repeatable(known_photo, known_fit):
    """Same photo, same settings: the same head (Dr.Jit and torch gradients accumulated on one thread)."""
    from pipeline.photo.fit import fit_photo

    again = fit_photo(known_photo.image, known_photo.landmarks2d, focal=known_photo.focal, config=_short_config())
    assert np.array_equal(again.rig_vertices, known_fit.rig_vertices)
    assert np.array_equal(again.appearance.albedo, known_fit.appearance.albedo)
    assert torch.get_num_threads() >= 1  # restored (not asserting a count: the machine decides)
