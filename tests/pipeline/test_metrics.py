"""The evaluations' measures and their one summary/table type (pipeline/metrics.py), against
naive loops, hand-computed values and the committed benchmark records."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from pipeline.evaluation.photos import METRICS as PHOTO_METRICS
from pipeline.evaluation.photos import PhotoEvaluation, PhotoRecord
from pipeline.evaluation.scans import METRICS as SCAN_METRICS
from pipeline.evaluation.scans import ScanEvaluation, ScanRecord
from pipeline.metrics import (
    ALL,
    EYE_OUTER,
    STD_DDOF,
    Column,
    DistanceStats,
    Evaluation,
    Group,
    Summary,
    distance_stats,
    landmark_errors,
    markdown_table,
    mean_vertex_error,
    scan_to_mesh_distances,
    summarize,
    summarize_records,
    vertex_errors,
)

RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"


# ------------------------------------------------------------------------------------------- measures


def test_scan_to_mesh_distances_by_hand():
    """The unit square in z = 0 (two triangles), mm: above it the distance is the height; beside it the
    distance to the nearest edge or corner."""
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    points = np.array([[0.5, 0.5, 2.0], [0.25, 0.75, -0.5], [2.0, 0.5, 0.0], [2.0, 2.0, 1.0], [0.5, -3.0, 4.0]])
    expected = [2.0, 0.5, 1.0, math.sqrt(3.0), 5.0]
    np.testing.assert_allclose(scan_to_mesh_distances(points, vertices, faces), expected, rtol=0, atol=1e-12)


def test_distance_stats_by_hand_with_ddof_0():
    stats = distance_stats(np.array([0.0, 1.0, 1.0, 2.0]))
    assert stats == DistanceStats(median_mm=1.0, mean_mm=1.0, std_mm=math.sqrt(0.5))  # over all the points
    assert stats.as_dict("s2m_") == {"s2m_median_mm": 1.0, "s2m_mean_mm": 1.0, "s2m_std_mm": math.sqrt(0.5)}
    with pytest.raises(ValueError, match="empty"):
        distance_stats(np.zeros(0))


def test_vertex_errors_against_a_loop():
    rng = np.random.default_rng(0)
    fitted, truth = rng.normal(size=(3, 7, 3)), rng.normal(size=(3, 7, 3))
    loop = np.array(
        [
            [math.sqrt(sum((fitted[b, v, c] - truth[b, v, c]) ** 2 for c in range(3))) for v in range(7)]
            for b in range(3)
        ]
    )
    np.testing.assert_allclose(vertex_errors(fitted, truth), loop, rtol=1e-12)
    np.testing.assert_allclose(mean_vertex_error(fitted, truth), loop.mean(axis=1), rtol=1e-12)
    assert mean_vertex_error(fitted[0], truth[0]).shape == ()  # one head
    assert vertex_errors(np.zeros((2, 3)), np.array([[3.0, 4.0, 0.0], [0.0, 0.0, -2.0]])).tolist() == [5.0, 2.0]


def test_vertex_errors_float32_tensors():
    torch = pytest.importorskip("torch")
    a = torch.zeros(2, 4, 3, dtype=torch.float32)
    b = torch.full((2, 4, 3), 2.0, dtype=torch.float32)
    np.testing.assert_allclose(mean_vertex_error(a, b), [2.0 * math.sqrt(3.0)] * 2, rtol=1e-12)


@pytest.mark.parametrize("shapes", [((5, 3), (4, 3)), ((5, 2), (5, 2)), ((3,), (3,))])
def test_vertex_errors_bad_shapes(shapes):
    with pytest.raises(ValueError, match="vertex_errors"):
        vertex_errors(np.zeros(shapes[0]), np.zeros(shapes[1]))


def test_landmark_errors_and_nme_by_hand():
    target = np.zeros((68, 2))
    target[EYE_OUTER[0]] = (100.0, 200.0)
    target[EYE_OUTER[1]] = (180.0, 260.0)  # 100 px apart
    projected = target.copy()
    projected[0] += (3.0, 4.0)  # 5 px
    projected[30] += (0.0, -6.8)  # 6.8 px
    error, nme = landmark_errors(projected, target)
    loop = [math.hypot(*(projected[i] - target[i])) for i in range(68)]
    np.testing.assert_allclose(error, loop, rtol=0, atol=1e-12)
    assert error[0] == 5.0 and nme == pytest.approx((5.0 + 6.8) / 68 / 100.0, rel=1e-12)
    same = np.zeros((68, 2))
    assert math.isnan(landmark_errors(same + 1.0, same)[1])  # eye corners coincide
    with pytest.raises(ValueError, match="landmark_errors"):
        landmark_errors(np.zeros((68, 2)), np.zeros((67, 2)))


# ------------------------------------------------------------------------------------------ summaries


def test_summarize_against_a_loop():
    x = list(np.random.default_rng(1).normal(3.0, 2.0, size=11))
    n = len(x)
    mean = sum(x) / n
    std = math.sqrt(sum((v - mean) ** 2 for v in x) / (n - 1))  # sample std
    median = sorted(x)[n // 2]
    s = summarize(x)
    assert STD_DDOF == 1
    assert s.n == n and s.mean == pytest.approx(mean, rel=1e-12) and s.std == pytest.approx(std, rel=1e-12)
    assert s.median == median
    assert summarize([1.0, 2.0, 4.0, 10.0]).median == 3.0  # even n: the mean of the middle two


def test_summarize_edge_cases():
    one = summarize([2.5])
    assert one.n == 1 and one.mean == 2.5 and math.isnan(one.std) and one.median == 2.5
    assert math.isnan(summarize([1.0, math.nan]).mean)  # NaN is not skipped
    with pytest.raises(ValueError, match="no values"):
        summarize([])


def test_summary_format():
    assert Summary(3, 2.3333, 1.5275, 2.0).format() == "2.33 ± 1.53"
    assert Summary(3, 27.549, 2.2412, 27.0).format(1) == "27.5 ± 2.2"
    assert Summary(1, 0.5, math.nan, 0.5).format() == "0.50"
    assert Summary(2, math.nan, math.nan, math.nan).format() == "–"


@dataclass(frozen=True)
class _Record:
    method: str
    kind: str
    error: float
    seconds: float


RECORDS = (
    _Record("a", "x", 1.0, 10.0),
    _Record("a", "x", 3.0, 20.0),
    _Record("a", "y", 2.0, 30.0),
    _Record("b", "y", 4.0, 40.0),
    _Record("b", "y", 8.0, 50.0),
)
GROUPS = (Group("kind", ("x", "y", ALL), title="things"), Group("method", ("a", "b")))


def test_summarize_records_groups_and_skips_empty_groups():
    rows = summarize_records(RECORDS, GROUPS, ("error", "seconds"))
    assert [row.group for row in rows] == [
        (("kind", "x"), ("method", "a")),
        (("kind", "y"), ("method", "a")),
        (("kind", "y"), ("method", "b")),
        (("kind", ALL), ("method", "a")),
        (("kind", ALL), ("method", "b")),
    ]  # no (x, b) records
    assert [row.n for row in rows] == [2, 1, 2, 3, 2]
    ax = rows[0]
    assert ax.stat("error") == Summary(2, 2.0, math.sqrt(2.0), 2.0)
    assert ax.as_dict() == {
        "kind": "x",
        "method": "a",
        "n": 2,
        "error": 2.0,
        "error_std": math.sqrt(2.0),
        "error_median": 2.0,
        "seconds": 15.0,
        "seconds_std": math.sqrt(50.0),
        "seconds_median": 15.0,
    }
    assert rows[3].stat("error").mean == 2.0 and rows[3].stat("error").std == 1.0  # a over all kinds: 1, 3, 2
    with pytest.raises(KeyError, match="nope"):
        ax.stat("nope")


def test_markdown_table():
    rows = summarize_records(RECORDS, GROUPS, ("error", "seconds"))
    table = markdown_table(
        rows, GROUPS, (Column("error (mm)", "error"), Column("s (median)", "seconds", digits=1, statistic="median"))
    )
    lines = table.splitlines()
    assert lines[0] == "| things | method | n | error (mm) | s (median) |"
    assert lines[1] == "|---|---|---|---|---|"
    assert lines[2] == "| x | a | 2 | 2.00 ± 1.41 | 15.0 |"
    assert lines[3] == "| y | a | 1 | 2.00 | 30.0 |"  # one record: no std
    assert len(lines) == 2 + len(rows)


@dataclass(frozen=True)
class _Evaluation(Evaluation):
    records: tuple[_Record, ...]
    settings: dict = field(default_factory=dict)

    GROUPS: ClassVar[tuple[Group, ...]] = (Group("method", ("a", "b")),)
    METRICS: ClassVar[tuple[str, ...]] = ("error",)
    COLUMNS: ClassVar[tuple[Column, ...]] = (Column("error", "error", digits=1),)


def test_an_evaluation_holds_a_tuple_and_summarises_itself():
    ev = _Evaluation(list(RECORDS), {"seed": 0})
    assert isinstance(ev.records, tuple) and ev.settings == {"seed": 0}
    assert [row["n"] for row in ev.summary()] == [3, 2]
    assert ev.table_markdown().splitlines()[2:] == ["| a | 3 | 2.0 ± 1.0 |", "| b | 2 | 6.0 ± 2.8 |"]
    with pytest.raises(AttributeError):
        ev.records = ()  # frozen


# ------------------------------------------------------------------------------ the committed records


def test_committed_scan_records_give_the_committed_summary():
    """The scan summary was already mean ± sample std: recomputed from the records it is the same."""
    bench = json.loads((RESULTS / "fit_scan_bench.json").read_text())
    ev = ScanEvaluation(tuple(ScanRecord(**r) for r in bench["records"]), bench["settings"])
    rows = ev.summary()
    assert len(rows) == len(bench["summary"]) == 4
    for new, old in zip(rows, bench["summary"]):
        assert (new["method"], new["kind"], new["n"]) == (old["method"], old["kind"], old["n"])
        for m in SCAN_METRICS:
            assert new[m] == pytest.approx(old[m], rel=1e-12)
            assert new[m + "_std"] == pytest.approx(old[m + "_std"], rel=1e-12)
        assert new["seconds_median"] == pytest.approx(old["seconds_median"], rel=1e-12)
    assert "| jnr | neutral | 5 | 0.87 ± 0.03 |" in ev.table_markdown()


def test_committed_photo_records_give_the_committed_summary_with_sample_stds():
    """Recomputed from the committed records, the photo summary is the committed one; its stds are the
    sample std (ddof=1) of the records (a naive computation)."""
    bench = json.loads((RESULTS / "fit_photo_bench.json").read_text())
    ev = PhotoEvaluation(tuple(PhotoRecord(**r) for r in bench["records"]), bench["settings"])
    rows = ev.summary()
    assert len(rows) == len(bench["summary"]) == 9
    for new, old in zip(rows, bench["summary"]):
        assert (new["kind"], new["method"], new["n"]) == (old["kind"], old["method"], old["n"])
        for m in PHOTO_METRICS:
            if math.isnan(old[m]):
                assert math.isnan(new[m])
                continue
            assert new[m] == pytest.approx(old[m], rel=1e-12)
            assert new[m + "_std"] == pytest.approx(old[m + "_std"], rel=1e-12, abs=1e-15)
        values = [
            r["vertex_mean_mm"]
            for r in bench["records"]
            if (new["kind"] in ("all", r["kind"])) and r["method"] == new["method"]
        ]
        mean = sum(values) / len(values)
        naive = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))
        assert new["vertex_mean_mm_std"] == pytest.approx(naive, rel=1e-9)
