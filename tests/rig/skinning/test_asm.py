"""ASM (rig/skinning/asm/): GMM skinning weights, dynamic bone binding, registration."""

import math

import numpy as np
import pytest
import torch

from rig.joints import JOINT_MIRROR
from rig.lbs import ShapeError, channels_to_trs
from rig.parameters import random_theta
from rig.skinning.asm import (
    AdaptiveSkinning,
    AsmParameters,
    AsmVariant,
    bone_positions_from_uv,
    cholesky_from_sigma,
    fit_asm,
    gmm_skinning_weights,
    load_initial_gmm,
    locate_uv,
    mirror_uv,
    sigma_from_cholesky,
    uv_barycentric,
    uv_domain,
)


@pytest.fixture(scope="module")
def asm64(rig64):
    return AdaptiveSkinning(rig64, components=2)


def _random_params(model: AdaptiveSkinning, batch: int, seed: int, scale: float = 1.0) -> AsmParameters:
    g = torch.Generator().manual_seed(seed)
    p = model.initial(batch)
    dt = p.tau.dtype

    def noise(t, s):
        return t + s * scale * torch.randn(t.shape, generator=g, dtype=dt)

    tau = (
        torch.randn(p.tau.shape, generator=g, dtype=dt)
        * scale
        * torch.tensor([2.0, 2.0, 2.0, 0.8, 0.8, 0.8, 0.03, 0.03, 0.03], dtype=dt)
    )
    return AsmParameters(
        tau=tau, zeta=noise(p.zeta, 0.004), log_pi=noise(p.log_pi, 0.3), mu=noise(p.mu, 0.004), chol=noise(p.chol, 0.1)
    )


def test_parameter_count_is_asm_table_1(rig32):
    for K in (2, 3, 5):
        model = AdaptiveSkinning(rig32, components=K)
        assert model.parameters_per_bone == 11 + 6 * K
        p = model.initial(1)
        assert sum(t[0].numel() for t in p.as_dict().values()) == model.num_parameters == 52 * (11 + 6 * K)


def test_gmm_weights_are_non_negative_and_sum_to_one(asm64):
    p = _random_params(asm64, 2, seed=0, scale=3.0)
    w = asm64.weights(p)
    assert w.shape == (2, asm64.rig.num_vertices, 52)
    assert (w >= 0).all()
    assert torch.allclose(w.sum(-1), torch.ones(2, asm64.rig.num_vertices, dtype=w.dtype), atol=1e-12)
    # far from every Gaussian (tiny covariances) the log-space normalisation still gives finite weights
    tight = AsmParameters(**{**p.as_dict(), "chol": p.chol - 4.0})
    assert torch.isfinite(asm64.weights(tight)).all()


def test_eq6_against_a_naive_per_vertex_loop(asm64):
    p = _random_params(asm64, 1, seed=1)
    w = asm64.gmm_weights(p)[0].numpy()
    domain = asm64.domain
    sigma = sigma_from_cholesky(p.chol)[0].numpy()
    centres = (p.zeta.unsqueeze(-2) + p.mu)[0].numpy()
    pi = p.log_pi[0].exp().numpy()
    rows = list(range(0, len(domain.gmm_vertices), 97)) + list(domain.seam_rows[:3])
    for row in rows:
        copies = domain.vertex_uv[row][domain.copy_mask[row]]
        W = np.zeros(52)
        for j in range(52):
            for u in copies:
                for k in range(2):
                    S = sigma[j, k]
                    d = u - centres[j, k]
                    density = math.exp(-0.5 * d @ np.linalg.inv(S) @ d) / (2 * math.pi * math.sqrt(np.linalg.det(S)))
                    W[j] += pi[j, k] * density / len(copies)
        np.testing.assert_allclose(w[row], W / W.sum(), rtol=1e-6, atol=1e-12)


def test_weights_are_mirror_symmetric_when_the_parameters_are(asm64, asset):
    domain = asm64.domain
    p = _random_params(asm64, 1, seed=2, scale=2.0)
    left_or_mid = asset.joint_positions[:, 0] >= -1e-6
    mid = np.abs(asset.joint_positions[:, 0]) < 1e-6
    values = {n: t.clone() for n, t in p.as_dict().items()}
    for j, partner in enumerate(JOINT_MIRROR):
        if not left_or_mid[j]:
            values["log_pi"][0, j] = values["log_pi"][0, partner]
            values["mu"][0, j] = values["mu"][0, partner] * torch.tensor([1.0, -1.0], dtype=torch.float64)
            values["chol"][0, j] = values["chol"][0, partner] * torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64)
            values["zeta"][0, j] = mirror_uv(values["zeta"][0, partner], domain.mirror_v)
        elif mid[j]:  # self-symmetric: on the mirror line, axis-aligned
            values["mu"][0, j, :, 1] = 0.0
            values["chol"][0, j, :, 2] = 0.0
            values["zeta"][0, j, 1] = domain.mirror_v
    sym = AsmParameters(**values)
    w = asm64.gmm_weights(sym)[0]
    row = {int(v): i for i, v in enumerate(domain.gmm_vertices)}
    mirror_rows = torch.tensor([row[int(asset.mirror[v])] for v in domain.gmm_vertices])
    assert torch.allclose(w, w[mirror_rows][:, list(JOINT_MIRROR)], atol=1e-10)
    # and the unsymmetrised parameters are not symmetric (the test can fail)
    w0 = asm64.gmm_weights(p)[0]
    assert (w0 - w0[mirror_rows][:, list(JOINT_MIRROR)]).abs().max() > 1e-3


def test_barycentric_interpolation_against_a_hand_computed_triangle():
    face_uv = torch.tensor(
        [[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]], dtype=torch.float64
    )
    face_xyz = torch.tensor(
        [
            [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 20.0, 0.0]],
            [[10.0, 0.0, 0.0], [10.0, 20.0, 5.0], [0.0, 20.0, 0.0]],
        ],
        dtype=torch.float64,
    )
    anchor = torch.tensor([[1.0, 1.0, 1.0]], dtype=torch.float64)
    psi0 = torch.tensor([[0.0, 0.0, 30.0]], dtype=torch.float64)
    zeta = torch.tensor([[[0.25, 0.5]]], dtype=torch.float64)
    # zeta = 0.25 A + 0.25 B + 0.5 C of the first triangle -> 0.25 (10, 0, 0) + 0.5 (0, 20, 0) = (2.5, 10, 0)
    assert torch.allclose(uv_barycentric(zeta[0, 0], face_uv[0]), torch.tensor([0.25, 0.25, 0.5], dtype=torch.float64))
    psi = bone_positions_from_uv(zeta, face_uv, face_xyz, anchor, psi0)
    assert torch.allclose(psi, torch.tensor([[[2.5 - 1.0, 10.0 - 1.0, 0.0 - 1.0 + 30.0]]], dtype=torch.float64))
    # the point (0.75, 0.75) lies in the second triangle: (0.75, 0.75) = 0.25 A' + 0.75 B' + 0 C'... solve by hand:
    # B' - A' = (0, 1), C' - A' = (-1, 1): (0.75, 0.75) = A' + s (0, 1) + t (-1, 1) -> t = 0.25, s = 0.5
    # -> weights (0.25, 0.5, 0.25) -> xyz = 0.25 (10,0,0) + 0.5 (10,20,5) + 0.25 (0,20,0) = (7.5, 15, 2.5)
    assert locate_uv(torch.tensor([[0.75, 0.75]], dtype=torch.float64), face_uv).item() == 1
    psi = bone_positions_from_uv(torch.tensor([[[0.75, 0.75]]], dtype=torch.float64), face_uv, face_xyz, anchor, psi0)
    assert torch.allclose(psi, torch.tensor([[[6.5, 14.0, 31.5]]], dtype=torch.float64))


def test_initial_binding_is_the_rigs_and_zeta_moves_bones_along_the_surface(asm64):
    p = asm64.initial(1)
    assert torch.allclose(asm64.bone_positions(p), asm64.rig.bind_positions[None], atol=1e-9)
    moved = AsmParameters(**{**p.as_dict(), "zeta": p.zeta + torch.tensor([0.0, 0.01], dtype=torch.float64)})
    shift = (asm64.bone_positions(moved) - asm64.rig.bind_positions[None]).norm(dim=-1)
    assert (shift > 1.0).all() and (shift < 25.0).all()  # 0.01 UV is 3-20 mm on the head


def test_rest_parameters_give_the_template_and_static_asm_equals_the_joint_rig(asm64, rig64):
    p = asm64.initial(1)
    assert torch.allclose(asm64(p).vertices[0], rig64.template, atol=1e-9)
    theta = random_theta(torch.Generator().manual_seed(3), batch=2, spread=0.6).double()
    rotation, translation, scale = channels_to_trs(theta, rig64.channel_joint, rig64.channel_kind, 52)
    tau = torch.cat([rotation * 180.0 / math.pi, translation, scale - 1.0], dim=-1)
    p2 = AsmParameters(**{**asm64.initial(2).as_dict(), "tau": tau})
    ours = asm64(p2, dynamic_binding=False, gmm_weights=False).vertices
    assert torch.allclose(ours, rig64(theta).vertices, atol=1e-8)


def test_gradients_of_zeta_pi_mu_sigma_match_finite_differences(asm64):
    p = _random_params(asm64, 1, seed=4)
    g = torch.Generator().manual_seed(5)
    probe = torch.randn(1, asm64.rig.num_vertices, 3, generator=g, dtype=torch.float64)

    def objective(q: AsmParameters) -> torch.Tensor:
        return (asm64(q).vertices * probe).sum()

    for name in ("zeta", "log_pi", "mu", "chol", "tau"):
        base = getattr(p, name).detach().clone().requires_grad_(True)
        value = objective(AsmParameters(**{**p.as_dict(), name: base}))
        (grad,) = torch.autograd.grad(value, base)
        direction = torch.randn(base.shape, generator=g, dtype=torch.float64)
        # float64 steps where truncation (~eps^4) and round-off (~1e-16 |objective| / eps) are both small,
        # checked by halving the step over 1e-3 .. 1e-8: the narrowest initial Gaussian is ~1e-5 UV wide (mu
        # needs 1e-8; at 1e-7 it is 6e-5 off); zeta moves vertices by ~1e4 mm per UV unit (1e-7); log_pi is a
        # log-weight whose gradient is small beside the objective, so round-off rules below 1e-4 (1e-6:
        # 5e-5 off, 1e-3: 2e-8)
        eps = {"zeta": 1e-7, "mu": 1e-8, "log_pi": 1e-3}.get(name, 1e-6)

        def at(step: float, name=name, base=base, direction=direction) -> torch.Tensor:
            return objective(AsmParameters(**{**p.as_dict(), name: base.detach() + step * direction}))

        # fourth-order central difference (the sharp initial Gaussians make the second-order one too coarse)
        numeric = (-at(2 * eps) + 8 * at(eps) - 8 * at(-eps) + at(-2 * eps)) / (12 * eps)
        assert torch.allclose((grad * direction).sum(), numeric, rtol=1e-5, atol=1e-6), name


def test_gmm_gradcheck_in_float64_including_sigma():
    g = torch.Generator().manual_seed(6)
    uv = torch.rand(7, 2, generator=g, dtype=torch.float64)
    log_pi = torch.randn(1, 3, 2, generator=g, dtype=torch.float64, requires_grad=True)
    centres = torch.rand(1, 3, 2, 2, generator=g, dtype=torch.float64, requires_grad=True)
    L = torch.randn(1, 3, 2, 2, 2, generator=g, dtype=torch.float64) * 0.2
    sigma = (L @ L.transpose(-1, -2) + 0.05 * torch.eye(2, dtype=torch.float64)).requires_grad_(True)
    seam_rows = torch.tensor([1, 4])
    seam_uv = torch.rand(2, 2, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(
        lambda a, b, c: gmm_skinning_weights(uv, a, b, c, seam_rows, seam_uv), (log_pi, centres, sigma)
    )
    chol = cholesky_from_sigma(sigma.detach())
    assert torch.allclose(sigma_from_cholesky(chol), sigma.detach(), atol=1e-12)


def test_a_head_made_by_asm_with_known_parameters_is_recovered(rig32):
    """Every parameter of every bone perturbed (transforms, binding, mixtures): registration from the
    initial model brings the mesh to within 15 % of the starting error (Adam, 300 steps: the problem is
    ill-conditioned, the error keeps falling slowly). Only the surface is compared: ASM's parameters are
    not identifiable (a bind position and a bone translation trade off), and the bones end up to 8 mm
    from their true binding while the mesh is within 1 mm."""
    model = AdaptiveSkinning(rig32, components=2)
    truth = _random_params(model, 1, seed=7, scale=0.5)
    with torch.no_grad():
        target = model(truth).vertices
    start = model.initial(1)
    start_rmse = ((model(start).vertices - target) ** 2).sum(-1).mean().sqrt().item()
    fit = fit_asm(model, target, iterations=300, lr=0.02)
    assert start_rmse > 4.0
    assert fit.rmse.item() < 0.15 * start_rmse and fit.rmse.item() < 1.0
    assert fit.losses[-1] < 0.05 * fit.losses[0]
    face = torch.as_tensor(rig32.asset.region_mask("nose", "lips", "eyelids", "cheeks", "chin", "forehead"))
    assert (fit.vertices - target).norm(dim=-1)[0, face].mean() < 1.0


def test_variants_free_the_right_parameters_and_dynamic_binding_adds_capacity(rig32):
    assert AsmVariant(False, False).free() == ("tau",)
    assert AsmVariant(True, False).free() == ("tau", "zeta")
    assert AsmVariant(False, True).free() == ("tau", "log_pi", "mu", "chol")
    assert AsmVariant().name == "asm"
    model = AdaptiveSkinning(rig32, components=2)
    truth = _random_params(model, 1, seed=8, scale=1.0)
    with torch.no_grad():
        target = model(truth).vertices
    static = fit_asm(model, target, variant=AsmVariant(False, False), iterations=150)
    full = fit_asm(model, target, variant=AsmVariant(True, True), iterations=150)
    assert full.rmse.item() < static.rmse.item()
    assert torch.equal(static.params.zeta, model.initial(1).zeta) and torch.equal(static.params.mu, model.initial(1).mu)


def test_initial_gmm_reproduces_the_painted_weights(asm64):
    for K, bound in ((2, 0.05), (5, 0.05)):
        model = AdaptiveSkinning(asm64.rig, components=K)
        w = model.gmm_weights(model.initial(1))[0]
        painted = model.painted[model.gmm_vertices]
        assert (w - painted).pow(2).mean().sqrt() < bound
    init = load_initial_gmm(2)
    assert init["log_pi"].shape == (52, 2) and init["mu"].shape == (52, 2, 2) and init["chol"].shape == (52, 2, 3)


def test_domain_covers_the_skin_island_and_anchors_are_symmetric(asset):
    d = uv_domain(asset)
    assert len(d.gmm_vertices) == 3185 and len(d.seam_rows) == 18
    static = asset.region_mask("eyeballs", "teeth", "tongue", "mouth_interior", "eye_pockets")
    assert not static[d.gmm_vertices].any()
    for j, partner in enumerate(JOINT_MIRROR):
        assert d.anchors[j] == asset.mirror[d.anchors[partner]]


def test_bad_input_raises(asm64, rig32):
    p = asm64.initial(1)
    with pytest.raises(ShapeError, match="zeta"):
        asm64(AsmParameters(**{**p.as_dict(), "zeta": p.zeta[:, :3]}))
    with pytest.raises(ValueError, match="components"):
        AdaptiveSkinning(rig32, components=0)
    with pytest.raises(ShapeError, match="targets"):
        fit_asm(AdaptiveSkinning(rig32), torch.zeros(1, 10, 3))
    with pytest.raises(ValueError, match="NaN"):
        fit_asm(AdaptiveSkinning(rig32), torch.full((1, rig32.num_vertices, 3), float("nan")))
