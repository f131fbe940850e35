"""The identity regressor (issue 37): the points' normalisation, the ridge map against a known linear one, the
conditional prior in the landmark fit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from pipeline.fitting import identity_regression as ir
from pipeline.fitting.identity import IdentityPrior
from pipeline.fitting.identity_regression import (
    IdentityRegressor,
    fit_identity_regressor,
    load_identity_regressor,
    normalise_points,
    procrustes_mean,
    regression_features,
)
from rig.asset import AssetError
from rig.errors import InputError
from rig.lbs import ShapeError


def _similar(points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``points (N, 3)`` under a random rotation, scale (0.5-3) and shift."""
    r = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
    return rng.uniform(0.5, 3.0) * points @ r.T + rng.normal(0, 50, 3)


def test_normalised_points_do_not_depend_on_position_size_and_rotation():
    rng = np.random.default_rng(0)
    shape = rng.normal(size=(40, 3))
    reference = normalise_points(shape)
    assert np.allclose(reference.mean(0), 0) and np.isclose(np.sqrt((reference**2).sum(1).mean()), 1)
    moved = np.stack([_similar(shape, rng) for _ in range(5)])
    assert np.allclose(normalise_points(moved, reference), reference, atol=1e-9)
    mirrored = shape * np.array([-1.0, 1.0, 1.0])  # a reflection is not undone (proper rotations only)
    assert not np.allclose(normalise_points(mirrored, reference), reference, atol=1e-3)


def test_bad_points_are_refused():
    with pytest.raises(ShapeError):
        normalise_points(np.zeros((10, 2)))
    with pytest.raises(InputError, match="finite"):
        normalise_points(np.full((10, 3), np.nan))
    with pytest.raises(InputError, match="extent"):
        normalise_points(np.ones((10, 3)))


def test_procrustes_mean_recovers_the_shape_of_randomly_placed_copies():
    rng = np.random.default_rng(1)
    shape = rng.normal(size=(30, 3))
    copies = np.stack([_similar(shape + rng.normal(0, 0.01, shape.shape), rng) for _ in range(20)])
    mean = procrustes_mean(copies)
    assert np.abs(normalise_points(shape, mean) - mean).max() < 0.01


def _linear_population(rng, n: int, p: int = 6, points: int = 25, noise: float = 0.0):
    """Point sets that are a base shape plus ``p`` known deformation fields driven by ``u (n, p)``, each placed
    at random; the truth is ``u``."""
    base = rng.normal(size=(points, 3))
    fields = rng.normal(scale=0.05, size=(p, points, 3))
    u = rng.normal(size=(n, p))
    sets = base + np.einsum("np,pkd->nkd", u, fields) + rng.normal(0, noise, (n, points, 3))
    return np.stack([_similar(s, rng) for s in sets]), u


def test_the_regression_recovers_a_known_linear_map_on_unseen_point_sets():
    rng = np.random.default_rng(2)
    points, u = _linear_population(rng, 400, noise=0.002)
    span = np.full(u.shape[1], 2.0)  # theta = u * span
    reg = fit_identity_regressor(points[:300], u[:300] * span, span, components=(2, 4))
    pred = reg.predict(points[300:]) / span
    err = np.sqrt(((pred - u[300:]) ** 2).mean())
    assert err < 0.1 * u.std(), err  # the truth is read through the random placements
    assert reg.meta["cv_explained"] > 0.95
    one = reg.predict(points[300])
    assert one.shape == (6,) and np.allclose(one, pred[0] * span)
    # the conditional prior is centred on the prediction, and its residual spread is the regression's
    prior = reg.prior(points[300])
    assert np.allclose(prior.mean, pred[0])
    truth, other = u[300] * span, u[301] * span
    assert prior.log_likelihood(truth[None])[0] > prior.log_likelihood(other[None])[0]
    resid = pred - u[300:]
    spread = np.sqrt(prior.variances.sum() + prior.noise * (6 - prior.rank))
    assert 0.5 < spread / np.sqrt((resid**2).sum(1).mean()) < 2.0  # the cross-validated residuals' size


def test_the_residual_gaussian_adds_the_targets_own_error():
    rng = np.random.default_rng(3)
    points, u = _linear_population(rng, 200, noise=0.002)
    span = np.ones(u.shape[1])
    plain = fit_identity_regressor(points, u, span, components=(2, 4))
    extra = rng.normal(0, 0.5, (100, u.shape[1]))
    wider = fit_identity_regressor(points, u, span, components=(2, 4), extra_residuals=extra)
    total = lambda r: r.residual.variances.sum() + r.residual.noise * (u.shape[1] - r.residual.rank)  # noqa: E731
    assert total(wider) > total(plain) + 0.5 * u.shape[1] * 0.25


def _symmetric_population(rng, n: int, pairs: int = 12, midline: int = 6, q: int = 3, m: int = 2, noise=0.002):
    """Mirror-symmetric point sets (x across the face: ``pairs`` points and their reflections, ``midline`` points
    at x = 0) deformed by ``q`` one-sided fields, their ``q`` mirror images and ``m`` symmetric fields, driven by
    ``u (n, 2 q + m)``; each set placed at random. Returns the sets, ``u``, the true partner of every point, and
    the mirror map of ``u`` (the one-sided channels swapped with their mirror images')."""
    left = rng.normal(size=(pairs, 3)) + np.array([1.5, 0, 0])
    mid = rng.normal(size=(midline, 3)) * np.array([0.0, 1, 1])
    base = np.concatenate([left, left * [-1, 1, 1], mid])
    perm = np.concatenate([np.arange(pairs, 2 * pairs), np.arange(pairs), 2 * pairs + np.arange(midline)])
    flip = lambda f: (f * np.array([-1.0, 1, 1]))[..., perm, :]  # noqa: E731
    one_sided = rng.normal(scale=0.05, size=(q, len(base), 3))
    sym = rng.normal(scale=0.05, size=(m, len(base), 3))
    fields = np.concatenate([one_sided, flip(one_sided), (sym + flip(sym)) / 2])
    u = rng.normal(size=(n, 2 * q + m))
    sets = base + np.einsum("np,pkd->nkd", u, fields) + rng.normal(0, noise, (n, len(base), 3))
    swap = np.concatenate([np.arange(q, 2 * q), np.arange(q), 2 * q + np.arange(m)])
    return np.stack([_similar(s, rng) for s in sets]), u, perm, lambda t: t[..., swap]


def test_mirror_partners_are_found_in_any_placement_and_refused_without_symmetry():
    rng = np.random.default_rng(7)
    points, _, perm, _ = _symmetric_population(rng, 1, q=0, noise=0.0)  # symmetric fields only
    assert np.array_equal(ir.mirror_permutation(points[0]), perm)
    shuffle = rng.permutation(len(perm))  # the same shape, its points in another order
    found = ir.mirror_permutation(points[0][shuffle])
    assert np.array_equal(shuffle[found], perm[shuffle])
    mirrored = ir.mirror_points(points[0], perm)
    assert np.allclose(normalise_points(mirrored, normalise_points(points[0])), normalise_points(points[0]), atol=1e-9)
    with pytest.raises(InputError, match="not mirror symmetric"):
        ir.mirror_permutation(rng.normal(size=(30, 3)))


def test_the_symmetric_reference_is_its_own_mirror_image_about_the_x_axis():
    rng = np.random.default_rng(9)
    points, _, perm, _ = _symmetric_population(rng, 1, q=1, noise=0.003)  # one-sided fields: nearly symmetric
    reference = ir.symmetric_reference(points[0], perm)  # placed at random: turned, scaled and shifted
    assert np.allclose(ir.mirror_points(reference, perm), reference, atol=1e-12)
    assert np.allclose(reference.mean(0), 0.0, atol=1e-12) and np.isclose(np.sqrt((reference**2).sum(-1).mean()), 1.0)
    # the same shape as the set itself, nearer to it than its own mirror image is (about half its asymmetry)
    own = normalise_points(points[0])
    asymmetry = np.abs(normalise_points(ir.mirror_points(own, perm), own) - own).max()
    assert np.abs(normalise_points(points[0], reference) - reference).max() < 0.75 * asymmetry
    with pytest.raises(ShapeError, match="symmetric_reference"):
        ir.symmetric_reference(points[0], perm[:-1])


def test_learning_from_mirror_images_gives_an_equivariant_and_better_map():
    rng = np.random.default_rng(8)
    points, u, perm, mirror_u = _symmetric_population(rng, 215, noise=0.01)
    span = np.full(u.shape[1], 2.0)
    train, test = slice(0, 15), slice(15, None)  # few photos: the mirror images double them
    plain = fit_identity_regressor(points[train], u[train] * span, span, components=(2,))
    both = fit_identity_regressor(points[train], u[train] * span, span, components=(2,), mirror=mirror_u)
    assert both.meta["mirror_augmented"] and not plain.meta["mirror_augmented"]
    # a mirrored photo reads as the mirrored head
    flipped = ir.mirror_points(points[test], ir.mirror_permutation(both.reference))
    assert np.allclose(both.predict(flipped), mirror_u(both.predict(points[test])), atol=1e-6)
    assert not np.allclose(plain.predict(flipped), mirror_u(plain.predict(points[test])), atol=2e-2)
    # with the yaw interaction too: the reference is turned into its own plane of symmetry, so a mirrored face's
    # yaw is exactly the opposite (the Procrustes mean keeps a random photo's frame, here a random placement)
    turning = fit_identity_regressor(
        points[train], u[train] * span, span, components=(2,), mirror=mirror_u, yaw_interaction=True
    )
    flipped = ir.mirror_points(points[test], ir.mirror_permutation(turning.reference))
    assert np.allclose(turning.predict(flipped), mirror_u(turning.predict(points[test])), atol=1e-6)
    err = lambda r: np.sqrt(((r.predict(points[test]) / span - u[test]) ** 2).mean())  # noqa: E731
    assert err(both) < 0.85 * err(plain), (err(both), err(plain))


def _turned(points: np.ndarray, yaw: float) -> np.ndarray:
    """``points (N, 3)`` turned by ``yaw`` radians about +Y."""
    return points @ Rotation.from_rotvec([0.0, yaw, 0.0]).as_matrix().T


def test_the_yaw_feature_is_the_turn_of_the_face_and_flips_with_its_mirror_image():
    rng = np.random.default_rng(11)
    left = rng.normal(size=(12, 3)) + np.array([1.5, 0, 0])
    reference = normalise_points(np.concatenate([left, left * [-1, 1, 1], rng.normal(size=(6, 3)) * [0, 1, 1]]))
    perm = np.concatenate([np.arange(12, 24), np.arange(12), np.arange(24, 30)])  # a symmetric layout's partners
    shape = reference + rng.normal(0, 0.01, reference.shape)  # a face a little unlike the reference
    for yaw in (-0.45, 0.2, 0.5):
        f = regression_features(_turned(shape, yaw), reference, yaw_interaction=True)[0]
        x, interaction = np.split(f, 2)
        assert np.allclose(x, regression_features(_turned(shape, yaw), reference)[0])
        read = interaction @ (x - reference.ravel()) / ((x - reference.ravel()) ** 2).sum()
        assert abs(abs(read) - abs(yaw)) < 0.02, (read, yaw)
        fm = regression_features(ir.mirror_points(_turned(shape, yaw), perm), reference, yaw_interaction=True)[0]
        xm, im = np.split(fm, 2)
        assert np.isclose(im @ (xm - reference.ravel()) / ((xm - reference.ravel()) ** 2).sum(), -read, atol=0.02)


def test_the_yaw_interaction_reads_a_detector_whose_error_changes_with_the_turn():
    """Stand-in photos: the detector reports the face's deformation fields ``F u`` misread by a part that grows
    with the turn, ``F (yaw M u)`` (as MediaPipe's errors on a turned face; in the fields' own span, so no fixed
    linear map can tell it apart); a map whose weights change with the yaw reads ``u`` through it, a plain
    linear one cannot."""
    rng = np.random.default_rng(12)
    n, p, k = 700, 5, 30
    base = normalise_points(rng.normal(size=(k, 3)))
    fields = rng.normal(scale=0.03, size=(p, k, 3))
    misread = rng.normal(scale=0.5, size=(p, p))
    u = rng.normal(size=(n, p))
    yaw = rng.uniform(-0.5, 0.5, n)
    shapes = base + np.einsum("np,pkd->nkd", u + yaw[:, None] * u @ misread.T, fields)
    points = np.stack([_turned(s, y) * rng.uniform(0.5, 2) + rng.normal(0, 20, 3) for s, y in zip(shapes, yaw)])
    points += rng.normal(0, 0.001, points.shape)
    span = np.full(p, 2.0)
    train, test = slice(0, 500), slice(500, None)
    err = {}
    for interaction in (False, True):
        reg = fit_identity_regressor(points[train], u[train] * span, span, components=(2,), yaw_interaction=interaction)
        assert reg.yaw_interaction is interaction and reg.meta["yaw_interaction"] is interaction
        assert reg.weights.shape == (3 * k * (2 if interaction else 1), p)
        err[interaction] = np.sqrt(((reg.predict(points[test]) / span - u[test]) ** 2).mean())
    assert err[True] < 0.4 * err[False], err  # what is left is the misreading's second order in the yaw


@pytest.mark.parametrize("yaw_interaction", [False, True])
def test_save_and_load_give_the_same_predictions(tmp_path, monkeypatch, yaw_interaction):
    rng = np.random.default_rng(4)
    points, u = _linear_population(rng, 60, p=107)
    span = np.ones(107)
    reg = fit_identity_regressor(
        points, u, span, components=(2,), yaw_interaction=yaw_interaction, meta={"note": "test"}
    )
    reg.save(tmp_path / "r.npz")
    back = load_identity_regressor(tmp_path / "r.npz")
    assert back.meta["note"] == "test" and back.yaw_interaction is yaw_interaction
    assert np.allclose(back.predict(points[:3]), reg.predict(points[:3]), atol=1e-4)  # float32 weights
    with pytest.raises(AssetError, match="jnr train --identity-regressor"):
        load_identity_regressor(tmp_path / "missing.npz")
    small = replace(reg, weights=reg.weights[:, :5], intercept=reg.intercept[:5])
    small.save(tmp_path / "small.npz")
    with pytest.raises(AssetError, match="joint channels"):
        load_identity_regressor(tmp_path / "small.npz")


def test_the_committed_regressor_reads_mediapipe_points():
    reg = load_identity_regressor()
    assert reg.count == 478 and reg.meta["layout"] == "mediapipe"
    assert np.isfinite(reg.weights).all() and reg.meta["photos"] >= 1000


# ---------------------------------------------------------------------------------------------------------
# In the landmark fit
# ---------------------------------------------------------------------------------------------------------


def _fake_regressor(theta_true: np.ndarray, sd: float) -> IdentityRegressor:
    """A regressor that reads any 478 points as ``theta_true`` with an isotropic spread ``sd`` (in ``u``)."""
    from rig.skinning.joint_fit import parameter_span

    span = parameter_span(torch.float64).numpy()
    p = len(span)
    return IdentityRegressor(
        reference=normalise_points(np.random.default_rng(0).normal(size=(478, 3))),
        weights=np.zeros((3 * 478, p)),
        feature_mean=np.zeros(3 * 478),
        intercept=theta_true / span,
        residual=IdentityPrior(np.zeros(p), np.zeros((0, p)), np.zeros(0), sd**2, span, {}),
        meta={},
    )


def test_the_conditional_prior_pulls_the_landmark_fit_to_the_regressed_head(monkeypatch):
    """Noisy landmarks of a known head (68 points, 3 px): with a regressor that reads the true joints the fit
    ends much closer to them than with the population prior; without 3D points, or disabled, it is the
    population prior's fit exactly."""
    from pipeline.camera import make_camera
    from pipeline.fitting.identity import load_identity_prior
    from pipeline.fitting.state import PhotoState, head_vertices
    from pipeline.photo.fit_config import FitPhotoConfig
    from pipeline.photo.landmark_fit import IdentityRegressionConfig, LandmarkTerm, fit_landmarks
    from rig.expressions import ExpressionModel
    from rig.geometry import head_rotation
    from rig.model import JointRig
    from rig.parameters import theta_limits
    from rig.skinning.neural import LATENT, load_neural
    from rig.template import FACE_REGIONS

    rig = JointRig()
    neural, _ = load_neural(rig)
    rng = np.random.default_rng(5)
    low, high = (t.numpy() for t in theta_limits(torch.float64))
    theta = np.clip(load_identity_prior().sample(rng, 1)[0] * 1.5, low, high)
    rotation, translation = head_rotation(15.0, 5.0, 0.0), np.array([10.0, -5.0, 650.0])
    state = PhotoState(rig, neural, ExpressionModel(rig.asset), rotation, translation)
    state.load(theta, np.zeros(LATENT), np.zeros(state.c.shape[0]))
    term = LandmarkTerm(rig.asset, np.zeros((68, 2)), make_camera(640, 640, 1000.0, pose=False), 5.0)
    landmarks = term.project(state, state.rig_vertices()) + 3.0 * rng.standard_normal((68, 2))
    face = rig.asset.region_mask(*FACE_REGIONS)
    none = np.zeros(state.c.shape[0])
    truth = head_vertices(rig, neural, theta, np.zeros(LATENT), none)

    def identity_error(fit) -> float:
        v = head_vertices(rig, neural, fit.theta, fit.z, none)
        return float(np.linalg.norm(v[face] - truth[face], axis=1).mean())

    monkeypatch.setattr(ir, "_REGRESSOR", [_fake_regressor(theta, 0.02)])
    enabled = FitPhotoConfig().landmarks
    assert enabled.regression.enabled  # the default
    config = replace(enabled, regression=IdentityRegressionConfig(enabled=False))
    points3d = rng.normal(size=(478, 3))
    kw = dict(focal=1000.0, rig=rig, neural=neural)
    plain = fit_landmarks(landmarks, 640, 640, config=config, **kw)
    ignored = fit_landmarks(landmarks, 640, 640, config=config, points3d=points3d, **kw)  # regression off
    no_points = fit_landmarks(landmarks, 640, 640, config=enabled, **kw)
    regressed = fit_landmarks(landmarks, 640, 640, config=enabled, points3d=points3d, **kw)
    assert plain.identity is None and ignored.identity is None and no_points.identity is None
    assert np.array_equal(ignored.theta, plain.theta) and np.array_equal(no_points.theta, plain.theta)
    assert regressed.identity is not None and np.allclose(regressed.identity.mean_theta, theta)
    assert identity_error(regressed) < 0.5 * identity_error(plain), (identity_error(regressed), identity_error(plain))


def test_a_bad_regression_setting_is_refused():
    from pipeline.photo.landmark_fit import IdentityRegressionConfig

    with pytest.raises(InputError, match="lambda_identity"):
        IdentityRegressionConfig(lambda_identity=-1.0)
    with pytest.raises(InputError, match="enabled"):
        IdentityRegressionConfig(enabled="yes")


def test_several_views_share_one_conditional_prior_centred_on_their_mean():
    from types import SimpleNamespace

    from pipeline.photo.multiview import views_identity_prior

    reg = _fake_regressor(np.zeros(107), 0.05)
    a = replace(reg.prior(np.random.default_rng(0).normal(size=(478, 3))), mean=np.full(107, 0.2))
    b = replace(a, mean=np.full(107, -0.1))
    singles = [SimpleNamespace(identity=a), SimpleNamespace(identity=None), SimpleNamespace(identity=b)]
    prior = views_identity_prior(singles)
    assert np.allclose(prior.mean, 0.05) and prior.noise == a.noise and prior.meta["views"] == 2
    assert views_identity_prior([SimpleNamespace(identity=None)]) is None


def test_a_face_turned_past_the_training_yaw_keeps_the_population_prior(monkeypatch):
    from pipeline.fitting.identity_regression import IdentityRegressionConfig, conditional_identity

    monkeypatch.setattr(ir, "_REGRESSOR", [_fake_regressor(np.zeros(107), 0.05)])
    points = np.random.default_rng(0).normal(size=(478, 3))
    config = IdentityRegressionConfig()
    assert conditional_identity(config, points, 29.0) is not None and conditional_identity(config, points) is not None
    assert conditional_identity(config, points, -31.0) is None
    assert conditional_identity(replace(config, max_yaw_deg=45.0), points, -31.0) is not None
    assert conditional_identity(config, points[:468], 0.0) is None  # a 468-point mesh: not the regressor's
