import numpy as np
import torch

from rig.losses import (
    LAMBDA_M,
    LAMBDA_P,
    LAMBDA_X,
    laplacian_loss,
    regularizer,
    rig_loss,
    uniform_laplacian,
    vertex_rmse,
)
from rig.parameters import NUM_PARAMETERS, params_to_theta, theta_limits


def test_vertex_rmse_matches_naive(rng):
    a, b = rng.normal(size=(2, 50, 3)), rng.normal(size=(2, 50, 3))
    naive = [np.sqrt(np.mean([np.sum((a[i, n] - b[i, n]) ** 2) for n in range(50)])) for i in range(2)]
    assert np.allclose(vertex_rmse(torch.tensor(a), torch.tensor(b)).numpy(), naive)


def test_laplacian_of_rigid_translation_is_zero_and_detects_bumps(asset):
    lap = uniform_laplacian(asset.faces, len(asset.vertices))
    v = torch.as_tensor(asset.vertices)[None]
    # zero up to the loss's floor sqrt(1e-20) = 1e-10 (kept for a finite gradient at zero)
    assert laplacian_loss(v + torch.tensor([3.0, -2.0, 1.0], dtype=torch.float64), v, lap).item() <= 1.0001e-10
    bumped = v.clone()
    bumped[0, 100] += torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    assert laplacian_loss(bumped, v, lap).item() > 1e-3  # a 1 mm bump at one vertex of ~4900


def test_regularizer_and_total_follow_eqs_4_and_7(asset):
    theta = params_to_theta({"neck.scale": 1.2, "crown.translate_y": -5.0, "neck.rotate_x": 3.0}, dtype=torch.float64)[
        None
    ]
    assert torch.allclose(regularizer(theta), torch.tensor([(0.2 + 5.0 + 3.0) / 52], dtype=torch.float64))
    lap = uniform_laplacian(asset.faces, len(asset.vertices))
    low, high = theta_limits(torch.float64)
    v = torch.as_tensor(asset.vertices)[None]
    terms = rig_loss(v + 0.5, v, theta, low, high, lap)
    expected = (
        terms["vertex"] + LAMBDA_M * terms["regularizer"] + LAMBDA_X * terms["limits"] + LAMBDA_P * terms["laplacian"]
    )
    assert torch.allclose(terms["total"], expected)
    assert torch.allclose(terms["vertex"], torch.tensor([np.sqrt(3 * 0.25)], dtype=torch.float64))


def test_known_pose_is_recovered_by_minimising_eq_7(rig32, asset):
    """Fit all 107 parameters to a mesh made by known parameters (known correspondence)."""
    truth = params_to_theta(
        {
            "nose_tip.translate_z": 6.0,
            "crown.translate_y": 12.0,
            "left_cheek.scale": 1.2,
            "right_cheek.scale": 1.2,
            "jaw_root.scale_x": 1.05,
            "skull_root.rotate_y": 5.0,
        }
    )[None]
    with torch.no_grad():
        target = rig32(truth).vertices
    lap = uniform_laplacian(asset.faces, len(asset.vertices))
    low, high = theta_limits()
    # Optimise in units of each channel's range so that degrees, mm and factors move alike.
    span = (high - low).clamp_min(1e-3)
    z = torch.zeros(1, NUM_PARAMETERS, requires_grad=True)
    opt = torch.optim.Adam([z], lr=0.01)
    start = vertex_rmse(rig32(z * span).vertices, target).item()
    for _ in range(400):
        theta = z * span
        loss = rig_loss(rig32(theta).vertices, target, theta, low, high, lap, lambda_m=0.0)["total"].sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
    final = vertex_rmse(rig32(z * span).vertices, target).item()
    assert start > 2.0 and final < 0.03 * start, (start, final)
