"""The loss curves of a fit: every recorded term per iteration, stage by stage (:func:`stage_curves`), drawn
one panel per stage (:func:`loss_curves`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.notebook.extra import require
from rig.errors import InputError

LM_COST = "LM cost ½|r|²"
"""The curve of a Levenberg-Marquardt stage (the landmark fit's default solver), which records its cost
after every accepted step (``metrics["lm_costs"]``) rather than each term per step."""


@dataclass(frozen=True)
class StageCurves:
    """The per-iteration record of one stage.

    Attributes:
        name: the stage's name. solver: ``adam`` (the engine: every weighted term per step) or ``lm``
            (Levenberg-Marquardt: its cost after each accepted step, one curve named :data:`LM_COST`).
        terms: curve name -> ``(N,)`` values in step order.
    """

    name: str
    solver: str
    terms: dict[str, np.ndarray]


def _stage_logs(fit) -> tuple:
    if isinstance(fit, Sequence):
        return tuple(fit)
    landmark = getattr(getattr(fit, "landmark_fit", None), "stages", ())
    stages = getattr(fit, "stages", None)
    if stages is None:
        raise InputError(
            f"loss_curves: expected a fit result with stages or a sequence of StageLog, got {type(fit).__name__}"
        )
    return tuple(landmark) + tuple(stages)


def stage_curves(fit) -> list[StageCurves]:
    """Every recorded loss curve of a fit, stage by stage in the order they ran.

    Args:
        fit: a fit result (``fit_photo``'s: its landmark stages, then the photometric ones; ``fit_scan``,
            ``fit_landmarks``, a multi-view fit) or a sequence of
            :class:`pipeline.fitting.engine.StageLog`.

    Stages that kept no per-iteration record (0 steps, or a log made outside the engine without LM
    costs) are left out.
    """
    out = []
    for log in _stage_logs(fit):
        history = getattr(log, "history", None) or {}
        if history:
            out.append(StageCurves(log.name, "adam", {k: np.asarray(v, np.float64) for k, v in history.items()}))
        elif log.metrics.get("lm_costs"):
            out.append(StageCurves(log.name, "lm", {LM_COST: np.asarray(log.metrics["lm_costs"], np.float64)}))
    return out


def loss_curves(fit, *, columns: int = 3, title: str | None = None):
    """A ``matplotlib`` figure of every loss term per iteration, one panel per stage (log y).

    Args:
        fit: as :func:`stage_curves`.
        columns: panels per row. title: the figure's title.

    Returns:
        ``matplotlib.figure.Figure`` (made without pyplot): one axes per stage, titled with the stage's
        name and solver, one line per term labelled with the term's name (x: step, y: the weighted term as
        the objective minimised it at that step). A term has one colour in every panel; one legend below
        the panels names them, marking terms that are 0 throughout (a log axis cannot draw 0).

    Raises:
        InputError: nothing to draw (no stage kept a per-iteration record).
    """
    figure_module = require("matplotlib.figure")
    ticker = require("matplotlib.ticker")
    curves = stage_curves(fit)
    if not curves:
        raise InputError("loss_curves: no stage of this fit recorded its losses per iteration")
    names = list(dict.fromkeys(name for stage in curves for name in stage.terms))
    zero = {name for name in names if all(not np.any(stage.terms[name]) for stage in curves if name in stage.terms)}
    palette = [f"C{i}" for i in (0, 1, 2, 3, 4, 5, 6, 8, 9)] + ["black", "#1b4965", "#9d0208", "#386641", "#6a4c93"]
    drawn = [name for name in names if name not in zero]
    colour = {name: palette[i % len(palette)] for i, name in enumerate(drawn)} | dict.fromkeys(zero, "0.6")
    cols = max(1, min(columns, len(curves)))
    rows = -(-len(curves) // cols)
    legend_rows = -(-len(names) // 6)
    fig = figure_module.Figure(
        figsize=(4.4 * cols, 3.0 * rows + 0.3 * legend_rows + (0.4 if title else 0.0)), layout="constrained"
    )
    axes = fig.subplots(rows, cols, squeeze=False)
    handles = {}
    plain = ticker.FormatStrFormatter("%g")
    for ax, stage in zip(axes.flat, curves):
        for name, values in stage.terms.items():
            (line,) = ax.plot(
                np.arange(len(values)),
                values,
                label=name,
                color=colour[name],
                marker="o" if len(values) < 12 else None,
                markersize=3,
                linewidth=1.4,
            )
            handles.setdefault(name, line)
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(plain)
        low, high = ax.get_ylim()
        # within one decade the major ticks are too few to read: label the minor ones too
        ax.yaxis.set_minor_formatter(plain if 0 < low and high < 10 * low else ticker.NullFormatter())
        ax.xaxis.set_major_locator(ticker.MaxNLocator(integer=True))
        solver = "Adam" if stage.solver == "adam" else "Levenberg-Marquardt"
        ax.set_title(f"{stage.name} ({solver})", fontsize=10)
        ax.set_xlabel("accepted step" if stage.solver == "lm" else "step", fontsize=9)
        ax.tick_params(labelsize=8, which="both")
        ax.grid(True, which="major", alpha=0.3)
    for ax in list(axes.flat)[len(curves) :]:
        ax.set_visible(False)
    fig.legend(
        [handles[n] for n in names],
        [f"{n} (0 throughout)" if n in zero else n for n in names],
        loc="outside lower center",
        ncols=min(6, len(names)),
        fontsize=8,
        frameon=False,
    )
    if title:
        fig.suptitle(title)
    return fig


__all__ = ["LM_COST", "StageCurves", "loss_curves", "stage_curves"]
