"""Levenberg-Marquardt for the small non-linear least-squares problems of jnr (the landmark fit).

A landmark fit has ~160 unknowns and ~300 residuals (136 landmark coordinates and the priors' rows):
second-order steps reach its minimum in tens of iterations where first-order Adam needs hundreds. The
residual function is *batched* (``(B, n) -> (B, m)``), so each iteration takes the Jacobian by forward
differences in one call on ``n + 1`` parameter sets, in float64 (step ``1e-7 max(1, |x_j|)``: about 8
significant digits, measured against ``torch.func.jacfwd`` in the tests; forward-mode autograd through
the rig's joint hierarchy was slower, docs/fit_photo.md "Levenberg-Marquardt"). It then solves the damped
normal equations

    (J^T J + mu diag(J^T J)) delta = -J^T r                        (Marquardt's scaling)

keeping unknowns that sit on a limit and are pushed outwards fixed (an active set), projects ``x + delta``
into the box limits, and accepts the step when the cost ``0.5 |r|^2`` falls (then
``mu`` shrinks) or rejects it (``mu`` grows). A ``prepare(x)`` hook runs before each Jacobian so a caller
can re-pick discrete choices (the jaw contour's silhouette vertices) and robust weights
(iteratively reweighted least squares for a Huber loss) at the current estimate.

A fit's LM stage is :func:`run_lm_stage`: a :class:`LeastSquaresProblem` (the stage's free parameters as
``x``, e.g. a state's groups packed by :class:`StateVector`, and what the terms read at a batch of ``x``) and
the fit's :class:`~pipeline.fitting.terms.Term` s, stacked as rows
(:class:`~pipeline.fitting.terms.LeastSquaresTerms`) and re-weighted by ``prepare``; the stage is logged as a
:class:`~pipeline.fitting.engine.StageLog` like the Adam engine's.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import torch

from pipeline.fitting.engine import Objective, Stage, StageLog
from pipeline.fitting.state import GroupedParameters
from pipeline.fitting.terms import Inputs, LeastSquaresTerms, Term
from rig.optim import Progress


@dataclass(frozen=True)
class LMSettings:
    """Settings of :func:`levenberg_marquardt`."""

    max_iterations: int = 25
    """Jacobian evaluations at most."""
    damping: float = 1e-3
    """Initial ``mu`` (relative to ``diag(J^T J)``)."""
    damping_up: float = 10.0
    """Factor on ``mu`` after a rejected step."""
    damping_down: float = 0.3
    """Factor on ``mu`` after an accepted step."""
    tolerance: float = 1e-3
    """Stop when an accepted step lowers the cost by less than this fraction."""
    max_rejections: int = 8
    """Stop after this many rejected steps in a row."""


@dataclass(frozen=True)
class LMResult:
    """Result of :func:`levenberg_marquardt`.

    Attributes:
        x: ``(n,)`` the solution (detached).
        cost: ``0.5 |r(x)|^2`` at the solution.
        costs: the cost after every accepted step (the start first).
        iterations: Jacobians evaluated.
        converged: stopped by the tolerance (not by ``max_iterations`` or rejections).
        seconds: wall time.
    """

    x: torch.Tensor
    cost: float
    costs: tuple[float, ...]
    iterations: int
    converged: bool
    seconds: float


def _cost(r: torch.Tensor) -> float:
    return 0.5 * float((r * r).sum())


def forward_difference_jacobian(
    residuals: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, relative_step: float = 1e-7
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(J (m, n), r (m,))`` of a batched residual function at ``x (n,)`` by forward differences, one call
    on ``n + 1`` rows (``x`` itself first), steps ``relative_step * max(1, |x_j|)``."""
    h = relative_step * x.abs().clamp_min(1.0)
    batch = torch.cat([x[None], x[None] + torch.diag(h)])
    out = residuals(batch)
    r = out[0]
    return ((out[1:] - r) / h[:, None]).T, r


class _Step:
    """One LM iteration's damped steps from ``x`` (the module docstring's normal equations), with unknowns at
    a limit that the gradient pushes outwards held there (an active set: a clipped full step would otherwise
    shrink every other unknown's progress)."""

    def __init__(self, residuals, x: torch.Tensor, J: torch.Tensor, r: torch.Tensor, lower, upper) -> None:
        self.residuals, self.x, self.lower, self.upper = residuals, x, lower, upper
        JtJ = J.T @ J
        g = J.T @ r
        free = torch.ones_like(x, dtype=torch.bool)
        if lower is not None:
            free &= ~((x <= lower + 1e-12) & (g > 0))
        if upper is not None:
            free &= ~((x >= upper - 1e-12) & (g < 0))
        self.free = free
        self.JtJ, self.g = JtJ[free][:, free], g[free]
        self.diag = self.JtJ.diagonal().clamp_min(1e-9)

    def search(
        self, cost: float, mu: float, rejections: int, settings: LMSettings
    ) -> tuple[torch.Tensor | None, float, float, int]:
        """Raise the damping ``mu`` until a step lowers ``cost`` (then lower it) or ``settings.max_rejections``
        steps in a row failed. Returns ``(x_new or None, its cost, mu, rejections)``."""
        x = self.x
        while rejections < settings.max_rejections:
            A = self.JtJ + torch.diag(mu * self.diag)
            try:
                step = torch.linalg.solve(A, -self.g)
            except RuntimeError:  # singular: more damping
                mu *= settings.damping_up
                rejections += 1
                continue
            delta = torch.zeros_like(x)
            delta[self.free] = step
            x_new = x + delta
            if self.lower is not None or self.upper is not None:
                x_new = torch.clamp(x_new, self.lower, self.upper)
            with torch.no_grad():
                r_new = self.residuals(x_new[None])[0]
            new_cost = _cost(r_new)
            if torch.isfinite(r_new).all() and new_cost < cost:
                return x_new, new_cost, max(mu * settings.damping_down, 1e-9), 0
            mu *= settings.damping_up
            rejections += 1
        return None, cost, mu, rejections


def levenberg_marquardt(
    residuals: Callable[[torch.Tensor], torch.Tensor],
    x0: torch.Tensor,
    *,
    lower: torch.Tensor | None = None,
    upper: torch.Tensor | None = None,
    settings: LMSettings = LMSettings(),
    prepare: Callable[[torch.Tensor], None] | None = None,
) -> LMResult:
    """Minimise ``0.5 |residuals(x)|^2`` from ``x0`` (module docstring).

    Args:
        residuals: batched, ``X (B, n) -> R (B, m)``, float64.
        x0: ``(n,)`` start (float64).
        lower, upper: optional ``(n,)`` box limits (``-inf``/``inf`` for free unknowns); ``x0`` is clipped.
        settings: :class:`LMSettings`.
        prepare: called as ``prepare(x)`` before each Jacobian (and before the first cost).

    Returns:
        :class:`LMResult`.

    Raises:
        FloatingPointError: the residuals at the start are not finite.
    """
    t0 = time.perf_counter()
    x = x0.detach().clone()
    if lower is not None or upper is not None:
        x = torch.clamp(x, lower, upper)
    mu = settings.damping
    costs: list[float] = []
    converged = False
    iterations = 0
    rejections = 0
    while iterations < settings.max_iterations:
        if prepare is not None:
            prepare(x)
        with torch.no_grad():
            J, r = forward_difference_jacobian(residuals, x)
        cost = _cost(r)
        if not costs:
            if not torch.isfinite(r).all():
                raise FloatingPointError("levenberg_marquardt: the residuals at the start are not finite")
            costs.append(cost)
        iterations += 1
        step = _Step(residuals, x, J, r, lower, upper)
        x_new, new_cost, mu, rejections = step.search(cost, mu, rejections, settings)
        if x_new is None:  # no step lowered the cost
            converged = rejections >= settings.max_rejections
            break
        x = x_new
        costs.append(new_cost)
        if cost - new_cost <= settings.tolerance * max(cost, 1e-12):
            converged = True
            break
    if prepare is not None:
        prepare(x)
    with torch.no_grad():
        final = _cost(residuals(x[None])[0])
    return LMResult(
        x=x.detach(),
        cost=final,
        costs=tuple(costs),
        iterations=iterations,
        converged=converged,
        seconds=time.perf_counter() - t0,
    )


# ----------------------------------------------------------------------------------------------------
# LM stages of a fit
# ----------------------------------------------------------------------------------------------------


class LeastSquaresProblem(Protocol):
    """What :func:`run_lm_stage` needs of a fit: its unknowns ``x`` and the inputs of its terms."""

    def pack(self) -> torch.Tensor:
        """``(n,)`` float64, the start."""

    def bounds(self) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """``(n,)`` box limits (``-inf``/``inf`` where free), or None."""

    def inputs(self, x: torch.Tensor) -> Inputs:
        """What the terms read at ``x (B, n)`` (:class:`~pipeline.fitting.terms.Inputs`, batch ``B``)."""

    def prepare(self, x: torch.Tensor) -> None:
        """Before each Jacobian, at ``x (n,)``: discrete re-picks (e.g. the jaw contour)."""

    def write(self, x: torch.Tensor) -> None:
        """The solution ``x (n,)`` into the fit's state."""


class StateVector:
    """The parameters of a state's free groups as one float64 vector, in the order of ``state.GROUPS``
    (:class:`~pipeline.fitting.state.GroupedParameters`), and back; the state's other parameters held at their
    values when it was made.

    Args:
        state: the fit state; its ``limits`` are the box.
        free: the groups in ``x``.
    """

    def __init__(self, state: GroupedParameters, free: tuple[str, ...]) -> None:
        self.state = state
        self.names = [name for group, pairs in state.GROUPS.items() if group in free for name, _ in pairs]
        with torch.no_grad():
            self.fixed = {name: p.detach().double() for name, p in state.named_parameters()}
        self.shapes = {name: self.fixed[name].shape for name in self.names}

    def pack(self) -> torch.Tensor:
        """``(n,)`` the free parameters' current values."""
        with torch.no_grad():
            return torch.cat([getattr(self.state, name).detach().double().reshape(-1) for name in self.names])

    def unpack(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        """``x (B, n)`` -> every parameter by name, ``(B, *shape)`` (the fixed ones expanded)."""
        batch = x.shape[0]
        out = {name: value[None].expand(batch, *value.shape) for name, value in self.fixed.items()}
        at = 0
        for name, shape in self.shapes.items():
            size = shape.numel()
            out[name] = x[:, at : at + size].reshape(batch, *shape)
            at += size
        return out

    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(n,)`` lower and upper limits (the state's ``limits``; infinite where a parameter has none)."""
        low, high = [], []
        for name in self.names:
            limits = self.state.limits(name)
            if limits is None:
                inf = torch.full((self.fixed[name].numel(),), float("inf"), dtype=torch.float64)
                limits = (-inf, inf)
            low.append(limits[0].double().reshape(-1))
            high.append(limits[1].double().reshape(-1))
        return torch.cat(low), torch.cat(high)

    def write(self, x: torch.Tensor) -> None:
        """Copy ``x (n,)`` into the state's free parameters."""
        values = self.unpack(x[None])
        with torch.no_grad():
            for name in self.names:
                getattr(self.state, name).copy_(values[name][0])


def run_lm_stage(
    problem: LeastSquaresProblem,
    terms: Sequence[Term] | LeastSquaresTerms,
    stage: Stage,
    settings: LMSettings,
    *,
    objective: Objective | None = None,
    loss_start: float | None = None,
    progress: Progress | None = None,
    metrics: Mapping | None = None,
) -> StageLog:
    """One LM stage: :func:`levenberg_marquardt` on ``problem`` with the ``terms`` as rows (``stage.iterations``
    Jacobians at most), the solution written into the fit's state.

    Args:
        problem: the fit's :class:`LeastSquaresProblem` for this stage's free groups.
        terms: the fit's terms (:class:`~pipeline.fitting.terms.Term`; a term the LM cannot take is an error),
            or them already stacked (:class:`~pipeline.fitting.terms.LeastSquaresTerms`: a fit that goes on
            using their IRLS weights after the stage).
        stage: the stage. settings: damping and stopping (``max_iterations`` from the stage).
        objective: the fit's Adam objective, to log every term's value at the stage's end (as the engine
            does); without it the log has the least-squares cost only.
        loss_start: the loss at the stage's start, if known (else the objective's, or the LM cost).
        progress: :data:`rig.optim.Progress`, called after each LM iteration (``iteration`` of at most
            ``stage.iterations``) and with ``stage.iterations`` at the end (a converged stage finishes early).
        metrics: more figures to log.

    Returns:
        :class:`~pipeline.fitting.engine.StageLog` (``metrics``: ``lm_cost``, ``lm_converged``, ``lm_costs``).

    Raises:
        ValueError: a term the LM solver cannot take (names it and why).
        FloatingPointError: non-finite residuals at the start.
    """
    t0 = time.perf_counter()
    rows = terms if isinstance(terms, LeastSquaresTerms) else LeastSquaresTerms(terms)
    if loss_start is None and objective is not None:
        with torch.no_grad():
            loss_start = float(objective(stage.free).total)

    jacobians = 0

    def prepare(x: torch.Tensor) -> None:
        # before each Jacobian (and once more at the end): the iterations done so far are the progress
        nonlocal jacobians
        if progress is not None and 0 < jacobians < stage.iterations:  # the last: once, at the stage's end
            progress(stage.name, jacobians, stage.iterations)
        jacobians += 1
        problem.prepare(x)
        rows.reweight(problem.inputs(x[None]))

    low, high = problem.bounds()
    result = levenberg_marquardt(
        lambda x: rows.rows(problem.inputs(x)),
        problem.pack(),
        lower=low,
        upper=high,
        settings=replace(settings, max_iterations=stage.iterations),
        prepare=prepare,
    )
    problem.write(result.x)
    logged: dict[str, float] = {}
    loss_end = result.cost
    if objective is not None:
        with torch.no_grad():
            end = objective(stage.free)
        loss_end = float(end.total)
        logged = {k: float(v) for k, v in end.terms.items()}
    if progress is not None:
        progress(stage.name, stage.iterations, stage.iterations)
    return StageLog(
        name=stage.name,
        free=stage.free,
        iterations=result.iterations,
        loss_start=result.costs[0] if loss_start is None else loss_start,
        loss_end=loss_end,
        terms=logged,
        metrics={
            **(metrics or {}),
            "lm_cost": result.cost,
            "lm_converged": result.converged,
            "lm_costs": [round(c, 4) for c in result.costs],
        },
        seconds=time.perf_counter() - t0,
    )
