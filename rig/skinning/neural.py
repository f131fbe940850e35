"""Neural skinning weights (JNR sections 3.2 and 4.4).

A decoder maps a 50-d latent ``Z`` to a residual over the learned linear weights' free floats; the
skinning weights are ``valid(linear + D(Z))`` (clipped non-negative, rows summing to 1, the rig's
sparsity pattern and mirror symmetry). The decoder has no biases, so ``Z = 0`` gives exactly the
learned linear weights. Its last three layers are group-wise fully connected layers
(:class:`GroupLinear`), which reuse one weight block on every group of inputs.

Training (``train_autoencoder`` then ``train_wgan``) follows the paper: an auto-encoder first (the
encoder halves 8,990 -> ... -> 50 in JNR; here ``S`` -> ... -> 50), then the encoder is dropped and the
decoder fine-tuned from noise ``Z`` in WGAN style against a critic (50 -> 256 in 4 layers, 256 -> 1 in
4), with eq. 9's generator loss (lambda_0 = 0.05 sparsity on the residual, lambda_1 = 0.1 adversarial).
The paper's critic is 50-dimensional at its input although skinning weights are 8,990-dimensional;
we read that as the critic judging weights through the (frozen) encoder's 50-d code.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from rig.asset import AssetError, default_skinning_path, write_npz_atomic
from rig.errors import InputError
from rig.lbs import ShapeError, skin_vertices
from rig.losses import LAMBDA_P, laplacian_loss, vertex_rmse
from rig.optim import Progress, frozen
from rig.skinning.joint_fit import fit_joints
from rig.skinning.linear import valid_weights

LATENT = 50
LATENT_LIMIT = 6.0
"""The largest ``|Z_i|`` a head may have: the decoder was trained on ``Z`` drawn from the standard normal
(``train_wgan``), and a coordinate beyond 6 standard deviations (probability 2e-9) lies outside what it
has seen (fits keep ``|Z|`` far smaller by their prior: 0.14-0.15 on simulated scans)."""
LAMBDA_SPARSE = 0.05
LAMBDA_ADV = 0.1


class GroupLinear(nn.Module):
    """Group-wise fully connected layer without bias: the input splits into ``groups`` equal parts and
    one ``(out/groups, in/groups)`` weight is applied to each, so it has ``in*out/groups^2`` weights.

    Shapes: ``(N, in_features) -> (N, out_features)``; output group ``g`` is ``W @ x_g``.
    """

    def __init__(self, in_features: int, out_features: int, groups: int) -> None:
        super().__init__()
        if in_features % groups or out_features % groups:
            raise InputError(
                f"GroupLinear: in_features {in_features} and out_features {out_features} must be "
                f"divisible by groups {groups}"
            )
        self.groups = groups
        self.in_features, self.out_features = in_features, out_features
        self.weight = nn.Parameter(torch.empty(out_features // groups, in_features // groups))
        nn.init.kaiming_uniform_(self.weight, a=math.sqrt(5))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n = x.shape[0]
        return (x.view(n, self.groups, -1) @ self.weight.t()).reshape(n, self.out_features)

    def as_convolution(self, x: torch.Tensor) -> torch.Tensor:
        """The same map written as the paper describes it: reshape the input to ``groups x in/groups``
        and apply a 2-D convolution with ``out/groups`` filters of kernel ``1 x in/groups``."""
        n = x.shape[0]
        image = x.view(n, 1, self.groups, self.in_features // self.groups)
        kernel = self.weight.view(self.out_features // self.groups, 1, 1, -1)
        out = torch.nn.functional.conv2d(image, kernel)  # (n, out/groups, groups, 1)
        return out.squeeze(-1).transpose(1, 2).reshape(n, self.out_features)


class SkinningDecoder(nn.Module):
    """``Z (N, 50) -> residual (N, S)``: 3 fc layers 50 -> 250, then group-wise layers 500 (n=2),
    1,100 (n=5) and ``S`` (n=10, padded up to a multiple of 10); swish between layers; no biases."""

    def __init__(self, num_floats: int, latent: int = LATENT) -> None:
        super().__init__()
        self.num_floats = num_floats
        padded = int(math.ceil(num_floats / 10.0) * 10)
        self.layers = nn.ModuleList(
            [
                nn.Linear(latent, 100, bias=False),
                nn.Linear(100, 175, bias=False),
                nn.Linear(175, 250, bias=False),
                GroupLinear(250, 500, 2),
                GroupLinear(500, 1100, 5),
                GroupLinear(1100, padded, 10),
            ]
        )

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        x = z
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = torch.nn.functional.silu(x)
        return x[:, : self.num_floats]

    @property
    def num_weights(self) -> int:
        return sum(p.numel() for p in self.parameters())


def _mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.SiLU())
    return nn.Sequential(*layers)


class SkinningEncoder(nn.Module):
    """``free floats (N, S) -> Z (N, 50)``: fully connected layers halving the width down to 50 (swish)."""

    def __init__(self, num_floats: int, latent: int = LATENT) -> None:
        super().__init__()
        sizes = [num_floats]
        while sizes[-1] // 2 > latent * 2:
            sizes.append(sizes[-1] // 2)
        sizes.append(latent)
        self.net = _mlp(sizes)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class Critic(nn.Module):
    """WGAN critic on 50-d codes: 50 -> 256 in 4 layers, then 256 -> 1 in 4 layers (swish)."""

    def __init__(self, latent: int = LATENT) -> None:
        super().__init__()
        self.net = _mlp([latent, 100, 150, 200, 256, 128, 64, 16, 1])

    def forward(self, code: torch.Tensor) -> torch.Tensor:
        return self.net(code).squeeze(-1)


@dataclass(frozen=True)
class NeuralTrainingLog:
    """Losses per epoch of the two training phases."""

    autoencoder: list[float]
    autoencoder_val: list[float]
    generator: list[float]
    critic: list[float]


def train_autoencoder(
    decoder: SkinningDecoder,
    encoder: SkinningEncoder,
    residuals: torch.Tensor,
    val_residuals: torch.Tensor,
    *,
    epochs: int = 30,
    batch_size: int = 64,
    lr: float = 1e-3,
    seed: int = 0,
    progress: Progress | None = None,
) -> tuple[list[float], list[float]]:
    """Phase 1: auto-encode training residuals (weights minus learned linear weights) with an L1 loss
    plus eq. 9's sparsity term on the decoded residual. Returns per-epoch train and validation losses."""
    if residuals.dim() != 2 or residuals.shape[1] != decoder.num_floats:
        raise ShapeError(
            f"train_autoencoder: residuals must be (N, {decoder.num_floats}), got {tuple(residuals.shape)}"
        )
    gen = torch.Generator().manual_seed(seed)
    opt = torch.optim.Adam(list(decoder.parameters()) + list(encoder.parameters()), lr=lr)
    train_log, val_log = [], []
    for epoch in range(epochs):
        perm = torch.randperm(residuals.shape[0], generator=gen)
        total = 0.0
        for start in range(0, len(perm), batch_size):
            x = residuals[perm[start : start + batch_size]]
            rec = decoder(encoder(x))
            loss = (x - rec).abs().sum(-1).mean() + LAMBDA_SPARSE * rec.abs().sum(-1).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(x)
        train_log.append(total / residuals.shape[0])
        with torch.no_grad():
            val_log.append(float((val_residuals - decoder(encoder(val_residuals))).abs().sum(-1).mean()))
        if progress is not None:
            progress("autoencoder", epoch + 1, epochs)
    return train_log, val_log


def train_wgan(
    decoder: SkinningDecoder,
    encoder: SkinningEncoder,
    critic: Critic,
    residuals: torch.Tensor,
    *,
    iterations: int = 300,
    batch_size: int = 64,
    lr: float = 1e-4,
    critic_steps: int = 5,
    clip: float = 0.05,
    seed: int = 0,
    progress: Progress | None = None,
) -> tuple[list[float], list[float]]:
    """Phase 2: drop the encoder as a generator input and fine-tune the decoder from noise ``Z``.

    Critic loss eq. 8: ``C(E(D(Z))) - C(E(J))`` minimised (Wasserstein estimate, weight clipping as in
    WGAN). Generator loss eq. 9: ``|J - D(E(J))| + lambda_0 |D(Z)| - lambda_1 C(E(D(Z)))``; the
    reconstruction term keeps the decoder faithful on real weights ``J`` while the noise half of the
    loss spreads it over the whole ``Z`` space. The encoder stays frozen.
    """
    gen = torch.Generator().manual_seed(seed)
    opt_d = torch.optim.Adam(decoder.parameters(), lr=lr)
    opt_c = torch.optim.RMSprop(critic.parameters(), lr=5e-5)
    g_log, c_log = [], []
    n = residuals.shape[0]
    with frozen(encoder):
        for it in range(iterations):
            for _ in range(critic_steps):
                real = residuals[torch.randint(n, (batch_size,), generator=gen)]
                z = torch.randn(batch_size, LATENT, generator=gen)
                with torch.no_grad():
                    fake = decoder(z)
                loss_c = critic(encoder(fake)).mean() - critic(encoder(real)).mean()
                opt_c.zero_grad()
                loss_c.backward()
                opt_c.step()
                with torch.no_grad():
                    for p in critic.parameters():
                        p.clamp_(-clip, clip)
            real = residuals[torch.randint(n, (batch_size,), generator=gen)]
            z = torch.randn(batch_size, LATENT, generator=gen)
            fake = decoder(z)
            rec = decoder(encoder(real))
            loss_g = (
                (real - rec).abs().sum(-1).mean()
                + LAMBDA_SPARSE * fake.abs().sum(-1).mean()
                - LAMBDA_ADV * critic(encoder(fake)).mean()
            )
            opt_d.zero_grad()
            loss_g.backward()
            opt_d.step()
            g_log.append(loss_g.item())
            c_log.append(loss_c.item())
            if progress is not None:
                progress("wgan", it + 1, iterations)
    return g_log, c_log


# ----------------------------------------------------------------------------------------------------
# The trained model and the test-time fit
# ----------------------------------------------------------------------------------------------------


class NeuralSkinning(nn.Module):
    """Learned linear weights plus the decoder: ``Z (N, 50) -> valid weights (N, V, K)``.

    Args:
        rig: the rig whose layout the floats follow.
        linear_free: ``(S,)`` learned linear weights (free floats).
        decoder: a trained :class:`SkinningDecoder` (default: untrained, near-zero residual).
    """

    def __init__(self, rig, linear_free: torch.Tensor, decoder: SkinningDecoder | None = None) -> None:
        super().__init__()
        self.rig = rig
        self.register_buffer("linear_free", linear_free.detach().to(rig.template.dtype).clone())
        self.decoder = decoder or SkinningDecoder(int(linear_free.shape[0]))
        self.decoder.to(rig.template.dtype)

    def free(self, z: torch.Tensor) -> torch.Tensor:
        """``(N, 50) -> (N, S)`` free floats before validation."""
        return self.linear_free + self.decoder(z)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return valid_weights(self.rig, self.free(z))

    def linear_weights(self) -> torch.Tensor:
        """``(V, K)`` the learned linear weights (``Z = 0``)."""
        return valid_weights(self.rig, self.linear_free)


@dataclass(frozen=True)
class NeuralFit:
    """Result of :func:`fit_neural`: ``theta (B, P)``, ``z (B, 50)``, ``rmse (B,)`` in mm after each stage."""

    theta: torch.Tensor
    z: torch.Tensor
    rmse: torch.Tensor
    rmse_per_stage: list[list[float]]


def fit_neural(
    neural: NeuralSkinning,
    targets: torch.Tensor,
    *,
    cycles: int = 2,
    joint_iterations: int = 300,
    z_iterations: int = 200,
    joint_lr: float = 0.01,
    z_lr: float = 0.02,
    z_prior: float = 1e-3,
    init: torch.Tensor | None = None,
    progress: Progress | None = None,
) -> NeuralFit:
    """JNR's test-time fit (4.4): ``Z = 0``, fit the joints, then fit ``Z`` with the joints fixed; repeat.

    Args:
        targets: ``(B, V, 3)`` meshes in the rig's topology, mm.
        z_prior: weight of ``|Z|^2`` (keeps the code in the region the decoder was trained on).

    Returns:
        :class:`NeuralFit`.
    """
    rig = neural.rig
    dtype = rig.template.dtype
    targets = targets.to(dtype)
    B = targets.shape[0]
    z = torch.zeros(B, LATENT, dtype=dtype)
    theta = init
    stages: list[list[float]] = []
    with frozen(neural.decoder):
        for cycle in range(cycles):
            with torch.no_grad():
                w = neural(z)
            fit = fit_joints(
                rig,
                targets,
                weights=w,
                init=theta,
                iterations=joint_iterations,
                lr=joint_lr,
                progress=(lambda _, it, n, c=cycle: progress(f"joints {c + 1}", it, n)) if progress else None,
            )
            theta = fit.theta
            stages.append(fit.rmse.tolist())
            with torch.no_grad():
                _, skinning = rig.joint_transforms(theta)
            zz = z.clone().requires_grad_(True)
            opt = torch.optim.Adam([zz], lr=z_lr)
            for it in range(z_iterations):
                w = neural(zz)
                pred = skin_vertices(rig.template, w, skinning)
                loss = (
                    vertex_rmse(pred, targets)
                    + LAMBDA_P * laplacian_loss(pred, targets, rig.laplacian)
                    + z_prior * zz.square().sum(-1)
                ).sum()
                opt.zero_grad()
                loss.backward()
                opt.step()
                if progress:
                    progress(f"latent {cycle + 1}", it + 1, z_iterations)
            z = zz.detach()
            with torch.no_grad():
                rmse = vertex_rmse(rig(theta, weights=neural(z)).vertices, targets)
            stages.append(rmse.tolist())
    return NeuralFit(theta, z, rmse, stages)


def save_neural(neural: NeuralSkinning, path, meta: dict | None = None) -> None:
    """Write the learned linear weights and the decoder as one ``.npz`` (named float32 arrays)."""
    import json

    import numpy as np

    arrays = {"linear_free": neural.linear_free.detach().cpu().numpy().astype(np.float64)}
    for name, value in neural.decoder.state_dict().items():
        arrays[f"decoder.{name}"] = value.detach().cpu().numpy().astype(np.float32)
    arrays["meta_json"] = np.array(json.dumps(meta or {}))
    write_npz_atomic(path, arrays)


def load_neural(rig, path=None) -> tuple[NeuralSkinning, dict]:
    """Read a file written by :func:`save_neural` (default: the committed :func:`rig.asset.default_skinning_path`)."""
    import json
    from pathlib import Path

    import numpy as np

    path = Path(path) if path else default_skinning_path()
    if not path.is_file():
        raise AssetError(f"learned skinning not found: {path} (train it with `jnr train`)")
    with np.load(path, allow_pickle=False) as data:
        linear = torch.as_tensor(data["linear_free"])
        state = {k[len("decoder.") :]: torch.as_tensor(data[k]) for k in data.files if k.startswith("decoder.")}
        meta = json.loads(str(data["meta_json"]))
    if linear.shape[0] != rig.num_skinning_floats:
        raise AssetError(f"{path} has {linear.shape[0]} skinning floats, the rig {rig.num_skinning_floats}; retrain it")
    decoder = SkinningDecoder(int(linear.shape[0]))
    decoder.load_state_dict(state)
    return NeuralSkinning(rig, linear, decoder), meta
