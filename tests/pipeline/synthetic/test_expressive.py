"""pipeline.synthetic.expressive: expressive synthetic heads whose expressions are not the model's blendshapes."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.synthetic.expressive import (
    EXPRESSIVE_FEATURE_NAMES,
    EXPRESSIVE_LIMITS,
    ExpressiveHeads,
    expressive_offsets,
    expressive_peaks,
    expressive_split,
    sample_expression_coefficients,
)
from pipeline.synthetic.population import population_split
from rig.expressions import build_expression_basis, left_eye_geometry

MIRROR_X = np.array([-1.0, 1.0, 1.0])
F = len(EXPRESSIVE_FEATURE_NAMES)


@pytest.fixture(scope="module")
def singles(asset):
    """``(F, V, 3)``: each feature alone at its upper limit."""
    return expressive_offsets(np.eye(F), asset)


@pytest.fixture(scope="module")
def heads(asset):
    return expressive_split("heldout", 0, n=12, asset=asset)


def _face_normals(v, f):
    t = v[f]
    return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])


def test_shapes_and_single(asset, singles):
    assert singles.shape == (F, len(asset.vertices), 3) and np.isfinite(singles).all()
    one = expressive_offsets(np.eye(F)[3], asset)
    np.testing.assert_allclose(one, singles[3])


def test_zero_is_neutral(asset, heads):
    assert np.abs(expressive_offsets(np.zeros(F), asset)).max() == 0.0
    assert np.abs(expressive_offsets(np.zeros((2, F)), asset)).max() == 0.0


def test_split_deterministic_and_consistent(asset, heads):
    again = expressive_split("heldout", 0, n=12, asset=asset)
    assert isinstance(heads, ExpressiveHeads) and len(heads) == 12
    np.testing.assert_array_equal(again.vertices, heads.vertices)
    np.testing.assert_array_equal(again.seeds, heads.seeds)
    identity = population_split("heldout", 0, asset)
    np.testing.assert_array_equal(heads.neutral, identity.vertices[:12])
    np.testing.assert_array_equal(heads.identity_coefficients, identity.coefficients[:12])
    assert heads.names == identity.names[:12]
    np.testing.assert_allclose(heads.vertices - heads.neutral,
                               expressive_offsets(heads.expression_coefficients, asset), atol=1e-12)
    for i, s in enumerate(heads.seeds):
        np.testing.assert_array_equal(sample_expression_coefficients(np.random.default_rng(int(s)), 1)[0],
                                      heads.expression_coefficients[i])
    other = expressive_split("heldout", 1, n=12, asset=asset)
    assert not np.array_equal(other.expression_coefficients, heads.expression_coefficients)


def test_sampling():
    c = sample_expression_coefficients(np.random.default_rng(5), 200)
    assert c.shape == (200, F)
    active = (c != 0).sum(axis=1)
    assert active.min() >= 1 and active.max() <= 3
    amp = np.abs(c[c != 0])
    assert amp.min() >= 0.4 and amp.max() <= 1.0
    for j, n in enumerate(EXPRESSIVE_FEATURE_NAMES):
        lo, hi = EXPRESSIVE_LIMITS[n]
        assert lo <= c[:, j].min() and c[:, j].max() <= hi
    np.testing.assert_array_equal(c, sample_expression_coefficients(5, 200))


def test_still_regions(asset, singles):
    d = np.linalg.norm(singles, axis=2)
    assert d[:, asset.region_mask("eyeballs")].max() == 0.0
    jaw = EXPRESSIVE_FEATURE_NAMES.index("jaw_drop")
    assert d[:, asset.region_mask("ears", "scalp")].max() < 0.05  # jaw included
    others = np.delete(d, jaw, axis=0)
    assert others[:, asset.region_mask("neck")].max() < 0.05


def test_left_right_mirror(asset, singles):
    for j, n in enumerate(EXPRESSIVE_FEATURE_NAMES):
        if n.endswith("_l"):
            r = EXPRESSIVE_FEATURE_NAMES.index(n[:-2] + "_r")
            np.testing.assert_allclose(singles[r], singles[j][asset.mirror] * MIRROR_X, atol=1e-9)
        elif not n.endswith("_r"):
            np.testing.assert_allclose(singles[j], singles[j][asset.mirror] * MIRROR_X, atol=1e-9, err_msg=n)
    # Nonlinear features mirror at partial coefficients too.
    c = np.zeros(F)
    c[EXPRESSIVE_FEATURE_NAMES.index("eye_close_l")] = 0.6
    m = np.zeros(F)
    m[EXPRESSIVE_FEATURE_NAMES.index("eye_close_r")] = 0.6
    np.testing.assert_allclose(expressive_offsets(m, asset), expressive_offsets(c, asset)[asset.mirror] * MIRROR_X,
                               atol=1e-9)


def test_peaks(asset):
    peaks = expressive_peaks(asset)
    assert 38.0 < peaks["jaw_drop"] < 50.0
    assert 5.0 < peaks["eye_close_l"] < 10.0
    for n, p in peaks.items():
        assert 3.0 <= p <= 50.0, (n, p)


def test_sampled_heads_peak_range(heads):
    d = np.linalg.norm(heads.vertices - heads.neutral, axis=2).max(axis=1)
    assert np.isfinite(heads.vertices).all()
    assert d.min() > 1.0 and d.max() < 50.0


def test_not_in_model_span(asset, heads):
    basis = build_expression_basis(asset).reshape(24, -1).T
    q, _ = np.linalg.qr(basis)
    off = (heads.vertices - heads.neutral).reshape(len(heads), -1)
    resid = np.linalg.norm(off - (off @ q) @ q.T, axis=1) / np.linalg.norm(off, axis=1)
    assert resid.min() > 0.25, resid


def test_jaw_opens_mouth(asset):
    loop = np.asarray(asset.mouth_loop)
    half = len(loop) // 2
    upper, lower = loop[1:half], loop[half + 1:]
    v = asset.vertices
    mid_u, mid_l = upper[np.argmin(np.abs(v[upper, 0]))], lower[np.argmin(np.abs(v[lower, 0]))]
    c = np.zeros(F)
    c[0] = 1.0
    off = expressive_offsets(c, asset)
    assert off[mid_l, 1] - off[mid_u, 1] < -15.0
    half_open = expressive_offsets(0.5 * c, asset)
    assert off[mid_l, 1] < half_open[mid_l, 1] < 0.0


def test_eye_close(asset):
    eye = left_eye_geometry(asset)
    c = np.zeros(F)
    c[EXPRESSIVE_FEATURE_NAMES.index("eye_close_l")] = 1.0
    v = asset.vertices + expressive_offsets(c, asset)
    assert np.linalg.norm(v[eye.upper] - v[eye.lower], axis=1).max() < 1.0
    right = asset.eye_loops[1]
    assert np.abs(v[right] - asset.vertices[right]).max() == 0.0
    # The closed lid stays in front of the (still) eyeball: no lid vertex inside radius 12.
    moved = np.linalg.norm(v - asset.vertices, axis=1) > 0
    assert np.linalg.norm(v[moved] - eye.center, axis=1).min() >= 12.0


def test_lips_independent_across_slit(asset):
    """The funnel opens the slit: the rims move apart vertically in the middle, not at the corners."""
    loop = np.asarray(asset.mouth_loop)
    half = len(loop) // 2
    upper, lower = loop[1:half], loop[half + 1:]
    c = np.zeros(F)
    c[EXPRESSIVE_FEATURE_NAMES.index("lip_funnel")] = 1.0
    off = expressive_offsets(c, asset)
    v = asset.vertices
    mu, ml = upper[np.argmin(np.abs(v[upper, 0]))], lower[np.argmin(np.abs(v[lower, 0]))]
    assert off[mu, 1] - off[ml, 1] > 2.0
    corners = loop[[0, half]]
    assert np.abs(off[corners, 1]).max() < 0.5


def test_no_flips_and_smooth(asset, singles):
    n0 = _face_normals(asset.vertices, asset.faces)
    edges = np.concatenate([asset.faces[:, [0, 1]], asset.faces[:, [1, 2]], asset.faces[:, [2, 0]]])
    # Skin edges only: the lids slide over the (still) eyeballs and the mouth interior stretches.
    edges = edges[~asset.region_mask("eyeballs", "mouth_interior")[edges].any(axis=1)]
    length = np.linalg.norm(asset.vertices[edges[:, 0]] - asset.vertices[edges[:, 1]], axis=1)
    for n, o in zip(EXPRESSIVE_FEATURE_NAMES, singles):
        ok = ((_face_normals(asset.vertices + o, asset.faces) * n0).sum(axis=1) > 0).mean()
        assert ok >= 0.998, (n, ok)
        # No spikes: the displacement difference along a skin edge stays below its length (the open
        # jaw stretches the lower lip towards the corners up to about 1.7 times).
        strain = np.linalg.norm(o[edges[:, 0]] - o[edges[:, 1]], axis=1) / length
        assert strain.max() < (2.0 if n == "jaw_drop" else 1.0), (n, strain.max())


def test_bad_input(asset):
    with pytest.raises(ValueError, match="shape"):
        expressive_offsets(np.zeros(F + 1), asset)
    with pytest.raises(ValueError, match="limits"):
        expressive_offsets(np.full(F, 1.5), asset)
    with pytest.raises(ValueError, match="finite"):
        expressive_offsets(np.full(F, np.nan), asset)
    with pytest.raises(ValueError):
        expressive_split("nope")
    with pytest.raises(ValueError):
        expressive_split("heldout", 0, n=101)
    with pytest.raises(ValueError):
        sample_expression_coefficients(0, -1)
