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
