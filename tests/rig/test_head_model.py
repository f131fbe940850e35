"""Both head models through the one interface: forward, limits, params round trip, and a new model by
registration only."""

import json

import numpy as np
import pytest
import torch

from rig.expressions import EXPRESSION_NAMES, ExpressionModel
from rig.head_model import (
    HeadModel,
    HeadModelError,
    HeadPose,
    ParameterGroup,
    create,
    create_from_dict,
    head_model_kinds,
    is_posable,
)
from rig.parameters import ParameterError, theta_limits
from rig.skinning.neural import load_neural


@pytest.fixture(scope="module")
def models():
    return {kind: create(kind) for kind in ("jnr", "asm")}


def _random_inside(group: ParameterGroup, rng) -> np.ndarray:
    low = np.where(np.isfinite(group.low), group.low, -1.0)
    high = np.where(np.isfinite(group.high), group.high, 1.0)
    return low + (high - low) * rng.uniform(0.2, 0.8, group.size)


def test_both_models_are_registered_and_satisfy_the_protocol(models):
    assert {"jnr", "asm"} <= set(head_model_kinds())
    for kind, model in models.items():
        assert isinstance(model, HeadModel) and model.kind == kind
        assert is_posable(kind) == model.posable
        groups = model.groups()
        assert groups[-1].name == "expressions" and groups[-1].names == tuple(EXPRESSION_NAMES)
        for g in groups:
            assert g.low.shape == g.high.shape == (g.size,) and np.all(g.low <= g.high)
            assert len(set(g.names)) == g.size  # every float has its own name


def test_rest_parameters_give_the_template(models, asset):
    for model in models.values():
        head = model.forward(model.initial())
        assert isinstance(head, HeadPose) and head.vertices.dtype == np.float64
        np.testing.assert_allclose(head.rest, asset.vertices, atol=1e-9)
        np.testing.assert_allclose(head.vertices, asset.vertices, atol=1e-6)


def test_jnr_forward_is_the_rig_with_the_neural_weights(models, rig64, rng):
    """Against the rig's own pieces: expressions on the template, the decoded weights, the joint hierarchy."""
    model = models["jnr"]
    joints, latent, expressions = model.groups()
    theta = _random_inside(joints, rng)
    z = rng.normal(0, 0.5, latent.size)
    c = _random_inside(expressions, rng)
    head = model.forward(model.params(theta, z, c))
    with torch.no_grad():
        rest = ExpressionModel(rig64.asset, dtype=torch.float64).vertices(torch.as_tensor(c)[None])[0]
        weights = load_neural(rig64)[0](torch.as_tensor(z)[None])[0]
        expected = rig64(torch.as_tensor(theta)[None], weights=weights, vertices=rest).vertices[0].numpy()
    np.testing.assert_allclose(head.vertices, expected, atol=1e-9)
    assert head.weights.shape == (len(expected), rig64.num_joints)
    assert head.joint_transforms.shape == (rig64.num_joints, 4, 4)
    assert np.abs(head.vertices - rest.numpy()).max() > 1.0  # the joints moved it


def test_jnr_limits_come_from_the_rig_and_are_enforced(models):
    joints = models["jnr"].groups()[0]
    low, high = theta_limits(torch.float64)
    np.testing.assert_array_equal(joints.low, low.numpy())
    np.testing.assert_array_equal(joints.high, high.numpy())
    data = models["jnr"].to_dict(models["jnr"].initial())
    name = joints.names[int(np.argmax(joints.high))]
    data["joints"][name] = float(joints.high.max()) * 2 + 1
    with pytest.raises(ParameterError, match="outside"):
        models["jnr"].from_dict(data)


@pytest.mark.parametrize("kind", ["jnr", "asm"])
def test_params_round_trip_through_json(models, kind, rng):
    model = models[kind]
    params = model.initial()
    c = _random_inside(model.groups()[-1], rng)
    if kind == "jnr":
        params = model.params(_random_inside(model.groups()[0], rng), rng.normal(0, 0.5, 50), c)
    else:
        asm = {k: v + rng.normal(0, 1e-3, v.shape) for k, v in params["asm"].items()}
        params = params.replace(asm=asm, expressions=c)
    text = json.dumps(model.to_dict(params))
    model2, params2 = create_from_dict(json.loads(text), kind=kind)
    assert model2.kind == kind
    np.testing.assert_array_equal(model2.forward(params2).vertices, model.forward(params).vertices)


def test_unknown_kind_and_foreign_parameters_are_refused(models):
    with pytest.raises(HeadModelError, match="unknown head model 'flame'"):
        create("flame")
    with pytest.raises(HeadModelError, match="asm head model given jnr parameters"):
        models["asm"].forward(models["jnr"].initial())
    with pytest.raises(HeadModelError, match="lacks"):
        models["jnr"].from_dict({"joints": {}})


def _jnr_values(model, rng, batch: int) -> dict[str, torch.Tensor]:
    joints, latent, expressions = model.groups()
    return {
        "joints": torch.as_tensor(np.stack([_random_inside(joints, rng) for _ in range(batch)])),
        "latent": torch.as_tensor(rng.normal(0, 0.5, (batch, latent.size))),
        "expressions": torch.as_tensor(np.stack([_random_inside(expressions, rng) for _ in range(batch)])),
    }


def test_the_batched_forward_is_each_head_forward_and_its_subset(models, rng):
    """``vertices`` of a batch of 3 is :meth:`forward` (the head written to files) of each, and a vertex
    subset is those rows of the whole head; float32 in gives float32 out, within float32's rounding."""
    model = models["jnr"]
    values = _jnr_values(model, rng, 3)
    with torch.no_grad():
        batch = model.vertices(values).numpy()
        ids = torch.as_tensor([0, 17, 2500, 4000])
        subset = model.vertices(values, ids).numpy()
        single = model.vertices({k: v.float() for k, v in values.items()})
    for i in range(3):
        params = model.params(*(values[g][i].numpy() for g in ("joints", "latent", "expressions")))
        np.testing.assert_allclose(batch[i], model.forward(params).vertices, atol=1e-9)
    np.testing.assert_allclose(subset, batch[:, ids.numpy()], atol=1e-12)
    assert single.dtype == torch.float32
    np.testing.assert_allclose(single.numpy(), batch, atol=1e-3)


def test_the_batched_forward_has_the_gradient_of_finite_differences(models, rng):
    """d(sum of some vertices' coordinates)/d(a joint channel, a latent, a coefficient) against central
    differences, float64: every group of the JNR head carries its gradient."""
    model = models["jnr"]
    values = {k: v.requires_grad_() for k, v in _jnr_values(model, rng, 1).items()}
    ids = torch.as_tensor([100, 1200, 3000])
    probe = torch.as_tensor(rng.normal(size=(3, 3)))

    def objective(vals):
        return (model.vertices(vals, ids)[0] * probe).sum()

    objective(values).backward()
    for group, index in (("joints", 5), ("joints", 60), ("latent", 3), ("expressions", 20)):
        h = 1e-5
        with torch.no_grad():
            plus = {k: v.detach().clone() for k, v in values.items()}
            minus = {k: v.detach().clone() for k, v in values.items()}
            plus[group][0, index] += h
            minus[group][0, index] -= h
            numeric = (objective(plus) - objective(minus)).item() / (2 * h)
        analytic = values[group].grad[0, index].item()
        assert abs(analytic - numeric) <= 1e-5 * max(1.0, abs(numeric)), (group, index, analytic, numeric)


def test_the_asm_batched_forward_is_its_forward_and_carries_gradients(models, rng):
    model = models["asm"]
    params = model.initial()
    c = _random_inside(model.groups()[1], rng)
    params = params.replace(expressions=c)
    p = model._parameters(params).map(lambda t: t.detach().clone().requires_grad_())
    out = model.vertices({"asm": p, "expressions": torch.as_tensor(c)[None]})
    np.testing.assert_allclose(out[0].detach().numpy(), model.forward(params).vertices, atol=1e-9)
    out[0, 1000].sum().backward()
    assert p.tau.grad is not None and p.tau.grad.abs().sum() > 0
