"""The priors of the rig fits, as named loss terms.

Every fit regularises the same parameters: the joints by JNR's L_m (eq. 4, deviation from the rest
pose in deg / mm / scale - 1) and L_x (eq. 5, the joint-limit penalty), the latent by ``|Z|^2`` (it
stays where the decoder was trained), the expression coefficients by ``|c|^2``, and optionally the
joints' asymmetry ``|theta - mirror(theta)|^2 / P``. The photo fit replaces L_m by the identity prior
learned from the training population (:mod:`pipeline.fitting.identity`): ``lambda_identity`` times the
Gaussian's negative log-density ``0.5 |M (theta / span - mu)|^2``. Their weights are a
:class:`PriorWeights` group of each fit's config (``prior:`` in YAML).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from pipeline.fitting.identity import IdentityPrior, load_identity_prior
from pipeline.fitting.state import FitState
from rig.losses import limit_loss, regularizer
from rig.parameters import mirror_theta


@dataclass(frozen=True)
class PriorWeights:
    """Weights of the rig priors (:func:`rig_prior_terms`)."""

    lambda_m: float = 0.3
    """L_m (eq. 4, deg / mm / scale-1 per joint) against the fit's data term."""
    lambda_x: float = 3.0
    """L_x (eq. 5), the joint-limit penalty."""
    lambda_z: float = 0.01
    """|Z|^2 keeps the latent where the decoder was trained."""
    lambda_expressions: float = 0.5
    """|c|^2 on the expression coefficients."""
    lambda_symmetry: float = 0.0
    """Optional symmetry prior ``|theta - mirror(theta)|^2 / P`` (0: off)."""
    lambda_identity: float = 0.0
    """The learned identity prior (:mod:`pipeline.fitting.identity`), its negative log-density (0: off)."""
    lambda_asm: float = 1e-2
    """ASM fits only (``skinning: asm``): weight of ASM's regulariser (its eq. 19, :meth:`rig.skinning.asm.
    AdaptiveSkinning.regularizer`), which replaces L_m, L_x and |Z|^2; it diminishes with L_m's schedule."""
    lambda_asm_smooth: float = 1.0
    """ASM fits only: weight of the squared uniform Laplacian of the head's offset from the template (mm^2,
    mean over vertices), against the folds that sharp mixtures and free bone scales make (0: off). On a
    simulated scan of held-out head 1 (expressive): without it the fit had folds at the eyes, cheeks and
    jaw (face error 3.20 mm; with lambda_asm 0.1 instead, 3.55 mm and the same folds); with 1.0 a smooth
    head, 2.65 mm (JNR's fit: 3.67 mm)."""


def rig_prior_terms(state: FitState, weights: PriorWeights, *, lambda_m: float | None = None,
                    identity: IdentityPrior | None = None) -> dict[str, torch.Tensor]:
    """The weighted prior terms of ``state``: ``L_m``, ``L_x``, ``latent``, ``expressions`` (and
    ``symmetry`` when its weight is not 0), scalar tensors; for an ASM state
    (:class:`~pipeline.fitting.state.AsmScanState`) ``asm`` (eq. 19) and ``expressions``.

    Args:
        state: the fit state (joints ``theta (P,)``, ``z (50,)``, ``c (E,)``).
        weights: their weights.
        lambda_m: overrides ``weights.lambda_m`` (the point-cloud fit lowers it as correspondences settle).
        identity: the identity prior; default :func:`pipeline.fitting.identity.load_identity_prior` when
            ``weights.lambda_identity`` is not 0 (term ``identity``).
    """
    if getattr(state, "asm", None) is not None:
        # ASM's own regulariser replaces the joint priors; it follows L_m's diminishing schedule.
        ratio = 1.0 if lambda_m is None or not weights.lambda_m else lambda_m / weights.lambda_m
        reg = state.asm.regularizer(state.asm_parameters())[0]
        return {"asm": weights.lambda_asm * ratio * reg,
                "expressions": weights.lambda_expressions * state.c.square().sum()}
    theta = state.theta
    terms = {
        "L_m": (weights.lambda_m if lambda_m is None else lambda_m) * regularizer(theta[None])[0],
        "L_x": weights.lambda_x * limit_loss(theta[None], state.low, state.high)[0],
        "latent": weights.lambda_z * state.z.square().sum(),
        "expressions": weights.lambda_expressions * state.c.square().sum(),
    }
    if weights.lambda_identity:
        identity = identity or cached_identity_prior()
        terms["identity"] = 0.5 * weights.lambda_identity * identity.whiten(state.theta_n).square().sum()
    if weights.lambda_symmetry:
        terms["symmetry"] = weights.lambda_symmetry * (theta - mirror_theta(theta)).square().mean()
    return terms


_IDENTITY: list[IdentityPrior] = []


def cached_identity_prior() -> IdentityPrior:
    """The committed identity prior, read once per process."""
    if not _IDENTITY:
        _IDENTITY.append(load_identity_prior())
    return _IDENTITY[0]
