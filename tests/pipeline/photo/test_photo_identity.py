"""The photometric stage of the identity (issue 37): the group ``identity`` moves the joint channels along the
identity prior's main directions, and on a render the image alone moves the head towards the truth."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.fitting.engine import Loss, run_schedule
from pipeline.fitting.priors import cached_identity_prior
from pipeline.photo.fit_config import PhotoLearningRates, PhotometricConfig, PhotoStage, identity_schedule
from rig.errors import InputError


def _state():
    from pipeline.fitting.state import PhotoState
    from rig.expressions import ExpressionModel
    from rig.model import JointRig

    rig = JointRig()
    return PhotoState(
        rig, None, ExpressionModel(rig.asset, dtype=rig.template.dtype), np.eye(3), np.array([0, 0, 600.0])
    )


def test_identity_steps_stay_in_the_prior_subspace_and_recover_a_known_offset():
    """A known offset along the first five directions is recovered by Adam on their coefficients; each step is
    folded into the joint channels (the coefficients are 0 between steps) and every channel moved lies in the
    directions' span."""
    state = _state()
    prior = cached_identity_prior()
    state.set_identity_subspace(prior, 5)
    basis = prior.components[:5].T * np.sqrt(prior.variances[:5])
    u0 = state.theta_n.detach().double().numpy().copy()
    c_true = np.array([0.8, -0.5, 0.3, 0.0, 0.6])
    target = torch.as_tensor(u0 + basis @ c_true, dtype=state.dtype)

    def objective(free):
        return Loss({"fit": (state.joints_n() - target).square().sum() * 100.0})

    stages = (PhotoStage("identity", ("identity",), 150),)
    run_schedule(state, stages, objective, PhotoLearningRates(identity=0.02), label="test")
    assert float(state.identity_c.detach().abs().max()) == 0.0
    moved = state.theta_n.detach().double().numpy() - u0
    c_fit, *_ = np.linalg.lstsq(basis, moved, rcond=None)
    assert np.abs(basis @ c_fit - moved).max() < 1e-4  # nothing outside the span (float32 steps)
    assert np.abs(c_fit - c_true).max() < 0.05, c_fit


def test_the_identity_prior_term_sees_the_live_step():
    """Between fold-ins the terms read ``theta_n + B c`` (so the prior's gradient reaches ``c``)."""
    state = _state()
    prior = cached_identity_prior()
    state.set_identity_subspace(prior, 3)
    with torch.no_grad():
        state.identity_c.copy_(torch.tensor([1.0, -2.0, 0.5]))
    expected = (
        state.theta_n
        + torch.as_tensor(prior.components[:3].T * np.sqrt(prior.variances[:3]), dtype=state.dtype) @ state.identity_c
    )
    got = state.term_inputs()["theta_n"][0]
    assert torch.allclose(got, expected)
    from pipeline.fitting.terms import term_values

    identity_terms = [t for t in state.prior_terms(PhotometricConfig().prior) if t.name == "identity"]
    value = term_values(identity_terms, state.term_inputs(), {})["identity"]
    value.backward()
    assert float(state.identity_c.grad.abs().max()) > 0.0  # the prior pulls c back


def test_bad_identity_settings_are_rejected():
    with pytest.raises(InputError, match="identity_components"):
        PhotometricConfig(identity_components=0)
    for step in (0.0, 1.5, -0.25):
        with pytest.raises(InputError, match="identity_step"):
            PhotometricConfig(identity_step=step)
    with pytest.raises(InputError, match="at least one direction"):
        _state().set_identity_subspace(cached_identity_prior(), 0)
    assert [s.free for s in identity_schedule(5)] == [("identity",)] and identity_schedule(0) == ()


# ----------------------------------------------------------------------------------------------------
# the pixels alone move the identity towards the truth
# ----------------------------------------------------------------------------------------------------

C_TRUE = np.array([1.2, -1.0, 0.8, -0.6, 0.7, 0.5, -0.5, 0.4])


@pytest.fixture(scope="module")
def identity_photo():
    """A head of the rig's identity space (the prior's mean plus a known offset along its first eight directions),
    path-traced with the benchmark's random skin, point light and background (not the fit's image model)."""
    from pipeline.fitting.state import head_vertices
    from pipeline.synthetic.photos.settings import PhotoSettings
    from pipeline.synthetic.photos.simulate import simulate_photo
    from rig.expressions import EXPRESSION_NAMES
    from rig.model import JointRig
    from rig.parameters import NUM_PARAMETERS
    from rig.skinning.joint_fit import parameter_span

    rig = JointRig()
    prior = cached_identity_prior()
    k = len(C_TRUE)
    u = prior.mean + (prior.components[:k].T * np.sqrt(prior.variances[:k])) @ C_TRUE
    theta = u * parameter_span(torch.float64).numpy()
    assert theta.shape == (NUM_PARAMETERS,)
    head = head_vertices(rig, None, theta, np.zeros(50), np.zeros(len(EXPRESSION_NAMES)))
    settings = PhotoSettings(width=256, height=256, spp=16, landmark_noise_px=0.5, offset_px=5)
    photo = simulate_photo(head, np.random.default_rng(11), settings, yaw_deg=20.0, pitch_deg=0.0, roll_deg=0.0)
    return rig, head, photo


@pytest.mark.slow  # 16 s: `make test-slow`
def test_the_identity_stage_moves_the_head_towards_the_truth_from_the_pixels_alone(identity_photo):
    """The landmark fit only places the head (its identity stays the prior's mean); the identity stage, its
    landmark term off, then brings the face closer to the truth from the image alone."""
    from dataclasses import replace

    from pipeline.evaluation.photos import face_error
    from pipeline.fitting.state import head_vertices
    from pipeline.photo.fit import fit_photo
    from pipeline.photo.fit_config import FitPhotoConfig

    rig, head, photo = identity_photo
    base = FitPhotoConfig()
    landmarks = replace(base.landmarks, lm_stages=tuple(s for s in base.landmarks.lm_stages if s.free == ("pose",)))
    photometric = replace(
        base.photometric,
        enabled=True,
        stages=identity_schedule(40),
        lambda_landmarks=0.0,
        render_size=96,
        spp=8,
        lambda_photo=60.0,
        identity_step=1.0,  # the stage's whole step (the default keeps a quarter of it)
    )
    config = replace(base, landmarks=landmarks, photometric=photometric)
    fit = fit_photo(photo.image, photo.landmarks2d, focal=photo.focal, config=config, rig=rig, neural=None)
    lf = fit.landmark_fit
    before = face_error(head_vertices(rig, None, lf.theta, lf.z, lf.expressions), head, rig.asset)
    after = face_error(np.asarray(fit.rig_vertices), head, rig.asset)
    assert [s.name for s in fit.stages] == ["photo identity"]
    # measured 1.91 -> 0.90 mm (the s2m median 0.40 -> 0.24)
    assert after["vertex_mean_mm"] < 0.7 * before["vertex_mean_mm"], (before, after)

    # identity_step keeps that fraction of the stage's change of the joint channels (the same repeatable stage)
    half = replace(config, photometric=replace(photometric, identity_step=0.5))
    fit_half = fit_photo(photo.image, photo.landmarks2d, focal=photo.focal, config=half, rig=rig, neural=None)
    np.testing.assert_allclose(fit_half.landmark_fit.theta, lf.theta)
    np.testing.assert_allclose(fit_half.theta, lf.theta + 0.5 * (fit.theta - lf.theta), rtol=1e-5, atol=1e-4)
    assert np.abs(fit.theta - lf.theta).max() > 0.1  # the stage moved the channels
    from rig.skinning.neural import load_neural

    neural, _ = load_neural(rig)  # the landmark config's use_neural: the fit skins with it
    expected = head_vertices(rig, neural, fit_half.theta, fit_half.z, fit_half.expressions)
    np.testing.assert_allclose(fit_half.rig_vertices, expected, atol=1e-3)
    np.testing.assert_allclose(fit_half.rotation, fit.rotation, atol=1e-6)
