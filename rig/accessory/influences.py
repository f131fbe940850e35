"""How an accessory's transferred weights and offsets are shaped: the contact falloff of the expression
offsets (:func:`contact_attenuation`), the smoothing over the accessory's points (:func:`smooth_over_points`)
and the limit of joints per vertex (:func:`keep_largest`; :func:`reduce_influences` with the joint tree's
:func:`joint_motion_distance` and :func:`channel_reach`). Pure numpy/scipy; millimetres. See :mod:`rig.accessory`.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from rig.parameters import CHANNELS

__all__ = [
    "channel_reach",
    "contact_attenuation",
    "joint_motion_distance",
    "keep_largest",
    "reduce_influences",
    "smooth_over_points",
]


def contact_attenuation(distance: np.ndarray, falloff_mm: float) -> np.ndarray:
    """How much of the skin's expression offset a point at ``distance`` from the skin follows.

    ``1`` up to ``falloff_mm / 2``, then a smoothstep down to ``0`` at ``falloff_mm`` (C1: no kink where a
    surface crosses either distance); ``falloff_mm = 0`` gives 0 everywhere.

    Args:
        distance: ``(N,)`` mm (non-negative). falloff_mm: mm.

    Returns:
        ``(N,)`` in [0, 1].

    Example:
        >>> contact_attenuation(np.array([0.0, 5.0, 7.5, 10.0, 12.0]), 10.0)
        array([1. , 1. , 0.5, 0. , 0. ])
    """
    d = np.asarray(distance, float)
    if falloff_mm <= 0:
        return np.zeros_like(d)
    t = np.clip((d - 0.5 * falloff_mm) / (0.5 * falloff_mm), 0.0, 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


def smooth_over_points(points: np.ndarray, values: np.ndarray, sigma_mm: float) -> np.ndarray:
    """Gaussian-kernel average of per-point values over the points' 3D neighbourhood.

    ``out_i = sum_j g_ij values_j / sum_j g_ij`` with ``g_ij = exp(-|x_i - x_j|^2 / (2 sigma^2))`` over the
    neighbours within ``3 sigma`` (a sparse KD-tree distance matrix). ``sigma_mm = 0`` returns the values;
    ``inf`` their plain mean for every point. Convex combinations: weight rows that sum to 1 still do.

    Args:
        points: ``(N, 3)`` mm; values: ``(N, C)``; sigma_mm: the kernel's sigma, mm.

    Returns:
        ``(N, C)``.
    """
    x = np.asarray(points, float)
    vals = np.asarray(values, float)
    if sigma_mm == 0 or len(x) == 1:
        return vals.copy()
    if math.isinf(sigma_mm):
        return np.broadcast_to(vals.mean(0), vals.shape).copy()
    tree = cKDTree(x)
    pairs = tree.sparse_distance_matrix(tree, 3.0 * sigma_mm, output_type="coo_matrix")
    off = pairs.row != pairs.col  # scipy stores the diagonal or not (distance 0): add it once, ourselves
    g = sp.coo_matrix(
        (np.exp(-0.5 * (pairs.data[off] / sigma_mm) ** 2), (pairs.row[off], pairs.col[off])), shape=(len(x), len(x))
    ) + sp.identity(len(x), format="coo")
    g = g.tocsr()
    return (g @ vals) / np.asarray(g.sum(1))


def keep_largest(weights: np.ndarray, max_influences: int | None) -> np.ndarray:
    """At most ``max_influences`` non-zero weights per row, continuously: each row minus its
    ``(max_influences + 1)``-th largest value, clipped at 0 and renormalised to sum 1.

    Hard pruning (keep the 4 largest) jumps where the 4th and 5th largest weights of neighbouring
    vertices swap, which tears a smoothed accessory apart under a pose; subtracting the first dropped
    value makes the kept weights go to zero where they would be dropped. Rows with at most
    ``max_influences`` non-zero weights are unchanged.

    Args:
        weights: ``(N, J)`` non-negative, rows summing to 1. max_influences: None keeps every weight.

    Returns:
        ``(N, J)`` rows summing to 1.

    Example:
        >>> keep_largest(np.array([[0.4, 0.3, 0.2, 0.1]]), 2)
        array([[0.66666667, 0.33333333, 0.        , 0.        ]])
    """
    w = np.where(weights > 1e-12, weights, 0.0)
    if max_influences is not None and w.shape[1] > max_influences:
        threshold = -np.partition(-w, max_influences, axis=1)[:, max_influences : max_influences + 1]
        reduced = np.clip(w - threshold, 0.0, None)
        # A tie among the largest values (all equal to the threshold) leaves nothing: keep the hard top-k.
        tie = reduced.sum(1) <= 1e-12
        if tie.any():
            drop = np.argsort(-w[tie], axis=1, kind="stable")[:, max_influences:]
            hard = w[tie].copy()
            np.put_along_axis(hard, drop, 0.0, axis=1)
            reduced[tie] = hard
        w = reduced
    return w / w.sum(1, keepdims=True)


def joint_motion_distance(parents: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """How differently two joints can move: ``(J, J)`` mm, the sum of :func:`channel_reach` over the joints on
    the tree path between them (their common ancestor excluded).

    A joint's skinning transform is its parent's times its own channel transform, so two joints differ only
    by the channels on the path between them: a joint without channels moves exactly as its parent
    (distance 0), ``left_crown_outer`` (translations of +-1 mm) nearly as ``crown``, and ``crown`` (+-40 mm)
    quite unlike ``cranium``.

    Args:
        parents: ``(J,)`` parent of each joint, ``-1`` for a root. reach: ``(J,)`` mm per joint.

    Returns:
        ``(J, J)`` symmetric, zero on the diagonal.
    """
    parents = np.asarray(parents)
    n = len(parents)
    chains = []
    for j in range(n):
        chain, k = [], j
        while k >= 0:
            chain.append(k)
            k = parents[k]
        chains.append(chain)
    up = [np.concatenate([[0.0], np.cumsum(np.asarray(reach, float)[c])]) for c in chains]  # reach below each
    out = np.zeros((n, n))
    for a in range(n):
        ancestors_a = {k: i for i, k in enumerate(chains[a])}
        for b in range(a + 1, n):
            ib = next(i for i, k in enumerate(chains[b]) if k in ancestors_a)  # the common ancestor on b's chain
            ia = ancestors_a[chains[b][ib]]
            out[a, b] = out[b, a] = up[a][ia] + up[b][ib]
    return out


def channel_reach(num_joints: int, lever_mm: float = 100.0) -> np.ndarray:
    """``(J,)`` mm: how far each joint's own channels can move a point ``lever_mm`` from it, summed over its
    channels at their limits (a rotation's angle in radians or a scale's change times the lever, a
    translation as it is; :data:`rig.parameters.CHANNELS`)."""
    reach = np.zeros(num_joints)
    for c in CHANNELS:
        span = max(abs(c.low - (1.0 if c.is_scale else 0.0)), abs(c.high - (1.0 if c.is_scale else 0.0)))
        reach[c.joint] += span * (
            math.pi / 180.0 * lever_mm if c.unit == "deg" else lever_mm if c.unit == "factor" else 1.0
        )
    return reach


def reduce_influences(
    weights: np.ndarray, max_influences: int, joint_distance: np.ndarray, scale_mm: float = 5.0, floor: float = 0.05
) -> np.ndarray:
    """At most ``max_influences`` non-zero weights per row, moving the extra weight to the kept joints that
    move most alike, continuously.

    With ``t`` the row's ``(max_influences + 1)``-th largest weight, each joint keeps ``e_j = max(w_j - t, 0)``
    (so at most ``max_influences`` keep anything) and gives up ``r_j = min(w_j, t)``, which is shared among
    the kept joints ``k`` in proportion to ``e_k / (e_k + t) * exp(-D[j, k] / scale_mm) + floor * e_k / sum(e)``
    (``D``: :func:`joint_motion_distance`; the floor keeps a barely kept joint from taking everything). So the weight
    of a dropped ``crown`` goes to a kept ``left_crown_outer``
    (its child, +-1 mm of its own) rather than to ``cranium`` (+-40 mm apart): renormalising the kept
    weights instead (:func:`keep_largest`) moves a cap's side 7 mm off under a 30 mm crown edit. Every step
    is continuous in the weights (a joint about to be dropped receives nothing), so neighbouring vertices
    do not tear apart where two weights change order, as they do with hard pruning. Rows with at most
    ``max_influences`` weights are unchanged.

    Args:
        weights: ``(N, J)`` non-negative, rows summing to 1. max_influences: at least 1.
        joint_distance: ``(J, J)`` mm. scale_mm: how sharply the nearest kept joint is preferred.
        floor: the part shared in proportion to the kept weights (against jumps).

    Returns:
        ``(N, J)`` rows summing to 1, at most ``max_influences`` non-zero.

    Example:
        >>> d = np.array([[0.0, 40.0, 1.0], [40.0, 0.0, 41.0], [1.0, 41.0, 0.0]])
        >>> reduce_influences(np.array([[0.3, 0.5, 0.2]]), 2, d).round(3)   # joint 2 goes mostly to joint 0
        array([[0.461, 0.539, 0.   ]])
    """
    w = np.where(weights > 1e-12, weights, 0.0)
    if w.shape[1] <= max_influences:
        return w / w.sum(1, keepdims=True)
    t = -np.partition(-w, max_influences, axis=1)[:, max_influences : max_influences + 1]  # (N, 1)
    kept = np.clip(w - t, 0.0, None)
    given = np.minimum(w, t)
    pull = kept / np.where(kept + t > 0, kept + t, 1.0)  # (N, J): 0 for a dropped joint, -> 1 for a strong one
    affinity = np.exp(-np.asarray(joint_distance, float) / scale_mm)  # (J, J)
    share = pull[:, None, :] * affinity[None]  # (N, j, k)
    # A floor shared in proportion to the kept weights: where no kept joint is near, nor one barely kept
    # may take everything (the share must not jump when a joint's kept weight leaves 0).
    share = share + floor * (kept / np.where(kept.sum(1, keepdims=True) > 0, kept.sum(1, keepdims=True), 1.0))[:, None]
    share = share / share.sum(2, keepdims=True)
    out = kept + np.einsum("nj,njk->nk", given, share)
    return out / out.sum(1, keepdims=True)
