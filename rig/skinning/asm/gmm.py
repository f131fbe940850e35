"""GMM skinning weights (ASM eq. 4-6) as pure tensor functions: covariances from Cholesky floats, each
bone's log mixture density in UV space and the weights normalised across bones. See :mod:`rig.skinning.asm`.
"""

from __future__ import annotations

import math

import torch

from rig.errors import check_shape

__all__ = ["cholesky_from_sigma", "gmm_log_density", "gmm_skinning_weights", "sigma_from_cholesky"]


def sigma_from_cholesky(chol: torch.Tensor) -> torch.Tensor:
    """Covariances from Cholesky floats: ``L = [[exp(a), 0], [c, exp(b)]]``, ``Sigma = L L^T``.

    Args:
        chol: ``(*, 3)`` floats ``(a, b, c)`` (UV units for ``exp(a)``, ``exp(b)``, ``c``).

    Returns:
        ``(*, 2, 2)`` symmetric positive-definite matrices, UV units squared.

    Example:
        >>> sigma_from_cholesky(torch.tensor([0.0, 0.0, 0.0]))
        tensor([[1., 0.],
                [0., 1.]])
    """
    check_shape(chol.shape[-1:] == (3,), "sigma_from_cholesky", "chol", "(*, 3)", tuple(chol.shape))
    l11, l22, l21 = chol[..., 0].exp(), chol[..., 1].exp(), chol[..., 2]
    s00 = l11 * l11
    s01 = l11 * l21
    s11 = l21 * l21 + l22 * l22
    return torch.stack([s00, s01, s01, s11], dim=-1).reshape(chol.shape[:-1] + (2, 2))


def cholesky_from_sigma(sigma: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`sigma_from_cholesky`: ``(*, 2, 2)`` SPD matrices -> ``(*, 3)`` floats."""
    check_shape(sigma.shape[-2:] == (2, 2), "cholesky_from_sigma", "sigma", "(*, 2, 2)", tuple(sigma.shape))
    L = torch.linalg.cholesky(sigma)
    return torch.stack([L[..., 0, 0].log(), L[..., 1, 1].log(), L[..., 1, 0]], dim=-1)


def gmm_log_density(uv: torch.Tensor, log_pi: torch.Tensor, centres: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Log of each bone's mixture ``log W_j(u) = log sum_k pi_jk N(u | c_jk, Sigma_jk)`` (ASM eq. 4).

    The exponent of every Gaussian is a quadratic in ``(u, v)``, so all of them come from one matrix
    product of the points' monomials ``(u^2, v^2, uv, u, v, 1)`` with per-component coefficients
    (computed in float64; the result has ``log_pi``'s dtype).

    Args:
        uv: ``(N, 2)`` UV points.
        log_pi: ``(B, J, K)`` log amplitudes.
        centres: ``(B, J, K, 2)`` component centres (``zeta_j + mu_jk``), UV.
        sigma: ``(B, J, K, 2, 2)`` covariances (symmetric positive definite; the symmetric part is used).

    Returns:
        ``(B, N, J)`` log mixture values.
    """
    check_shape(uv.dim() == 2 and uv.shape[1] == 2, "gmm_log_density", "uv", "(N, 2)", tuple(uv.shape))
    check_shape(log_pi.dim() == 3, "gmm_log_density", "log_pi", "(B, J, K)", tuple(log_pi.shape))
    check_shape(
        centres.shape == log_pi.shape + (2,),
        "gmm_log_density",
        "centres",
        f"{tuple(log_pi.shape) + (2,)}",
        tuple(centres.shape),
    )
    check_shape(
        sigma.shape == log_pi.shape + (2, 2),
        "gmm_log_density",
        "sigma",
        f"{tuple(log_pi.shape) + (2, 2)}",
        tuple(sigma.shape),
    )
    B, J, K = log_pi.shape
    out_dtype = log_pi.dtype
    # float64 throughout: the expanded quadratic cancels (p x^2 - 2 p x c + p c^2 with p = 1 / sigma^2 up to
    # 1e7), which float32 cannot resolve for sharp Gaussians; the products are small, float64 costs little.
    uv, log_pi, centres, sigma = uv.double(), log_pi.double(), centres.double(), sigma.double()
    origin = uv.detach().mean(0)
    x, y = (uv - origin).unbind(-1)
    cx, cy = (centres - origin).unbind(-1)
    a, d = sigma[..., 0, 0], sigma[..., 1, 1]
    b = 0.5 * (sigma[..., 0, 1] + sigma[..., 1, 0])
    det = a * d - b * b
    p, q, r = d / det, -b / det, a / det  # Sigma^-1 = [[p, q], [q, r]]
    const = log_pi - math.log(2.0 * math.pi) - 0.5 * det.log() - 0.5 * (p * cx * cx + 2.0 * q * cx * cy + r * cy * cy)
    coeffs = torch.stack([-0.5 * p, -0.5 * r, -q, p * cx + q * cy, q * cx + r * cy, const], dim=-1)  # (B, J, K, 6)
    monomials = torch.stack([x * x, y * y, x * y, x, y, torch.ones_like(x)], dim=-1)  # (N, 6)
    # (K, 6, B*J): one GEMM per component, then a log-sum-exp across the K slices (elementwise, fast).
    per_k = coeffs.permute(2, 3, 0, 1).reshape(K, 6, B * J)
    exponent = monomials.unsqueeze(0) @ per_k  # (K, N, B*J)
    if K == 1:
        out = exponent[0]
    else:
        peak = exponent.detach().amax(0)
        out = peak + (exponent - peak).exp().sum(0).log()
    return out.view(-1, B, J).transpose(0, 1).to(out_dtype)


def gmm_skinning_weights(
    vertex_uv: torch.Tensor,
    log_pi: torch.Tensor,
    centres: torch.Tensor,
    sigma: torch.Tensor,
    seam_rows: torch.Tensor | None = None,
    seam_uv: torch.Tensor | None = None,
) -> torch.Tensor:
    """GMM skinning weights normalised across bones (ASM eq. 6), ``w_vj = W_j(u_v) / sum_i W_i(u_v)``.

    A vertex on a UV seam has a second UV copy; its mixture value is the mean of the values at both.

    Args:
        vertex_uv: ``(N, 2)`` the (first) UV of each vertex.
        log_pi, centres, sigma: as :func:`gmm_log_density`.
        seam_rows: optional ``(S,)`` int64 rows of ``vertex_uv`` that have a second copy,
            ``seam_uv``: ``(S, 2)`` those copies.

    Returns:
        ``(B, N, J)`` weights: non-negative, each row sums to 1.
    """
    check_shape(
        vertex_uv.dim() == 2 and vertex_uv.shape[-1] == 2,
        "gmm_skinning_weights",
        "vertex_uv",
        "(N, 2)",
        tuple(vertex_uv.shape),
    )
    N = vertex_uv.shape[0]
    if seam_rows is not None and len(seam_rows):
        check_shape(
            seam_uv is not None and seam_uv.shape == (len(seam_rows), 2),
            "gmm_skinning_weights",
            "seam_uv",
            f"({len(seam_rows)}, 2)",
            None if seam_uv is None else tuple(seam_uv.shape),
        )
        log_w = gmm_log_density(torch.cat([vertex_uv, seam_uv.to(vertex_uv.dtype)]), log_pi, centres, sigma)
        first, second = log_w[:, :N], log_w[:, N:]
        mean = torch.logaddexp(first[:, seam_rows], second) - math.log(2.0)
        log_w = first.index_copy(1, seam_rows, mean)
    else:
        log_w = gmm_log_density(vertex_uv, log_pi, centres, sigma)
    return torch.softmax(log_w, dim=-1)
