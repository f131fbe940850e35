"""Evaluating the scan fit on simulated depth scans of held-out heads (JNR Tables 2-3 style).

For each of the first ``n_neutral`` / ``n_expressive`` heads of
:func:`pipeline.synthetic.expressive.expressive_split` one depth scan is simulated
(:func:`pipeline.synthetic.scans.simulate_scan`: Kinect-like noise, holes, ~1 % outliers, a random
head pose), and the same cloud is fitted by

- ``jnr``: :func:`pipeline.scan.fit.fit_scan` (the rig: pose, joints, neural-skinning latent,
  expressions), and
- ``nricp_amberg``: :func:`pipeline.scan.baseline.nricp_baseline` (trimesh's free-form non-rigid ICP of
  the template), started from jnr's own rigid pre-alignment (``fit.prealign``).

Neutral scans use ``heads.neutral[i]``, expressive scans ``heads.vertices[i]`` (expressions that are
not the rig's blendshapes, so the fit cannot reproduce them exactly).

Metrics, all in mm:

- **scan-to-mesh** (``s2m_*``): the exact distance from *every* scan point to the fitted surface
  (:func:`pipeline.metrics.scan_to_mesh_distances`; std over the points, ddof=0).
  The outliers of the scan (~1 %) are kept, so the mean and the std include them; the median is
  the robust figure. This is what a user without ground truth can measure.
- **true vertex error** (``vertex_*``): ``|fitted_v - true_v|`` per vertex, with the known
  correspondence (the fitted mesh and the simulated head share the template's topology), over the
  face region (:data:`rig.template.FACE_REGIONS`), over all vertices (includes the back of the
  head that no scan sees), and over the face-region vertices the camera saw.

Summaries over scans (:mod:`pipeline.metrics`): mean ± sample std (ddof=1) and median.

Timing: ``jnr`` is ``fit.timings["total"]`` (pre-alignment + fit; models loaded once beforehand);
``nricp_amberg`` is the same pre-alignment's seconds plus the ``nricp_amberg`` call, so both pay for
the rigid search.
"""

from __future__ import annotations

import math
import time
import zlib
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import ClassVar

import numpy as np

from pipeline.fitting.state import scan_state_class
from pipeline.metrics import (
    Column,
    Evaluation,
    Group,
    distance_stats,
    scan_to_mesh_distances,
    vertex_errors,
)
from pipeline.scan.baseline import DEFAULT_STEPS, nricp_baseline
from pipeline.scan.fit import fit_scan
from pipeline.scan.fit_config import FitScanConfig
from pipeline.scan.pointcloud.validate import validate_points
from pipeline.synthetic.expressive import expressive_split
from pipeline.synthetic.population import SPLIT_SIZES
from pipeline.synthetic.scans import DepthCamera, ScanSettings, simulate_scan
from rig.asset import load_asset
from rig.errors import InputError
from rig.expressions import ExpressionModel
from rig.model import JointRig
from rig.skinning.neural import load_neural
from rig.template import FACE_REGIONS

__all__ = ["KINDS", "METHODS", "METRICS", "ScanEvaluation", "ScanRecord", "evaluate_scans", "scan_seed"]

KINDS: tuple[str, ...] = ("neutral", "expressive")
METHODS: tuple[str, ...] = ("jnr", "asm_k2", "asm_k3", "asm_k5", "nricp_amberg")
#: Per-scan metrics summarised by :meth:`ScanEvaluation.summary` (mean, std and median over scans).
METRICS: tuple[str, ...] = (
    "s2m_median_mm",
    "s2m_mean_mm",
    "s2m_std_mm",
    "vertex_mean_mm",
    "vertex_median_mm",
    "vertex_all_mean_mm",
    "vertex_visible_mean_mm",
    "prealign_vertex_mean_mm",
    "seconds",
)


@dataclass(frozen=True)
class ScanRecord:
    """One method on one simulated scan.

    Attributes:
        name: head name (``heldout_000``, ...).
        kind: ``"neutral"`` or ``"expressive"``.
        points: number of scan points (outliers included).
        hole_fraction: fraction of the face's pixels removed by the simulated holes.
        method: ``"jnr"``, ``"asm_k<K>"`` (``skinning: asm``) or ``"nricp_amberg"``.
        seconds: wall time, s (see the module docstring for what it includes).
        s2m_median_mm, s2m_mean_mm, s2m_std_mm: statistics of the ``(N,)`` distances from every scan
            point (outliers included) to the fitted surface, mm.
        vertex_mean_mm, vertex_median_mm: true per-vertex error over the face region, mm.
        vertex_all_mean_mm: true per-vertex error over all vertices, mm.
        vertex_visible_mean_mm: true per-vertex error over the face-region vertices the camera saw, mm.
        prealign_vertex_mean_mm: reference: the face-region error of the unregistered template after
            the shared rigid pre-alignment (the same for both methods of a scan), mm.
    """

    name: str
    kind: str
    points: int
    hole_fraction: float
    method: str
    seconds: float
    s2m_median_mm: float
    s2m_mean_mm: float
    s2m_std_mm: float
    vertex_mean_mm: float
    vertex_median_mm: float
    vertex_all_mean_mm: float
    vertex_visible_mean_mm: float
    prealign_vertex_mean_mm: float


@dataclass(frozen=True)
class ScanEvaluation(Evaluation):
    """Result of :func:`evaluate_scans` (:class:`pipeline.metrics.Evaluation`).

    Attributes:
        records: one :class:`ScanRecord` per (scan, method), in scan order (neutral first).
        settings: what was run (counts, seeds, split, camera, scan settings, schedule, baseline steps).

    :meth:`summary`: per (method, kind) with at least one record, ``n`` and for every name in
    :data:`METRICS` ``<metric>`` (mean over scans), ``<metric>_std`` (sample std over scans, ddof=1; NaN
    for a single scan) and ``<metric>_median`` (e.g. ``seconds_median``). :meth:`table_markdown`: rows
    method x kind; mean ± std over scans, mm; median seconds.
    """

    records: tuple[ScanRecord, ...]
    settings: dict = field(default_factory=dict)

    GROUPS: ClassVar[tuple[Group, ...]] = (Group("method", METHODS), Group("kind", KINDS))
    METRICS: ClassVar[tuple[str, ...]] = METRICS
    COLUMNS: ClassVar[tuple[Column, ...]] = (
        Column("s2m median (mm)", "s2m_median_mm"),
        Column("s2m mean (mm)", "s2m_mean_mm"),
        Column("s2m std (mm)", "s2m_std_mm"),
        Column("vertex err face (mm)", "vertex_mean_mm"),
        Column("vertex err seen (mm)", "vertex_visible_mean_mm"),
        Column("vertex err all (mm)", "vertex_all_mean_mm"),
        Column("prealigned template (mm)", "prealign_vertex_mean_mm"),
        Column("seconds (median)", "seconds", digits=1, statistic="median"),
    )


def scan_seed(seed: int, kind: str, index: int) -> int:
    """The seed of scan ``index`` of ``kind``: from ``SeedSequence([seed, crc32(kind), index])``."""
    ss = np.random.SeedSequence([int(seed), zlib.crc32(kind.encode()), int(index)])
    return int(ss.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def _check_count(value, name: str, limit: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= limit:
        raise InputError(f"evaluate_scans: {name} must be an integer in [0, {limit}], got {value!r}")
    return int(value)


def _s2m_stats(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> dict:
    return distance_stats(scan_to_mesh_distances(points, vertices, faces)).as_dict("s2m_")


def _vertex_stats(vertices: np.ndarray, truth: np.ndarray, face: np.ndarray, seen: np.ndarray) -> dict:
    e = vertex_errors(vertices, truth)
    return {
        "vertex_mean_mm": float(e[face].mean()),
        "vertex_median_mm": float(np.median(e[face])),
        "vertex_all_mean_mm": float(e.mean()),
        "vertex_visible_mean_mm": float(e[seen].mean()) if seen.any() else math.nan,
    }


def evaluate_scans(
    n_neutral: int = 5,
    n_expressive: int = 5,
    *,
    seed: int = 0,
    config=None,
    camera=None,
    settings=None,
    baseline: bool = True,
    split: str = "heldout",
    progress: Callable[[ScanRecord], None] | None = None,
) -> ScanEvaluation:
    """Simulate one scan per held-out head, fit it with jnr (and the nricp_amberg baseline), measure.

    Args:
        n_neutral: neutral scans (heads ``0 .. n_neutral - 1`` of the split), >= 0.
        n_expressive: expressive scans (heads ``0 .. n_expressive - 1``, with their expressions), >= 0.
        seed: base seed (>= 0) of the heads' expressions (:func:`pipeline.synthetic.expressive.expressive_split`) and of
            the scans (:func:`scan_seed` of ``(seed, kind, i)``).
        config: :class:`pipeline.scan.fit.FitScanConfig` (default: its defaults).
        camera: :class:`pipeline.synthetic.scans.DepthCamera` (default 320x288, ~3-5k points).
        settings: :class:`pipeline.synthetic.scans.ScanSettings` (default: its defaults).
        baseline: also run :func:`pipeline.scan.baseline.nricp_baseline` on every scan.
        split: identity split (``heldout`` by default; heads never seen in training).
        progress: called with each :class:`ScanRecord` as soon as it is measured.

    Returns:
        :class:`ScanEvaluation` with ``(n_neutral + n_expressive) * (2 if baseline else 1)`` records.

    Raises:
        ValueError: negative or too large counts, both zero, a negative seed, an unknown split;
            :class:`pipeline.scan.pointcloud.cloud.CloudError` (a ValueError) if a scan fails the pre-alignment.
    """
    n_neutral, n_expressive = _check_arguments(n_neutral, n_expressive, seed, split)
    config = config or FitScanConfig()
    camera = camera or DepthCamera()
    settings = settings or ScanSettings()

    asset = load_asset()
    heads = expressive_split(split, int(seed), n=max(n_neutral, n_expressive), asset=asset)
    # Models loaded once, so that jnr's timing is the fit, not the file loading.
    rig = JointRig(asset)
    state_class = scan_state_class(config.skinning)  # an unknown model fails before any work
    neural = load_neural(rig)[0] if config.use_neural else None
    expressions = ExpressionModel(asset, dtype=rig.template.dtype)
    face = asset.region_mask(*FACE_REGIONS)

    records: list[ScanRecord] = []

    def add(**fields) -> None:
        record = ScanRecord(**fields)
        records.append(record)
        if progress is not None:
            progress(record)

    jobs = [("neutral", i) for i in range(n_neutral)] + [("expressive", i) for i in range(n_expressive)]
    for kind, i in jobs:
        truth_rig = heads.neutral[i] if kind == "neutral" else heads.vertices[i]
        scan = simulate_scan(truth_rig, asset.faces, rng=scan_seed(seed, kind, i), settings=settings, camera=camera)
        # simulate_scan's world frame is +Y up, mm: the rig frame, so the cloud is not transformed.
        cloud = validate_points(scan.points, scan.normals, units="mm", frame="y-up")
        seen = face & scan.visible
        common = {
            "name": heads.names[i],
            "kind": kind,
            "points": len(scan.points),
            "hole_fraction": float(scan.hole_fraction),
        }

        fit = fit_scan(cloud, config, rig=rig, neural=neural, expressions=expressions)
        al = fit.prealign
        prealigned = float(al.scale) * asset.vertices @ np.asarray(al.rotation).T + np.asarray(al.translation)
        pre_err = float(vertex_errors(prealigned, scan.gt_vertices)[face].mean())
        method = state_class.label(config)
        add(
            **common,
            method=method,
            seconds=float(fit.timings["total"]),
            **_s2m_stats(scan.points, fit.vertices, asset.faces),
            **_vertex_stats(fit.vertices, scan.gt_vertices, face, seen),
            prealign_vertex_mean_mm=pre_err,
        )

        if baseline:
            base = nricp_baseline(
                asset.vertices,
                asset.faces,
                cloud.points,
                rotation=al.rotation,
                translation=al.translation,
                scale=al.scale,
            )
            add(
                **common,
                method="nricp_amberg",
                seconds=float(fit.timings["prealign"] + base.seconds),
                **_s2m_stats(scan.points, base.vertices, asset.faces),
                **_vertex_stats(base.vertices, scan.gt_vertices, face, seen),
                prealign_vertex_mean_mm=pre_err,
            )

    run_settings = {
        "n_neutral": n_neutral,
        "n_expressive": n_expressive,
        "seed": int(seed),
        "split": split,
        "camera": asdict(camera),
        "scan_settings": asdict(settings),
        **_fit_settings(config, baseline),
        "finished": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    return ScanEvaluation(records=tuple(records), settings=run_settings)


def _check_arguments(n_neutral, n_expressive, seed, split: str) -> tuple[int, int]:
    if split not in SPLIT_SIZES:
        raise InputError(f"evaluate_scans: split must be one of {list(SPLIT_SIZES)}, got {split!r}")
    n_neutral = _check_count(n_neutral, "n_neutral", SPLIT_SIZES[split])
    n_expressive = _check_count(n_expressive, "n_expressive", SPLIT_SIZES[split])
    if n_neutral + n_expressive == 0:
        raise InputError("evaluate_scans: n_neutral and n_expressive are both 0; nothing to evaluate")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"evaluate_scans: seed must be an integer >= 0, got {seed!r}")
    return n_neutral, n_expressive


def _fit_settings(config, baseline: bool) -> dict:
    """The schedule, the baseline's steps and the thread count, for the evaluation's settings."""
    import torch

    return {
        "stages": [(s.name, list(s.free), s.iterations) for s in config.stages],
        "baseline": bool(baseline),
        "baseline_steps": [list(s) for s in DEFAULT_STEPS] if baseline else None,
        "s2m": "over all scan points, outliers included",
        "torch_threads": torch.get_num_threads(),
    }
