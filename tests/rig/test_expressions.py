"""rig.expressions: 24 sculpted expression blendshapes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rig.expressions import (
    EXPRESSION_NAMES,
    EXPRESSIONS,
    ExpressionError,
    ExpressionModel,
    build_expression_basis,
    coefficients_from_dict,
    expression_limits,
    mirror_coefficients,
    peak_displacements,
)
from rig.model import JointRig

MIRROR_X = np.array([-1.0, 1.0, 1.0])

GOLDEN_NAMES = (
    "brow_raise_left", "brow_raise_right", "brow_lower_left", "brow_lower_right", "brow_inner_up",
    "eye_blink_left", "eye_blink_right", "eye_squint_left", "eye_squint_right", "eye_wide_left",
    "eye_wide_right", "cheek_puff", "nose_sneer", "jaw_open", "mouth_smile_left", "mouth_smile_right",
    "mouth_frown_left", "mouth_frown_right", "mouth_stretch_left", "mouth_stretch_right", "mouth_pucker",
    "lips_press", "upper_lip_up", "lower_lip_down",
)

# The regions where each shape's largest displacement must lie (by name prefix).
OWN_REGIONS = {
    "brow_": ("brows",),
    "eye_": ("eyelids",),
    "cheek_puff": ("cheeks",),
    "nose_sneer": ("nose",),
    "jaw_open": ("chin", "jaw", "lips"),
    "mouth_": ("lips", "cheeks"),
    "lips_press": ("lips",),
    "upper_lip_up": ("lips",),
    "lower_lip_down": ("lips",),
}


def _own(name):
    return next(v for k, v in OWN_REGIONS.items() if name.startswith(k))


@pytest.fixture(scope="module")
def model(asset):
    return ExpressionModel(asset, dtype=torch.float64)


@pytest.fixture(scope="module")
def shapes(model):
    """Offsets ``(E, V, 3)`` of every shape alone at its ``high`` limit (through the model)."""
    _, high = expression_limits(torch.float64)
    with torch.no_grad():
        return model(torch.diag(high)).numpy()


def _offset(model, name, value=1.0):
    c = coefficients_from_dict({name: value}, dtype=torch.float64)[None]
    with torch.no_grad():
        return model(c)[0].numpy()


def test_golden_names():
    assert EXPRESSION_NAMES == GOLDEN_NAMES
    assert len(EXPRESSION_NAMES) == 24 == len(EXPRESSIONS)
    for spec in EXPRESSIONS:
        assert spec.side in ("left", "right", "center")
        assert spec.side != "left" or spec.name.endswith("_left")
        assert spec.side != "right" or spec.name.endswith("_right")
        assert spec.high == 1.0 and spec.low in (0.0, -1.0)
    assert [s.name for s in EXPRESSIONS if s.low < 0] == ["cheek_puff"]


def test_basis_deterministic_and_matches_model(asset, model, shapes):
    b1, b2 = build_expression_basis(asset), build_expression_basis(asset)
    assert b1.shape == (24, len(asset.vertices), 3)
    np.testing.assert_array_equal(b1, b2)
    np.testing.assert_allclose(shapes, b1, atol=1e-9)  # jaw_open: exact rotation agrees at c = 1


def test_zero_coefficients(model):
    out = model(torch.zeros(3, 24, dtype=torch.float64))
    assert out.shape == (3, model.template.shape[0], 3)
    assert torch.count_nonzero(out) == 0


def test_locality(asset, shapes):
    still = asset.region_mask("ears", "scalp")
    neck = asset.region_mask("neck")
    for i, name in enumerate(EXPRESSION_NAMES):
        d = np.linalg.norm(shapes[i], axis=1)
        top = asset.region_names[asset.regions[d.argmax()]]
        assert top in _own(name), (name, top)
        assert d[still].max() < 0.05, name
        if name != "jaw_open":
            assert d[neck].max() < 0.05, name
        assert d[asset.region_mask("eyeballs")].max() == 0.0, name


def test_peaks_plausible(asset):
    peaks = peak_displacements(asset)
    for name, peak in peaks.items():
        assert 2.0 <= peak <= (40.0 if name == "jaw_open" else 12.0), (name, peak)


def test_left_right_mirror(asset, shapes):
    for i, name in enumerate(EXPRESSION_NAMES):
        if name.endswith("_left"):
            j = EXPRESSION_NAMES.index(name[:-5] + "_right")
            np.testing.assert_allclose(shapes[j][asset.mirror] * MIRROR_X, shapes[i], atol=1e-9, err_msg=name)
        elif not name.endswith("_right"):
            np.testing.assert_allclose(shapes[i][asset.mirror] * MIRROR_X, shapes[i], atol=1e-9, err_msg=name)


def test_mirror_coefficients(asset, model):
    c = torch.rand(2, 24, dtype=torch.float64)
    with torch.no_grad():
        a, b = model(c), model(mirror_coefficients(c))
    np.testing.assert_allclose(b.numpy()[:, asset.mirror] * MIRROR_X, a.numpy(), atol=1e-9)
    np.testing.assert_array_equal(mirror_coefficients(mirror_coefficients(c.numpy())), c.numpy())


def _rims(asset, loop):
    v = asset.vertices
    half = len(loop) // 2
    upper, lower = loop[1:half], loop[half + 1:]
    lower = lower[np.argmin(np.abs(v[lower, 0][None] - v[upper, 0][:, None]), axis=1)]  # same columns
    return upper, lower


def test_blink_closes_left_eye_only(asset, model):
    v = asset.vertices + _offset(model, "eye_blink_left")
    (ul, ll), (ur, lr) = _rims(asset, asset.eye_loops[0]), _rims(asset, asset.eye_loops[1])
    assert np.linalg.norm(v[ul] - v[ll], axis=1).max() < 1.5  # closed
    template_gap = np.linalg.norm(asset.vertices[ur] - asset.vertices[lr], axis=1).max()
    assert np.linalg.norm(v[ur] - v[lr], axis=1).max() == pytest.approx(template_gap)  # right eye open
    d = np.linalg.norm(v - asset.vertices, axis=1)
    assert d[ll].max() < 1e-9  # the lower lid stays
    assert d[ul].min() > 3.0


def test_lids_other_lid_still(asset, model):
    for name, still in (("eye_blink_left", "lower"), ("eye_squint_left", None), ("eye_wide_left", None)):
        d = np.linalg.norm(_offset(model, name), axis=1)
        upper, lower = _rims(asset, asset.eye_loops[0])
        if still == "lower":
            assert d[lower].max() < 1e-9
        assert d[asset.eye_loops[1]].max() == 0.0  # the other eye


def test_jaw_open(asset, model):
    loop = asset.mouth_loop
    upper, lower = _rims(asset, loop)
    mid = np.argmin(np.abs(asset.vertices[upper, 0]))
    off = _offset(model, "jaw_open")
    drop = -(off[lower[mid], 1] - off[upper[mid], 1])
    assert drop >= 15.0
    chin = asset.region_mask("chin")
    assert off[chin, 1].mean() < -10.0
    # Half-way: the exact rotation by 9 degrees (not the chord).
    half = _offset(model, "jaw_open", 0.5)
    assert 0.0 < -half[lower[mid], 1] < -off[lower[mid], 1]


def test_lips_independent(asset, model):
    upper, lower = _rims(asset, asset.mouth_loop)
    down = np.linalg.norm(_offset(model, "lower_lip_down"), axis=1)
    up = np.linalg.norm(_offset(model, "upper_lip_up"), axis=1)
    assert down[upper].max() < 1e-9 and down[lower].max() > 2.0
    assert up[lower].max() < 1e-9 and up[upper].max() > 2.0


def _face_normals(v, f):
    t = v[f]
    return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])


def test_smooth_no_flips(asset, model):
    n0 = _face_normals(asset.vertices, asset.faces)
    for i, spec in enumerate(EXPRESSIONS):
        for value in {spec.low, spec.high} - {0.0}:
            v = asset.vertices + _offset(model, spec.name, value)
            assert np.isfinite(v).all()
            ok = ((_face_normals(v, asset.faces) * n0).sum(axis=1) > 0).mean()
            assert ok >= 0.995, (spec.name, value, ok)


def test_composes_with_rig(asset):
    rig = JointRig(asset)
    expr = ExpressionModel(asset)
    c = torch.zeros(2, 24)
    c[0, EXPRESSION_NAMES.index("jaw_open")] = 0.7
    c[1, EXPRESSION_NAMES.index("mouth_smile_left")] = 1.0
    c.requires_grad_(True)
    theta = torch.zeros(2, rig.num_parameters)
    out = rig(theta, vertices=rig.template + expr(c)).vertices
    assert out.shape == (2, rig.num_vertices, 3) and torch.isfinite(out).all()
    torch.testing.assert_close(out, rig.template + expr(c), atol=1e-3, rtol=0)  # rest pose: no change
    out.sum().backward()
    assert c.grad is not None and torch.isfinite(c.grad).all()


def test_coefficients_from_dict():
    c = coefficients_from_dict({"jaw_open": 0.5, "cheek_puff": -0.5}, dtype=torch.float64)
    assert c.shape == (24,) and c[EXPRESSION_NAMES.index("jaw_open")] == 0.5
    with pytest.raises(ExpressionError):
        coefficients_from_dict({"eye_wink": 1.0})
    with pytest.raises(ValueError):
        coefficients_from_dict({"jaw_open": 1.5})
    with pytest.raises(ExpressionError):
        coefficients_from_dict({"jaw_open": -0.1})
    with pytest.raises(ExpressionError):
        coefficients_from_dict({"jaw_open": float("nan")})
    with pytest.warns(UserWarning):
        c = coefficients_from_dict({"jaw_open": 1.5, "cheek_puff": -3.0}, clamp=True)
    assert c[EXPRESSION_NAMES.index("jaw_open")] == 1.0 and c[EXPRESSION_NAMES.index("cheek_puff")] == -1.0


def test_bad_shape(model):
    with pytest.raises(ExpressionError):
        model(torch.zeros(2, 23))
    low, high = expression_limits(torch.float32)
    assert low.shape == high.shape == (24,) and (low <= 0).all() and (high > 0).all()
