"""The priors of the rig fits, each defined once as a :class:`~pipeline.fitting.terms.Term`.

Every fit regularises the same parameters: the joints by JNR's L_m (eq. 4, deviation from the rest
pose in deg / mm / scale - 1, an L1 norm: iteratively reweighted in least squares) and L_x (eq. 5, the
joint-limit penalty), the latent by ``|Z|^2`` (it stays where the decoder was trained), the expression
coefficients by ``|c|^2``, and optionally the joints' asymmetry ``|theta - mirror(theta)|^2 / P``. The photo
fit replaces L_m by the identity prior learned from the training population
(:mod:`pipeline.fitting.identity`): ``lambda_identity`` times the Gaussian's negative log-density
``0.5 |M (theta / span - mu)|^2``. An ASM head (:mod:`rig.skinning.asm`) has ASM's own regulariser (its eq. 19)
and a smoothness term instead of the joint priors. Their weights are a :class:`PriorWeights` group of each
fit's config (``prior:`` in YAML).

Which priors a fit has comes from its state (:meth:`pipeline.fitting.state.FitState.prior_terms`, overridden by
the ASM states); the terms read the inputs ``theta (B, P)``, ``theta_n (B, P)``, ``z (B, 50)``, ``c (B, E)``,
``asm`` (:class:`rig.skinning.asm.AsmParameters`) and ``rig_vertices (B, V, 3)``
(:class:`~pipeline.fitting.terms.Inputs`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch

from pipeline.fitting.identity import IdentityPrior, load_identity_prior
from pipeline.fitting.terms import L1, L2, Inputs, Term, Value, term_values
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES
from rig.parameters import mirror_theta

NUM_JOINTS = 52
"""L_m and L_x are sums over channels divided by the number of joints (JNR eqs. 4-5)."""


@dataclass(frozen=True)
class PriorWeights:
    """Weights of the rig priors (:func:`jnr_prior_terms`, :func:`asm_prior_terms`)."""

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
    lambda_gaze: float = 0.02
    """|c|^2 of the eight eyeLook* coefficients instead of ``lambda_expressions`` when the landmarks see the
    irises (MediaPipe's 478 points, :func:`gaze_scale`); without them the gaze keeps ``lambda_expressions``."""
    lambda_asm: float = 1e-2
    """ASM fits only (``skinning: asm``): weight of ASM's regulariser (its eq. 19, :meth:`rig.skinning.asm.
    AdaptiveSkinning.regularizer`), which replaces L_m, L_x and |Z|^2; it diminishes with L_m's schedule."""
    lambda_asm_smooth: float = 1.0
    """ASM fits only: weight of the squared uniform Laplacian of the head's offset from the template (mm^2,
    mean over vertices), against the folds that sharp mixtures and free bone scales make (0: off); chosen on
    a simulated scan, docs/asm.md (the point-cloud section)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise InputError(f"prior.{f.name} must be a finite number >= 0, got {value!r}")


# ----------------------------------------------------------------------------------------------------
# The terms
# ----------------------------------------------------------------------------------------------------


def joint_magnitude_term(weight: float) -> Term:
    """L_m (JNR eq. 4): ``weight * sum_p |theta_p| / 52`` (deg, mm, ``scale - 1``), L1 (IRLS in least squares)."""
    return Term("L_m", weight, lambda p: p["theta"], L1(eps=1e-3), normaliser=float(NUM_JOINTS))


def joint_limit_term(weight: float, low: torch.Tensor, high: torch.Tensor) -> Term:
    """L_x (JNR eq. 5): ``weight * sum_p (max(0, theta_p - high_p) + max(0, low_p - theta_p)) / 52``; limits
    ``(P,)`` in joint units. The LM solver keeps the joints inside the limits (its box) instead."""

    def violation(p: Inputs) -> torch.Tensor:
        theta = p["theta"]
        return (theta - high.to(theta.dtype)).clamp_min(0.0) + (low.to(theta.dtype) - theta).clamp_min(0.0)

    return Term(
        "L_x",
        weight,
        violation,
        Value(),
        normaliser=float(NUM_JOINTS),
        lm="box",
        note="the joints' box limits of the LM solver hold it at 0",
    )


def latent_term(weight: float) -> Term:
    """``weight * |Z|^2``: the neural-skinning latent stays where the decoder was trained."""
    return Term("latent", weight, lambda p: p["z"], L2())


def expression_term(
    weight: float, name: str = "expressions", key: str = "c", scale: torch.Tensor | None = None
) -> Term:
    """``weight * |scale * c|^2`` on the expression coefficients (the input ``key``, ``(B, E)``; ``scale``
    ``(E,)``, default all 1: :func:`gaze_scale`)."""
    if scale is None:
        return Term(name, weight, lambda p: p[key], L2())
    return Term(name, weight, lambda p: p[key] * scale.to(p[key].dtype), L2())


GAZE_NAMES = tuple(n for n in EXPRESSION_NAMES if n.startswith("eyeLook"))
"""The eight ARKit coefficients of the eyes' direction."""


def gaze_scale(weights: PriorWeights) -> torch.Tensor:
    """``(E,)`` float64 scale of :func:`expression_term` that gives the eyeLook* coefficients the weight
    ``lambda_gaze`` instead of ``lambda_expressions`` (1 elsewhere)."""
    scale = torch.ones(len(EXPRESSION_NAMES), dtype=torch.float64)
    if weights.lambda_expressions > 0:
        ratio = (weights.lambda_gaze / weights.lambda_expressions) ** 0.5
        scale[[EXPRESSION_NAMES.index(n) for n in GAZE_NAMES]] = ratio
    return scale


def identity_term(weight: float, identity: IdentityPrior) -> Term:
    """``0.5 weight |M (theta / span - mu)|^2``, the learned identity prior's negative log-density
    (:meth:`pipeline.fitting.identity.IdentityPrior.whiten`)."""
    return Term("identity", 0.5 * weight, lambda p: identity.whiten(p["theta_n"]), L2())


def symmetry_term(weight: float) -> Term:
    """``weight * |theta - mirror(theta)|^2 / P``: the joints' asymmetry (:func:`rig.parameters.mirror_theta`)."""
    return Term("symmetry", weight, lambda p: p["theta"] - mirror_theta(p["theta"]), L2(), normaliser="mean")


def asm_regulariser_term(weight: float, model) -> Term:
    """``weight * R(asm)``, ASM's eq. 19 (:meth:`rig.skinning.asm.AdaptiveSkinning.regularizer`) of the input
    ``asm`` (:class:`rig.skinning.asm.AsmParameters`)."""
    return Term(
        "asm",
        weight,
        lambda p: model.regularizer(p["asm"])[:, None],
        Value(),
        lm="none",
        note="ASM's regulariser (rig.skinning.asm) is given as a value per head, not as residuals",
    )


def smoothness_term(weight: float, laplacian: torch.Tensor, template: torch.Tensor, name: str = "smooth") -> Term:
    """``weight * mean_v |L (x - template)|_v^2`` (mm^2): the squared uniform Laplacian of the head's offset
    from the template (``laplacian`` sparse ``(V, V)``; the input ``rig_vertices (B, V, 3)``)."""

    def laplacian_of_offset(p: Inputs) -> torch.Tensor:
        offset = p["rig_vertices"] - template
        return torch.stack([torch.sparse.mm(laplacian, o) for o in offset])

    return Term(name, weight, laplacian_of_offset, L2(), normaliser="mean")


def sparsity_term(
    weight: float, mask: torch.Tensor | None = None, name: str = "expressions_sparse", key: str = "c"
) -> Term:
    """``weight * sum_i mask_i c_i`` on non-negative coefficients (the input ``key``, ``(B, E)``, held ``>= 0`` by
    their limits): an L1 prior that keeps the unused coefficients at 0 without holding the used ones back as
    much as ``|c|^2`` does (``mask`` ``(E,)``: 1 where it applies, default everywhere).

    Written as the squares of ``sqrt(mask_i c_i + 1)``, so that the LM solver stacks it with the exact gradient
    (``weight * mask_i``) and a Gauss-Newton curvature; its value is therefore ``weight * (sum_i mask_i c_i + E)``,
    a constant above the prior's (which moves no fit).
    """

    def root(p: Inputs) -> torch.Tensor:
        c = p[key]
        m = torch.ones_like(c) if mask is None else mask.to(c.dtype)
        return torch.sqrt((c * m).clamp_min(0.0) + 1.0)

    return Term(name, weight, root, L2())


def velocity_term(weight: float, last: torch.Tensor, key: str, name: str) -> Term:
    """``weight * |x - x_1|^2`` of the input ``key`` ``(B, n)`` against the frame before's ``x_1`` ``(n,)``: a
    sequence's first-order temporal prior."""
    return Term(name, weight, lambda p: p[key] - last.to(p[key].dtype), L2())


def acceleration_term(weight: float, last: torch.Tensor, before: torch.Tensor, key: str, name: str) -> Term:
    """``weight * |x - 2 x_1 + x_2|^2`` of the input ``key`` ``(B, n)`` against the two frames before (``x_1``,
    ``x_2``, ``(n,)``): a sequence's second-order temporal prior (steady motion costs nothing): the first-order
    one towards the steady motion's next value ``2 x_1 - x_2``."""
    return velocity_term(weight, 2.0 * last.double() - before.double(), key, name)


# ----------------------------------------------------------------------------------------------------
# The priors of a head model (called by the states)
# ----------------------------------------------------------------------------------------------------


def jnr_prior_terms(
    weights: PriorWeights,
    low: torch.Tensor,
    high: torch.Tensor,
    *,
    lambda_m: float | None = None,
    identity: IdentityPrior | None = None,
    latent: bool = True,
    gaze: bool = False,
) -> tuple[Term, ...]:
    """The priors of the JNR joints: ``L_m``, ``L_x``, ``latent`` (unless ``latent=False``: a head without a
    latent), ``expressions`` (and ``identity``, ``symmetry`` when their weights are not 0).

    Args:
        weights: their weights. low, high: ``(P,)`` the joints' limits (deg, mm, ``scale - 1``).
        lambda_m: overrides ``weights.lambda_m`` (the point-cloud fit lowers it as correspondences settle).
        identity: the identity prior; default :func:`cached_identity_prior` when ``weights.lambda_identity``
            is not 0.
        gaze: the data sees the irises: the eyeLook* coefficients get ``weights.lambda_gaze``.
    """
    terms = [
        joint_magnitude_term(weights.lambda_m if lambda_m is None else lambda_m),
        joint_limit_term(weights.lambda_x, low, high),
        *((latent_term(weights.lambda_z),) if latent else ()),
        expression_term(weights.lambda_expressions, scale=gaze_scale(weights) if gaze else None),
    ]
    if weights.lambda_identity:
        terms.append(identity_term(weights.lambda_identity, identity or cached_identity_prior()))
    if weights.lambda_symmetry:
        terms.append(symmetry_term(weights.lambda_symmetry))
    return tuple(terms)


def asm_prior_terms(
    weights: PriorWeights, model, *, lambda_m: float | None = None, expressions: bool = True
) -> tuple[Term, ...]:
    """The priors of an ASM head: ``asm`` (eq. 19, following L_m's diminishing schedule: its weight is
    ``lambda_asm * lambda_m / weights.lambda_m``), ``expressions`` (unless ``expressions=False``: a fit that
    keeps them fixed) and ``smooth`` (when ``lambda_asm_smooth`` is not 0; the rig's Laplacian and template)."""
    ratio = 1.0 if lambda_m is None or not weights.lambda_m else lambda_m / weights.lambda_m
    terms = [asm_regulariser_term(weights.lambda_asm * ratio, model)]
    if expressions:
        terms.append(expression_term(weights.lambda_expressions))
    if weights.lambda_asm_smooth:
        terms.append(smoothness_term(weights.lambda_asm_smooth, model.rig.laplacian, model.rig.template))
    return tuple(terms)


def rig_prior_terms(
    state, weights: PriorWeights, *, lambda_m: float | None = None, identity: IdentityPrior | None = None
) -> dict[str, torch.Tensor]:
    """The weighted prior values of ``state`` (:meth:`~pipeline.fitting.state.FitState.prior_terms` at its
    :meth:`~pipeline.fitting.state.FitState.term_inputs`), by name, scalar tensors."""
    return term_values(state.prior_terms(weights, lambda_m=lambda_m, identity=identity), state.term_inputs())


_IDENTITY: list[IdentityPrior] = []


def cached_identity_prior() -> IdentityPrior:
    """The committed identity prior, read once per process."""
    if not _IDENTITY:
        _IDENTITY.append(load_identity_prior())
    return _IDENTITY[0]
