"""rig.geometry.Similarity against known transforms and a naive per-point loop."""

import numpy as np
import pytest

from rig.geometry import Similarity, head_rotation


def _known(rng):
    return Similarity(head_rotation(*rng.uniform(-60, 60, 3)), rng.normal(0, 50, 3), 1.17)


def test_apply_matches_a_loop_and_the_matrix():
    rng = np.random.default_rng(0)
    s, pts = _known(rng), rng.normal(0, 80, (20, 3))
    loop = np.array([s.scale * s.rotation @ p + s.translation for p in pts])
    np.testing.assert_allclose(s.apply(pts), loop, atol=1e-9)
    np.testing.assert_allclose((s.matrix() @ np.c_[pts, np.ones(20)].T).T[:, :3], loop, atol=1e-9)
    np.testing.assert_allclose(s.apply_inverse(s.apply(pts)), pts, atol=1e-9)
    np.testing.assert_allclose(s.inverse().apply(s.apply(pts)), pts, atol=1e-9)
    other = _known(rng)
    np.testing.assert_allclose(s.then(other).apply(pts), other.apply(s.apply(pts)), atol=1e-9)


def test_fit_recovers_a_known_similarity_even_with_noise_and_weights():
    rng = np.random.default_rng(1)
    truth, src = _known(rng), rng.normal(0, 60, (40, 3))
    fit = Similarity.fit(src, truth.apply(src), with_scale=True)
    np.testing.assert_allclose(fit.rotation, truth.rotation, atol=1e-9)
    assert fit.scale == pytest.approx(truth.scale) and np.linalg.det(fit.rotation) == pytest.approx(1.0)
    dst = truth.apply(src)
    dst[:5] += 500.0  # outliers given zero weight do not move it
    w = np.ones(40)
    w[:5] = 0
    np.testing.assert_allclose(Similarity.fit(src, dst, w, with_scale=True).translation, truth.translation, atol=1e-6)
    assert Similarity.fit(src, truth.apply(src)).scale == 1.0  # without scale: rotation only


def test_bad_input():
    with pytest.raises(ValueError, match="Similarity.fit"):
        Similarity.fit(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="scale"):
        Similarity(np.eye(3), np.zeros(3), -1.0)
    with pytest.raises(ValueError, match="rotation"):
        Similarity(np.eye(2), np.zeros(3))
