"""Registration of ASM to meshes in the template's topology (:func:`fit_asm`): Adam on the free
parameters of a variant, in normalised units. See :mod:`rig.skinning.asm`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch

from rig.errors import InputError, ShapeError
from rig.optim import Progress
from rig.skinning.asm.model import AdaptiveSkinning
from rig.skinning.asm.parameters import TAU_UNITS, UV_UNIT, AsmParameters, AsmRegularizer, AsmVariant

__all__ = ["AsmFit", "fit_asm"]


@dataclass(frozen=True)
class AsmFit:
    """Result of :func:`fit_asm`.

    Attributes:
        params: the fitted :class:`AsmParameters`.
        vertices: ``(B, V, 3)`` fitted vertices, mm.
        rmse: ``(B,)`` vertex RMSE against the targets, mm.
        losses: ``(T,)`` mean loss per iteration.
        seconds: wall time of the fit.
    """

    params: AsmParameters
    vertices: torch.Tensor
    rmse: torch.Tensor
    losses: torch.Tensor
    seconds: float


#: Adam step scale per parameter (its unit): tau as :data:`TAU_UNITS`, UV in :data:`UV_UNIT`.
def _units(p: AsmParameters) -> dict[str, torch.Tensor | float]:
    return {"tau": p.tau.new_tensor(TAU_UNITS), "zeta": UV_UNIT, "log_pi": 1.0, "mu": UV_UNIT, "chol": 1.0}


def fit_asm(
    model: AdaptiveSkinning,
    targets: torch.Tensor,
    *,
    variant: AsmVariant | None = None,
    init: AsmParameters | None = None,
    iterations: int = 400,
    lr: float = 0.02,
    regularizer: AsmRegularizer | None = None,
    vertex_mask: torch.Tensor | None = None,
    progress: Progress | None = None,
) -> AsmFit:
    """Register ASM to meshes with known correspondence (point-to-point, ASM Appendix C's setting with
    known correspondence): Adam on the free parameters of ``variant`` in normalised units, cosine
    learning-rate decay, plus the eq.-19 regulariser.

    Args:
        model: the model.
        targets: ``(B, V, 3)`` meshes in the template's topology, mm.
        variant: which parts are tunable (default ``AsmVariant()``: all).
        init: starting parameters (default: :meth:`AdaptiveSkinning.initial`).
        iterations, lr: Adam steps and step size (in the units of :func:`_units`).
        regularizer: eq.-19 weights (default: 1e-4 on ``tau``, 1e-3 on the rest); the loss is the mean
            squared vertex distance (mm^2) + the regulariser divided by the number of vertices.
        vertex_mask: optional ``(V,)`` bool, the vertices that count (default: all).
        progress: ``progress("asm", i, iterations)``.

    Returns:
        :class:`AsmFit`.
    """
    variant = AsmVariant() if variant is None else variant
    if regularizer is None:
        regularizer = AsmRegularizer(tau=1e-4, zeta=1e-3, pi=1e-3, mu=1e-3, sigma=1e-3)
    V = model.rig.num_vertices
    if targets.dim() != 3 or targets.shape[1:] != (V, 3):
        raise ShapeError(f"fit_asm: targets must have shape (B, {V}, 3), got {tuple(targets.shape)}")
    if not torch.isfinite(targets).all():
        raise InputError("fit_asm: targets contain NaN or infinite values")
    t0 = time.perf_counter()
    dtype = model.rig.template.dtype
    targets = targets.to(dtype)
    B = targets.shape[0]
    start = (init or model.initial(B)).map(lambda t: t.detach().to(dtype))
    if start.batch != B:
        raise ShapeError(f"fit_asm: init has {start.batch} heads, targets {B}")
    units = _units(start)
    free = variant.free()
    scaled = {n: (getattr(start, n) / units[n]).clone().requires_grad_(True) for n in free}
    opt = torch.optim.Adam(list(scaled.values()), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(iterations, 1), eta_min=lr * 0.02)
    mask = None if vertex_mask is None else vertex_mask.to(targets.device)
    count = V if mask is None else int(mask.sum())

    def current() -> AsmParameters:
        values = start.as_dict()
        values.update({n: scaled[n] * units[n] for n in free})
        return AsmParameters(**values)

    losses = []
    for it in range(iterations):
        p = current()
        pred = model(p, dynamic_binding=variant.dynamic_binding, gmm_weights=variant.gmm_weights).vertices
        sq = ((pred - targets) ** 2).sum(-1)
        data = (sq if mask is None else sq[:, mask]).mean(-1)
        loss = (data + model.regularizer(p, regularizer) / count).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(loss.item())
        if progress is not None:
            progress("asm", it + 1, iterations)
    with torch.no_grad():
        p = current().map(torch.Tensor.detach)
        pred = model(p, dynamic_binding=variant.dynamic_binding, gmm_weights=variant.gmm_weights).vertices
        rmse = ((pred - targets) ** 2).sum(-1).mean(-1).sqrt()
    return AsmFit(p, pred, rmse, torch.tensor(losses), time.perf_counter() - t0)
