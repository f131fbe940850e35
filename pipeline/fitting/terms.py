"""Loss terms, each defined once: a named, weighted residual with its robust loss, for both solvers.

A :class:`Term` maps the fit's parameters (batched, by name: :class:`Inputs`) to a residual ``r`` of shape
``(B, n)`` (``n`` scalar residuals) or ``(B, n, d)`` (``n`` groups of ``d``, e.g. a landmark's pixel error),
and reads it through a robust kernel ``rho`` (:class:`Robust`) applied per residual or per group::

    value(p)  = weight * sum_g w_g rho(r_g) / Z            (the Adam engine minimises this)
    rows(p)   = sqrt(weight * w_g / Z * omega_g) * r_g       (Levenberg-Marquardt stacks these)

``w_g`` are optional per-group weights, ``Z`` the term's normaliser (a constant, the number of groups or the
sum of the ``w_g``) and ``omega_g`` the kernel's iteratively-reweighted-least-squares (IRLS) weight at the
point the LM solver last re-weighted at (:meth:`Robust.irls`): with it the gradient of ``0.5 |rows|^2`` is the
gradient of ``value`` there, so a robust term is minimised by a sequence of weighted least-squares steps. For
``L2`` (``rho = |r|^2``, ``omega = 2``) ``0.5 |rows|^2`` *is* the value; for the other kernels it is the value up
to :meth:`Robust.offset` (the IRLS majoriser's constant), which the tests check.

A term says in its one definition how the LM solver takes it (:attr:`Term.lm`): ``rows`` (stacked),
``box`` (the solver's box limits hold it at 0, e.g. the joint-limit penalty, so it is not stacked) or
``none`` (it cannot: a term given only by its value; :class:`LeastSquaresTerms` then raises with the
term's :attr:`Term.note`). The Adam engine takes every term.

Adding a term to a fit is one definition, e.g. a pull of joint channel ``k`` towards 8 mm::

    pull = Term("pull", 1.0, lambda p: p["theta"][:, k : k + 1] - 8.0, L2())
    fit_landmarks(landmarks2d, width, height, terms=(pull,))  # minimised by LM (the default) or Adam

A prior of every fit of a head model goes into its state's ``prior_terms``
(:meth:`pipeline.fitting.state.FitState.prior_terms`, :mod:`pipeline.fitting.priors`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch

from rig.errors import InputError

LM_MODES = ("rows", "box", "none")


# ----------------------------------------------------------------------------------------------------
# Robust kernels
# ----------------------------------------------------------------------------------------------------


def _squared(r: torch.Tensor) -> torch.Tensor:
    """``|r_g|^2`` per residual (``(B, n)``) or per group (``(B, n, d)`` -> ``(B, n)``)."""
    return r * r if r.dim() == 2 else (r * r).sum(-1)


class Robust:
    """A robust loss ``rho`` of a residual (or of a group's norm) and its IRLS weight.

    Subclasses define :meth:`rho` (``(B, n)`` or ``(B, n, d)`` -> ``(B, n)``) and :meth:`irls` (the same
    shapes -> ``(B, n)`` tensor or a float): ``omega`` with ``d/dr [0.5 omega |r|^2] = d/dr rho(r)`` at ``r``.
    """

    name = "robust"

    def rho(self, r: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def irls(self, r: torch.Tensor) -> torch.Tensor | float:
        raise NotImplementedError

    def offset(self, r: torch.Tensor) -> torch.Tensor:
        """``rho(r) - 0.5 omega(r) |r|^2`` per residual or group: what the IRLS surrogate leaves out of the
        value at the point it was weighted at (0 for ``L2``)."""
        return self.rho(r) - 0.5 * self.irls(r) * _squared(r)

    def __repr__(self) -> str:
        return self.name


class L2(Robust):
    """``rho = |r|^2`` (no factor 1/2: the value is the squared norm); ``omega = 2``."""

    name = "l2"

    def rho(self, r: torch.Tensor) -> torch.Tensor:
        return r.square() if r.dim() == 2 else r.square().sum(-1)

    def irls(self, r: torch.Tensor) -> float:
        return 2.0


class L1(Robust):
    """``rho = |r|`` of scalar residuals; ``omega = 1 / max(|r|, eps)`` (``eps`` in the residual's units)."""

    name = "l1"

    def __init__(self, eps: float = 1e-3) -> None:
        self.eps = float(eps)

    def rho(self, r: torch.Tensor) -> torch.Tensor:
        return r.abs()

    def irls(self, r: torch.Tensor) -> torch.Tensor:
        return 1.0 / r.abs().clamp_min(self.eps)


class Huber(Robust):
    """Huber of a group's norm ``e = |r_g|``: ``e^2 / 2`` up to ``delta``, ``delta (e - delta / 2)`` beyond
    (as :func:`landmarks.loss.landmark_reprojection_loss`); ``omega = min(1, delta / e)``."""

    name = "huber"

    def __init__(self, delta: float) -> None:
        self.delta = float(delta)

    def rho(self, r: torch.Tensor) -> torch.Tensor:
        delta = self.delta
        sq = _squared(r)
        # sqrt has an infinite derivative at 0: take it of a value kept away from 0
        e = torch.sqrt(sq.clamp_min(delta * delta))
        return torch.where(sq <= delta * delta, 0.5 * sq, delta * (e - 0.5 * delta))

    def irls(self, r: torch.Tensor) -> torch.Tensor:
        e = r.abs() if r.dim() == 2 else r.norm(dim=-1)
        return torch.where(e > self.delta, self.delta / e.clamp_min(1e-12), torch.ones_like(e))


class GemanMcClure(Robust):
    """Geman-McClure of the squared norm ``s = |r_g|^2`` at scale ``sigma``: ``sigma^2 s / (sigma^2 + s)``;
    ``omega = 2 sigma^4 / (sigma^2 + s)^2``."""

    name = "geman-mcclure"

    def __init__(self, sigma: float) -> None:
        self.sigma = float(sigma)

    def rho(self, r: torch.Tensor) -> torch.Tensor:
        s2 = self.sigma * self.sigma
        sq = _squared(r)
        return s2 * sq / (s2 + sq)

    def irls(self, r: torch.Tensor) -> torch.Tensor:
        s2 = self.sigma * self.sigma
        return 2.0 * s2 * s2 / (s2 + _squared(r)).square()


class Charbonnier(Robust):
    """Charbonnier of the squared norm: ``sqrt(|r_g|^2 + eps^2) - eps``; ``omega = 1 / sqrt(|r_g|^2 + eps^2)``."""

    name = "charbonnier"

    def __init__(self, eps: float) -> None:
        self.eps = float(eps)

    def rho(self, r: torch.Tensor) -> torch.Tensor:
        return (_squared(r) + self.eps**2).sqrt() - self.eps

    def irls(self, r: torch.Tensor) -> torch.Tensor:
        return 1.0 / (_squared(r) + self.eps**2).sqrt()


class Value(Robust):
    """The residual already is the loss (``rho = r``, e.g. a penalty linear in a limit's violation, or a
    term only given by its value); no IRLS form, so the LM solver cannot stack it."""

    name = "value"

    def rho(self, r: torch.Tensor) -> torch.Tensor:
        return r if r.dim() == 2 else r.sum(-1)

    def irls(self, r: torch.Tensor) -> float:
        raise InputError("a Value term has no least-squares form")


# ----------------------------------------------------------------------------------------------------
# Inputs: the parameters by name
# ----------------------------------------------------------------------------------------------------


class Inputs(Mapping[str, Any]):
    """What terms read: named batched tensors (``theta_n (B, P)``, ``c (B, E)``, ``landmarks_px (B, 68, 2)``,
    ...), each given as a tensor or a zero-argument function computed on first use and kept.

    The Adam engine's objectives build one with batch 1 from the live parameters (gradients flow); the LM
    stages one per batch of parameter sets. Example::

        p = Inputs({"c": c[None]}, vertices=lambda: model.vertices(c[None]))
    """

    def __init__(self, values: Mapping[str, Any] | None = None, **lazy: Callable[[], Any]) -> None:
        self._values: dict[str, Any] = dict(values or {})
        self._lazy: dict[str, Callable[[], Any]] = dict(lazy)

    def __getitem__(self, name: str) -> Any:
        if name not in self._values:
            if name not in self._lazy:
                raise KeyError(f"term input {name!r} not provided (have {sorted(self)})")
            self._values[name] = self._lazy.pop(name)()
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter([*self._values, *self._lazy])

    def __len__(self) -> int:
        return len(self._values) + len(self._lazy)

    def add(self, values: Mapping[str, Any] | None = None, **lazy: Callable[[], Any]) -> Inputs:
        """A new :class:`Inputs` with these added (or replaced)."""
        out = Inputs(self._values, **self._lazy)
        for name, value in (values or {}).items():
            out._lazy.pop(name, None)
            out._values[name] = value
        for name, fn in lazy.items():
            out._values.pop(name, None)
            out._lazy[name] = fn
        return out


# ----------------------------------------------------------------------------------------------------
# The term
# ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Term:
    """A named, weighted residual with its robust loss (module docstring).

    Attributes:
        name: the key in the loss logs (``report.json``).
        weight: its weight (0: evaluated by the Adam engine, left out by the LM solver).
        residual: ``residual(p: Inputs) -> (B, n)`` or ``(B, n, d)``.
        robust: the kernel (:class:`L2`, :class:`L1`, :class:`Huber`, :class:`GemanMcClure`,
            :class:`Charbonnier`, :class:`Value`).
        normaliser: ``Z``: a number, ``"mean"`` (the number of groups ``n``) or ``"weights"`` (the sum of the
            group weights, at least ``min_normaliser``).
        group_weights: ``(n,)`` weights ``w_g`` of the groups (None: all 1), in any float dtype, or the name of
            an input holding them (``(n,)`` or ``(B, n)``: weights that change with each evaluation).
        min_normaliser: floor of ``Z = "weights"``.
        lm: ``rows``, ``box`` or ``none`` (module docstring). note: why, when not ``rows``.
    """

    name: str
    weight: float
    residual: Callable[[Inputs], torch.Tensor]
    robust: Robust
    normaliser: float | str = 1.0
    group_weights: torch.Tensor | str | None = None
    min_normaliser: float | None = None
    lm: str = "rows"
    note: str = ""

    def __post_init__(self) -> None:
        if self.lm not in LM_MODES:
            raise InputError(f"term {self.name!r}: lm must be one of {list(LM_MODES)}, got {self.lm!r}")
        if isinstance(self.normaliser, str) and self.normaliser not in ("mean", "weights"):
            raise InputError(f"term {self.name!r}: normaliser must be a number, 'mean' or 'weights'")
        if self.normaliser == "weights" and self.group_weights is None:
            raise InputError(f"term {self.name!r}: normaliser 'weights' needs group_weights")
        if self.lm == "rows" and isinstance(self.robust, Value):
            raise InputError(f"term {self.name!r}: a Value term cannot be stacked by the LM solver (lm='rows')")

    def _weights(self, p: Inputs, r: torch.Tensor) -> torch.Tensor | None:
        w = p[self.group_weights] if isinstance(self.group_weights, str) else self.group_weights
        return None if w is None else w.to(r.dtype)

    def _normaliser(self, w: torch.Tensor) -> torch.Tensor:
        return w.sum() if self.min_normaliser is None else w.sum().clamp_min(self.min_normaliser)

    def reduced(self, p: Inputs) -> torch.Tensor:
        """``(B,)`` the unweighted value ``sum_g w_g rho(r_g) / Z``."""
        r = self.residual(p)
        rho = self.robust.rho(r)
        w = self._weights(p, r)
        if self.normaliser == "mean":
            return rho.mean(-1) if w is None else (rho * w).mean(-1)
        total = rho.sum(-1) if w is None else (rho * w).sum(-1)
        if self.normaliser == "weights":
            return total / self._normaliser(w)
        return total / self.normaliser

    def value(self, p: Inputs) -> torch.Tensor:
        """``(B,)`` the weighted value, what the Adam engine minimises."""
        return self.weight * self.reduced(p)

    def irls(self, p: Inputs) -> torch.Tensor | float:
        """The kernel's IRLS weights at ``p`` (batch 1): ``(1, n)`` or a float."""
        if self.lm != "rows":
            raise InputError(f"term {self.name!r} has no least-squares rows (lm={self.lm!r}): {self.note}")
        return self.robust.irls(self.residual(p).detach())

    def coefficients(self, p: Inputs, r: torch.Tensor, omega: torch.Tensor | float) -> torch.Tensor | float:
        """``weight * w_g / Z * omega_g``: the squared scale of each residual's (group's) row."""
        n = r.shape[1]
        w = self._weights(p, r)
        if w is None:
            scale = self.weight / (n if self.normaliser == "mean" else self.normaliser)
        elif self.normaliser == "weights":
            scale = self.weight * (w / self._normaliser(w))
        else:
            scale = self.weight * (w / (n if self.normaliser == "mean" else self.normaliser))
        return scale * omega

    def rows(self, p: Inputs, omega: torch.Tensor | float) -> torch.Tensor:
        """``(B, m)`` the LM solver's rows at IRLS weights ``omega`` (:meth:`irls`): half their squared norm
        has the gradient of :meth:`value` where ``omega`` was taken."""
        r = self.residual(p)
        c = self.coefficients(p, r, omega)
        scale = math.sqrt(c) if isinstance(c, float) else c.sqrt()
        if r.dim() == 3 and not isinstance(scale, float):
            scale = scale[..., None]
        return (r * scale).reshape(r.shape[0], -1)


def term_values(
    terms: Sequence[Term], p: Inputs, unweighted: dict[str, torch.Tensor] | None = None
) -> dict[str, torch.Tensor]:
    """``{name: scalar}`` the weighted values of ``terms`` at batch-1 inputs ``p``, in order (an Adam
    objective's :class:`~pipeline.fitting.engine.Loss` terms); ``unweighted``, if given, receives each
    term's value before its weight."""
    values = {}
    for t in terms:
        reduced = t.reduced(p)
        if unweighted is not None:
            unweighted[t.name] = reduced[0]
        values[t.name] = (t.weight * reduced)[0]
    return values


def check_unique(terms: Sequence[Term]) -> None:
    """Raise ValueError when two terms share a name (the logs and IRLS weights are keyed by it)."""
    names = [t.name for t in terms]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"loss terms must have distinct names; {twice} appear more than once")


class LeastSquaresTerms:
    """Terms as the LM solver's residual rows: every ``lm="rows"`` term of non-zero weight, stacked in order,
    at the IRLS weights of the last :meth:`reweight`; ``lm="box"`` terms are left to the solver's box limits.

    Raises:
        ValueError: a term that the LM solver cannot take (``lm="none"``), naming it and why; two terms with
            one name.
    """

    def __init__(self, terms: Sequence[Term]) -> None:
        check_unique(terms)
        bad = [t for t in terms if t.lm == "none"]
        if bad:
            reasons = "; ".join(f"{t.name!r}: {t.note or 'no least-squares form'}" for t in bad)
            raise InputError(f"Levenberg-Marquardt cannot minimise the term(s) {reasons}; use the Adam solver")
        self.terms = tuple(t for t in terms if t.lm == "rows" and t.weight != 0)
        self.omega: dict[str, torch.Tensor | float] = {}

    def subset(self, names: Sequence[str]) -> LeastSquaresTerms:
        """The stacked terms named ``names`` with their current IRLS weights (a later stage that goes on with
        part of the terms, as they were weighted)."""
        out = LeastSquaresTerms([t for t in self.terms if t.name in names])
        out.omega = {t.name: self.omega[t.name] for t in out.terms}
        return out

    def reweight(self, p: Inputs) -> None:
        """The IRLS weights of every stacked term at batch-1 inputs ``p``."""
        self.omega = {t.name: t.irls(p) for t in self.terms}

    def rows(self, p: Inputs) -> torch.Tensor:
        """``(B, m)`` all rows at inputs ``p`` (batch ``B``)."""
        if len(self.omega) != len(self.terms):
            raise RuntimeError("LeastSquaresTerms.rows: call reweight first")
        return torch.cat([t.rows(p, self.omega[t.name]) for t in self.terms], dim=1)

    def cost(self, p: Inputs) -> torch.Tensor:
        """``(B,)`` the least-squares cost ``0.5 |rows|^2`` (the IRLS surrogate of the terms' summed value)."""
        return 0.5 * self.rows(p).square().sum(-1)
