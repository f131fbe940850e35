"""The whole track smoothed at once: each frame's own result weighed by its information, and a prior on the
second difference over frames.

A frame's fit (:func:`pipeline.track.solver.solve_frame`) gives its result ``x^_t = [r_t, t_t, c_t]`` (rotation
vector, mm, ARKit coefficients) and the Gauss-Newton matrix ``H_t`` of its landmarks and its coefficients'
prior: the cost of moving away from ``x^_t`` to second order. :func:`smooth_track` minimises, over a run of
consecutive observed frames,

    sum_t (x_t - x^_t)^T H_t (x_t - x^_t) + sum_t |W (x_{t+1} - 2 x_t + x_{t-1})|^2

(one sparse, banded least-squares solve): well seen quantities stay where the frame put them, weakly seen ones
(a brow in a turned head, the gaze) follow their neighbours, and the second difference, zero along any steady
motion, removes jitter without the lag of a causal filter (it looks at the frames after as well as before).
``W`` holds :class:`SmoothSettings`' weights per degree, mm and coefficient. Rotations enter as rotation vectors
relative to the run's first frame, to first order (the head turns tens of degrees, not a full turn). The
coefficients are clipped to their limits afterwards. Runs longer than :data:`WINDOW` frames are solved in
overlapping windows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve
from scipy.spatial.transform import Rotation

from rig.errors import InputError

WINDOW = 600
"""Frames solved at once (longer runs: overlapping windows, :data:`OVERLAP` frames blended)."""
OVERLAP = 60


@dataclass(frozen=True)
class SmoothSettings:
    """Weights of the second-difference prior (``track.smooth.*``; chosen on synthetic validation clips,
    ``benchmarks/bench_track.py``).

    Attributes:
        coefficients: per ARKit coefficient unit (0 turns the smoothing of the expressions off).
        rotation_per_deg: per degree of head rotation.
        translation_per_mm: per mm of head translation.
    """

    coefficients: float = 30.0
    rotation_per_deg: float = 3.0
    translation_per_mm: float = 1.0

    def __post_init__(self) -> None:
        for name in ("coefficients", "rotation_per_deg", "translation_per_mm"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise InputError(f"track.smooth.{name} must be a finite number >= 0, got {value!r}")


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)`` SO(3)'s left Jacobian of rotation vectors ``phi (n, 3)``: ``exp(phi + d) ~ exp(J d) exp(phi)``."""
    phi = np.asarray(phi, np.float64)
    theta = np.linalg.norm(phi, axis=1)
    k = np.zeros((len(phi), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t**3)
    return np.eye(3)[None] + a[:, None, None] * k + b[:, None, None] * (k @ k)


def _second_difference(n: int) -> sparse.csr_matrix:
    if n < 3:
        return sparse.csr_matrix((0, n))
    return sparse.diags([np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)], [0, 1, 2], shape=(n - 2, n)).tocsr()


def _solve(x_hat: np.ndarray, information: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``(n, d)`` the minimiser for ``x_hat (n, d)``, ``information (n, d, d)``, ``weights (d,)``."""
    n, d = x_hat.shape
    h = sparse.block_diag(list(information), format="csr")
    dd = _second_difference(n)
    prior = sparse.kron(dd.T @ dd, sparse.diags(weights**2), format="csr")
    a = (h + prior).tocsc()
    b = h @ x_hat.reshape(-1)
    return np.asarray(spsolve(a, b)).reshape(n, d)


def smooth_run(
    rotations: np.ndarray,
    translations: np.ndarray,
    coefficients: np.ndarray,
    information: np.ndarray,
    settings: SmoothSettings,
    low: np.ndarray,
    high: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One run of consecutive observed frames: ``rotations (n, 3, 3)``, ``translations (n, 3)``, ``coefficients
    (n, 52)``, ``information (n, 58, 58)`` -> the smoothed three (module docstring)."""
    n = len(rotations)
    if n < 3:
        return rotations.copy(), translations.copy(), coefficients.copy()
    reference = Rotation.from_matrix(rotations[0])
    r_hat = (Rotation.from_matrix(rotations) * reference.inv()).as_rotvec()  # (n, 3) rad, left of the reference
    x_hat = np.concatenate([r_hat, translations, coefficients], axis=1)
    # the frames' information is about a rotation omega on the left of their own result, exp(omega) R^_t:
    # in rotation vectors r about the reference, omega = J_l(r^_t) (r - r^_t) to first order
    change = np.repeat(np.eye(x_hat.shape[1])[None], n, axis=0)
    change[:, :3, :3] = left_jacobian(r_hat)
    information = np.einsum("nji,njk,nkl->nil", change, information, change)
    deg = 180.0 / math.pi
    weights = np.concatenate(
        [
            np.full(3, settings.rotation_per_deg * deg),
            np.full(3, settings.translation_per_mm),
            np.full(coefficients.shape[1], settings.coefficients),
        ]
    )
    # a little of each frame's own value everywhere: a quantity no frame sees is held, not extrapolated
    information = information + np.eye(x_hat.shape[1])[None] * 1e-6
    if n <= WINDOW:
        x = _solve(x_hat, information, weights)
    else:
        x = np.zeros_like(x_hat)
        total = np.zeros(n)
        start = 0
        while start < n:
            end = min(start + WINDOW, n)
            part = _solve(x_hat[start:end], information[start:end], weights)
            ramp = np.ones(end - start)
            if start > 0:
                ramp[:OVERLAP] = np.linspace(0.0, 1.0, OVERLAP + 2)[1:-1]
            if end < n:
                ramp[-OVERLAP:] = np.minimum(ramp[-OVERLAP:], np.linspace(1.0, 0.0, OVERLAP + 2)[1:-1])
            x[start:end] += part * ramp[:, None]
            total[start:end] += ramp
            if end == n:
                break
            start = end - OVERLAP
        x /= total[:, None]
    smoothed_rotations = (Rotation.from_rotvec(x[:, :3]) * reference).as_matrix()
    return smoothed_rotations, x[:, 3:6], np.clip(x[:, 6:], low, high)


def observed_runs(observed: np.ndarray) -> list[tuple[int, int]]:
    """``[(start, end), ...]`` the runs of consecutive True frames (end exclusive)."""
    runs, start = [], None
    for i, seen in enumerate(np.asarray(observed, bool)):
        if seen and start is None:
            start = i
        elif not seen and start is not None:
            runs.append((start, i))
            start = None
    if start is not None:
        runs.append((start, len(observed)))
    return runs


def smooth_track(
    rotations: np.ndarray,
    translations: np.ndarray,
    coefficients: np.ndarray,
    information: np.ndarray,
    observed: np.ndarray,
    settings: SmoothSettings,
    low: np.ndarray,
    high: np.ndarray,
) -> None:
    """Smooth every run of observed frames in place (module docstring); unobserved frames are left as they are
    (:func:`pipeline.track.tracker.bridge` fills them)."""
    for start, end in observed_runs(observed):
        r, t, c = smooth_run(
            rotations[start:end],
            translations[start:end],
            coefficients[start:end],
            information[start:end],
            settings,
            low,
            high,
        )
        rotations[start:end], translations[start:end], coefficients[start:end] = r, t, c


__all__ = ["SmoothSettings", "observed_runs", "smooth_run", "smooth_track"]
