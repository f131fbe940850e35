"""Tests of pipeline/camera.py and pipeline/photo/landmark_fit.py (single-photo landmark fitting)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from landmarks.ibug68.contour import contour_landmarks
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.positions import landmark_positions
from landmarks.loss import project_points
from pipeline.camera import (
    RIG_TO_OPENCV,
    camera_center_in_rig,
    default_focal,
    make_camera,
    solve_pose,
)
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.landmark_fit import LandmarkFit, fit_landmarks
from rig.expressions import ExpressionModel, coefficients_from_dict
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS, random_theta
from rig.skinning.neural import LATENT, load_neural

W, H = 640, 480


@pytest.fixture(scope="module")
def models():
    rig = JointRig()
    neural, _ = load_neural(rig)
    return rig, neural


def _head_pose(yaw_deg: float, pitch_deg: float = 0.0) -> np.ndarray:
    """Yaw about rig +Y, then pitch about rig +X."""
    return Rotation.from_euler("yx", [yaw_deg, pitch_deg], degrees=True).as_matrix()


def _rigid_aligned_error(a: np.ndarray, b: np.ndarray) -> float:
    """Mean distance (mm) between ``(N, 3)`` point sets after the best rigid alignment of ``a`` onto ``b``
    (a shape error: the head's rotation in rig space trades off against the pose from one photo)."""
    ma, mb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ma).T @ (b - mb))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rot = (u @ d @ vt).T
    return float(np.linalg.norm((a - ma) @ rot.T + mb - b, axis=1).mean())


class TestCamera:
    def test_default_focal(self):
        assert default_focal(640, 480) == pytest.approx(896.0)
        with pytest.raises(ValueError, match="width and height"):
            default_focal(0, 480)

    def test_projection_follows_pinhole_and_axis_flip(self):
        f, t = 900.0, np.array([0.0, 0.0, 600.0])
        cam = make_camera(W, H, f, translation=t, dtype=torch.float64)
        assert cam.intrinsics.shape == (1, 4, 4) and cam.extrinsics.shape == (1, 4, 4)
        assert cam.height.shape == (1,) and cam.width.shape == (1,)
        x = np.array([[20.0, 30.0, 100.0], [20.0, -30.0, 100.0], [0.0, 0.0, 0.0]])  # in front of the face
        uv = project_points(torch.as_tensor(x)[None], cam)[0].numpy()
        xc = x @ RIG_TO_OPENCV.T + t
        expected = np.stack([f * xc[:, 0] / xc[:, 2] + (W - 1) / 2, f * xc[:, 1] / xc[:, 2] + (H - 1) / 2], 1)
        np.testing.assert_allclose(uv, expected, atol=1e-9)
        assert uv[0, 1] < uv[1, 1]  # lower in rig space (y smaller) -> further down the image (v larger)
        assert uv[0, 0] > (W - 1) / 2  # rig +x (the subject's left) -> image right for a facing head

    def test_nose_is_nearer_than_ears(self, models):
        rig, _ = models
        v = rig.template.double().numpy()
        ext = make_camera(W, H, 900.0, translation=np.array([0.0, 0.0, 600.0])).extrinsics[0].double().numpy()
        depth = v @ ext[:3, :3].T[:, 2] + ext[2, 3]
        lm = landmark_positions(v, ibug68_embedding(rig.asset), rig.asset.faces)[0]
        nose_depth = lm[30] @ ext[:3, :3][2] + ext[2, 3]
        ears = rig.asset.region_mask("ears")
        assert nose_depth < depth[ears].min()

    def test_camera_center(self):
        rot, t = _head_pose(30.0), np.array([10.0, -5.0, 600.0])
        c = camera_center_in_rig(rot, t)
        ext = make_camera(W, H, 900.0, rotation=rot, translation=t).extrinsics[0].double().numpy()
        np.testing.assert_allclose(ext[:3, :3] @ c + ext[:3, 3], 0.0, atol=1e-4)
        assert c[2] > 0  # the camera is in front of the face (+Z)

    def test_solve_pose_recovers_known_pose(self, models):
        rig, _ = models
        model_points = landmark_positions(rig.template.double().numpy(), ibug68_embedding(rig.asset), rig.asset.faces)[
            0
        ]
        rot, t = _head_pose(20.0, -10.0), np.array([0.0, 0.0, 600.0])
        f = default_focal(W, H)
        cam = make_camera(W, H, f, rotation=rot, translation=t, dtype=torch.float64)
        lm = project_points(torch.as_tensor(model_points)[None], cam)[0].numpy()
        rot_fit, t_fit = solve_pose(lm, model_points, W, H, f)
        angle = np.degrees(Rotation.from_matrix(rot_fit @ rot.T).magnitude())
        assert angle < 1.0
        assert np.linalg.norm(t_fit - t) < 2.0

    def test_solve_pose_bad_input(self):
        pts3 = np.random.default_rng(0).normal(size=(68, 3)) * 30
        pts2 = np.random.default_rng(1).normal(size=(68, 2)) * 50 + 300
        with pytest.raises(ValueError, match="NaN"):
            solve_pose(np.where(np.arange(68)[:, None] == 40, np.nan, pts2), pts3, W, H, 900.0)
        with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
            solve_pose(pts2[:, :1], pts3, W, H, 900.0)
        with pytest.raises(ValueError, match="at least 6"):
            solve_pose(pts2[:20], pts3[:20], W, H, 900.0)  # 3 left outside the jaw contour


@pytest.fixture(scope="module")
def synthetic_head(models):
    """A head made by the rig itself (random joints, an expression), yaw 15 deg, its 68 landmarks
    projected at 640 x 480 with 0.5 px noise."""
    rig, neural = models
    theta = random_theta(torch.Generator().manual_seed(1), spread=0.2)
    expr = ExpressionModel(rig.asset)
    c = coefficients_from_dict({"jawOpen": 0.3, "mouthSmileLeft": 0.5})
    rot, t = _head_pose(15.0), np.array([5.0, -10.0, 600.0])
    f = default_focal(W, H)
    faces, emb = rig.asset.faces, ibug68_embedding(rig.asset)
    with torch.no_grad():
        weights = neural(torch.zeros(1, LATENT))[0]
        v = rig(theta, weights=weights, vertices=expr.template + expr(c[None])[0]).vertices[0]
        template = rig(torch.zeros(1, NUM_PARAMETERS), weights=weights).vertices[0]
        contour = contour_landmarks(v, faces, camera_center_in_rig(rot, t), rig.asset)
        lm3 = torch.cat([contour, landmark_positions(v, emb, faces)[0, 17:]])
        lm2 = project_points(lm3[None], make_camera(W, H, f, rotation=rot, translation=t))[0].double().numpy()
    noisy = lm2 + np.random.default_rng(0).normal(0.0, 0.5, lm2.shape)
    return {
        "landmarks2d": noisy,
        "truth3d": landmark_positions(v, emb, faces)[0].double().numpy(),
        "template3d": landmark_positions(template, emb, faces)[0].double().numpy(),
        "rotation": rot,
        "translation": t,
        "expressions": c.numpy(),
    }


@pytest.fixture(scope="module")
def fitted(models, synthetic_head) -> LandmarkFit:
    rig, neural = models
    return fit_landmarks(synthetic_head["landmarks2d"], W, H, rig=rig, neural=neural)


class TestFitLandmarks:
    def test_cardinality(self, fitted):
        assert fitted.theta.shape == (NUM_PARAMETERS,)
        assert fitted.z.shape == (LATENT,)
        assert fitted.expressions.shape == (52,)
        assert fitted.rotation.shape == (3, 3) and fitted.translation.shape == (3,)
        assert fitted.landmarks_px.shape == (68, 2) and fitted.error_px.shape == (68,)
        assert fitted.landmarks3d.shape == (68, 3)
        assert fitted.camera.extrinsics.shape == (1, 4, 4)
        assert "data_px2" in fitted.losses

    def test_recovers_synthetic_head(self, fitted, synthetic_head):
        print(
            f"\nfit_landmarks: {fitted.seconds:.2f} s, mean error {fitted.error_px.mean():.2f} px, NME {fitted.nme:.4f}"
        )
        assert fitted.error_px.mean() < 2.0
        assert fitted.nme < 0.02
        # the fitted camera reproduces the reported projection (for the static landmarks 17-67)
        uv = project_points(torch.as_tensor(fitted.landmarks3d)[None].float(), fitted.camera)[0].numpy()
        np.testing.assert_allclose(uv[17:], fitted.landmarks_px[17:], atol=0.05)
        truth, template = synthetic_head["truth3d"], synthetic_head["template3d"]
        err_fit = _rigid_aligned_error(fitted.landmarks3d, truth)
        err_template = _rigid_aligned_error(template, truth)
        print(f"3D landmark error after rigid alignment: fit {err_fit:.2f} mm, template {err_template:.2f} mm")
        assert err_fit < 0.5 * err_template
        angle = np.degrees(Rotation.from_matrix(fitted.rotation @ synthetic_head["rotation"].T).magnitude())
        print(f"pose: rotation off by {angle:.1f} deg, translation {fitted.translation.round(1)}")
        jaw = fitted.expressions[list(ExpressionModel().names).index("jawOpen")]
        assert jaw > 0.1  # the open mouth is taken up by the expression

    def test_bad_input(self, models):
        rig, neural = models
        lm = np.full((68, 2), 300.0)
        lm[5] = np.nan
        with pytest.raises(ValueError, match=r"rows \[5\] contain NaN"):
            fit_landmarks(lm, W, H, rig=rig, neural=neural)
        with pytest.raises(ValueError, match=r"shape \(68, 2\).*got \(5, 2\)"):
            fit_landmarks(np.zeros((5, 2)), W, H, rig=rig, neural=neural)
        with pytest.raises(ValueError, match="width and height"):
            fit_landmarks(np.zeros((68, 2)), 0, H, rig=rig, neural=neural)


def test_dense_layout_recovers_pose_identity_and_jaw(models, synthetic_head):
    """The same head seen through MediaPipe's 478-point layout (its outline re-picked on the silhouette):
    the dense fit recovers the pose within 2.5 deg, the open jaw within 0.1 and most of the shape."""
    from landmarks.mediapipe.layout import mediapipe_layout

    rig, neural = models
    layout = mediapipe_layout(rig.asset)
    theta = random_theta(torch.Generator().manual_seed(1), spread=0.2)
    expr = ExpressionModel(rig.asset)
    c = torch.as_tensor(synthetic_head["expressions"])
    rot, t = synthetic_head["rotation"], synthetic_head["translation"]
    faces = rig.asset.faces
    with torch.no_grad():
        weights = neural(torch.zeros(1, LATENT))[0]
        v = rig(theta, weights=weights, vertices=expr.template + expr(c[None].float())[0]).vertices[0].double()
        template = rig(torch.zeros(1, NUM_PARAMETERS), weights=weights).vertices[0].double()
    points = layout.points3d(v, faces, camera_center_in_rig(rot, t))
    camera = make_camera(W, H, default_focal(W, H), rotation=rot, translation=t, dtype=torch.float64)
    lm2 = project_points(points[None], camera)[0].numpy()
    lm2 = lm2 + np.random.default_rng(0).normal(0.0, 0.5, lm2.shape)
    # the points' noise stated: 0.5 px on a face ~130 px between the eyes, 0.4 px at the term's 100 px
    # (the default 3 px is MediaPipe's own error on a photo)
    config = replace(FitPhotoConfig().landmarks, dense_noise_px=0.5)
    fit = fit_landmarks(lm2, W, H, rig=rig, neural=neural, layout=layout, config=config)
    assert fit.landmarks_px.shape == (478, 2) and fit.error_px.shape == (478,)
    angle = np.degrees(Rotation.from_matrix(fit.rotation @ rot.T).magnitude())
    jaw = fit.expressions[list(expr.names).index("jawOpen")]
    fixed = np.setdiff1d(np.arange(layout.count), layout.contour)
    truth3 = landmark_positions(v, layout.embedding, faces)[0].numpy()[fixed]
    template3 = landmark_positions(template, layout.embedding, faces)[0].numpy()[fixed]
    err_fit = _rigid_aligned_error(fit.landmarks3d[fixed], truth3)
    err_template = _rigid_aligned_error(template3, truth3)
    print(
        f"\nface scale {fit.losses['face_scale']:.2f}; dense fit: pose {angle:.2f} deg, jawOpen {jaw:.3f} (0.3), "
        f"3D {err_fit:.2f} vs {err_template:.2f} mm"
    )
    assert angle < 2.5
    assert abs(jaw - 0.3) < 0.1
    assert err_fit < 0.5 * err_template


def test_lm_progress_counts_the_iterations(models, synthetic_head):
    """The LM stages report each iteration as it is done (a progress bar moves with the fit), then the stage's
    full count at its end, in order."""
    rig, neural = models
    calls = []
    fit = fit_landmarks(
        synthetic_head["landmarks2d"], W, H, rig=rig, neural=neural, progress=lambda *a: calls.append(a)
    )
    for log in fit.stages:
        mine = [(it, total) for name, it, total in calls if name == log.name]
        assert mine[-1] == (mine[-1][1], mine[-1][1])  # complete at the end
        done = [it for it, _ in mine[:-1]]
        assert done == list(range(1, len(done) + 1))  # one call per iteration done, in order
        assert len(done) >= min(log.iterations, mine[-1][1]) - 1
    assert any(len([c for c in calls if c[0] == log.name]) > 2 for log in fit.stages)
