"""``jnr train``: the whole learned-skinning path of JNR (sections 3.1-3.2, 4.1-4.4), from seeds.

1. Fit the joints of the 85 synthetic training heads with the initial weights (eq. 7, Adam), keeping
   intermediate parameter sets.
2. Learn one global sparse symmetric linear weight matrix, alternating with refitting the joints.
3. Synthesise skinning-weight training sets: saved and sparsely perturbed joint parameters, each with
   the closed-form weights that best reproduce its head (:func:`rig.skinning.linear.solve_weights`).
4. Neural skinning: auto-encoder, then WGAN-style fine-tuning of the decoder from noise.
Artifacts: ``rig/assets/jnr_skinning_v3.npz`` (learned linear floats + decoder) and a training log.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from pipeline.config import load_config as load_typed
from pipeline.fitting.identity import IdentityPrior, build_identity_prior, clip_to_limits, default_identity_prior_path
from pipeline.synthetic.population import (
    ict_coefficients,
    ict_heads,
    population_split,
    similarity_normalised,
    split_seeds,
)
from rig.io.atomic import write_bytes_atomic
from rig.model import JointRig
from rig.optim import Progress
from rig.skinning.joint_fit import fit_joints, parameter_span
from rig.skinning.linear import OrbitSystem, learn_linear_skinning, solve_weights
from rig.skinning.neural import (
    Critic,
    NeuralSkinning,
    SkinningDecoder,
    SkinningEncoder,
    load_neural,
    save_neural,
    train_autoencoder,
    train_wgan,
)


@dataclass(frozen=True)
class TrainConfig:
    """Settings of ``jnr train`` (scaled from JNR's GPU schedule to a 2-core CPU)."""

    seed: int = 0
    """Seed of the population, the perturbations and the networks."""
    joint_iterations: int = 300
    """Adam steps per joint fit (JNR: 3,000 at lr 1e-3 on raw parameters; we optimise range-normalised ones)."""
    joint_lr: float = 0.01
    weight_iterations: int = 300
    """Adam steps per global-weight fit (JNR: 3,000 at lr 1e-4)."""
    weight_lr: float = 1e-3
    cycles: int = 3
    """Joint / global-weight alternations (JNR: 5)."""
    snapshot_every: int = 50
    """Keep the joint parameters every this many iterations (training-set material)."""
    perturb_copies: int = 3
    """Sparsely perturbed copies of every saved parameter set (JNR: 3 more, at 5 %)."""
    perturb_fraction: float = 0.05
    perturb_probability: float = 0.3
    solve_reg: float = 1e-3
    """Tikhonov weight of the per-set weight solve towards the learned linear weights."""
    max_training_sets: int = 6000
    autoencoder_epochs: int = 25
    autoencoder_lr: float = 1e-3
    wgan_iterations: int = 150
    wgan_lr: float = 1e-4
    critic_steps: int = 2
    batch_size: int = 64


def load_config(path: str | Path | None, overrides: dict | None = None) -> TrainConfig:
    """Typed defaults, overridden by a YAML file and then by ``overrides``; unknown keys are errors."""
    return load_typed(TrainConfig, path, overrides)


@dataclass(frozen=True)
class TrainReport:
    config: dict
    counts: dict
    seconds: dict
    rmse_train_mm: dict
    losses: dict


def perturb(theta: torch.Tensor, config: TrainConfig, gen: torch.Generator) -> torch.Tensor:
    """Sparsely perturbed copies: each channel, with probability ``perturb_probability``, moves by up to
    ``perturb_fraction`` of its range; ``(N, P) -> (copies * N, P)``."""
    span = parameter_span(theta.dtype)
    out = []
    for _ in range(config.perturb_copies):
        mask = torch.rand(theta.shape, generator=gen) < config.perturb_probability
        noise = (2 * torch.rand(theta.shape, generator=gen, dtype=theta.dtype) - 1) * config.perturb_fraction * span
        out.append(theta + mask * noise)
    return torch.cat(out) if out else theta.new_zeros(0, theta.shape[1])


def _training_parameter_sets(
    snapshots: torch.Tensor, config: TrainConfig, gen: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor, int]:
    """Saved plus sparsely perturbed joint parameters (step 3 inputs), capped at ``max_training_sets``.

    ``snapshots`` is ``(T, N, P)``; returns ``(S, P)`` parameters, ``(S,)`` head indices and the number of
    perturbed sets (before the cap). Draws the perturbations, then the cap's permutation, from ``gen``.
    """
    T, N, P = snapshots.shape
    theta_sets = snapshots.reshape(T * N, P)
    head_index = torch.arange(N).repeat(T)
    perturbed = perturb(theta_sets, config, gen)
    theta_all = torch.cat([theta_sets, perturbed])
    head_all = torch.cat([head_index, head_index.repeat(config.perturb_copies)])
    if theta_all.shape[0] > config.max_training_sets:
        keep = torch.randperm(theta_all.shape[0], generator=gen)[: config.max_training_sets]
        theta_all, head_all = theta_all[keep], head_all[keep]
    return theta_all, head_all, int(perturbed.shape[0])


def _solve_weight_sets(
    rig: JointRig,
    theta_all: torch.Tensor,
    head_all: torch.Tensor,
    targets: torch.Tensor,
    free: torch.Tensor,
    config: TrainConfig,
    progress: Progress | None,
) -> torch.Tensor:
    """Closed-form skinning floats that best reproduce each set's head, in chunks of 64 (bounded memory).

    ``theta_all`` ``(S, P)``, ``head_all`` ``(S,)`` index into ``targets`` ``(N, V, 3)`` mm; ``free`` is the
    learned linear floats ``(F,)``; returns ``(S, F)`` float32.
    """
    system = OrbitSystem.from_rig(rig)
    solved = []
    chunk = 64
    for start in range(0, theta_all.shape[0], chunk):
        solved.append(
            solve_weights(
                rig,
                theta_all[start : start + chunk],
                targets[head_all[start : start + chunk]],
                free,
                reg=config.solve_reg,
                system=system,
            )
        )
        if progress:
            progress("weight sets", min(start + chunk, theta_all.shape[0]), theta_all.shape[0])
    return torch.cat(solved).float()


def _split_residuals(residuals: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Random 1-in-20 (at least one) validation split of the ``(S, F)`` residual floats; ``(val, train)``."""
    n_val = max(1, residuals.shape[0] // 20)
    split = torch.randperm(residuals.shape[0], generator=gen)
    return residuals[split[:n_val]], residuals[split[n_val:]]


def _train_neural(
    rig: JointRig,
    train_res: torch.Tensor,
    val_res: torch.Tensor,
    config: TrainConfig,
    seconds: dict[str, float],
    progress: Progress | None,
) -> tuple[SkinningDecoder, dict]:
    """Step 4: auto-encoder, then WGAN fine-tuning of the decoder; returns it and its losses (last 20 of the WGAN).

    Records ``seconds["autoencoder"]`` and ``seconds["wgan"]`` (wall time, s).
    """
    t = time.perf_counter()
    decoder = SkinningDecoder(rig.num_skinning_floats)
    encoder = SkinningEncoder(rig.num_skinning_floats)
    critic = Critic()
    ae_train, ae_val = train_autoencoder(
        decoder,
        encoder,
        train_res,
        val_res,
        epochs=config.autoencoder_epochs,
        batch_size=config.batch_size,
        lr=config.autoencoder_lr,
        seed=config.seed,
        progress=progress,
    )
    seconds["autoencoder"] = time.perf_counter() - t
    t = time.perf_counter()
    g_log, c_log = train_wgan(
        decoder,
        encoder,
        critic,
        train_res,
        iterations=config.wgan_iterations,
        batch_size=config.batch_size,
        lr=config.wgan_lr,
        critic_steps=config.critic_steps,
        seed=config.seed,
        progress=progress,
    )
    seconds["wgan"] = time.perf_counter() - t
    losses = {"autoencoder_train": ae_train, "autoencoder_val": ae_val, "generator": g_log[-20:], "critic": c_log[-20:]}
    return decoder, losses


def train(
    config: TrainConfig, out_path: Path, *, log_path: Path | None = None, progress: Progress | None = None
) -> TrainReport:
    """Run the whole training; write the artifact to ``out_path`` (and a JSON log)."""
    torch.manual_seed(config.seed)
    gen = torch.Generator().manual_seed(config.seed)
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    rig = JointRig(dtype=torch.float32)
    train_set = population_split("train", seed=config.seed)
    val_set = population_split("val", seed=config.seed)
    targets = torch.as_tensor(similarity_normalised(train_set.vertices, rig.asset.vertices), dtype=torch.float32)
    seconds["population"] = time.perf_counter() - t0

    # 1 + 2: joints with the initial weights, then alternate with the global linear weights.
    t = time.perf_counter()
    linear = learn_linear_skinning(
        rig,
        targets,
        cycles=config.cycles,
        joint_iterations=config.joint_iterations,
        weight_iterations=config.weight_iterations,
        joint_lr=config.joint_lr,
        weight_lr=config.weight_lr,
        snapshot_every=config.snapshot_every,
        progress=progress,
    )
    seconds["linear_skinning"] = time.perf_counter() - t

    # 3: skinning-weight training sets.
    t = time.perf_counter()
    T, N, _ = linear.snapshots.shape  # (T, N, P)
    theta_all, head_all, n_perturbed = _training_parameter_sets(linear.snapshots, config, gen)
    solved_free = _solve_weight_sets(rig, theta_all, head_all, targets, linear.free, config, progress)
    val_res, train_res = _split_residuals(solved_free - linear.free[None], gen)
    seconds["weight_sets"] = time.perf_counter() - t

    # 4: neural skinning.
    decoder, nn_losses = _train_neural(rig, train_res, val_res, config, seconds, progress)
    seconds["total"] = time.perf_counter() - t0

    neural = NeuralSkinning(rig, linear.free, decoder)
    report = TrainReport(
        config=asdict(config),
        counts={
            "train_heads": N,
            "val_heads": len(val_set.names),
            "saved_parameter_sets": T * N,
            "perturbed_parameter_sets": n_perturbed,
            "weight_training_sets": int(train_res.shape[0]),
            "weight_validation_sets": int(val_res.shape[0]),
            "skinning_floats": rig.num_skinning_floats,
            "decoder_weights": decoder.num_weights,
        },
        seconds={k: round(v, 1) for k, v in seconds.items()},
        rmse_train_mm={"per_joint_fit": linear.rmse_per_cycle},
        losses={**nn_losses, "linear_weights_last": linear.weight_losses[-5:]},
    )
    save_neural(neural, out_path, meta={"config": asdict(config), "counts": report.counts, "seconds": report.seconds})
    if log_path is not None:
        write_bytes_atomic(log_path, (json.dumps(asdict(report), indent=2) + "\n").encode())
    return report


def fit_population_joints(
    vertices: np.ndarray, *, iterations: int = 400, chunk: int = 32, progress: Progress | None = None
) -> np.ndarray:
    """Joint channels of heads in the template's topology (known correspondence).

    Each head is similarity-normalised onto the template (:func:`pipeline.synthetic.population.similarity_normalised`:
    a photo or scan fit has its own pose and scale), then fitted by eq. 7 with the learned linear weights
    (:func:`rig.skinning.joint_fit.fit_joints`; the latent Z adds little here: ``docs/capacity.md``).

    Args:
        vertices: ``(N, V, 3)`` heads, mm.
        iterations: Adam steps per head. chunk: heads per batch.

    Returns:
        ``(N, P)`` float64 joint channels (deg, mm, ``scale - 1``).
    """
    rig = JointRig()
    neural, _ = load_neural(rig)
    weights = neural.linear_weights().detach()
    targets = torch.as_tensor(similarity_normalised(vertices, rig.asset.vertices), dtype=rig.template.dtype)
    out = []
    for start in range(0, len(targets), chunk):
        out.append(fit_joints(rig, targets[start : start + chunk], weights=weights, iterations=iterations).theta)
        if progress is not None:
            progress("identity prior: joints", min(start + chunk, len(targets)), len(targets))
    return torch.cat(out).double().numpy()


def train_identity_prior(
    out_path: str | Path | None = None,
    *,
    seed: int = 0,
    extra_heads: int = 215,
    iterations: int = 400,
    progress: Progress | None = None,
) -> IdentityPrior:
    """Fit the training population's joints and write the prior (``jnr train --identity-prior``).

    The heads: the 85 of the ``train`` split plus ``extra_heads`` more ICT identities drawn from the same
    (unshifted) distribution with seeds of their own stream (never the ``val``, ``test`` or ``heldout``
    seeds).
    """
    t0 = time.perf_counter()
    train = population_split("train", seed=seed)
    vertices = [train.vertices]
    if extra_heads:
        used = set().union(*(set(split_seeds(s, seed).tolist()) for s in ("train", "val", "test", "heldout")))
        ss = np.random.SeedSequence([seed, 0x1D_E7_17])
        seeds = [int(s) for s in ss.generate_state(extra_heads + 16, dtype=np.uint32) if int(s) not in used]
        vertices.append(ict_heads(np.stack([ict_coefficients(s) for s in seeds[:extra_heads]])))
    vertices = np.concatenate(vertices)
    theta = fit_population_joints(vertices, iterations=iterations, progress=progress)
    prior = build_identity_prior(
        clip_to_limits(theta),
        parameter_span(torch.float64).numpy(),
        meta={
            "seed": seed,
            "train_heads": int(len(train.vertices)),
            "extra_heads": int(extra_heads),
            "iterations": iterations,
        },
    )
    prior = IdentityPrior(
        prior.mean,
        prior.components,
        prior.variances,
        prior.noise,
        prior.span,
        {**prior.meta, "seconds": round(time.perf_counter() - t0, 1)},
    )
    prior.save(out_path or default_identity_prior_path())
    return prior
