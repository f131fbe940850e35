"""The one staged fitting engine of jnr: a schedule of stages, each an optimiser over named groups.

The landmark, photometric, point-cloud and multi-view fits are definitions on top of it: a state
(:class:`~pipeline.fitting.state.FitState` or another :class:`~pipeline.fitting.state.GroupedParameters`), an
*objective* that returns the named loss terms of one step (:class:`Loss`: the values of the fit's
:class:`~pipeline.fitting.terms.Term` s, :func:`~pipeline.fitting.terms.term_values`), a schedule (a tuple of
:class:`Stage`), learning rates by parameter group, and optional hooks before each stage (re-select outliers,
re-pick the light) and before each step (rebuild correspondences). The same terms are minimised by
Levenberg-Marquardt stages (:func:`pipeline.fitting.least_squares.run_lm_stage`), logged as the same
:class:`StageLog`. Per Adam stage, :func:`run_schedule` does, in this order::

    optimiser = Adam(state.parameter_groups(stage.free, lr))       # one group per named tensor
    for it in range(stage.iterations):
        before_step(stage, it)                                      # e.g. rebuild ICP correspondences
        loss = objective(free)                                      # named terms, summed in order
        check that it is finite                                     # else FloatingPointError
        optimiser.zero_grad(); loss.backward(); optimiser.step()
        state.project(free)                                         # back into the limits
        progress(stage.name, it + 1, stage.iterations)

with the neural-skinning decoder frozen throughout, and logs every term at the stage's end and at
every step (:class:`StageLog`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import torch

from pipeline.fitting.state import FREE_GROUPS, GroupedParameters
from rig.errors import InputError
from rig.optim import Progress, frozen

MAX_STAGE_ITERATIONS = 100_000
"""The most steps a stage may take (the shipped schedules take at most a few hundred): a typo such as 10^9
would run for days."""


@dataclass(frozen=True)
class Stage:
    """One stage of a schedule."""

    name: str
    """Label in reports and progress bars."""
    free: tuple[str, ...]
    """What is optimised: a subset of ``pose``, ``joints``, ``latent``, ``expressions``."""
    iterations: int
    """Optimiser steps (0 leaves the stage out)."""

    groups: ClassVar[tuple[str, ...]] = FREE_GROUPS
    """What ``free`` may name (a subclass may allow more)."""

    def __post_init__(self) -> None:
        bad = [f for f in self.free if f not in self.groups]
        if bad or not self.free:
            raise InputError(
                f"stage {self.name!r}: free must be a non-empty subset of {list(self.groups)}, got {list(self.free)}"
            )
        if not (isinstance(self.iterations, int) and 0 <= self.iterations <= MAX_STAGE_ITERATIONS):
            raise InputError(
                f"stage {self.name!r}: iterations must be an integer within [0, {MAX_STAGE_ITERATIONS}], "
                f"got {self.iterations!r}"
            )


@dataclass(frozen=True)
class LearningRates:
    """Adam steps of the geometry's parameter groups (``lr:`` in YAML); the defaults are the landmark
    fit's, each fit's config sets its own (the photometric and point-cloud fits add their groups'
    steps in subclasses)."""

    rotation: float = 0.01
    """Head rotation vector, radians."""
    translation: float = 2.0
    """Head translation, mm."""
    joints: float = 0.01
    """Joint channels, as a fraction of each channel's range."""
    latent: float = 0.05
    """Neural-skinning latent Z."""
    expressions: float = 0.05
    """Expression coefficients."""


class Loss(NamedTuple):
    """What an objective returns for one step.

    Attributes:
        terms: named scalar tensors, already weighted; the engine minimises their sum (in this order).
        metrics: named figures to log that are not minimised (unweighted terms, pixel counts, ...).
    """

    terms: dict[str, torch.Tensor]
    metrics: Mapping[str, Any] = {}

    @property
    def total(self) -> torch.Tensor:
        """The scalar minimised: the terms added left to right."""
        values = iter(self.terms.values())
        total = next(values)
        for value in values:
            total = total + value
        return total


Objective = Callable[[tuple[str, ...]], Loss]
"""``objective(free) -> Loss`` for the groups ``free`` of the current stage."""


@dataclass(frozen=True)
class StageLog:
    """What one stage did.

    Attributes:
        name, free, iterations: the stage (``free`` without groups the state cannot move).
        loss_start, loss_end: the total at its first and last step (before that step).
        terms: each weighted term at the last step.
        metrics: the objective's metrics at the last step, plus what the ``before_stage`` hook returned.
        seconds: wall time, hooks included.
        history: each weighted term at every step, in step order (the value minimised at that step, before
            it); ``terms`` is each one's last entry. Empty for stages not run by :func:`run_stage`.
    """

    name: str
    free: tuple[str, ...]
    iterations: int
    loss_start: float
    loss_end: float
    terms: dict[str, float] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    history: dict[str, tuple[float, ...]] = field(default_factory=dict)


def _scalar(value: Any) -> Any:
    return float(value.detach()) if isinstance(value, torch.Tensor) else value


def run_stage(
    state: GroupedParameters,
    stage: Stage,
    objective: Objective,
    lr,
    *,
    label: str = "the fit",
    progress: Progress | None = None,
    before_stage: Callable[[Stage], Mapping[str, Any] | None] | None = None,
    before_step: Callable[[Stage, int], None] | None = None,
) -> StageLog | None:
    """Run one stage (module docstring); None when it has nothing to do (0 iterations, or only groups
    the state cannot move).

    Args:
        state: the fit state (:class:`~pipeline.fitting.state.GroupedParameters`, e.g. a
            :class:`~pipeline.fitting.state.FitState`); its ``parameter_groups`` and ``project`` define what
            moves and how it is limited.
        stage: the stage. objective: ``objective(free) -> Loss``.
        lr: learning-rate config (fields named by ``state.GROUPS``).
        label: how a divergence error names the fit.
        progress: :data:`rig.optim.Progress`.
        before_stage: called once before the optimiser is made; what it returns is logged in ``metrics``.
        before_step: called as ``before_step(stage, iteration)`` before each step (0-based).

    Raises:
        FloatingPointError: the loss became NaN or infinite.
    """
    free = state.available(stage.free)
    if stage.iterations == 0 or not free:
        return None
    t0 = time.perf_counter()
    stage_metrics = dict(before_stage(stage) or {}) if before_stage is not None else {}
    optimiser = torch.optim.Adam(state.parameter_groups(free, lr))
    loss_start = None
    history: dict[str, list[float]] = {}
    for it in range(stage.iterations):
        if before_step is not None:
            before_step(stage, it)
        result = objective(free)
        loss = result.total
        if not torch.isfinite(loss):
            raise FloatingPointError(
                f"{label} diverged in stage {stage.name!r} (non-finite loss); try smaller learning rates in the config"
            )
        if loss_start is None:
            loss_start = float(loss.detach())
        for name, value in result.terms.items():  # read only: the step is the same with or without it
            history.setdefault(name, []).append(_scalar(value))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        state.project(free)
        if progress is not None:
            progress(stage.name, it + 1, stage.iterations)
    return StageLog(
        name=stage.name,
        free=free,
        iterations=stage.iterations,
        loss_start=loss_start,
        loss_end=float(loss.detach()),
        terms={k: _scalar(v) for k, v in result.terms.items()},
        metrics={**stage_metrics, **{k: _scalar(v) for k, v in result.metrics.items()}},
        seconds=time.perf_counter() - t0,
        history={k: tuple(v) for k, v in history.items()},
    )


def run_schedule(
    state: GroupedParameters,
    stages: tuple[Stage, ...],
    objective: Objective,
    lr,
    *,
    label: str = "the fit",
    progress: Progress | None = None,
    before_stage: Callable[[Stage], Mapping[str, Any] | None] | None = None,
    before_step: Callable[[Stage, int], None] | None = None,
) -> tuple[StageLog, ...]:
    """Run every stage of ``stages`` in order (:func:`run_stage`) with the state's neural-skinning
    decoder frozen; returns one :class:`StageLog` per stage that ran."""
    logs: list[StageLog] = []
    with frozen(None if state.neural is None else state.neural.decoder):
        for stage in stages:
            log = run_stage(
                state,
                stage,
                objective,
                lr,
                label=label,
                progress=progress,
                before_stage=before_stage,
                before_step=before_step,
            )
            if log is not None:
                logs.append(log)
    return tuple(logs)
