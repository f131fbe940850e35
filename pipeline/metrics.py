"""The error measures of the evaluations, and their one summary and table type.

The three evaluations (:mod:`pipeline.evaluation.capacity`, :mod:`pipeline.evaluation.scans`,
:mod:`pipeline.evaluation.photos`) measure with these functions and summarise with :func:`summarize`,
so that every "mean ± std" jnr prints means the same thing.

Measures (numpy; millimetres in, millimetres out; pixels for landmarks):

- :func:`scan_to_mesh_distances`: the exact distance from every point to a triangle mesh's surface;
  :func:`distance_stats` its median, mean and std (over *all* the points of one scan or face region:
  the points measured are the whole population, so ``ddof=0``).
- :func:`vertex_errors` / :func:`mean_vertex_error`: ``|fitted - true|`` per vertex with known
  correspondence (same topology), and its mean per head.
- :func:`landmark_errors`: per-landmark pixel error and the NME (mean error / outer-eye-corner distance).

Summaries over records (heads, scans, photos: a sample of them, so the std is the sample std,
``ddof=1`` = :data:`STD_DDOF`, NaN for a single record):

- :class:`Summary` of one metric (``n``, ``mean``, ``std``, ``median``), made by :func:`summarize`;
- :class:`SummaryRow`: one group of records (e.g. ``method=jnr, kind=neutral``) and the
  :class:`Summary` of each metric, made by :func:`summarize_records` over :class:`Group` levels;
- :class:`Evaluation`: the records of an evaluation (a tuple of frozen record dataclasses) and its
  settings, with ``summary()`` (JSON-ready dicts) and ``table_markdown()`` (:class:`Column` s).

Example:
    >>> s = summarize([1.0, 2.0, 4.0])
    >>> s.n, round(s.mean, 4), round(s.std, 4), s.median
    (3, 2.3333, 1.5275, 2.0)
    >>> s.format(2)
    '2.33 ± 1.53'
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from itertools import product
from typing import Any, ClassVar

import numpy as np

from rig.errors import InputError
from rig.geometry import closest_surface_points

__all__ = [
    "ALL",
    "EYE_OUTER",
    "STD_DDOF",
    "Column",
    "DistanceStats",
    "Evaluation",
    "Group",
    "Summary",
    "SummaryRow",
    "distance_stats",
    "landmark_errors",
    "markdown_table",
    "mean_vertex_error",
    "scan_to_mesh_distances",
    "summarize",
    "summarize_records",
    "vertex_errors",
]

STD_DDOF = 1
"""Delta degrees of freedom of every std over records (heads, scans, photos): the sample std."""

EYE_OUTER = (36, 45)
"""The outer eye corners in iBUG-68 order (0-based): the NME's normalising distance."""

ALL = "all"
"""A :class:`Group` value that matches every record (e.g. ``kind="all"``: neutral and expressive)."""


# ------------------------------------------------------------------------------------------- measures


def scan_to_mesh_distances(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Exact distance from every point to the surface of a triangle mesh.

    Args:
        points: ``(N, 3)`` mm.
        vertices: ``(V, 3)`` mm; faces: ``(F, 3)`` vertex indices.

    Returns:
        ``(N,)`` distances, mm (:func:`rig.geometry.closest_surface_points`).
    """
    return closest_surface_points(points, vertices, faces).distance


@dataclass(frozen=True)
class DistanceStats:
    """Statistics of the ``(N,)`` distances of one scan (or face region) to a surface, mm."""

    median_mm: float
    mean_mm: float
    std_mm: float
    """Std over the N points (``ddof=0``: every point of the scan is measured)."""

    def as_dict(self, prefix: str = "") -> dict[str, float]:
        """``{prefix + "median_mm": ..., prefix + "mean_mm": ..., prefix + "std_mm": ...}``."""
        return {prefix + "median_mm": self.median_mm, prefix + "mean_mm": self.mean_mm, prefix + "std_mm": self.std_mm}


def distance_stats(distances: np.ndarray) -> DistanceStats:
    """Median, mean and std (``ddof=0``, over all the points) of ``(N,)`` distances, mm.

    Example:
        >>> distance_stats(np.array([0.0, 1.0, 1.0, 2.0]))
        DistanceStats(median_mm=1.0, mean_mm=1.0, std_mm=0.7071067811865476)
    """
    d = np.asarray(distances, dtype=np.float64).reshape(-1)
    if d.size == 0:
        raise InputError("distance_stats: distances is empty, got shape (0,)")
    return DistanceStats(median_mm=float(np.median(d)), mean_mm=float(d.mean()), std_mm=float(d.std()))


def vertex_errors(fitted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-vertex distance between corresponding vertices (same topology).

    Args:
        fitted, truth: ``(..., V, 3)`` mm (numpy arrays or CPU tensors without gradients).

    Returns:
        ``(..., V)`` float64 distances, mm.

    Raises:
        ValueError: the shapes differ or the last axis is not 3.
    """
    fitted = np.asarray(fitted, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    if fitted.shape != truth.shape or fitted.ndim < 2 or fitted.shape[-1] != 3:
        raise InputError(
            f"vertex_errors: fitted and truth must have the same shape (..., V, 3), got "
            f"{fitted.shape} and {truth.shape}"
        )
    return np.linalg.norm(fitted - truth, axis=-1)


def mean_vertex_error(fitted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Mean of :func:`vertex_errors` over the vertices: ``(..., V, 3)`` -> ``(...)`` mm (a float64 array;
    a 0-d array for one head)."""
    return vertex_errors(fitted, truth).mean(axis=-1)


def landmark_errors(
    projected: np.ndarray, landmarks2d: np.ndarray, eye_corners: tuple[int, int] = EYE_OUTER
) -> tuple[np.ndarray, float]:
    """Per-landmark pixel error and the NME.

    Args:
        projected: ``(N, 2)`` fitted landmarks, px (iBUG-68 order by default).
        landmarks2d: ``(N, 2)`` target landmarks, px.
        eye_corners: the indices of the outer eye corners (:data:`EYE_OUTER` for iBUG-68;
            :attr:`landmarks.layout.LandmarkLayout.eye_corners` for another layout).

    Returns:
        ``(N,)`` errors, px, and the NME: their mean divided by the distance between the outer eye
        corners of the *target* (NaN if those coincide).
    """
    projected = np.asarray(projected, dtype=np.float64)
    landmarks2d = np.asarray(landmarks2d, dtype=np.float64)
    if (
        projected.shape != landmarks2d.shape
        or projected.ndim != 2
        or projected.shape[1] != 2
        or projected.shape[0] <= max(eye_corners)
    ):
        raise InputError(
            f"landmark_errors: projected and landmarks2d must have the same shape (N, 2), got "
            f"{projected.shape} and {landmarks2d.shape}"
        )
    error = np.linalg.norm(projected - landmarks2d, axis=1)
    inter_ocular = float(np.linalg.norm(landmarks2d[eye_corners[0]] - landmarks2d[eye_corners[1]]))
    return error, (float(error.mean() / inter_ocular) if inter_ocular > 0 else math.nan)


# ------------------------------------------------------------------------------------------ summaries


@dataclass(frozen=True)
class Summary:
    """One metric over ``n`` records: mean, sample std (``ddof=1``; NaN for ``n < 2``) and median.

    NaN values are not skipped: a metric that is NaN for some record (e.g. no landmark error for the
    unfitted template) has a NaN mean.
    """

    n: int
    mean: float
    std: float
    median: float

    def format(self, digits: int = 2) -> str:
        """``"mean ± std"`` with ``digits`` decimals; ``"mean"`` alone without a std, ``"–"`` for NaN."""
        if math.isnan(self.mean):
            return "–"
        text = f"{self.mean:.{digits}f}"
        return text if math.isnan(self.std) else f"{text} ± {self.std:.{digits}f}"


def summarize(values: Iterable[float]) -> Summary:
    """:class:`Summary` of the values of one metric over records.

    Raises:
        ValueError: no values.
    """
    x = np.asarray(list(values), dtype=np.float64).reshape(-1)
    if x.size == 0:
        raise InputError("summarize: no values")
    std = float(x.std(ddof=STD_DDOF)) if x.size > STD_DDOF else math.nan
    return Summary(n=int(x.size), mean=float(x.mean()), std=std, median=float(np.median(x)))


@dataclass(frozen=True)
class Group:
    """One level of grouping: records are grouped by ``field`` taking each of ``values`` in turn
    (:data:`ALL` takes every record); ``title`` heads its table column (default: ``field``)."""

    field: str
    values: tuple[str, ...]
    title: str | None = None


@dataclass(frozen=True)
class SummaryRow:
    """The records of one group and the :class:`Summary` of each metric over them."""

    group: tuple[tuple[str, str], ...]
    """``((field, value), ...)`` in :class:`Group` order, e.g. ``(("method", "jnr"), ("kind", "neutral"))``."""
    n: int
    stats: tuple[tuple[str, Summary], ...]
    """``((metric, Summary), ...)`` in the order the metrics were given."""

    def stat(self, metric: str) -> Summary:
        """The :class:`Summary` of ``metric``."""
        for name, summary in self.stats:
            if name == metric:
                return summary
        raise KeyError(f"SummaryRow.stat: no metric {metric!r}; the row has {[name for name, _ in self.stats]}")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: the group's fields, ``n``, and per metric ``<m>`` (mean), ``<m>_std`` and ``<m>_median``."""
        row: dict[str, Any] = {**dict(self.group), "n": self.n}
        for name, s in self.stats:
            row[name] = s.mean
            row[name + "_std"] = s.std
            row[name + "_median"] = s.median
        return row


def summarize_records(
    records: Sequence[Any], groups: Sequence[Group], metrics: Sequence[str]
) -> tuple[SummaryRow, ...]:
    """One :class:`SummaryRow` per combination of group values (the first group outermost) that has
    at least one record, summarising each of ``metrics`` (record attributes) with :func:`summarize`."""
    rows = []
    for values in product(*(g.values for g in groups)):
        chosen = [r for r in records if all(v == ALL or getattr(r, g.field) == v for g, v in zip(groups, values))]
        if not chosen:
            continue
        stats = tuple((m, summarize(getattr(r, m) for r in chosen)) for m in metrics)
        rows.append(SummaryRow(group=tuple((g.field, v) for g, v in zip(groups, values)), n=len(chosen), stats=stats))
    return tuple(rows)


@dataclass(frozen=True)
class Column:
    """A metric column of a summary table: ``statistic`` ``"mean_std"`` prints ``mean ± std``,
    ``"median"`` the median, with ``digits`` decimals."""

    title: str
    metric: str
    digits: int = 2
    statistic: str = "mean_std"

    def cell(self, row: SummaryRow) -> str:
        s = row.stat(self.metric)
        if self.statistic == "median":
            return "–" if math.isnan(s.median) else f"{s.median:.{self.digits}f}"
        return s.format(self.digits)


def markdown_table(rows: Sequence[SummaryRow], groups: Sequence[Group], columns: Sequence[Column]) -> str:
    """A Markdown table: one column per group level (its title), ``n``, then ``columns``."""
    titles = [g.title or g.field for g in groups] + ["n"] + [c.title for c in columns]
    lines = ["| " + " | ".join(titles) + " |", "|" + "---|" * len(titles)]
    for row in rows:
        cells = [value for _, value in row.group] + [str(row.n)] + [c.cell(row) for c in columns]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


@dataclass(frozen=True)
class Evaluation:
    """The records of an evaluation and what was run; subclasses name the grouping, metrics and table.

    Attributes:
        records: one frozen record dataclass per (item, method), in evaluation order (a tuple).
        settings: what was run (JSON-ready).
    """

    records: tuple[Any, ...]
    settings: dict = field(default_factory=dict)

    GROUPS: ClassVar[tuple[Group, ...]] = ()
    """The grouping of :meth:`summary` (the first group outermost)."""
    METRICS: ClassVar[tuple[str, ...]] = ()
    """The record attributes summarised."""
    COLUMNS: ClassVar[tuple[Column, ...]] = ()
    """The metric columns of :meth:`table_markdown`."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "records", tuple(self.records))

    def summary_rows(self) -> tuple[SummaryRow, ...]:
        """:func:`summarize_records` of the records by :attr:`GROUPS` over :attr:`METRICS`."""
        return summarize_records(self.records, self.GROUPS, self.METRICS)

    def summary(self) -> list[dict]:
        """JSON-ready rows (:meth:`SummaryRow.as_dict`): the group's fields, ``n``, and for every metric
        its mean over the records, ``<metric>_std`` (sample std, ``ddof=1``; NaN for one record) and
        ``<metric>_median``."""
        return [row.as_dict() for row in self.summary_rows()]

    def table_markdown(self) -> str:
        """The summary as a Markdown table (:func:`markdown_table` with :attr:`COLUMNS`)."""
        return markdown_table(self.summary_rows(), self.GROUPS, self.COLUMNS)
