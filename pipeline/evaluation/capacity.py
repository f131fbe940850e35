"""``jnr eval capacity``: JNR's known-correspondence ablation (its Tables 1 and 2) on synthetic heads.

For the 7 test heads and the held-out set, the rig is fitted to each head with
(1) the initial painted weights, (2) the learned linear weights, (3) neural skinning (test-time fit of
joints and Z), each head first mapped onto the template by its least-squares similarity
(:func:`pipeline.synthetic.population.similarity_normalised`: the rig has no global scale, the fits of
photos and scans estimate pose and scale). The error is the point-to-point distance between fitted and
true vertices (mm), mean
over a head's vertices (:func:`pipeline.evaluation.metrics.mean_vertex_error`), then mean, sample std
(ddof=1) and median over heads (:func:`pipeline.evaluation.metrics.summarize`). Model sizes count the
identity part in floats.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from pipeline.evaluation.metrics import mean_vertex_error, summarize

EVAL_CHUNK = 20


@dataclass(frozen=True)
class CapacitySettings:
    """Iteration counts of the capacity evaluation (the fits must converge for a fair comparison)."""

    joint_iterations: int = 400
    z_iterations: int = 300
    cycles: int = 2
    seed: int = 0


def _per_head_error(pred: torch.Tensor, target: torch.Tensor) -> np.ndarray:
    """``(B, V, 3)`` -> ``(B,)`` (or ``(V, 3)`` -> ``()``) mean vertex error per head, mm."""
    return mean_vertex_error(pred.detach().cpu(), target.detach().cpu())


def _summary(errors: list[np.ndarray]) -> dict:
    """Mean, sample std (ddof=1) and median over heads (:func:`pipeline.evaluation.metrics.summarize`)."""
    s = summarize(np.concatenate([np.atleast_1d(e) for e in errors]))
    return {"mean_mm": round(s.mean, 4), "std_mm": round(s.std, 4), "median_mm": round(s.median, 4), "heads": s.n}


def _oracle_errors(rig, targets: torch.Tensor, linear_theta: torch.Tensor, linear_free: torch.Tensor,
                   settings: CapacitySettings, rounds: int = 3) -> list[np.ndarray]:
    """Per-head optimal weights alternated with joint refits, from the learned-linear joint fit."""
    from rig.skinning.joint_fit import fit_joints
    from rig.skinning.linear import solve_weights, valid_weights

    errs = []
    for start in range(0, targets.shape[0], EVAL_CHUNK):
        chunk = targets[start:start + EVAL_CHUNK]
        theta = linear_theta[start:start + EVAL_CHUNK]
        for r in range(rounds):
            w = valid_weights(rig, solve_weights(rig, theta, chunk, linear_free, reg=1.0))
            if r < rounds - 1:
                theta = fit_joints(rig, chunk, weights=w, init=theta, iterations=settings.joint_iterations // 2).theta
        with torch.no_grad():
            errs.extend(_per_head_error(rig(theta[i:i + 1], weights=w[i]).vertices[0], chunk[i])
                        for i in range(chunk.shape[0]))
    return errs


def evaluate_capacity(splits: tuple[str, ...] = ("test", "heldout"), settings: CapacitySettings = CapacitySettings(),
                      neural_path: str | None = None, limit: int | None = None, progress=None,
                      oracle: bool = False) -> dict:
    """Fit the three skinning variants to each split's heads; return errors and model sizes.

    With ``oracle``, also the bound that no skinning model with the rig's sparsity pattern can beat:
    per-head optimal weights (closed form, :func:`rig.skinning.linear.solve_weights`) alternated with refitting
    the joints, starting from the learned-linear fit.
    """
    from pipeline.synthetic.population import population_split, similarity_normalised
    from rig.model import JointRig
    from rig.skinning.joint_fit import fit_joints
    from rig.skinning.neural import fit_neural, load_neural

    rig = JointRig(dtype=torch.float32)
    neural, meta = load_neural(rig, neural_path)
    S = rig.num_skinning_floats
    result: dict = {
        "model_floats": {
            "initial": {"skinning": S, "decoder": 0, "template_and_joints": 3 * rig.num_vertices + 3 * rig.num_joints},
            "learned_linear": {"skinning": S, "decoder": 0},
            "neural": {"skinning": S, "decoder": neural.decoder.num_weights, "latent": 50},
        },
        "settings": settings.__dict__, "splits": {}, "training": meta.get("counts", {}),
    }
    linear_w = neural.linear_weights().detach()
    for split in splits:
        heads = population_split(split, seed=settings.seed)
        targets = torch.as_tensor(similarity_normalised(heads.vertices, rig.asset.vertices), dtype=torch.float32)
        if limit:
            targets = targets[:limit]
        row: dict = {}
        t0 = time.perf_counter()
        for name, weights in (("initial", None), ("learned_linear", linear_w)):
            errs, thetas = [], []
            for start in range(0, targets.shape[0], EVAL_CHUNK):
                chunk = targets[start:start + EVAL_CHUNK]
                fit = fit_joints(rig, chunk, weights=weights, iterations=settings.joint_iterations)
                thetas.append(fit.theta)
                with torch.no_grad():
                    errs.append(_per_head_error(rig(fit.theta, weights=weights).vertices, chunk))
                if progress:
                    progress(f"{split}: {name}", min(start + EVAL_CHUNK, targets.shape[0]), targets.shape[0])
            row[name] = _summary(errs)
        linear_theta = torch.cat(thetas)  # the last loop's: learned linear
        errs = []
        for start in range(0, targets.shape[0], EVAL_CHUNK):
            chunk = targets[start:start + EVAL_CHUNK]
            fit = fit_neural(neural, chunk, cycles=settings.cycles, joint_iterations=settings.joint_iterations,
                             z_iterations=settings.z_iterations)
            with torch.no_grad():
                errs.append(_per_head_error(rig(fit.theta, weights=neural(fit.z)).vertices, chunk))
            if progress:
                progress(f"{split}: neural", min(start + EVAL_CHUNK, targets.shape[0]), targets.shape[0])
        row["neural"] = _summary(errs)
        if oracle:
            row["per_head_optimal_weights"] = _summary(_oracle_errors(rig, targets, linear_theta, neural.linear_free,
                                                                      settings))
        row["seconds"] = round(time.perf_counter() - t0, 1)
        result["splits"][split] = row
    return result
