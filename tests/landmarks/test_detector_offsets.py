"""The embedded iBUG-68 landmarks against the detector jnr uses (dlib), on fresh renders of the template.

A short version of ``benchmarks/bench_landmark_offsets.py`` (which measured, over 132 held-out views at
an inter-ocular distance of 100 px, a mean per-view error of 2.98 px over the inner 51 landmarks with the
committed corrections and 4.19 px without): three views it never fitted on (seed 20).
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_landmark_offsets.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_landmark_offsets", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_detected_landmarks_sit_on_the_embedding(bench, asset, tmp_path_factory):
    data = bench.render_and_detect(
        [-15.0, 0.0, 15.0], [0.0], [20], tmp_path_factory.mktemp("views"), True, log=lambda *_: None
    )
    assert data["found"].sum() >= 2
    inner = slice(17, 68)
    corrected = np.linalg.norm(bench.offsets(data, asset, corrected=True)[:, inner], axis=2).mean()
    geometric = np.linalg.norm(bench.offsets(data, asset, corrected=False)[:, inner], axis=2).mean()
    assert corrected < 4.5, corrected  # px at IOD 100 (benchmark: 2.98; these three views: 3.73 vs 4.63)
    assert corrected < geometric, (corrected, geometric)  # the committed corrections help on unseen views
