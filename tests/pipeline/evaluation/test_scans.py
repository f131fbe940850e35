"""Tests of the simulated-scan evaluation (pipeline/evaluation/scans.py)."""

import math

import pytest

from pipeline.evaluation.scans import (
    METRICS,
    ScanEvaluation,
    ScanRecord,
    evaluate_scans,
)
from pipeline.scan.fit_config import FitScanConfig, jnr_schedule


@pytest.fixture(scope="module")
def evaluation() -> ScanEvaluation:
    """One neutral and one expressive scan, jnr on a short schedule and the baseline."""
    config = FitScanConfig(stages=jnr_schedule(10, 5, 10, 1, 1))
    return evaluate_scans(1, 1, baseline=True, config=config)


def test_records_and_metrics(evaluation):
    recs = evaluation.records
    assert len(recs) == 4
    assert all(isinstance(r, ScanRecord) for r in recs)
    assert {(r.kind, r.method) for r in recs} == {
        (k, m) for k in ("neutral", "expressive") for m in ("jnr", "nricp_amberg")
    }
    for r in recs:
        assert r.points > 500 and 0.0 <= r.hole_fraction < 1.0
        for m in METRICS:
            assert math.isfinite(getattr(r, m)), (r.name, r.kind, r.method, m)
        assert r.s2m_median_mm <= r.s2m_mean_mm  # outliers are included: the mean is pulled up


@pytest.mark.parametrize(
    "kind",
    [
        "neutral",
        "expressive",
    ],
)
def test_jnr_beats_prealigned_template(evaluation, kind):
    """The rig fit improves on the unregistered template after the shared rigid pre-alignment."""
    (r,) = [r for r in evaluation.records if r.method == "jnr" and r.kind == kind]
    assert r.vertex_mean_mm < r.prealign_vertex_mean_mm, r


def test_summary_and_table(evaluation):
    rows = evaluation.summary()
    assert len(rows) == 4 and all(row["n"] == 1 for row in rows)
    assert all(math.isnan(row["vertex_mean_mm_std"]) for row in rows)  # one scan: no std
    table = evaluation.table_markdown()
    assert "jnr" in table and "nricp_amberg" in table
    assert len(table.splitlines()) == 2 + 4
    assert evaluation.settings["n_neutral"] == 1 and evaluation.settings["baseline"]


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_neutral": -1},
        {"n_expressive": -2},
        {"n_neutral": 0, "n_expressive": 0},
        {"n_neutral": 1.5},
        {"seed": -1},
        {"split": "nope"},
        {"n_neutral": 10_000},
    ],
)
def test_bad_arguments(kwargs):
    with pytest.raises(ValueError):
        evaluate_scans(**{"n_neutral": 1, "n_expressive": 0, **kwargs})
