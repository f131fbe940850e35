"""Fitting the rig to meshes in its own topology (known correspondence, JNR section 3.1).

Joint parameters are optimised with Adam on eq. 7. Degrees, millimetres and scale factors live on very
different scales, so the optimiser works on ``z = theta / span`` where ``span`` is each channel's range
(``high - low``); the loss is still eq. 7 on ``theta``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from rig.lbs import ShapeError, skinning_basis
from rig.losses import LAMBDA_M, LAMBDA_P, LAMBDA_X, rig_loss, vertex_rmse
from rig.model import JointRig
from rig.optim import Progress
from rig.parameters import NUM_PARAMETERS, theta_limits


@dataclass(frozen=True)
class JointFit:
    """Result of :func:`fit_joints`.

    Attributes:
        theta: ``(B, P)`` fitted parameters (deg, mm, ``scale - 1``).
        rmse: ``(B,)`` final vertex RMSE in mm.
        losses: ``(T,)`` mean eq.-7 loss per iteration.
        snapshots: ``(S, B, P)`` intermediate parameter sets (every ``snapshot_every`` iterations).
    """

    theta: torch.Tensor
    rmse: torch.Tensor
    losses: torch.Tensor
    snapshots: torch.Tensor


def parameter_span(dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """``(P,)`` width of each channel's range, the optimiser's unit."""
    low, high = theta_limits(dtype)
    return (high - low).clamp_min(1e-3)


def fit_joints(
    rig: JointRig,
    targets: torch.Tensor,
    *,
    weights: torch.Tensor | None = None,
    init: torch.Tensor | None = None,
    iterations: int = 500,
    lr: float = 0.01,
    lambda_m: float = LAMBDA_M,
    lambda_x: float = LAMBDA_X,
    lambda_p: float = LAMBDA_P,
    snapshot_every: int = 0,
    progress: Progress | None = None,
) -> JointFit:
    """Fit joint parameters to meshes with known correspondence by minimising eq. 7.

    Args:
        rig: the rig.
        targets: ``(B, V, 3)`` target meshes in the template's topology, mm.
        weights: optional ``(V, K)`` or ``(B, V, K)`` skinning weights (default: the rig's own).
        init: optional ``(B, P)`` starting parameters (default: rest pose, as JNR).
        iterations: Adam steps; lr: learning rate on the normalised parameters.
        snapshot_every: keep the parameters every this many iterations (0: none).
        progress: called as ``progress("joints", iteration, iterations)`` (:data:`rig.optim.Progress`).

    Returns:
        :class:`JointFit`.
    """
    if targets.dim() != 3 or targets.shape[1:] != (rig.num_vertices, 3):
        raise ShapeError(f"fit_joints: targets must have shape (B, {rig.num_vertices}, 3), got {tuple(targets.shape)}")
    dtype = rig.template.dtype
    targets = targets.to(dtype)
    B = targets.shape[0]
    low, high = theta_limits(dtype)
    span = parameter_span(dtype)
    z0 = torch.zeros(B, NUM_PARAMETERS, dtype=dtype) if init is None else init.detach().to(dtype) / span
    z = z0.clone().requires_grad_(True)
    opt = torch.optim.Adam([z], lr=lr)
    lap = rig.laplacian
    losses, snapshots = [], []
    # The weights stay fixed: build the skinning basis once, then each step is one matrix product.
    basis = None if weights is None else skinning_basis(rig.template, weights.detach().to(dtype))
    if basis is not None and basis.dim() == 3 and basis.shape[0] != B:
        basis = basis.expand(B, -1, -1)
    for it in range(iterations):
        theta = z * span
        pred = rig(theta, basis=basis).vertices
        loss = rig_loss(pred, targets, theta, low, high, lap, lambda_m, lambda_x, lambda_p)["total"].mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if snapshot_every and (it + 1) % snapshot_every == 0:
            snapshots.append((z.detach() * span).clone())
        if progress is not None:
            progress("joints", it + 1, iterations)
    with torch.no_grad():
        theta = z.detach() * span
        rmse = vertex_rmse(rig(theta, basis=basis).vertices, targets)
    snaps = torch.stack(snapshots) if snapshots else theta.new_zeros(0, B, NUM_PARAMETERS)
    return JointFit(theta, rmse, torch.tensor(losses), snaps)
