"""``jnr eval capacity``: known-correspondence capacity of the face models, measured like JNR (Tables 1
and 2) and ASM (Table 7) on synthetic heads.

For the 7 test heads and the held-out set, each head first mapped onto the template by its
least-squares similarity (:func:`pipeline.synthetic.population.similarity_normalised`: the rig has no
global scale, the fits of photos and scans estimate pose and scale), every model in ``models`` is fitted
to each head:

- ``jnr`` (:data:`JNR_ROWS`): the rig with (1) the initial painted weights, (2) the learned linear
  weights, (3) neural skinning (test-time fit of joints and Z); with ``oracle`` also
  ``per_head_optimal_weights`` (:func:`_oracle_errors`).
- ``pca`` (:data:`PCA_ROWS`): the "3DMM reference", a linear PCA shape model
  (:mod:`pipeline.evaluation.pca_model`) with ``k`` = :data:`PCA_COMPONENTS` components, trained on the
  85 ``train`` heads that the learned skinning was trained on (similarity-normalised the same way) and
  fitted by least-squares projection.
- ``asm`` (:data:`ASM_ROWS`): the Adaptive Skinning Model (ASM, ICCV 2023; :mod:`rig.skinning.asm`),
  its Table 7 ablation: ``asm_static`` (the initial painted weights, fixed binding, full 9-DoF bone
  transforms), ``asm_dynamic_binding``, ``asm_gmm_k{K}`` (GMM skinning weights) and ``asm_k{K}`` (both),
  for ``K`` in :data:`ASM_COMPONENTS`. The static and dynamic-binding rows do not depend on ``K`` and
  are fitted once.

Each row reports (JSON: ``splits[split][row]``):

- the error: the point-to-point distance between fitted and true vertices (mm), mean over a head's
  vertices (:func:`pipeline.metrics.mean_vertex_error`), then ``mean_mm``, sample ``std_mm``
  (ddof=1), ``median_mm`` over the ``heads`` (:func:`pipeline.metrics.summarize`);
- ``seconds_per_head``: wall-clock seconds (:func:`time.perf_counter`) around the row's fitting calls
  only (not the error measurement, data generation or model training/loading), divided by the number of
  heads; fits run in chunks of :data:`EVAL_CHUNK` heads, on the CPU threads torch is given, after one
  untimed warm-up fit of one head with 2 iterations per kind of fit (so that one-time costs, caches and
  the allocator's first growth, are not charged to whichever row comes first);
- ``model_floats``: the model size in floats, the total of ``result["model_floats"][row]``
  (:func:`_total_floats`): everything the model stores (template, joints, skinning weights, decoder;
  PCA mean and components; ASM's fixed part) plus the floats that identify one head (joint parameters,
  latent code, PCA coefficients, ASM's per-head tunable part).
"""

from __future__ import annotations

import functools
import time
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from pipeline.evaluation.pca_model import train_pca
from pipeline.metrics import mean_vertex_error, summarize
from pipeline.synthetic.population import population_split, similarity_normalised
from rig.asset import load_asset
from rig.errors import InputError, SetupError
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS
from rig.skinning.joint_fit import fit_joints
from rig.skinning.linear import solve_weights, valid_weights
from rig.skinning.neural import LATENT, fit_neural, load_neural

EVAL_CHUNK = 20
"""Heads fitted together by the iterative fits (rig and ASM rows)."""

MODEL_GROUPS = ("jnr", "pca", "asm")
"""The model families of ``models`` (``jnr eval capacity --models``), in table order."""
JNR_ROWS = ("initial", "learned_linear", "neural")
ORACLE_ROW = "per_head_optimal_weights"
PCA_COMPONENTS = (10, 50, 84)
"""Components of the PCA rows; 84 = N - 1 for the 85 training heads (the most a PCA of them has)."""
PCA_ROWS = tuple(f"pca_k{k}" for k in PCA_COMPONENTS)
ASM_COMPONENTS = (2, 5)
"""GMM components ``K`` of the ASM rows (ASM's Table 7)."""
ASM_ROWS = ("asm_static", "asm_dynamic_binding") + tuple(
    row for k in ASM_COMPONENTS for row in (f"asm_gmm_k{k}", f"asm_k{k}")
)
CAPACITY_ROWS = JNR_ROWS + (ORACLE_ROW,) + PCA_ROWS + ASM_ROWS
"""Every row name of the capacity table, in table order."""


@dataclass(frozen=True)
class CapacitySettings:
    """Iteration counts of the capacity evaluation (the fits must converge for a fair comparison).
    ``seed`` is the population seed of every split, the PCA's training heads included."""

    joint_iterations: int = 400
    z_iterations: int = 300
    cycles: int = 2
    seed: int = 0
    asm_iterations: int | None = None
    """Iterations of each ASM fit (``fit_asm``'s ``iterations``); None: ``fit_asm``'s own default."""


def _per_head_error(pred: torch.Tensor, target: torch.Tensor) -> np.ndarray:
    """``(B, V, 3)`` -> ``(B,)`` (or ``(V, 3)`` -> ``()``) mean vertex error per head, mm."""
    return mean_vertex_error(pred.detach().cpu(), target.detach().cpu())


def _summary(errors: list[np.ndarray], seconds: float | None = None, row: str = "") -> dict:
    """Mean, sample std (ddof=1) and median over heads (:func:`pipeline.metrics.summarize`);
    with ``seconds`` (the row's total fitting time), also ``seconds_per_head``.

    A fit that returned non-finite vertices gives a NaN error, which is kept (the mean is NaN: a failed
    fit is not dropped silently); the row then also counts them in ``nonfinite_heads``, with a warning.
    """
    per_head = np.concatenate([np.atleast_1d(e) for e in errors])
    s = summarize(per_head)
    out = {"mean_mm": round(s.mean, 4), "std_mm": round(s.std, 4), "median_mm": round(s.median, 4), "heads": s.n}
    if seconds is not None:
        out["seconds_per_head"] = round(seconds / s.n, 6) if s.n else float("nan")
    bad = int((~np.isfinite(per_head)).sum())
    if bad:
        out["nonfinite_heads"] = bad
        warnings.warn(
            f"jnr eval capacity: {row or 'a row'}: {bad} of {s.n} fits returned non-finite vertices",
            RuntimeWarning,
            stacklevel=2,
        )
    return out


def _oracle_errors(
    rig,
    targets: torch.Tensor,
    linear_theta: torch.Tensor,
    linear_free: torch.Tensor,
    settings: CapacitySettings,
    rounds: int = 3,
) -> tuple[list[np.ndarray], float]:
    """Per-head optimal weights alternated with joint refits, from the learned-linear joint fit:
    the per-head errors and the seconds spent solving and refitting (not the learned-linear start)."""
    errs, seconds = [], 0.0
    for start in range(0, targets.shape[0], EVAL_CHUNK):
        chunk = targets[start : start + EVAL_CHUNK]
        theta = linear_theta[start : start + EVAL_CHUNK]
        t0 = time.perf_counter()
        for r in range(rounds):
            w = valid_weights(rig, solve_weights(rig, theta, chunk, linear_free, reg=1.0))
            if r < rounds - 1:
                theta = fit_joints(rig, chunk, weights=w, init=theta, iterations=settings.joint_iterations // 2).theta
        seconds += time.perf_counter() - t0
        with torch.no_grad():
            errs.extend(
                _per_head_error(rig(theta[i : i + 1], weights=w[i]).vertices[0], chunk[i])
                for i in range(chunk.shape[0])
            )
    return errs, seconds


@functools.lru_cache(maxsize=2)
def pca_training_heads(seed: int = 0) -> np.ndarray:
    """The PCA's training heads: the ``train`` split (85 heads, the learned skinning's training heads),
    each mapped onto the template by its least-squares similarity as the evaluated heads are:
    ``(85, V, 3)`` float64 mm, read-only (cached: the split takes seconds to synthesise)."""
    heads = similarity_normalised(population_split("train", seed=seed).vertices, load_asset().vertices)
    heads.flags.writeable = False
    return heads


def _check_models(models) -> tuple[str, ...]:
    """``models`` as a tuple in table order, or :class:`rig.errors.InputError` naming the bad one."""
    if isinstance(models, str):
        models = (models,)
    models = tuple(models)
    unknown = [m for m in models if m not in MODEL_GROUPS]
    if unknown or not models:
        raise InputError(
            f"evaluate_capacity: models must be a non-empty subset of {', '.join(MODEL_GROUPS)}, "
            f"got {', '.join(map(str, models)) or 'none'}"
        )
    return tuple(m for m in MODEL_GROUPS if m in models)


def load_asm():
    """``(AdaptiveSkinning, AsmVariant, fit_asm)`` from :mod:`rig.skinning.asm`, or a
    :class:`rig.errors.SetupError` that says how to run without the ASM rows."""
    try:
        from rig.skinning.asm import AdaptiveSkinning, AsmVariant, fit_asm
    except ImportError as exc:
        raise SetupError(
            f"the ASM rows need rig.skinning.asm (AdaptiveSkinning, AsmVariant, fit_asm), which "
            f"could not be imported ({exc}); leave them out with --models jnr,pca"
        ) from None
    return AdaptiveSkinning, AsmVariant, fit_asm


def _asm_rows(asm_variant) -> list[tuple[str, int, object]]:
    """``(row, K, AsmVariant)`` of the ASM rows in :data:`ASM_ROWS` order; the rows without GMM weights
    use the first ``K`` (they do not depend on it)."""
    rows = [
        ("asm_static", ASM_COMPONENTS[0], asm_variant(dynamic_binding=False, gmm_weights=False)),
        ("asm_dynamic_binding", ASM_COMPONENTS[0], asm_variant(dynamic_binding=True, gmm_weights=False)),
    ]
    for k in ASM_COMPONENTS:
        rows += [
            (f"asm_gmm_k{k}", k, asm_variant(dynamic_binding=False, gmm_weights=True)),
            (f"asm_k{k}", k, asm_variant(dynamic_binding=True, gmm_weights=True)),
        ]
    return rows


def _total_floats(parts: dict) -> int:
    """The one number of a ``model_floats`` entry: the sum of its parts; for ASM's
    :meth:`AdaptiveSkinning.num_floats <rig.skinning.asm.AdaptiveSkinning.num_floats>` (which also
    reports ``static_vertices``, a vertex count) ``fixed + per_head``."""
    if "fixed" in parts and "per_head" in parts:
        return int(parts["fixed"]) + int(parts["per_head"])
    return int(sum(int(v) for v in parts.values()))


def _jnr_rows(
    rig, neural, targets: torch.Tensor, split: str, settings: CapacitySettings, oracle: bool, progress
) -> dict:
    """The rig rows (initial, learned linear, neural, and the oracle) of one split."""
    rows: dict = {}
    linear_w = neural.linear_weights().detach()
    n = targets.shape[0]
    fit_joints(rig, targets[:1], weights=linear_w, iterations=2)  # warm-up, untimed
    fit_neural(neural, targets[:1], cycles=1, joint_iterations=2, z_iterations=2)
    for name, weights in (("initial", None), ("learned_linear", linear_w)):
        errs, thetas, seconds = [], [], 0.0
        for start in range(0, n, EVAL_CHUNK):
            chunk = targets[start : start + EVAL_CHUNK]
            t0 = time.perf_counter()
            fit = fit_joints(rig, chunk, weights=weights, iterations=settings.joint_iterations)
            seconds += time.perf_counter() - t0
            thetas.append(fit.theta)
            with torch.no_grad():
                errs.append(_per_head_error(rig(fit.theta, weights=weights).vertices, chunk))
            if progress:
                progress(f"{split}: {name}", min(start + EVAL_CHUNK, n), n)
        rows[name] = _summary(errs, seconds, f"{split}: {name}")
    linear_theta = torch.cat(thetas)  # the last loop's: learned linear
    errs, seconds = [], 0.0
    for start in range(0, n, EVAL_CHUNK):
        chunk = targets[start : start + EVAL_CHUNK]
        t0 = time.perf_counter()
        fit = fit_neural(
            neural,
            chunk,
            cycles=settings.cycles,
            joint_iterations=settings.joint_iterations,
            z_iterations=settings.z_iterations,
        )
        seconds += time.perf_counter() - t0
        with torch.no_grad():
            errs.append(_per_head_error(rig(fit.theta, weights=neural(fit.z)).vertices, chunk))
        if progress:
            progress(f"{split}: neural", min(start + EVAL_CHUNK, n), n)
    rows["neural"] = _summary(errs, seconds, f"{split}: neural")
    if oracle:
        errs, seconds = _oracle_errors(rig, targets, linear_theta, neural.linear_free, settings)
        rows[ORACLE_ROW] = _summary(errs, seconds, f"{split}: {ORACLE_ROW}")
    return rows


def _pca_rows(models: dict, targets: torch.Tensor, split: str, progress) -> dict:
    """The PCA rows of one split: ``models`` maps row name -> :class:`PcaShapeModel`."""
    rows = {}
    next(iter(models.values())).fit(targets[:1])  # warm-up, untimed
    for i, (name, pca) in enumerate(models.items()):
        t0 = time.perf_counter()
        fitted = pca.fit(targets)
        seconds = time.perf_counter() - t0
        rows[name] = _summary([_per_head_error(fitted, targets.to(fitted.dtype))], seconds, f"{split}: {name}")
        if progress:
            progress(f"{split}: pca", i + 1, len(models))
    return rows


def _asm_fit_rows(rig, asm, targets: torch.Tensor, split: str, settings: CapacitySettings, progress) -> dict:
    """The ASM rows of one split (a fresh :class:`AdaptiveSkinning` per row, built outside the timing)."""
    adaptive_skinning, asm_variant, fit_asm = asm
    options = {} if settings.asm_iterations is None else {"iterations": settings.asm_iterations}
    rows = {}
    n = targets.shape[0]
    for name, k, variant in _asm_rows(asm_variant):
        model = adaptive_skinning(rig, components=k)
        fit_asm(model, targets[:1], variant=variant, iterations=2, progress=None)  # warm-up, untimed
        errs, seconds = [], 0.0
        for start in range(0, n, EVAL_CHUNK):
            chunk = targets[start : start + EVAL_CHUNK]
            t0 = time.perf_counter()
            fit = fit_asm(model, chunk, variant=variant, progress=None, **options)
            seconds += time.perf_counter() - t0
            errs.append(_per_head_error(torch.as_tensor(fit.vertices).to(chunk.dtype), chunk))
            if progress:
                progress(f"{split}: {name}", min(start + EVAL_CHUNK, n), n)
        rows[name] = _summary(errs, seconds, f"{split}: {name}")
    return rows


def evaluate_capacity(
    splits: tuple[str, ...] = ("test", "heldout"),
    settings: CapacitySettings = CapacitySettings(),
    neural_path: str | None = None,
    limit: int | None = None,
    progress=None,
    oracle: bool = False,
    models: tuple[str, ...] = MODEL_GROUPS,
) -> dict:
    """Fit each model of ``models`` to each split's heads; return errors, fitting times and model sizes.

    Args:
        splits: population splits to evaluate (:func:`pipeline.synthetic.population.population_split`).
        settings: iteration counts and the population seed.
        neural_path: learned-skinning artifact (default: the packaged one); used by the ``jnr`` rows.
        limit: only the first ``limit`` heads of each split (the PCA is always trained on all 85
            ``train`` heads).
        progress: ``progress(stage, done, total)`` callback, or None.
        oracle: also the ``per_head_optimal_weights`` row (needs ``"jnr"`` in ``models``): the bound that
            no skinning model with the rig's sparsity pattern can beat, per-head optimal weights (closed
            form, :func:`rig.skinning.linear.solve_weights`) alternated with refitting the joints, starting
            from the learned-linear fit.
        models: a subset of :data:`MODEL_GROUPS` (module docstring).

    Returns:
        JSON-ready dict: ``splits[split][row]`` (``mean_mm``, ``std_mm``, ``median_mm``, ``heads``,
        ``seconds_per_head``, ``model_floats``) and ``splits[split]["seconds"]`` (the split's wall time);
        ``model_floats[row]`` (the parts of each row's model size); ``settings``; ``models``;
        ``training`` (the learned skinning's training counts, and the PCA's training heads and seconds).

    Raises:
        InputError: unknown ``models``, or ``oracle`` without ``"jnr"``.
        SetupError: ``"asm"`` in ``models`` but :mod:`rig.skinning.asm` cannot be imported.
    """
    models = _check_models(models)
    if oracle and "jnr" not in models:
        raise InputError(
            "evaluate_capacity: oracle (per-head optimal weights) starts from the jnr rows' "
            "learned-linear fit; add jnr to models"
        )
    asm = load_asm() if "asm" in models else None  # fail before any work
    rig = JointRig(dtype=torch.float32)
    template_and_joints = 3 * rig.num_vertices + 3 * rig.num_joints
    S = rig.num_skinning_floats
    result: dict = {
        "model_floats": {},
        "settings": settings.__dict__,
        "models": list(models),
        "splits": {},
        "training": {},
    }
    floats = result["model_floats"]
    neural = None
    if "jnr" in models:
        neural, meta = load_neural(rig, neural_path)
        result["training"].update(meta.get("counts", {}))
        rig_parts = {
            "template_and_joints": template_and_joints,
            "skinning": S,
            "decoder": 0,
            "joint_parameters": NUM_PARAMETERS,
        }
        floats["initial"] = dict(rig_parts)
        floats["learned_linear"] = dict(rig_parts)
        floats["neural"] = {**rig_parts, "decoder": neural.decoder.num_weights, "latent": LATENT}
        if oracle:
            floats[ORACLE_ROW] = {
                "template_and_joints": template_and_joints,
                "skinning_per_head": S,
                "joint_parameters": NUM_PARAMETERS,
            }
    pcas: dict = {}
    if "pca" in models:
        train_heads = pca_training_heads(settings.seed)
        t0 = time.perf_counter()
        largest = train_pca(train_heads, max(PCA_COMPONENTS))  # the smaller models are its first k components
        pcas = {f"pca_k{k}": largest.truncated(k) for k in PCA_COMPONENTS}
        result["training"].update(
            {"pca_train_heads": int(train_heads.shape[0]), "pca_train_seconds": round(time.perf_counter() - t0, 3)}
        )
        floats.update({name: pca.num_floats() for name, pca in pcas.items()})
    if asm is not None:
        adaptive_skinning, asm_variant, _ = asm
        for name, k, variant in _asm_rows(asm_variant):
            floats[name] = {key: int(v) for key, v in adaptive_skinning(rig, components=k).num_floats(variant).items()}
    for split in splits:
        heads = population_split(split, seed=settings.seed, first=limit or None)
        targets = torch.as_tensor(similarity_normalised(heads.vertices, rig.asset.vertices), dtype=torch.float32)
        row: dict = {}
        t0 = time.perf_counter()
        if neural is not None:
            row.update(_jnr_rows(rig, neural, targets, split, settings, oracle, progress))
        if pcas:
            row.update(_pca_rows(pcas, targets, split, progress))
        if asm is not None:
            row.update(_asm_fit_rows(rig, asm, targets, split, settings, progress))
        for name in row:
            row[name]["model_floats"] = _total_floats(floats[name])
        row["seconds"] = round(time.perf_counter() - t0, 1)
        result["splits"][split] = row
    return result
