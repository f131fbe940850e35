"""Learning skinning weights from meshes in the rig's topology (JNR sections 3.1-3.2, 4.1, 4.3).

- :func:`valid_weights`: free floats -> a valid dense weight matrix (non-negative, rows sum to 1, the
  rig's sparsity pattern and mirror symmetry by construction).
- :func:`fit_linear_weights`: one global weight matrix across many heads with their joints fixed.
- :func:`learn_linear_skinning`: JNR's alternation, joints <-> global weights, for a number of cycles.
- :func:`solve_weights`: the per-head optimal weights for given joint parameters. LBS is linear in the
  weights, so each mirror orbit of vertices is a tiny least-squares problem with a sum-to-one
  constraint, solved in closed form for all orbits and all heads at once (the skinning-weight training
  sets of the neural decoder).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from rig.lbs import ShapeError, skin_vertices
from rig.losses import LAMBDA_P, laplacian_loss, vertex_rmse
from rig.model import JointRig
from rig.optim import Progress
from rig.skinning.joint_fit import fit_joints


def valid_weights(rig: JointRig, free: torch.Tensor) -> torch.Tensor:
    """Free skinning floats ``(S,)`` or ``(N, S)`` -> dense ``(V, K)`` or ``(N, V, K)`` valid weights.

    Negative floats are clipped to 0 and each row is divided by its sum, so the result is
    non-negative, sums to 1 per vertex, keeps the rig's sparsity pattern and stays mirror-symmetric.
    """
    free = free.clamp_min(0.0)
    if free.dim() == 1:
        dense = rig.dense_weights(free)
        return dense / dense.sum(-1, keepdim=True).clamp_min(1e-12)
    rows, cols, idx = rig.weight_rows, rig.weight_cols, rig.weight_free_index
    dense = free.new_zeros(free.shape[0], rig.num_vertices, rig.num_joints)
    dense[:, rows, cols] = free[:, idx]
    return dense / dense.sum(-1, keepdim=True).clamp_min(1e-12)


def fit_linear_weights(
    rig: JointRig,
    targets: torch.Tensor,
    theta: torch.Tensor,
    init_free: torch.Tensor,
    *,
    iterations: int = 300,
    lr: float = 1e-3,
    lambda_p: float = LAMBDA_P,
    batch_size: int | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> tuple[torch.Tensor, list[float]]:
    """One global weight matrix for many heads with fixed joints: minimise mean ``L_v + lambda_p L_p``.

    Args:
        targets: ``(N, V, 3)`` meshes, mm; theta: ``(N, P)`` their (fixed) joint parameters.
        init_free: ``(S,)`` starting free floats (e.g. the rig's initial weights).
        batch_size: heads per step (default: all, as JNR's batch of 85).

    Returns:
        ``(free (S,), losses)``.
    """
    N = targets.shape[0]
    free = init_free.detach().clone().to(rig.template.dtype).requires_grad_(True)
    opt = torch.optim.Adam([free], lr=lr)
    lap = rig.laplacian
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        _, skinning = rig.joint_transforms(theta.to(rig.template.dtype))
    losses = []
    for it in range(iterations):
        idx = torch.arange(N) if not batch_size or batch_size >= N else torch.randperm(N, generator=gen)[:batch_size]
        w = valid_weights(rig, free)
        pred = skin_vertices(rig.template, w, skinning[idx])
        loss = (vertex_rmse(pred, targets[idx]) + lambda_p * laplacian_loss(pred, targets[idx], lap)).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        with torch.no_grad():
            free.clamp_(min=0.0)
        losses.append(loss.item())
        if progress is not None:
            progress("weights", it + 1, iterations)
    with torch.no_grad():
        # Store the normalised floats: each vertex's floats then sum to one as stored.
        w = valid_weights(rig, free.detach())
        out = torch.zeros_like(free)
        out[rig.weight_free_index] = w[rig.weight_rows, rig.weight_cols]
    return out.detach(), losses


@dataclass(frozen=True)
class LinearSkinningResult:
    """Result of :func:`learn_linear_skinning`.

    Attributes:
        free: ``(S,)`` learned global weights (free floats).
        theta: ``(N, P)`` joints refitted with them.
        rmse_per_cycle: mean training RMSE (mm) after each joint fit, first with the initial weights.
        snapshots: ``(T, N, P)`` every intermediate joint parameter set that was kept.
    """

    free: torch.Tensor
    theta: torch.Tensor
    rmse_per_cycle: list[float]
    snapshots: torch.Tensor
    weight_losses: list[float] = field(default_factory=list)


def learn_linear_skinning(
    rig: JointRig,
    targets: torch.Tensor,
    *,
    cycles: int = 3,
    joint_iterations: int = 300,
    weight_iterations: int = 300,
    joint_lr: float = 0.01,
    weight_lr: float = 1e-3,
    snapshot_every: int = 50,
    progress: Progress | None = None,
) -> LinearSkinningResult:
    """JNR's alternation: fit joints with the current weights, then the global weights with those joints.

    Starts from the rig's initial weights. ``progress(stage, step, total)`` is called per iteration.
    """
    free = rig.weights_free.detach().clone()
    theta = None
    rmse, snaps, weight_losses = [], [], []
    total = cycles * (joint_iterations + weight_iterations) + joint_iterations
    done = 0

    def tick(stage: str) -> Progress | None:
        # one bar over the whole alternation: each inner routine's step, counted from the cycle's start
        return None if progress is None else (lambda _, it, n: progress(stage, done + it, total))

    for cycle in range(cycles + 1):
        w = valid_weights(rig, free).detach()
        fit = fit_joints(
            rig,
            targets,
            weights=w,
            init=theta,
            iterations=joint_iterations,
            lr=joint_lr,
            snapshot_every=snapshot_every,
            progress=tick(f"joints {cycle + 1}"),
        )
        done += joint_iterations
        theta = fit.theta
        rmse.append(float(fit.rmse.mean()))
        snaps.append(fit.snapshots if len(fit.snapshots) else fit.theta[None])
        if cycle == cycles:
            break
        free, losses = fit_linear_weights(
            rig, targets, theta, free, iterations=weight_iterations, lr=weight_lr, progress=tick(f"weights {cycle + 1}")
        )
        done += weight_iterations
        weight_losses.extend(losses)
    return LinearSkinningResult(free, theta, rmse, torch.cat(snaps), weight_losses)


# ----------------------------------------------------------------------------------------------------
# Closed-form per-head weights
# ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class OrbitSystem:
    """The rig's skinning layout regrouped by mirror orbits of vertices, for :func:`solve_weights`.

    Attributes:
        vertices: ``(O, 2)`` the orbit's vertices (a midline vertex twice).
        entry_float: ``(O, 2, 4)`` for each vertex of the orbit and each of its (<= 4) non-zeros, the
            slot (0..3) of the orbit's unknown float, -1 for padding.
        entry_joint: ``(O, 2, 4)`` the joint of each non-zero (0 for padding).
        floats: ``(O, 4)`` the global free-float index of each unknown slot, -1 for padding.
    """

    vertices: np.ndarray
    entry_float: np.ndarray
    entry_joint: np.ndarray
    floats: np.ndarray

    @staticmethod
    def from_rig(rig: JointRig) -> OrbitSystem:
        mirror = np.asarray(rig.asset.mirror)
        rows = rig.weight_rows.numpy()
        cols = rig.weight_cols.numpy()
        fidx = rig.weight_free_index.numpy()
        per_vertex: dict[int, list[tuple[int, int]]] = {}
        for r, c, f in zip(rows, cols, fidx):
            per_vertex.setdefault(int(r), []).append((int(c), int(f)))
        orbits = sorted({(min(v, int(mirror[v])), max(v, int(mirror[v]))) for v in range(len(mirror))})
        n_orbits = len(orbits)
        verts = np.array(orbits, dtype=np.int64)
        entry_float = -np.ones((n_orbits, 2, 4), np.int64)
        entry_joint = np.zeros((n_orbits, 2, 4), np.int64)
        floats = -np.ones((n_orbits, 4), np.int64)
        for o, (a, b) in enumerate(orbits):
            slots: dict[int, int] = {}
            for side, v in enumerate((a, b)):
                for e, (c, f) in enumerate(per_vertex.get(v, [])):
                    if f not in slots:
                        if len(slots) == 4:
                            raise RuntimeError("a mirror orbit needs more than 4 free floats")
                        slots[f] = len(slots)
                        floats[o, slots[f]] = f
                    entry_float[o, side, e] = slots[f]
                    entry_joint[o, side, e] = c
        return OrbitSystem(verts, entry_float, entry_joint, floats)


def solve_weights(
    rig: JointRig,
    theta: torch.Tensor,
    targets: torch.Tensor,
    prior_free: torch.Tensor,
    *,
    reg: float = 1e-3,
    system: OrbitSystem | None = None,
    chunk: int = 64,
) -> torch.Tensor:
    """Per-head optimal free floats for fixed joints: for each mirror orbit of vertices solve

    ``min_f |G f - t|^2 + reg * |f - f_prior|^2  s.t.  sum_k w_vk = 1``

    (``G`` stacks ``A_k v`` for the orbit's vertices; a shared float appears on both sides of the face),
    then clip negatives and renormalise.

    Args:
        theta: ``(N, P)`` joint parameters; targets: ``(N, V, 3)`` meshes, mm.
        prior_free: ``(S,)`` floats to regularise towards (e.g. the learned linear weights).
        reg: Tikhonov weight (mm^2 per unit weight^2).

    Returns:
        ``(N, S)`` free floats of valid weights (rows sum to 1).
    """
    if theta.shape[0] != targets.shape[0]:
        raise ShapeError(
            f"solve_weights: theta (N, P) and targets (N, V, 3) disagree: {tuple(theta.shape)}, {tuple(targets.shape)}"
        )
    system = system or OrbitSystem.from_rig(rig)
    dtype = torch.float64
    verts = torch.as_tensor(system.vertices)
    ef = torch.as_tensor(system.entry_float)
    ej = torch.as_tensor(system.entry_joint)
    floats = torch.as_tensor(system.floats)
    valid_entry = ef >= 0
    valid_float = floats >= 0
    n_orbits = verts.shape[0]
    prior = prior_free.to(dtype)[floats.clamp_min(0)] * valid_float  # (O, 4)
    rest = rig.template.to(dtype)[verts]  # (O, 2, 3)
    # One-hot map entry -> slot: (O, 2, 4 entries, 4 slots).
    onehot = torch.nn.functional.one_hot(ef.clamp_min(0), 4).to(dtype) * valid_entry[..., None]
    constraint = onehot[:, 0].sum(1)  # (O, 4): how often each slot appears among vertex a's entries
    out = torch.zeros(theta.shape[0], prior_free.shape[0], dtype=dtype)
    eye = torch.eye(4, dtype=dtype)
    for start in range(0, theta.shape[0], chunk):
        th = theta[start : start + chunk].to(dtype)
        n = th.shape[0]
        with torch.no_grad():
            _, A = rig.joint_transforms(th.to(rig.template.dtype))
        A = A.to(dtype)
        # Position of each orbit vertex under each of its entries' joints: (n, O, 2, 4, 3).
        Ae = A[:, ej]  # (n, O, 2, 4, 4, 4)
        p = (Ae[..., :3, :3] @ rest[None, :, :, None, :, None]).squeeze(-1) + Ae[..., :3, 3]
        # G: (n, O, 2*3 equations, 4 slots)
        G = torch.einsum("nosec,osek->nosck", p, onehot)
        G = G.reshape(n, n_orbits, 6, 4)
        t = targets[start : start + chunk].to(dtype)[:, verts].reshape(n, n_orbits, 6)
        # Midline orbits list the same vertex twice: count its equations once.
        same = (verts[:, 0] == verts[:, 1]).to(dtype)
        row_w = torch.ones(n_orbits, 6, dtype=dtype)
        row_w[:, 3:] = (1.0 - same)[:, None]
        G = G * row_w[None, :, :, None]
        t = t * row_w[None]
        H = G.transpose(-1, -2) @ G + reg * eye  # (n, O, 4, 4)
        g = (G.transpose(-1, -2) @ t[..., None]).squeeze(-1) + reg * prior[None]
        # Padding slots: pin them to zero.
        pad = (~valid_float).to(dtype)
        H = H + torch.diag_embed(pad * 1e6)[None]
        # KKT: [H c; c^T 0] [f; mu] = [g; 1]
        c = constraint[None].expand(n, -1, -1)
        K = torch.zeros(n, n_orbits, 5, 5, dtype=dtype)
        K[..., :4, :4] = H
        K[..., :4, 4] = c
        K[..., 4, :4] = c
        rhs = torch.cat([g, torch.ones(n, n_orbits, 1, dtype=dtype)], -1)
        sol = torch.linalg.solve(K, rhs[..., None]).squeeze(-1)[..., :4]
        sol = sol.clamp_min(0.0) * valid_float
        sol = sol / (sol * c).sum(-1, keepdim=True).clamp_min(1e-12)
        out[start : start + n, floats[valid_float]] = sol[:, valid_float]
    return out.to(rig.template.dtype)


__all__ = [
    "LinearSkinningResult",
    "OrbitSystem",
    "fit_linear_weights",
    "learn_linear_skinning",
    "solve_weights",
    "valid_weights",
]
