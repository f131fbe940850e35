"""An identity prior learned from data: where the joints of real-looking heads are (issue 14).

JNR regularises a fit by L_m (eq. 4), a pull of every joint channel towards the rest pose with one
weight: a photo can then move any joint as cheaply as any other, whatever faces actually do. Here the
rig is fitted to the synthetic training population instead (known correspondence, the heads
similarity-normalised onto the template, :func:`fit_population_joints`), and the distribution of the
fitted joint channels becomes the prior: a **probabilistic PCA** Gaussian (Tipping & Bishop 1999) in
range-normalised units ``u = theta / span`` (each channel over its range, so degrees, millimetres and
scale factors are comparable),

    Sigma = W W^T + sigma^2 I,      W = U_k (Lambda_k - sigma^2 I)^(1/2),

with the ``k`` leading principal directions ``U_k`` of the fitted parameters, their variances
``Lambda_k``, and ``sigma^2`` the mean of the discarded variances. ``k`` is chosen by five-fold
cross-validated log-likelihood on the training fits (:func:`build_identity_prior`). The fit's prior term
is the negative log-density up to a constant, ``0.5 (u - mu)^T Sigma^-1 (u - mu)``, written as the
squared norm of whitened residuals ``r = L^T (u - mu)`` with ``L L^T = Sigma^-1``
(:meth:`IdentityPrior.whiten`), so a least-squares solver can use it as rows of its residual vector.

The committed prior is ``rig/assets/jnr_identity_prior_v<version>.npz``, made by
``jnr train --identity-prior`` (:func:`train_identity_prior`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from rig.asset import ASSET_DIR, TEMPLATE_VERSION, AssetError, write_npz_atomic
from rig.errors import InputError
from rig.lbs import ShapeError
from rig.parameters import NUM_PARAMETERS, theta_limits

PRIOR_COMPONENTS = (2, 4, 8, 16, 32, 48, 64, 80, 96)
"""The ranks tried by the cross-validation of :func:`build_identity_prior`."""


def default_identity_prior_path() -> Path:
    """The committed prior (``rig/assets/jnr_identity_prior_v<template version>.npz``)."""
    return ASSET_DIR / f"jnr_identity_prior_v{TEMPLATE_VERSION}.npz"


@dataclass(frozen=True)
class IdentityPrior:
    """A Gaussian over range-normalised joint channels ``u = theta / span`` (module docstring).

    Attributes:
        mean: ``(P,)`` mean of ``u``.
        components: ``(k, P)`` orthonormal principal directions.
        variances: ``(k,)`` their variances (``> noise``).
        noise: ``sigma^2``, the isotropic variance of every other direction.
        span: ``(P,)`` each channel's range (deg, mm, scale), the unit of ``u``.
        meta: how it was made (heads, seconds, the cross-validation table).
    """

    mean: np.ndarray
    components: np.ndarray
    variances: np.ndarray
    noise: float
    span: np.ndarray
    meta: dict

    @property
    def rank(self) -> int:
        return int(len(self.variances))

    @property
    def mean_theta(self) -> np.ndarray:
        """``(P,)`` the mean in joint units (deg, mm, ``scale - 1``)."""
        return self.mean * self.span

    @cached_property
    def whitening_matrix(self) -> np.ndarray:
        """:meth:`whitening`, computed once."""
        return self.whitening()

    def whitening(self) -> np.ndarray:
        """``(P, P)`` matrix ``M`` with ``|M (u - mean)|^2 = (u - mean)^T Sigma^-1 (u - mean)``.

        ``Sigma^-1 = I / sigma^2 - U_k diag(1/sigma^2 - 1/lambda) U_k^T``, so
        ``M = I / sigma - U_k diag(1/sigma - 1/sqrt(lambda)) U_k^T`` (symmetric; its square is the precision).
        """
        s = np.sqrt(self.noise)
        shrink = 1.0 / s - 1.0 / np.sqrt(self.variances)
        return np.eye(len(self.mean)) / s - (self.components.T * shrink) @ self.components

    def whiten(self, theta_n: torch.Tensor) -> torch.Tensor:
        """Whitened residuals ``(..., P)`` of normalised channels ``theta_n (..., P)`` (``theta / span``): half
        their squared norm is the negative log-density up to a constant."""
        m = torch.as_tensor(self.whitening_matrix, dtype=theta_n.dtype)
        mu = torch.as_tensor(self.mean, dtype=theta_n.dtype)
        return (theta_n - mu) @ m.T

    def log_likelihood(self, theta: np.ndarray) -> np.ndarray:
        """``(N,)`` Gaussian log-density of joint channels ``theta (N, P)`` (deg, mm, ``scale - 1``)."""
        u = np.asarray(theta, np.float64) / self.span
        r = (u - self.mean) @ self.whitening().T
        p = len(self.mean)
        logdet = np.log(self.variances).sum() + (p - self.rank) * np.log(self.noise)
        return -0.5 * ((r * r).sum(-1) + logdet + p * np.log(2 * np.pi))

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``(n, P)`` joint channels (deg, mm, ``scale - 1``) drawn from the prior."""
        k, p = self.rank, len(self.mean)
        coeff = rng.standard_normal((n, k)) * np.sqrt(self.variances - self.noise)
        u = self.mean + coeff @ self.components + np.sqrt(self.noise) * rng.standard_normal((n, p))
        return u * self.span

    def save(self, path: str | Path) -> None:
        """Write the prior as one ``.npz`` of named float64 arrays (atomic)."""
        write_npz_atomic(
            path,
            {"mean": self.mean, **gaussian_arrays(self.components, self.variances, self.noise, self.span, self.meta)},
        )


def gaussian_arrays(components, variances, noise: float, span, meta: dict) -> dict[str, np.ndarray]:
    """The arrays a PPCA Gaussian is saved as (its ``meta`` as JSON), shared by the priors' files."""
    return {
        "components": components,
        "variances": variances,
        "noise": np.array(noise),
        "span": span,
        "meta_json": np.array(json.dumps(meta)),
    }


def read_asset_arrays(path: Path, what: str, command: str) -> dict:
    """Every array of the ``.npz`` asset ``path`` (``meta_json`` decoded as ``meta``, ``noise`` a float).

    Raises:
        rig.asset.AssetError: the file is missing (the message names ``what`` and the ``command`` that makes it).
    """
    if not path.is_file():
        raise AssetError(f"{what} not found: {path} (make it with `{command}`)")
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["meta"] = json.loads(str(arrays.pop("meta_json")))
    arrays["noise"] = float(arrays["noise"])
    return arrays


def load_identity_prior(path: str | Path | None = None) -> IdentityPrior:
    """Read a prior written by :meth:`IdentityPrior.save` (default: :func:`default_identity_prior_path`).

    Raises:
        rig.asset.AssetError: the file is missing or does not match the rig's parameters.
    """
    path = Path(path) if path else default_identity_prior_path()
    prior = IdentityPrior(**read_asset_arrays(path, "identity prior", "jnr train --identity-prior"))
    if prior.mean.shape != (NUM_PARAMETERS,) or prior.components.shape[1:] != (NUM_PARAMETERS,):
        raise AssetError(f"{path} has {prior.mean.shape[0]} joint channels, the rig {NUM_PARAMETERS}; rebuild it")
    return prior


def _ppca(u: np.ndarray, k: int, floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    mean = u.mean(0)
    _, s, vt = np.linalg.svd(u - mean, full_matrices=True)
    n, p = u.shape
    eig = np.zeros(p)
    eig[: len(s)] = s * s / max(n - 1, 1)
    k = min(k, n - 1, p - 1)
    noise = max(float(eig[k:].mean()), floor)
    keep = eig[:k] > noise
    return mean, vt[:k][keep], eig[:k][keep], noise


def build_identity_prior(
    theta: np.ndarray,
    span: np.ndarray,
    *,
    components: tuple[int, ...] = PRIOR_COMPONENTS,
    folds: int = 5,
    seed: int = 0,
    noise_floor: float = 1e-4,
    meta: dict | None = None,
) -> IdentityPrior:
    """The PPCA prior of fitted joint channels, its rank chosen by cross-validated log-likelihood.

    Args:
        theta: ``(N, P)`` fitted joint channels of training heads (deg, mm, ``scale - 1``), ``N >= 2 folds``.
        span: ``(P,)`` the channels' ranges (:func:`rig.skinning.joint_fit.parameter_span`).
        components: ranks to try. folds: cross-validation folds. seed: of the fold split.
        noise_floor: the least isotropic variance (in ``u`` units^2), so channels that never moved in
            training stay movable.
        meta: recorded with the prior (the cross-validation table is added).

    Returns:
        :class:`IdentityPrior` fitted on all of ``theta`` with the best rank.
    """
    theta = np.asarray(theta, np.float64)
    span = np.asarray(span, np.float64)
    if theta.ndim != 2 or theta.shape[1] != span.shape[0]:
        raise ShapeError(f"build_identity_prior: theta must be (N, {span.shape[0]}), got {theta.shape}")
    if len(theta) < 2 * folds:
        raise InputError(
            f"build_identity_prior: need at least {2 * folds} heads for {folds}-fold validation, got {len(theta)}"
        )
    u = theta / span
    order = np.random.default_rng(seed).permutation(len(u))
    table = {}
    for k in components:
        if k >= len(u) * (folds - 1) // folds:
            continue
        ll = []
        for f in range(folds):
            test = order[f::folds]
            train = np.setdiff1d(order, test)
            mean, comp, var, noise = _ppca(u[train], k, noise_floor)
            prior = IdentityPrior(mean, comp, var, noise, np.ones_like(span), {})
            ll.append(prior.log_likelihood(u[test]).mean())
        table[k] = float(np.mean(ll))
    best = max(table, key=table.get)
    mean, comp, var, noise = _ppca(u, best, noise_floor)
    return IdentityPrior(
        mean,
        comp,
        var,
        noise,
        span,
        {
            **(meta or {}),
            "rank": int(len(var)),
            "heads": int(len(u)),
            "cv_log_likelihood": {str(k): v for k, v in table.items()},
        },
    )


def clip_to_limits(theta: np.ndarray) -> np.ndarray:
    """Joint channels ``(N, P)`` clipped into the rig's limits: the known-correspondence fits keep them there
    by a soft penalty only (5 % of the values fall outside, the ears' translations by up to 4 mm), while
    the photo fit projects into the limits, so the prior describes what a photo fit can reach."""
    low, high = (t.numpy() for t in theta_limits(torch.float64))
    return np.clip(np.asarray(theta, np.float64), low, high)
