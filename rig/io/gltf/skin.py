"""The skeleton and the skinning weights of a glTF file: argument checks (:func:`_check_rig`,
:func:`_check_morphs`), the 4 influences per vertex (:func:`_top_influences`) and the joint nodes
(:func:`_joint_nodes`). See :mod:`rig.io.gltf`.
"""

from __future__ import annotations

import numpy as np
import pygltflib

from rig.errors import InputError, shape_error
from rig.io.gltf.encoding import MAX_DROPPED_WEIGHT, MAX_INFLUENCES, MM_TO_M, WEIGHT_EPS, _decompose_trs, _translation


def _check_rig(func, n_vertices, joint_names, parents, joint_positions, weights, joint_transforms):
    names = list(joint_names) if not isinstance(joint_names, str) else None
    if names is None or any(not isinstance(n, str) for n in names):
        raise InputError(f"{func}: joint_names must be a list of K str")
    k = len(names)
    if k == 0:
        raise InputError(f"{func}: joint_names must name at least one joint, got an empty list")
    if len(set(names)) != k:
        raise InputError(f"{func}: joint_names must be unique")

    par = np.asarray(parents)
    if par.shape != (k,):
        raise shape_error(func, "parents", f"(K,) = ({k},)", par.shape)
    if not np.issubdtype(par.dtype, np.integer):
        raise InputError(f"{func}: parents must be integers, got dtype {par.dtype}")
    par = par.astype(np.int64)
    bad = np.nonzero((par < -1) | (par >= np.arange(k)))[0]
    if bad.size:
        j = int(bad[0])
        raise InputError(
            f"{func}: parents must be -1 (root) or the index of an earlier joint; "
            f"joint {j} ({names[j]!r}) has parent {int(par[j])}"
        )

    pos = np.asarray(joint_positions)
    if pos.shape != (k, 3):
        raise shape_error(func, "joint_positions", f"(K, 3) = ({k}, 3)", pos.shape)
    pos = pos.astype(np.float64)
    if not np.isfinite(pos).all():
        raise InputError(f"{func}: joint_positions contain NaN or infinite values")

    w = np.asarray(weights)
    if w.shape != (n_vertices, k):
        raise shape_error(func, "weights", f"(V, K) = ({n_vertices}, {k})", w.shape)
    w = w.astype(np.float64)
    if not np.isfinite(w).all():
        raise InputError(f"{func}: weights contain NaN or infinite values")
    if w.min() < -WEIGHT_EPS:
        raise InputError(f"{func}: weights must be non-negative, got minimum {w.min()}")
    row_sum = w.sum(axis=1)
    worst = int(np.argmax(np.abs(row_sum - 1.0)))
    if abs(row_sum[worst] - 1.0) > MAX_DROPPED_WEIGHT:
        raise InputError(f"{func}: weights rows must sum to 1; vertex {worst} sums to {row_sum[worst]}")

    taus = None
    if joint_transforms is not None:
        taus = np.asarray(joint_transforms)
        if taus.shape != (k, 4, 4):
            raise shape_error(func, "joint_transforms", f"(K, 4, 4) = ({k}, 4, 4)", taus.shape)
        taus = taus.astype(np.float64)
        if not np.isfinite(taus).all():
            raise InputError(f"{func}: joint_transforms contain NaN or infinite values")
        if not np.allclose(taus[:, 3, :], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
            raise InputError(f"{func}: joint_transforms must be affine (last row 0, 0, 0, 1)")
    return names, par, pos, w, taus


def _top_influences(func: str, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 4 largest weights per vertex, renormalised: ``(joints (V, 4) int, weights (V, 4))``."""
    n_vertices, k = weights.shape
    w = np.where(weights > WEIGHT_EPS, weights, 0.0)
    if k < MAX_INFLUENCES:
        w = np.concatenate([w, np.zeros((n_vertices, MAX_INFLUENCES - k))], axis=1)
    order = np.argsort(-w, axis=1, kind="stable")[:, :MAX_INFLUENCES]
    top = np.take_along_axis(w, order, axis=1)
    dropped = w.sum(axis=1) - top.sum(axis=1)
    lossy = np.nonzero(dropped > MAX_DROPPED_WEIGHT)[0]
    if lossy.size:
        worst = int(lossy[np.argmax(dropped[lossy])])
        n_influences = int((w[worst] > 0).sum())
        raise InputError(
            f"{func}: weights of {lossy.size} vertices have more than {MAX_INFLUENCES} influences "
            f"and keeping the {MAX_INFLUENCES} largest would drop more than {MAX_DROPPED_WEIGHT} "
            f"of their weight (worst: vertex {worst}, {n_influences} influences, dropped weight "
            f"{dropped[worst]:.3g}); prune the weights to {MAX_INFLUENCES} joints per vertex first"
        )
    top = top / top.sum(axis=1, keepdims=True)
    order = np.where(top > 0.0, order, 0)  # unused influences point at joint 0 with weight 0
    return order.astype(np.int64), top


def _check_morphs(func: str, n_vertices: int, targets, names, weights) -> tuple[np.ndarray, list[str], list[float]]:
    """Validated morph targets ``(M, V, 3)`` float64 mm, their names and default weights."""
    if targets is None:
        if names is not None or weights is not None:
            raise InputError(f"{func}: morph_names / morph_weights given without morph_targets")
        return np.zeros((0, n_vertices, 3)), [], []
    t = np.asarray(targets, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (n_vertices, 3):
        raise shape_error(func, "morph_targets", f"(M, {n_vertices}, 3)", t.shape)
    if not np.isfinite(t).all():
        raise InputError(f"{func}: morph_targets must be finite")
    names = [str(n) for n in (names or [])]
    if len(names) != len(t) or len(set(names)) != len(names):
        raise InputError(f"{func}: morph_names must be {len(t)} unique names, got {len(names)}")
    w = np.zeros(len(t)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (len(t),) or not np.isfinite(w).all():
        raise InputError(f"{func}: morph_weights must be {len(t)} finite numbers")
    return t, names, [float(x) for x in w]


def _scale_affine_to_metres(m: np.ndarray) -> np.ndarray:
    out = m.copy()
    out[..., :3, 3] *= MM_TO_M
    return out


def _joint_nodes(
    func: str, names: list[str], par: np.ndarray, pos: np.ndarray, taus: np.ndarray | None
) -> tuple[list[pygltflib.Node], list[int]]:
    """One node per joint (local T @ R @ S in metres, children linked) and the root joints."""
    k = len(names)
    joint_nodes = []
    for j in range(k):
        parent_pos = pos[par[j]] if par[j] >= 0 else np.zeros(3)
        offset_m = (pos[j] - parent_pos) * MM_TO_M
        node = pygltflib.Node(name=names[j])
        if taus is None:
            node.translation = [float(x) for x in offset_m]
        else:
            local = _translation(offset_m) @ _scale_affine_to_metres(taus[j])
            trs = _decompose_trs(local)
            if trs is None:
                raise InputError(
                    f"{func}: joint_transforms[{j}] (joint {names[j]!r}) has a shear, a reflection "
                    "or a zero scale; glTF joint nodes need translation @ rotation @ positive scale"
                )
            t, r, s = trs
            node.translation = [float(x) for x in t]
            if not np.allclose(r, [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12):
                node.rotation = [float(x) for x in r]
            if not np.allclose(s, 1.0, rtol=0.0, atol=1e-12):
                node.scale = [float(x) for x in s]
        joint_nodes.append(node)
    for j in range(k):
        if par[j] >= 0:
            joint_nodes[par[j]].children.append(j)
    roots = [j for j in range(k) if par[j] < 0]
    return joint_nodes, roots
