"""Spherical-harmonic lighting (pipeline.photo.sh): the irradiance basis against the clamped cosine it
approximates, least squares recovering known coefficients (the differentiable normals it shades with are
rig.geometry.vertex_normals, tested in tests/rig/test_geometry.py)."""

import math

import numpy as np
import pytest

from pipeline.photo.sh import fit_sh, sh_basis

KERNEL = np.array([math.pi] + [2 * math.pi / 3] * 3 + [math.pi / 4] * 5)  # Lambertian band factors


def _sphere(n: int, seed: int = 0) -> np.ndarray:
    p = np.random.default_rng(seed).standard_normal((n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def test_directional_light_irradiance_is_the_clamped_cosine():
    """A distant light of unit irradiance from ``d`` has SH coefficients ``Y_k(d)``; with the kernel folded into
    the basis, ``sh_basis(n) @ Y(d)`` is Ramamoorthi & Hanrahan's order-2 approximation of ``max(0, n . d)``."""
    d = np.array([0.3, -0.5, 0.8])
    d /= np.linalg.norm(d)
    y_d = sh_basis(d) / KERNEL
    n = _sphere(20000)
    approx = sh_basis(n) @ y_d
    exact = np.clip(n @ d, 0.0, None)
    assert np.sqrt(np.mean((approx - exact) ** 2)) < 0.05
    assert np.abs(approx - exact).max() < 0.2
    # facing the light the irradiance is ~1, facing away ~0
    assert sh_basis(d) @ y_d == pytest.approx(1.0, abs=0.1)
    assert sh_basis(-d) @ y_d == pytest.approx(0.0, abs=0.1)


def test_fit_sh_recovers_known_coefficients():
    rng = np.random.default_rng(1)
    normals = _sphere(3000, 2)
    normals = normals[normals[:, 2] < 0.2]  # mostly the camera's side, as a face shows
    albedo = rng.uniform(0.2, 0.8, (len(normals), 3))
    truth = rng.normal(0.0, 0.3, (9, 3))
    truth[0] = 1.0
    target = albedo * (sh_basis(normals) @ truth)
    np.testing.assert_allclose(fit_sh(albedo, normals, target, ridge=1e-9), truth, atol=1e-5)


def test_fit_sh_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="fit_sh"):
        fit_sh(np.ones((5, 3)), np.ones((4, 3)), np.ones((5, 3)))
