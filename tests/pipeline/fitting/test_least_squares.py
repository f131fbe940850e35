"""Levenberg-Marquardt (pipeline.fitting.least_squares) against scipy's solvers and autograd Jacobians."""

import numpy as np
import pytest
import torch
from scipy.optimize import least_squares

from pipeline.fitting.least_squares import LMSettings, forward_difference_jacobian, levenberg_marquardt


def _exp_fit_problem():
    """Fit ``a exp(-b t) + c`` to noisy samples (a classic small non-linear least-squares problem)."""
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 4.0, 40)
    y = 2.5 * np.exp(-1.3 * t) + 0.5 + 0.02 * rng.standard_normal(t.size)
    tt, yy = torch.tensor(t), torch.tensor(y)

    def batched(x: torch.Tensor) -> torch.Tensor:
        return x[:, :1] * torch.exp(-x[:, 1:2] * tt) + x[:, 2:3] - yy

    def numpy_residuals(x: np.ndarray) -> np.ndarray:
        return x[0] * np.exp(-x[1] * t) + x[2] - y

    return batched, numpy_residuals


def test_lm_reaches_scipy_minimum_in_few_iterations():
    batched, numpy_residuals = _exp_fit_problem()
    x0 = np.array([1.0, 0.3, 0.0])
    ref = least_squares(numpy_residuals, x0, method="lm", xtol=1e-12, ftol=1e-12)
    out = levenberg_marquardt(batched, torch.tensor(x0), settings=LMSettings(max_iterations=50, tolerance=1e-10))
    np.testing.assert_allclose(out.x.numpy(), ref.x, atol=1e-5)
    assert out.cost == pytest.approx(ref.cost, rel=1e-6)
    assert out.iterations <= 20
    assert all(b <= a + 1e-15 for a, b in zip(out.costs, out.costs[1:]))  # accepted steps only go down


def test_lm_respects_bounds_like_scipy_trf():
    batched, numpy_residuals = _exp_fit_problem()
    x0 = np.array([1.0, 0.3, 0.0])
    low, high = np.array([0.0, 0.0, 0.7]), np.array([10.0, 10.0, 10.0])  # the offset's optimum (0.5) is cut off
    ref = least_squares(
        numpy_residuals, np.clip(x0, low, high), bounds=(low, high), method="trf", xtol=1e-12, ftol=1e-12
    )
    out = levenberg_marquardt(
        batched,
        torch.tensor(x0),
        lower=torch.tensor(low),
        upper=torch.tensor(high),
        settings=LMSettings(max_iterations=60, tolerance=1e-12),
    )
    assert out.x[2] == pytest.approx(0.7)
    np.testing.assert_allclose(out.x.numpy(), ref.x, atol=1e-4)
    assert out.cost == pytest.approx(ref.cost, rel=1e-5)


@pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning")  # inside torch.func
def test_forward_difference_jacobian_matches_autograd():
    batched, _ = _exp_fit_problem()
    x = torch.tensor([1.7, 0.9, 0.2], dtype=torch.float64)
    J, r = forward_difference_jacobian(batched, x)
    exact = torch.func.jacfwd(lambda v: batched(v[None])[0])(x)
    torch.testing.assert_close(r, batched(x[None])[0])
    torch.testing.assert_close(J, exact, rtol=1e-6, atol=1e-7)


def test_non_finite_start_is_an_error():
    def bad(x):
        return x * float("nan")

    with pytest.raises(FloatingPointError, match="not finite"):
        levenberg_marquardt(bad, torch.zeros(2, dtype=torch.float64))
