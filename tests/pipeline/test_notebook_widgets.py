"""pipeline/notebook/ (the notebook's 3D view, sliders and loss curves, and what its saved outputs keep) and
the engine's per-step loss history it plots: sliders checked against the rig's forward pass, curves against
the recorded values, the history checked not to change a fit by one bit, pictures kept once and the viewer
frame's address relative to the notebook."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from landmarks.ibug68.contour import contour_landmarks
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.positions import landmark_positions
from landmarks.loss import project_points
from pipeline.camera import camera_center_in_rig, default_focal, make_camera
from pipeline.fitting.engine import LearningRates, Loss, Stage, StageLog, run_schedule
from pipeline.fitting.priors import PriorWeights, rig_prior_terms
from pipeline.fitting.state import FitState
from pipeline.notebook.curves import LM_COST, loss_curves, stage_curves
from pipeline.notebook.embed import picture, relative_src, viewer_frame
from pipeline.notebook.head import posable_head
from pipeline.notebook.sliders import rig_sliders
from pipeline.notebook.view import head_view, update_head_view
from pipeline.photo.landmark_fit import LandmarkFitConfig, fit_landmarks
from rig.errors import InputError, ShapeError
from rig.expressions import EXPRESSION_NAMES, ExpressionModel, coefficients_from_dict
from rig.head_model import HeadParams
from rig.model import JointRig
from rig.optim import frozen
from rig.parameters import CHANNEL_INDEX, CHANNELS, params_to_theta, random_theta, theta_to_params
from rig.skinning.neural import LATENT, load_neural
from tests.pipeline.conftest import rig_head_vertices

W, H = 320, 240


@pytest.fixture(scope="module")
def rig64():
    return JointRig(dtype=torch.float64)


@pytest.fixture(scope="module")
def fit_params():
    """A fitted head's params.json content: random joints, an open jaw and a smile, a random latent Z."""
    theta = random_theta(torch.Generator().manual_seed(7), spread=0.3)[0].double()
    z = np.random.default_rng(3).normal(0.0, 0.3, LATENT)
    return {
        "joints": theta_to_params(theta),
        "expressions": {"jawOpen": 0.25, "mouthSmileLeft": 0.4},
        "latent_z": [float(x) for x in z],
    }


@pytest.fixture(scope="module")
def head(fit_params, rig64):
    return posable_head(fit_params, rig=rig64)


def _rig_forward(rig64, params) -> np.ndarray:
    """The reference: JointRig's float64 forward pass with the head's weights (neural skinning of its Z)
    and rest mesh (expressions applied), written out here."""
    neural, _ = load_neural(rig64)
    theta = params_to_theta(params["joints"], dtype=torch.float64)
    c = coefficients_from_dict(params["expressions"], dtype=torch.float64)
    with torch.no_grad():
        weights = neural(torch.as_tensor(params["latent_z"], dtype=torch.float64)[None])[0]
        rest = ExpressionModel(rig64.asset, dtype=torch.float64).vertices(c[None])[0]
        return rig64(theta[None], weights=weights, vertices=rest).vertices[0].numpy()


def _view_vertices(view) -> np.ndarray:
    mesh = view.data[0]
    return np.stack([np.asarray(mesh.x), np.asarray(mesh.y), np.asarray(mesh.z)], axis=1)


def _edited(params, joints=None, expressions=None):
    return {
        "joints": {**params["joints"], **(joints or {})},
        "expressions": {**params["expressions"], **(expressions or {})},
        "latent_z": params["latent_z"],
    }


class TestHeadViewAndSliders:
    def test_view_shows_the_fitted_head(self, head, fit_params, rig64):
        view = head_view(head)
        expected = _rig_forward(rig64, fit_params)
        np.testing.assert_allclose(_view_vertices(view), expected, rtol=0, atol=1e-6)
        mesh = view.data[0]
        assert np.asarray(mesh.x).dtype == np.float64
        np.testing.assert_array_equal(np.stack([mesh.i, mesh.j, mesh.k], 1), rig64.asset.faces)
        assert view.layout.scene.camera.up.y == 1 and view.layout.scene.aspectmode == "data"

    def test_every_channel_and_shape_has_a_slider_within_its_limits(self, head):
        sliders = rig_sliders(head)
        assert list(sliders.joint_sliders) == [c.name for c in CHANNELS] and len(sliders.joint_sliders) == 107
        assert list(sliders.expression_sliders) == list(EXPRESSION_NAMES)
        for c in CHANNELS:
            s = sliders.joint_sliders[c.name]
            assert (s.min, s.max) == (c.low, c.high)
            assert s.value == pytest.approx(c.from_theta(head.theta[CHANNEL_INDEX[c.name]]), abs=1e-12)
        assert sliders.expression_sliders["jawOpen"].value == pytest.approx(0.25)
        np.testing.assert_allclose(sliders.theta(), head.theta, rtol=0, atol=1e-12)

    @pytest.mark.parametrize(
        "name, value",
        [("nose_tip.translate_z", "high"), ("left_upper_eyelid.rotate_x", "low"), ("left_cheek.scale", "high")],
    )
    def test_a_joint_slider_reposes_the_view_as_the_rig_does(self, head, fit_params, rig64, name, value):
        view = head_view(head)
        sliders = rig_sliders(head, view)
        channel = CHANNELS[CHANNEL_INDEX[name]]
        target = channel.high if value == "high" else channel.low
        before = _view_vertices(view)
        sliders.joint_sliders[name].value = target  # the widget's own callback, as a user's drag
        after = _view_vertices(view)
        expected = _rig_forward(rig64, _edited(fit_params, joints={name: target}))
        np.testing.assert_allclose(after, expected, rtol=0, atol=1e-6)
        assert np.linalg.norm(after - before, axis=1).max() > 0.5  # the edit is visible (mm)

    def test_an_expression_slider_reposes_the_view_as_the_rig_does(self, head, fit_params, rig64):
        view = head_view(head)
        sliders = rig_sliders(head, view)
        sliders.expression_sliders["jawOpen"].value = 0.9
        expected = _rig_forward(rig64, _edited(fit_params, expressions={"jawOpen": 0.9}))
        moved = np.linalg.norm(expected - head.vertices, axis=1)
        assert moved.max() > 5.0  # the jaw opened
        np.testing.assert_allclose(_view_vertices(view), expected, rtol=0, atol=1e-6)

    def test_set_values_matches_the_params_json_path_and_reset_restores_the_fit(self, head, fit_params, rig64):
        view = head_view(head)
        sliders = rig_sliders(head, view, continuous_update=True)
        edit = {"nose_tip.translate_z": 4.0, "crown.translate_y": 10.0, "browInnerUp": 0.7, "eyeBlinkLeft": 1.0}
        sliders.set_values(edit)
        joints = {k: v for k, v in edit.items() if k in CHANNEL_INDEX}
        expressions = {k: v for k, v in edit.items() if k not in CHANNEL_INDEX}
        # the jnr rig export / params.json reader: another code path to the same head
        expected = rig_head_vertices(_edited(fit_params, joints, expressions), rig=rig64)
        np.testing.assert_allclose(_view_vertices(view), expected, rtol=0, atol=1e-6)
        np.testing.assert_allclose(sliders.vertices, expected, rtol=0, atol=1e-6)
        sliders.reset()
        np.testing.assert_allclose(_view_vertices(view), head.vertices, rtol=0, atol=1e-9)

    def test_a_subset_of_channels_and_no_expressions(self, head):
        sliders = rig_sliders(head, channels=["nose_tip.translate_z"], expressions=False)
        assert list(sliders.joint_sliders) == ["nose_tip.translate_z"] and not sliders.expression_sliders
        sliders.joint_sliders["nose_tip.translate_z"].value = 2.0
        theta = sliders.theta()
        assert theta[CHANNEL_INDEX["nose_tip.translate_z"]] == 2.0
        others = np.arange(len(theta)) != CHANNEL_INDEX["nose_tip.translate_z"]
        np.testing.assert_array_equal(theta[others], head.theta[others])
        np.testing.assert_array_equal(sliders.expressions(), head.expressions)

    def test_from_a_fit_result_with_albedo(self, head, rig64):
        albedo = np.full((rig64.num_vertices, 3), 0.318547)  # linear 0.318547 = sRGB 0.6
        fit = SimpleNamespace(theta=head.theta, z=np.zeros(LATENT), expressions=head.expressions, albedo=albedo)
        from_fit = posable_head(fit, rig=rig64)
        assert from_fit.colours is not None and from_fit.colours == pytest.approx(0.6, abs=1e-5)
        view = head_view(from_fit)
        assert len(view.data[0].vertexcolor) == rig64.num_vertices and view.data[0].vertexcolor[0] == "rgb(153,153,153)"

    def test_bad_input(self, head, rig64):
        with pytest.raises(InputError, match="unknown joint channel"):
            rig_sliders(head, channels=["nose_tip.translate_w"])
        sliders = rig_sliders(head, expressions=False)
        with pytest.raises(InputError, match="outside"):
            sliders.set_values({"nose_tip.translate_z": 1e3})
        with pytest.raises(InputError, match="no slider named 'jawOpen'"):
            sliders.set_values({"jawOpen": 0.5})
        asm_fit = SimpleNamespace(
            theta=head.theta, z=np.zeros(LATENT), expressions=head.expressions, head=HeadParams("asm", {})
        )
        with pytest.raises(InputError, match="'asm' head model has no joint channels"):
            posable_head(asm_fit, rig=rig64)
        with pytest.raises(InputError, match="without"):
            posable_head(object(), rig=rig64)
        with pytest.raises(ShapeError, match="update_head_view: vertices"):
            update_head_view(head_view(head), np.zeros((10, 3)))
        with pytest.raises(ShapeError, match="FittedHead.pose: theta"):
            head.pose(np.zeros(3), head.expressions)


# ----------------------------------------------------------------------------------------------------
# The per-step history and the loss curves
# ----------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def models():
    rig = JointRig()
    return rig, load_neural(rig)[0], ExpressionModel(rig.asset, dtype=rig.template.dtype)


def _plain_schedule(state, stages, objective, lr, **_):
    """The engine's loop as its module docstring writes it, without any logging."""
    with frozen(None if state.neural is None else state.neural.decoder):
        for stage in stages:
            free = state.available(stage.free)
            if stage.iterations == 0 or not free:
                continue
            optimiser = torch.optim.Adam(state.parameter_groups(free, lr))
            for _ in range(stage.iterations):
                loss = objective(free).total
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
                state.project(free)
    return ()


def _deformation_fit(models, schedule):
    """Joints, Z and expressions pulled towards a known deformed head; returns (state, logs)."""
    rig, neural, expr = models
    with torch.no_grad():
        target = rig(random_theta(torch.Generator().manual_seed(2), spread=0.3)).vertices[0]
    state = FitState(rig, neural, expr, np.eye(3))

    def objective(free):
        data = (state.rig_vertices(free) - target).square().sum(-1).mean()
        return Loss({"data_mm2": data, **rig_prior_terms(state, PriorWeights(lambda_z=0.01))})

    stages = (
        Stage("joints", ("joints",), 8),
        Stage("latent", ("latent",), 2),
        Stage("expressions", ("expressions",), 3),
    )
    return state, schedule(state, stages, objective, LearningRates())


@pytest.fixture(scope="module")
def deformation(models):
    return _deformation_fit(models, run_schedule)


class TestStageHistory:
    def test_history_records_every_term_at_every_step_and_changes_nothing(self, models, deformation):
        state, logs = deformation
        plain, _ = _deformation_fit(models, _plain_schedule)
        for name, value in state.named_parameters():
            assert torch.equal(value, dict(plain.named_parameters())[name]), name  # bit for bit
        assert [log.name for log in logs] == ["joints", "latent", "expressions"]
        for log in logs:
            assert set(log.history) == set(log.terms)
            assert all(len(v) == log.iterations for v in log.history.values())
            assert {k: v[-1] for k, v in log.history.items()} == log.terms
            assert sum(v[0] for v in log.history.values()) == pytest.approx(log.loss_start, rel=1e-6)
            assert sum(v[-1] for v in log.history.values()) == pytest.approx(log.loss_end, rel=1e-6)
        data = logs[0].history["data_mm2"]
        assert data[-1] < 0.5 * data[0]  # the fit moved towards the target

    def test_a_real_fit_is_bit_identical_with_and_without_the_history(self, models, monkeypatch):
        rig, neural, _ = models
        landmarks2d = _synthetic_landmarks(rig, neural)
        config = LandmarkFitConfig(
            solver="adam",
            stages=(
                Stage("pose", ("pose",), 3),
                Stage("joints", ("pose", "joints"), 4),
                Stage("expr", ("pose", "expressions"), 3),
            ),
        )
        logged = fit_landmarks(landmarks2d, W, H, config=config, rig=rig, neural=neural)
        monkeypatch.setattr("pipeline.photo.landmark_fit.run_schedule", _plain_schedule)
        plain = fit_landmarks(landmarks2d, W, H, config=config, rig=rig, neural=neural)
        for key in ("theta", "z", "expressions", "rotation", "translation", "landmarks_px"):
            np.testing.assert_array_equal(getattr(logged, key), getattr(plain, key), err_msg=key)
        assert [len(s.history["landmarks_px2"]) for s in logged.stages] == [3, 4, 3]


def _synthetic_landmarks(rig, neural) -> np.ndarray:
    """The 68 landmarks of a rig head (an expression on), seen at 600 mm, pixels."""
    rotation, translation = np.eye(3), np.array([0.0, 0.0, 600.0])
    expr = ExpressionModel(rig.asset)
    with torch.no_grad():
        weights = neural(torch.zeros(1, LATENT))[0]
        v = rig(
            torch.zeros(1, rig.num_parameters),
            weights=weights,
            vertices=expr.vertices(coefficients_from_dict({"jawOpen": 0.2})[None])[0],
        ).vertices[0]
        contour = contour_landmarks(v, rig.asset.faces, camera_center_in_rig(rotation, translation), rig.asset)
        points = torch.cat([contour, landmark_positions(v, ibug68_embedding(rig.asset), rig.asset.faces)[0, 17:]])
        camera = make_camera(W, H, default_focal(W, H), rotation=rotation, translation=translation)
        return project_points(points[None], camera)[0].double().numpy() + 1.5  # off by 1.5 px: work to do


class TestLossCurves:
    def test_one_line_per_stage_and_term_with_the_recorded_values(self, deformation):
        _, logs = deformation
        lm = StageLog("landmarks lm", ("pose",), 3, 9.0, 2.0, metrics={"lm_costs": [9.0, 4.5, 2.0]})
        skipped = StageLog("average", ("joints",), 0, 1.0, 1.0)  # nothing per step: no panel
        fit = SimpleNamespace(landmark_fit=SimpleNamespace(stages=(lm,)), stages=logs + (skipped,))
        assert [c.name for c in stage_curves(fit)] == ["landmarks lm", "joints", "latent", "expressions"]
        fig = loss_curves(fit, title="test")
        axes = [ax for ax in fig.axes if ax.get_visible()]
        assert [ax.get_title() for ax in axes] == [
            "landmarks lm (Levenberg-Marquardt)",
            "joints (Adam)",
            "latent (Adam)",
            "expressions (Adam)",
        ]
        assert all(ax.get_yscale() == "log" for ax in axes)
        lines = axes[0].get_lines()
        assert [line.get_label() for line in lines] == [LM_COST]
        np.testing.assert_array_equal(lines[0].get_ydata(), [9.0, 4.5, 2.0])
        for ax, log in zip(axes[1:], logs):
            lines = {line.get_label(): line for line in ax.get_lines()}
            assert list(lines) == list(log.history)  # one trace per (stage, term)
            for name, values in log.history.items():
                np.testing.assert_array_equal(lines[name].get_ydata(), values)
                np.testing.assert_array_equal(lines[name].get_xdata(), np.arange(log.iterations))
        legend = [t.get_text() for t in fig.legends[0].get_texts()]
        assert legend[:2] == [LM_COST, "data_mm2"]

    def test_terms_at_zero_throughout_are_named_in_the_legend(self):
        logs = [
            StageLog("a", ("joints",), 2, 1.0, 0.5, history={"data": (1.0, 0.5), "off": (0.0, 0.0)}),
            StageLog(
                "b", ("joints",), 2, 0.5, 0.2, history={"data": (0.5, 0.2), "off": (0.0, 0.0), "late": (0.0, 0.1)}
            ),
        ]
        fig = loss_curves(logs)
        assert [t.get_text() for t in fig.legends[0].get_texts()] == ["data", "off (0 throughout)", "late"]
        colours = {(ax.get_title(), line.get_label()): line.get_color() for ax in fig.axes for line in ax.get_lines()}
        assert colours[("a (Adam)", "data")] == colours[("b (Adam)", "data")] != colours[("b (Adam)", "late")]

    def test_a_default_landmark_fit_draws_its_lm_stages(self, models):
        rig, neural, _ = models
        fit = fit_landmarks(_synthetic_landmarks(rig, neural), W, H, rig=rig, neural=neural)
        curves = stage_curves(fit)
        assert [c.name for c in curves] == [s.name for s in fit.stages] and all(c.solver == "lm" for c in curves)
        for c, s in zip(curves, fit.stages):
            np.testing.assert_array_equal(c.terms[LM_COST], s.metrics["lm_costs"])
        assert len([ax for ax in loss_curves(fit).axes if ax.get_visible()]) == len(fit.stages)

    def test_nothing_recorded_is_an_error(self):
        with pytest.raises(InputError, match="no stage"):
            loss_curves([StageLog("average", ("joints",), 0, 1.0, 1.0)])
        with pytest.raises(InputError, match="expected a fit result"):
            loss_curves(object())


class TestSavedOutputs:
    """pipeline.notebook.embed: one representation per picture, and the 3D view as a relative <iframe>."""

    @staticmethod
    def _bundle(obj) -> dict:
        from IPython.core.formatters import DisplayFormatter

        data, _ = DisplayFormatter().format(obj)
        return data

    def test_a_pil_image_displayed_as_such_is_stored_twice(self):
        # the reason for picture(): Jupyter keeps every representation Pillow offers
        from PIL import Image

        assert {"image/png", "image/jpeg"} <= set(self._bundle(Image.new("RGB", (8, 8))))

    @pytest.mark.parametrize("fmt", ["jpeg", "png"])
    def test_picture_is_one_image(self, fmt):
        import base64
        import io

        from PIL import Image

        image = np.zeros((30, 40, 3), np.uint8)
        image[:, :20] = (200, 120, 40)
        bundle = self._bundle(picture(image, format=fmt))
        assert [m for m in bundle if m.startswith("image/")] == [f"image/{fmt}"]
        decoded = np.asarray(Image.open(io.BytesIO(base64.b64decode(bundle[f"image/{fmt}"]))))
        assert decoded.shape == image.shape
        error = np.abs(decoded.astype(int) - image)
        if fmt == "png":
            assert error.max() == 0
        else:  # lossy; its ringing is in the 16 px blocks at the colour edge
            assert error.mean() < 2 and error[:, :16].max() <= 3 and error[:, 32:].max() <= 3
        assert [m for m in self._bundle(picture(Image.fromarray(image), format=fmt))] == [f"image/{fmt}", "text/plain"]
        with pytest.raises(InputError, match="format"):
            picture(image, format="gif")

    def test_viewer_frame_points_at_the_page_relative_to_the_notebook(self, tmp_path):
        page = tmp_path / "out" / "a fit" / "viewer.html"
        page.parent.mkdir(parents=True)
        page.write_text("<html></html>")
        assert relative_src(page, tmp_path) == "out/a%20fit/viewer.html"
        html = self._bundle(viewer_frame(page, base=tmp_path, height=500))["text/html"]
        assert 'src="out/a%20fit/viewer.html"' in html and 'height="500"' in html and "://" not in html

    def test_viewer_frame_refuses_what_jupyter_cannot_serve(self, tmp_path):
        page = tmp_path / "viewer.html"
        page.write_text("<html></html>")
        with pytest.raises(InputError, match="not inside"):
            viewer_frame(page, base=tmp_path / "notebooks")
        with pytest.raises(InputError, match="does not exist"):
            viewer_frame(tmp_path / "missing.html", base=tmp_path)
