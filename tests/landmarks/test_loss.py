import math

import numpy as np
import pytest
import torch
from kornia.geometry.camera import PinholeCamera

from landmarks.loss import (
    default_landmark_weights,
    landmark_reprojection_loss,
    project_points,
)
from rig.lbs import ShapeError


def _camera(fx=800.0, fy=820.0, cx=300.5, cy=250.25, width=640, height=480, rotation=None, t=(0.0, 0.0, 0.0)):
    K = torch.eye(4, dtype=torch.float64)
    K[0, 0], K[1, 1], K[0, 2], K[1, 2] = fx, fy, cx, cy
    E = torch.eye(4, dtype=torch.float64)
    if rotation is not None:
        E[:3, :3] = torch.as_tensor(rotation, dtype=torch.float64)
    E[:3, 3] = torch.as_tensor(t, dtype=torch.float64)
    return PinholeCamera(
        K[None],
        E[None],
        torch.tensor([float(height)], dtype=torch.float64),
        torch.tensor([float(width)], dtype=torch.float64),
    )


def _rot_y(deg):
    a = math.radians(deg)
    return [[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]]


def test_optical_axis_projects_to_principal_point():
    cam = _camera()
    out = project_points(torch.tensor([[[0.0, 0.0, 500.0], [0.0, 0.0, 1234.0]]], dtype=torch.float64), cam)
    assert out.shape == (1, 2, 2)
    np.testing.assert_allclose(out[0].numpy(), [[300.5, 250.25]] * 2)


def test_projection_matches_pinhole_formula_with_rotated_extrinsics():
    R, t = np.array(_rot_y(20.0)) @ np.array([[1, 0, 0], [0, -1, 0], [0, 0, -1]]), np.array([5.0, -12.0, 600.0])
    cam = _camera(rotation=R, t=t, width=1000, height=300)  # non-square image, off-centre principal point
    X = np.array([[10.0, 20.0, 30.0], [-40.0, 5.0, 70.0]])
    Xc = X @ R.T + t
    expected = np.stack([800.0 * Xc[:, 0] / Xc[:, 2] + 300.5, 820.0 * Xc[:, 1] / Xc[:, 2] + 250.25], 1)
    out = project_points(torch.tensor(X)[None], cam)
    np.testing.assert_allclose(out[0].numpy(), expected, rtol=1e-12)
    # a batch-1 camera broadcasts over a batch of point sets
    out2 = project_points(torch.tensor(np.stack([X, X])), cam)
    np.testing.assert_allclose(out2[1].numpy(), expected, rtol=1e-12)


def _setup(b=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    pts = torch.randn(b, 68, 3, generator=g, dtype=torch.float64) * 30 + torch.tensor(
        [0.0, 0.0, 600.0], dtype=torch.float64
    )
    cam = _camera(rotation=_rot_y(10.0), t=(3.0, 4.0, 20.0))
    return pts, cam, g


def test_zero_loss_at_projected_points():
    pts, cam, _ = _setup()
    target = project_points(pts, cam)
    for robust in ("huber", "l2"):
        loss = landmark_reprojection_loss(pts, target, cam, robust=robust)
        assert loss.shape == (2,)
        np.testing.assert_allclose(loss.numpy(), 0.0, atol=1e-20)


def _naive(pts, target, cam, weights, robust, delta):
    proj = project_points(pts, cam).detach().numpy()
    out = []
    for b in range(len(proj)):
        total = 0.0
        for i in range(proj.shape[1]):
            r = math.dist(proj[b, i], target[b, i].tolist())
            rho = 0.5 * r * r if robust == "l2" or r <= delta else delta * (r - 0.5 * delta)
            total += float(weights[i]) * rho
        out.append(total / float(weights.sum()))
    return np.array(out)


@pytest.mark.parametrize("robust", ["huber", "l2"])
def test_loss_matches_naive_loop(robust):
    pts, cam, g = _setup()
    target = project_points(pts, cam) + torch.randn(2, 68, 2, generator=g, dtype=torch.float64) * 6.0  # both branches
    w = default_landmark_weights(torch.float64)
    assert w[:17].eq(0.5).all() and w[17:].eq(1.0).all()
    got = landmark_reprojection_loss(pts, target, cam, robust=robust, delta_px=5.0)
    np.testing.assert_allclose(got.numpy(), _naive(pts, target, cam, w, robust, 5.0), rtol=1e-12)
    custom = torch.rand(68, generator=g, dtype=torch.float64)
    got = landmark_reprojection_loss(pts, target, cam, weights=custom, robust=robust, delta_px=3.0)
    np.testing.assert_allclose(got.numpy(), _naive(pts, target, cam, custom, robust, 3.0), rtol=1e-12)


def test_huber_is_quadratic_below_delta_and_linear_above():
    pts, cam, _ = _setup(b=1)
    target = project_points(pts, cam)
    w = torch.ones(68, dtype=torch.float64)
    shift = torch.zeros_like(target)
    values = []
    for r in (1.0, 2.0, 5.0, 10.0, 20.0):
        shift[..., 0] = r
        values.append(float(landmark_reprojection_loss(pts, target + shift, cam, w, "huber", 5.0)))
    np.testing.assert_allclose(values[:3], [0.5, 2.0, 12.5], rtol=1e-9)  # r^2 / 2
    np.testing.assert_allclose(values[3:], [5.0 * (10 - 2.5), 5.0 * (20 - 2.5)], rtol=1e-9)  # linear, slope delta
    shift[..., 0] = 20.0
    assert float(landmark_reprojection_loss(pts, target + shift, cam, w, "l2")) == pytest.approx(200.0)


@pytest.mark.parametrize("robust", ["huber", "l2"])
def test_gradcheck_float64(robust):
    pts, cam, g = _setup(b=1)
    pts = pts[:, :6].clone().requires_grad_(True)
    target = project_points(pts.detach(), cam) + torch.randn(1, 6, 2, generator=g, dtype=torch.float64) * 6.0
    w = torch.tensor([0.5, 1.0, 1.0, 2.0, 1.0, 0.1], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p: landmark_reprojection_loss(p, target, cam, w, robust, 5.0), (pts,))
    # finite gradient at an exact fit (no sqrt(0) derivative)
    exact = pts.detach().clone().requires_grad_(True)
    landmark_reprojection_loss(exact, project_points(exact.detach(), cam), cam, w, robust).sum().backward()
    assert torch.isfinite(exact.grad).all()


def test_bad_arguments_raise():
    pts, cam, _ = _setup()
    target = project_points(pts, cam)
    with pytest.raises(ShapeError, match="points3d"):
        landmark_reprojection_loss(pts[..., :2], target, cam)
    with pytest.raises(ShapeError, match="landmarks2d"):
        landmark_reprojection_loss(pts, target[:, :60], cam)
    with pytest.raises(ShapeError, match="weights"):
        landmark_reprojection_loss(pts, target, cam, weights=torch.ones(5))
    with pytest.raises(ShapeError, match="default weights"):
        landmark_reprojection_loss(pts[:, :5], target[:, :5], cam)
    with pytest.raises(ValueError, match="robust"):
        landmark_reprojection_loss(pts, target, cam, robust="cauchy")
    with pytest.raises(ShapeError, match="project_points"):
        project_points(pts[0], cam)


def test_detector_weights_follow_the_measured_errors():
    """Inverse variance of dlib's measured errors (benchmarks/results/landmark_offsets.json), symmetric, within
    [0.05, 1]."""
    import json
    from pathlib import Path

    from landmarks.ibug68.names import IBUG68_MIRROR
    from landmarks.loss import DETECTOR_ERROR_PX, DETECTOR_REFERENCE_PX, detector_landmark_weights

    results = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
    table = json.loads((results / "landmark_offsets.json").read_text())
    measured = [lm["error"] for lm in table["corrected"]["landmarks"]]
    assert len(DETECTOR_ERROR_PX) == 68
    np.testing.assert_allclose(DETECTOR_ERROR_PX, measured, atol=0.006)
    w = detector_landmark_weights(torch.float64).numpy()
    np.testing.assert_allclose(w, w[list(IBUG68_MIRROR)])
    assert w.min() >= 0.05 and w.max() <= 1.0
    # the nose tip (30) counts fully, the jaw's ends and the brows far less
    assert w[30] == 1.0 and w[0] < 0.1 and w[19] < 0.25
    e = 0.5 * (np.array(DETECTOR_ERROR_PX) + np.array(DETECTOR_ERROR_PX)[list(IBUG68_MIRROR)])
    free = (w > 0.05) & (w < 1.0)
    np.testing.assert_allclose(w[free], (DETECTOR_REFERENCE_PX / e[free]) ** 2)


def test_landmark_weights_of_both_weightings():
    from landmarks.ibug68.names import CHIN, JAW_CONTOUR
    from landmarks.loss import CONTOUR_WEIGHT, detector_landmark_weights, landmark_weights

    contour = [i for i in JAW_CONTOUR if i != CHIN]
    inner = [i for i in range(68) if i not in JAW_CONTOUR]
    w = landmark_weights("contour", 0.2, torch.float64)
    assert (w[inner] == 1).all() and (w[contour] == 0.2).all() and w[CHIN] == CONTOUR_WEIGHT
    d = landmark_weights("detector", 0.0, torch.float64)
    ref = detector_landmark_weights(torch.float64)
    assert (d[contour] == 0).all() and d[CHIN] == ref[CHIN] and torch.equal(d[inner], ref[inner])
    torch.testing.assert_close(landmark_weights("detector", CONTOUR_WEIGHT, torch.float64), ref)
    with pytest.raises(ValueError, match="weighting"):
        landmark_weights("uniform")
    with pytest.raises(ValueError, match="contour_weight"):
        landmark_weights("contour", -1.0)
