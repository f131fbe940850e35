"""Loss terms defined once (pipeline/fitting/terms.py, priors.py): the robust kernels' IRLS weights, each
prior's least-squares rows against its Adam value, and a throwaway term minimised by both solvers."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.camera import default_focal, make_camera
from pipeline.fitting.engine import LearningRates, Stage
from pipeline.fitting.identity import load_identity_prior
from pipeline.fitting.landmark_term import LandmarkTerm
from pipeline.fitting.least_squares import StateVector
from pipeline.fitting.priors import PriorWeights, asm_prior_terms
from pipeline.fitting.state import AsmScanState, FitState, PhotoState
from pipeline.fitting.terms import (
    L1,
    L2,
    Charbonnier,
    GemanMcClure,
    Huber,
    Inputs,
    LeastSquaresTerms,
    Term,
    Value,
    term_values,
)
from pipeline.photo.landmark_fit import LandmarkFitConfig, fit_landmarks, lm_schedule
from rig.expressions import ExpressionModel, coefficients_from_dict
from rig.geometry import head_rotation
from rig.parameters import CHANNEL_INDEX, NUM_PARAMETERS, random_theta
from rig.skinning.asm import AdaptiveSkinning
from rig.skinning.neural import LATENT, load_neural

KERNELS = [L2(), L1(eps=1e-6), Huber(0.7), GemanMcClure(0.5), Charbonnier(0.1)]


def _residuals(kernel, seed: int = 0) -> torch.Tensor:
    """``(2, 9)`` scalar residuals, or ``(2, 9, 2)`` groups for the kernels of a group's norm."""
    gen = torch.Generator().manual_seed(seed)
    shape = (2, 9) if isinstance(kernel, (L2, L1)) else (2, 9, 2)
    return torch.randn(shape, generator=gen, dtype=torch.float64) * 1.5


# -- kernels ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("kernel", KERNELS, ids=repr)
def test_irls_weight_gives_the_kernels_gradient_and_offset_its_value(kernel):
    r = _residuals(kernel).requires_grad_(True)
    (grad,) = torch.autograd.grad(kernel.rho(r).sum(), r)
    omega = kernel.irls(r.detach())
    omega = omega if isinstance(omega, float) else omega[..., None] if r.dim() == 3 else omega
    torch.testing.assert_close(omega * r.detach(), grad, rtol=1e-12, atol=1e-12)  # d/dr 0.5 omega |r|^2
    squared = r.detach().square() if r.dim() == 2 else r.detach().square().sum(-1)
    surrogate = 0.5 * kernel.irls(r.detach()) * squared + kernel.offset(r.detach())
    torch.testing.assert_close(surrogate, kernel.rho(r.detach()), rtol=1e-12, atol=1e-12)


def test_l2_has_no_offset_and_value_has_no_least_squares_form():
    r = _residuals(L2())
    assert float(L2().offset(r).abs().max()) == 0.0
    with pytest.raises(ValueError, match="least-squares"):
        Value().irls(r)


def test_a_term_says_how_the_lm_solver_takes_it():
    with pytest.raises(ValueError, match="lm must be one of"):
        Term("t", 1.0, lambda p: p["x"], L2(), lm="maybe")
    with pytest.raises(ValueError, match="needs group_weights"):
        Term("t", 1.0, lambda p: p["x"], L2(), normaliser="weights")
    with pytest.raises(ValueError, match="cannot be stacked"):
        Term("t", 1.0, lambda p: p["x"], Value())
    value_only = Term("scan data", 1.0, lambda p: p["x"], Value(), lm="none", note="a root of a mean")
    with pytest.raises(ValueError, match=r"'scan data': a root of a mean; use the Adam solver"):
        LeastSquaresTerms([value_only])
    a = Term("a", 1.0, lambda p: p["x"], L2())
    with pytest.raises(ValueError, match=r"distinct names; \['a'\]"):
        LeastSquaresTerms([a, a])
    box = Term("limits", 1.0, lambda p: p["x"], Value(), lm="box", note="held by the box")
    zero = Term("zero", 0.0, lambda p: p["x"], L2())
    assert [t.name for t in LeastSquaresTerms([a, box, zero]).terms] == ["a"]


def test_inputs_are_computed_once_and_name_what_is_missing():
    calls = []
    p = Inputs({"a": torch.ones(1, 2)}, b=lambda: calls.append(1) or torch.zeros(1, 2))
    assert torch.equal(p["b"], p["b"]) and calls == [1]
    assert sorted(p) == ["a", "b"] and len(p) == 2
    q = p.add(c=lambda: p["a"] * 2)
    assert float(q["c"].sum()) == 4.0 and "c" not in p
    with pytest.raises(KeyError, match="'theta' not provided"):
        p["theta"]


# -- the priors: one definition, two solvers -------------------------------------------------------


@pytest.fixture(scope="module")
def state64(rig64):
    """A float64 JNR state at a random point inside the joint limits, some channels beyond them."""
    state = FitState(rig64, None, ExpressionModel(rig64.asset, dtype=torch.float64), np.eye(3))
    gen = torch.Generator().manual_seed(4)
    with torch.no_grad():
        state.theta_n.copy_(torch.rand(NUM_PARAMETERS, generator=gen, dtype=torch.float64) * 0.8 - 0.4)
        state.z.normal_(0.0, 0.3, generator=gen)
        state.c.uniform_(0.0, 0.6, generator=gen)
    return state


WEIGHTS = PriorWeights(
    lambda_m=0.7, lambda_x=2.0, lambda_z=0.3, lambda_expressions=0.4, lambda_symmetry=1.5, lambda_identity=0.05
)


def _surrogate_matches_value(term: Term, p: Inputs, leaves: list[torch.Tensor]) -> None:
    """``0.5 |rows|^2`` (IRLS weights at ``p``) plus the kernel's offset is the term's value, and has its
    gradient, in float64."""
    omega = term.irls(p)
    rows = term.rows(p, omega)
    value = term.value(p)
    r = term.residual(p).detach()
    w = 1.0 if term.group_weights is None else term.group_weights.double()
    if term.normaliser == "mean":
        z = r.shape[1]
    elif term.normaliser == "weights":
        z = w.sum()
    else:
        z = term.normaliser
    offset = term.weight * (w * term.robust.offset(r)).sum(-1) / z
    torch.testing.assert_close(0.5 * rows.detach().square().sum(-1) + offset, value.detach(), rtol=1e-12, atol=1e-12)
    if isinstance(term.robust, L2):  # the least-squares cost *is* the value
        torch.testing.assert_close(0.5 * rows.detach().square().sum(-1), value.detach(), rtol=1e-12, atol=0.0)
    g_rows = torch.autograd.grad(0.5 * rows.square().sum(), leaves, allow_unused=True, retain_graph=True)
    g_value = torch.autograd.grad(value.sum(), leaves, allow_unused=True)
    for a, b in zip(g_rows, g_value):
        if a is None or b is None:
            assert a is None and b is None
        else:
            torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)


def test_each_priors_least_squares_rows_give_its_value_and_gradient(state64):
    terms = state64.prior_terms(WEIGHTS, identity=load_identity_prior())
    assert [t.name for t in terms] == ["L_m", "L_x", "latent", "expressions", "identity", "symmetry"]
    leaves = [state64.theta_n, state64.z, state64.c]
    for term in terms:
        if term.lm == "box":  # L_x: the LM solver's box limits keep it at 0 instead
            continue
        _surrogate_matches_value(term, state64.term_inputs(), leaves)
    # the joint-limit penalty is 0 inside the limits, the LM solver's box
    inside = Inputs(theta=lambda: state64.theta.detach()[None].clamp(state64.low, state64.high))
    assert float(terms[1].value(inside)[0]) == 0.0


def test_the_landmark_term_rows_give_its_huber_value(rig64, state64):
    camera = make_camera(320, 240, 400.0, dtype=torch.float64, pose=False)
    gen = torch.Generator().manual_seed(2)
    target = torch.rand(68, 2, generator=gen, dtype=torch.float64).numpy() * [320, 240]
    term = LandmarkTerm(rig64.asset, target, camera, 5.0, weighting="detector").term()
    pixels = (torch.as_tensor(target) + torch.randn(68, 2, generator=gen, dtype=torch.float64) * 6.0)[None]
    pixels.requires_grad_(True)
    p = Inputs({"landmarks_px": pixels})
    assert 0 < float((term.irls(p) < 1).float().mean()) < 1  # some landmarks beyond the Huber threshold
    _surrogate_matches_value(term, p, [pixels])


def test_priors_come_from_the_head_model(rig32):
    expressions = ExpressionModel(rig32.asset)
    jnr = FitState(rig32, None, expressions, np.eye(3)).prior_terms(PriorWeights())
    assert [t.name for t in jnr] == ["L_m", "L_x", "latent", "expressions"]
    asm = AsmScanState(AdaptiveSkinning(rig32), expressions, np.eye(3), np.zeros(3), 1.0)
    terms = asm.prior_terms(PriorWeights(lambda_m=0.3), lambda_m=0.15)
    assert [t.name for t in terms] == ["asm", "expressions", "smooth"]
    assert terms[0].weight == pytest.approx(PriorWeights().lambda_asm * 0.5) and terms[0].lm == "none"
    values = term_values(terms, asm.term_inputs().add({"rig_vertices": asm.rig_vertices()[None]}))
    assert set(values) == {"asm", "expressions", "smooth"} and all(torch.isfinite(v) for v in values.values())
    assert [t.name for t in asm_prior_terms(PriorWeights(lambda_asm_smooth=0.0), asm.asm, expressions=False)] == ["asm"]


def test_state_vector_packs_the_free_groups_and_their_box(rig32):
    state = PhotoState(rig32, None, ExpressionModel(rig32.asset), np.eye(3), np.array([1.0, 2.0, 600.0]))
    vector = StateVector(state, ("pose", "expressions"))
    x = vector.pack()
    assert x.dtype == torch.float64 and x.shape == (6 + state.c.numel(),)
    low, high = vector.bounds()
    assert torch.isinf(low[:6]).all() and torch.equal(low[6:], state.c_low.double())
    values = vector.unpack(torch.stack([x, x + 0.1]))
    assert values["translation"].shape == (2, 3) and float(values["translation"][1, 2]) == pytest.approx(600.1)
    assert torch.equal(values["theta_n"][1], state.theta_n.double())  # not free: held
    vector.write(x + 0.25)
    assert (
        float(state.translation.detach()[0]) == pytest.approx(1.25) and float(state.theta_n.detach().abs().max()) == 0
    )


# -- a throwaway term, minimised by both solvers -----------------------------------------------------

CHANNEL = CHANNEL_INDEX["nose_tip.translate_z"]
TARGET_MM = 8.0


@pytest.fixture(scope="module")
def head_landmarks(rig32):
    """68 landmarks of a head made by the rig (random joints, a small expression), yaw 20 deg, 640 x 480."""
    neural, _ = load_neural(rig32)
    theta = random_theta(torch.Generator().manual_seed(5), spread=0.2)
    theta[0, CHANNEL] = 0.0
    c = coefficients_from_dict({"jawOpen": 0.2})
    state = PhotoState(rig32, neural, ExpressionModel(rig32.asset), head_rotation(20.0, 0.0, 0.0), [0, 0, 650.0])
    state.load(theta[0], np.zeros(LATENT), c.numpy())
    term = LandmarkTerm(rig32.asset, np.zeros((68, 2)), make_camera(640, 480, default_focal(640, 480), pose=False), 5)
    return neural, term.project(state, state.rig_vertices())


def _pull(weight: float) -> Term:
    """A throwaway term: one joint channel towards ``TARGET_MM``."""
    return Term("pull", weight, lambda p: p["theta"][:, CHANNEL : CHANNEL + 1] - TARGET_MM, L2())


@pytest.mark.parametrize("solver", ["lm", "adam"])
def test_a_term_added_once_is_minimised_by_either_solver(rig32, head_landmarks, solver):
    neural, landmarks = head_landmarks
    config = LandmarkFitConfig(
        solver=solver,
        lm_stages=lm_schedule(3, 3, 6),
        stages=(Stage("pose", ("pose",), 10), Stage("joints", ("pose", "joints"), 40)),
        lr=LearningRates(joints=0.03),
    )

    def fit(*terms):
        return fit_landmarks(landmarks, 640, 480, config=config, rig=rig32, neural=neural, terms=terms)

    free, pulled = fit(), fit(_pull(1.0))
    assert abs(free.theta[CHANNEL] - TARGET_MM) > 4.0, free.theta[CHANNEL]  # nothing else pulls it there
    assert abs(pulled.theta[CHANNEL] - TARGET_MM) < 0.5 * abs(free.theta[CHANNEL] - TARGET_MM), (
        pulled.theta[CHANNEL],
        free.theta[CHANNEL],
    )
    last = pulled.stages[-1]
    assert "pull" in last.terms and "pull" not in free.stages[-1].terms  # logged with the others


def test_an_lm_fit_refuses_a_term_it_cannot_take(rig32, head_landmarks):
    neural, landmarks = head_landmarks
    rmse = Term("rmse", 1.0, lambda p: p["theta"].square().mean(-1, keepdim=True).sqrt(), Value(), lm="none")
    config = LandmarkFitConfig(lm_stages=lm_schedule(2, 0, 0))
    with pytest.raises(ValueError, match="Levenberg-Marquardt cannot minimise the term"):
        fit_landmarks(landmarks, 640, 480, config=config, rig=rig32, neural=neural, terms=(rmse,))
    adam = LandmarkFitConfig(solver="adam", stages=(Stage("pose", ("pose",), 2),))
    fitted = fit_landmarks(landmarks, 640, 480, config=adam, rig=rig32, neural=neural, terms=(rmse,))
    assert "rmse" in fitted.stages[-1].terms  # the Adam engine takes any term
