import pytest
import torch

from rig.joints import JOINT_MIRROR
from rig.parameters import random_theta
from rig.skinning.linear import fit_linear_weights, solve_weights, valid_weights
from rig.skinning.neural import (
    LATENT,
    Critic,
    GroupLinear,
    NeuralSkinning,
    SkinningDecoder,
    SkinningEncoder,
    fit_neural,
    train_autoencoder,
)


def test_group_linear_equals_its_convolution_form_and_counts_weights():
    torch.manual_seed(0)
    layer = GroupLinear(1100, 7400, 10)
    x = torch.randn(3, 1100)
    assert torch.allclose(layer(x), layer.as_convolution(x), atol=1e-5)
    assert sum(p.numel() for p in layer.parameters()) == 1100 * 7400 // 100
    # naive: each group of 110 inputs through the same 740 x 110 block
    naive = torch.cat([x[:, g * 110 : (g + 1) * 110] @ layer.weight.t() for g in range(10)], 1)
    assert torch.allclose(layer(x), naive, atol=1e-5)
    with pytest.raises(ValueError, match="divisible"):
        GroupLinear(100, 75, 10)


def test_decoder_has_papers_layer_sizes_and_no_bias(rig32):
    dec = SkinningDecoder(rig32.num_skinning_floats)
    padded = (rig32.num_skinning_floats + 9) // 10 * 10
    expected = 50 * 100 + 100 * 175 + 175 * 250 + 125 * 250 + 100 * 220 + 110 * (padded // 10)
    assert dec.num_weights == expected
    assert all("bias" not in name for name, _ in dec.named_parameters())
    assert torch.equal(dec(torch.zeros(2, LATENT)), torch.zeros(2, rig32.num_skinning_floats))


def test_decoded_weights_are_valid_and_zero_code_is_symmetric(rig32, asset):
    torch.manual_seed(1)
    neural = NeuralSkinning(rig32, rig32.weights_free.clone())
    with torch.no_grad():
        neural.decoder.layers[-1].weight.mul_(100.0)  # a large residual, some floats pushed negative
        w = neural(torch.randn(4, LATENT))
    assert (w >= 0).all() and torch.allclose(w.sum(-1), torch.ones(4, rig32.num_vertices), atol=1e-5)
    assert (w[:, torch.as_tensor(asset.weights) == 0] == 0).all()  # sparsity pattern kept
    w0 = neural(torch.zeros(1, LATENT))[0]
    mirror = torch.as_tensor(asset.mirror)
    assert torch.abs(w0[mirror][:, list(JOINT_MIRROR)] - w0).max() < 1e-6
    assert torch.abs(w0 - torch.as_tensor(asset.weights, dtype=torch.float32)).max() < 1e-6
    # any code gives symmetric weights, since floats are shared by mirror pairs
    w1 = w[0]
    assert torch.abs(w1[mirror][:, list(JOINT_MIRROR)] - w1).max() < 1e-6


def test_solve_weights_recovers_weights_that_made_the_mesh(rig64):
    g = torch.Generator().manual_seed(0)
    theta = random_theta(g, 4, spread=0.3, dtype=torch.float64)
    truth = valid_weights(
        rig64, rig64.weights_free * (1 + torch.rand(rig64.num_skinning_floats, generator=g, dtype=torch.float64))
    )
    with torch.no_grad():
        targets = rig64(theta, weights=truth).vertices
    free = solve_weights(rig64, theta, targets, rig64.weights_free, reg=1e-8)
    w = valid_weights(rig64, free)
    assert torch.allclose(w.sum(-1), torch.ones_like(w[..., 0])) and (w >= 0).all()
    rec = torch.stack([rig64(theta[i : i + 1], weights=w[i]).vertices[0] for i in range(4)])
    before = (rig64(theta).vertices - targets).norm(dim=-1).mean()
    after = (rec - targets).norm(dim=-1).mean()
    assert before > 0.05 and after < 0.05 * before


def test_learned_linear_weights_reduce_error_on_heads_they_can_express(rig32):
    """Heads made with other (valid) weights: fitting global weights with the joints known lowers the error."""
    g = torch.Generator().manual_seed(3)
    theta = random_theta(g, 6, spread=0.3)
    truth = valid_weights(rig32, rig32.weights_free * (1 + torch.rand(rig32.num_skinning_floats, generator=g)))
    with torch.no_grad():
        targets = rig32(theta, weights=truth).vertices
    free, losses = fit_linear_weights(rig32, targets, theta, rig32.weights_free, iterations=60, lr=3e-3)
    assert losses[-1] < 0.6 * losses[0]
    w = valid_weights(rig32, free)
    assert (w >= 0).all() and torch.allclose(w.sum(-1), torch.ones(rig32.num_vertices), atol=1e-5)


@pytest.mark.slow  # 6 s of the fast suite's 6 minutes: CI's make test-slow runs it
def test_tiny_training_run_lowers_its_loss_and_fit_uses_z(rig32):
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    S = rig32.num_skinning_floats
    # Residual data on a 3-d manifold: the auto-encoder must find it.
    basis = torch.randn(3, S, generator=g) * 0.02
    codes = torch.randn(96, 3, generator=g)
    data = codes @ basis
    dec, enc = SkinningDecoder(S), SkinningEncoder(S)
    train_log, val_log = train_autoencoder(dec, enc, data[:80], data[80:], epochs=8, batch_size=16, lr=1e-3)
    untrained = data[80:].abs().sum(-1).mean().item()  # D(E(x)) ~ 0 before training
    assert train_log[-1] < train_log[0] and val_log[-1] < 0.9 * untrained, (train_log, val_log, untrained)
    assert Critic()(torch.zeros(5, LATENT)).shape == (5,)
    # Test-time fit: Z moves away from 0 and does not make the fit worse.
    neural = NeuralSkinning(rig32, rig32.weights_free.clone(), dec)
    theta = random_theta(g, 2, spread=0.2)
    with torch.no_grad():
        targets = rig32(theta, weights=neural(torch.randn(2, LATENT, generator=g))).vertices
    fit = fit_neural(neural, targets, cycles=1, joint_iterations=80, z_iterations=40)
    assert fit.z.abs().max() > 0
    assert all(b <= a + 1e-4 for a, b in zip(fit.rmse_per_stage[0], fit.rmse_per_stage[1]))


def test_artifact_round_trip_and_missing_file(rig32, tmp_path):
    from rig.asset import AssetError
    from rig.skinning.neural import load_neural, save_neural

    neural, meta = load_neural(rig32)  # the committed artifact
    assert meta["counts"]["train_heads"] == 85
    save_neural(neural, tmp_path / "n.npz", meta)
    again, _ = load_neural(rig32, tmp_path / "n.npz")
    z = torch.randn(2, LATENT, generator=torch.Generator().manual_seed(0))
    assert torch.equal(neural(z), again(z))
    with pytest.raises(AssetError, match="jnr train"):
        load_neural(rig32, tmp_path / "missing.npz")
