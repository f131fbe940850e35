"""The staged fitting engine, on the real rig state with objectives whose optimum is known."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import pipeline
from pipeline.fitting.engine import LearningRates, Loss, Stage, run_schedule, run_stage
from pipeline.fitting.priors import PriorWeights, rig_prior_terms
from pipeline.fitting.state import FitState, PhotoState, ScanState
from pipeline.scan.fit_config import ScanLearningRates
from rig.expressions import ExpressionModel
from rig.losses import limit_loss, regularizer
from rig.model import JointRig
from rig.skinning.neural import load_neural


@pytest.fixture(scope="module")
def models():
    rig = JointRig()
    return rig, load_neural(rig)[0], ExpressionModel(rig.asset, dtype=rig.template.dtype)


def test_loss_total_adds_the_terms_in_order():
    terms = {"a": torch.tensor(1.0), "b": torch.tensor(2.5), "c": torch.tensor(-0.5)}
    assert float(Loss(terms).total) == 3.0


def test_a_stage_reaches_a_known_optimum_and_is_projected_into_the_limits(models):
    rig, neural, expr = models
    state = FitState(rig, neural, expr, np.eye(3))
    target = torch.full_like(state.c, 0.3)
    target[0] = 5.0  # far above every expression's upper limit
    calls = []

    def objective(free):
        return Loss({"pull": (state.c - target).square().sum()}, {"c0": state.c[0]})

    log = run_stage(
        state,
        Stage("expr", ("expressions",), 200),
        objective,
        LearningRates(expressions=0.05),
        progress=lambda *a: calls.append(a),
        before_stage=lambda s: {"hook": s.name},
    )
    expected = torch.minimum(torch.maximum(target, state.c_low), state.c_high)
    torch.testing.assert_close(state.c.detach(), expected, atol=2e-3, rtol=0)
    assert calls == [("expr", i, 200) for i in range(1, 201)]
    assert log.metrics["hook"] == "expr" and log.metrics["c0"] == pytest.approx(float(state.c_high[0]))
    assert log.terms["pull"] == pytest.approx(log.loss_end) and log.loss_start > log.loss_end
    assert state.theta_n.abs().max() == 0  # not freed, not moved


def test_the_decoder_is_frozen_during_a_schedule_and_released_after(models):
    rig, neural, expr = models
    state = FitState(rig, neural, expr, np.eye(3))
    seen = []

    def objective(free):
        seen.append(all(not p.requires_grad for p in neural.decoder.parameters()))
        return Loss({"z": (state.rig_vertices(free)[:10] ** 2).mean() * 1e-3 + state.z.square().sum()})

    logs = run_schedule(state, (Stage("z", ("latent",), 3), Stage("none", ("joints",), 0)), objective, LearningRates())
    assert [log.name for log in logs] == ["z"] and seen == [True] * 3
    assert all(p.requires_grad for p in neural.decoder.parameters())
    assert all(p.grad is None for p in neural.decoder.parameters())


def test_latent_stages_are_skipped_without_neural_skinning(models):
    rig, _, expr = models
    state = FitState(rig, None, expr, np.eye(3))
    assert (
        run_stage(state, Stage("z", ("latent",), 5), lambda free: Loss({"x": state.z.sum()}), LearningRates()) is None
    )


def test_divergence_is_an_error_and_releases_the_decoder(models):
    rig, neural, expr = models
    state = FitState(rig, neural, expr, np.eye(3))
    with pytest.raises(FloatingPointError, match="my fit diverged in stage 'bad'"):
        run_schedule(
            state,
            (Stage("bad", ("joints",), 3),),
            lambda free: Loss({"nan": state.theta_n.sum() * float("nan")}),
            LearningRates(),
            label="my fit",
        )
    assert all(p.requires_grad for p in neural.decoder.parameters())


def test_parameter_groups_come_from_names_and_learning_rate_fields(models):
    rig, neural, expr = models
    photo = PhotoState(rig, neural, expr, np.eye(3), np.array([0.0, 0.0, 600.0]))
    groups = photo.parameter_groups(("pose", "joints"), LearningRates(rotation=0.1, translation=2.0, joints=0.3))
    assert [g["lr"] for g in groups] == [0.1, 2.0, 0.3]
    assert [g["params"][0] is p for g, p in zip(groups, (photo.rotvec, photo.translation, photo.theta_n))] == [True] * 3
    lr = ScanLearningRates()
    scaled = ScanState(rig, neural, expr, np.eye(3), np.zeros(3), 1.1, fit_scale=True)
    fixed = ScanState(rig, neural, expr, np.eye(3), np.zeros(3), 1.1, fit_scale=False)
    assert len(scaled.parameter_groups(("pose",), lr)) == 3 and len(fixed.parameter_groups(("pose",), lr)) == 2
    assert scaled.scale == pytest.approx(1.1)
    # The models are not parameters of the fit: the optimiser can only see the state's own tensors.
    assert {n for n, _ in photo.named_parameters()} == {"rotvec", "theta_n", "identity_c", "z", "c", "translation"}


def test_prior_terms_match_the_rig_losses(models):
    rig, neural, expr = models
    state = FitState(rig, neural, expr, np.eye(3))
    with torch.no_grad():
        state.theta_n.uniform_(-0.6, 0.6, generator=torch.Generator().manual_seed(0))
        state.z.fill_(0.5)
    w = PriorWeights(lambda_m=2.0, lambda_x=3.0, lambda_z=0.5, lambda_expressions=1.0, lambda_symmetry=0.0)
    terms = rig_prior_terms(state, w)
    theta = state.theta.detach()
    assert set(terms) == {"L_m", "L_x", "latent", "expressions"}
    terms = {k: v.detach() for k, v in terms.items()}
    assert float(terms["L_m"]) == pytest.approx(2.0 * float(regularizer(theta[None])[0]), rel=1e-6)
    assert float(terms["L_x"]) == pytest.approx(
        3.0 * float(limit_loss(theta[None], state.low, state.high)[0]), rel=1e-6
    )
    assert float(terms["latent"]) == pytest.approx(0.5 * 50 * 0.25, rel=1e-6)
    assert "symmetry" in rig_prior_terms(state, PriorWeights(lambda_symmetry=1.0))
    assert float(rig_prior_terms(state, w, lambda_m=0.0)["L_m"].detach()) == 0.0


def test_the_public_facade():
    from pipeline.photo.fit import fit_photo
    from pipeline.scan.fit_config import FitScanConfig

    assert pipeline.fit_photo is fit_photo and pipeline.FitScanConfig is FitScanConfig
    assert set(pipeline.__all__) <= set(dir(pipeline))
    with pytest.raises(AttributeError, match="no attribute 'fit_everything'"):
        pipeline.fit_everything  # noqa: B018
