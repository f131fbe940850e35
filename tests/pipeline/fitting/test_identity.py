"""The identity prior (pipeline.fitting.identity): PPCA algebra against naive formulas, rank selection, the
committed asset."""

import numpy as np
import pytest
import torch
from scipy.stats import multivariate_normal

from pipeline.fitting.identity import (
    build_identity_prior,
    clip_to_limits,
    load_identity_prior,
)
from rig.parameters import NUM_PARAMETERS, theta_limits


def _low_rank_samples(n=400, p=12, rank=3, noise=0.01, seed=0):
    rng = np.random.default_rng(seed)
    basis = np.linalg.qr(rng.standard_normal((p, rank)))[0]
    coeff = rng.standard_normal((n, rank)) * np.array([3.0, 2.0, 1.0])[:rank]
    return coeff @ basis.T + np.sqrt(noise) * rng.standard_normal((n, p)) + 0.5, basis


def test_whitening_is_the_ppca_precision():
    u, _ = _low_rank_samples()
    span = np.linspace(1.0, 3.0, u.shape[1])
    prior = build_identity_prior(u * span, span, components=(3,), noise_floor=1e-8)
    sigma = (prior.components.T * prior.variances) @ prior.components
    sigma += prior.noise * (np.eye(len(span)) - prior.components.T @ prior.components)
    M = prior.whitening()
    np.testing.assert_allclose(M.T @ M, np.linalg.inv(sigma), rtol=1e-8, atol=1e-8)
    # the log-density is a Gaussian's, in theta units divided by span
    x = u[:5] * span
    expected = multivariate_normal(prior.mean, sigma).logpdf(u[:5])
    np.testing.assert_allclose(prior.log_likelihood(x), expected, rtol=1e-10)
    # the torch residuals: half their squared norm is the negative log-density up to one constant
    r = prior.whiten(torch.as_tensor(u[:5]))
    constant = 0.5 * (r**2).sum(-1).numpy() + expected
    np.testing.assert_allclose(constant, constant[0], rtol=1e-9)


def test_cross_validation_finds_the_true_rank():
    u, basis = _low_rank_samples(rank=3)
    prior = build_identity_prior(u, np.ones(u.shape[1]), components=(1, 2, 3, 5, 8), noise_floor=1e-8)
    assert prior.rank == 3
    # the principal subspace is the generating one
    overlap = np.linalg.svd(prior.components @ basis, compute_uv=False)
    assert overlap.min() > 0.99
    assert prior.noise == pytest.approx(0.01, rel=0.2)


def test_samples_have_the_prior_covariance():
    u, _ = _low_rank_samples(rank=3)
    prior = build_identity_prior(u, np.ones(u.shape[1]), components=(3,), noise_floor=1e-8)
    draws = prior.sample(np.random.default_rng(1), 20000)
    np.testing.assert_allclose(np.cov(draws.T), np.cov(u.T), atol=0.15)


def test_too_few_heads_is_an_error():
    with pytest.raises(ValueError, match="at least 10 heads"):
        build_identity_prior(np.zeros((4, 3)), np.ones(3))


def test_committed_prior_matches_the_rig():
    prior = load_identity_prior()
    assert prior.mean.shape == (NUM_PARAMETERS,)
    assert prior.components.shape == (prior.rank, NUM_PARAMETERS)
    np.testing.assert_allclose(prior.components @ prior.components.T, np.eye(prior.rank), atol=1e-8)
    assert (prior.variances > prior.noise).all() and prior.noise >= 1e-4
    assert prior.meta["heads"] == 300 and prior.meta["rank"] == prior.rank
    low, high = (t.numpy() for t in theta_limits(torch.float64))
    # the mean is a reachable pose, and the head of the mean is a pose inside every limit
    theta = prior.mean_theta
    assert ((theta >= low - 1e-9) & (theta <= high + 1e-9)).all()
    np.testing.assert_array_equal(clip_to_limits(theta), np.clip(theta, low, high))


def test_prior_log_likelihood_prefers_population_heads():
    """Population-like joint sets are far likelier than random ones of the same size."""
    prior = load_identity_prior()
    rng = np.random.default_rng(0)
    drawn = prior.sample(rng, 50)
    shuffled = drawn.copy()
    for j in range(shuffled.shape[1]):  # same marginals, no correlations
        rng.shuffle(shuffled[:, j])
    assert np.median(prior.log_likelihood(drawn)) > np.median(prior.log_likelihood(shuffled)) + 20
