"""Tests of pipeline/track: the per-frame solve against a known head (a minimum of the fits' shared terms, a
known pose and expression recovered), the bridging of lost frames, the clip reader's refusals."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.track.solver import FrameModel, FrameState, TrackSettings, solve_frame
from rig.geometry import head_rotation


@pytest.fixture(scope="module")
def model():
    from landmarks.mediapipe.layout import mediapipe_layout
    from rig.model import JointRig
    from rig.parameters import NUM_PARAMETERS

    rig = JointRig(dtype=torch.float64)
    return FrameModel(rig, np.zeros(NUM_PARAMETERS), None, mediapipe_layout(rig.asset), 900.0, (640, 480))


def _truth(seed: int) -> FrameState:
    """A turned head with 8 random coefficients (not the gaze's: eyeLookIn and eyeLookOut together move the
    iris both ways at once, which no face does and no fit can undo)."""
    from rig.expressions import EXPRESSION_NAMES

    rng = np.random.default_rng(seed)
    c = np.zeros(52)
    allowed = [i for i, n in enumerate(EXPRESSION_NAMES) if not n.startswith("eyeLook")]
    picked = rng.choice(allowed, 8, replace=False)
    c[picked] = rng.uniform(0.2, 0.8, 8)
    return FrameState(head_rotation(15.0, -8.0, 4.0), np.array([10.0, -5.0, 650.0]), c)


def test_points_agree_with_the_rig_and_expression_model(model):
    """The precomputed affine skinning gives the landmarks the rig itself gives (template, 52 shapes with the
    jaw hinge, skinned) to 1e-9 mm."""
    from landmarks.ibug68.positions import landmark_positions
    from rig.expressions import ExpressionModel
    from rig.model import JointRig

    rig = JointRig(dtype=torch.float64)
    c = _truth(1).coefficients
    expr = ExpressionModel(rig.asset, dtype=torch.float64)
    with torch.no_grad():
        rest = expr.vertices(torch.as_tensor(c)[None])[0]
        theta = torch.zeros(1, rig.num_parameters, dtype=torch.float64)
        posed = rig(theta, vertices=rest).vertices[0].numpy()
    expected = landmark_positions(posed, model.layout.embedding, rig.asset.faces)[0]
    np.testing.assert_allclose(model.points(c), np.asarray(expected), atol=1e-9)


def test_batched_points_agree_with_the_single_ones(model):
    """The batched torch form the solver's terms read equals :meth:`FrameModel.points` (the jaw's hinge
    included), row by row."""
    rows = np.stack([_truth(s).coefficients for s in (2, 3)])
    rows[0, 24] = 0.4  # the jaw
    batch = model.points_batch(torch.as_tensor(rows)).numpy()
    for k in range(2):
        np.testing.assert_allclose(batch[k], model.points(rows[k]), atol=1e-10)


def test_the_frame_fit_is_a_minimum_of_the_shared_terms(model):
    """The track's frame fit minimises the sum of its terms' values (the fits' Term objects, the photo fit's
    landmark term among them): with every term on (two frames before), no small move of the unknowns off
    their limits lowers that sum, and the landmark term is the photo fit's definition."""
    from pipeline.fitting.landmark_term import landmark_pixel_term
    from pipeline.fitting.terms import Term
    from pipeline.track.solver import FrameProblem, frame_terms

    truth = _truth(4)
    model.pick_contour(truth)
    rng = np.random.default_rng(5)
    observed = model.landmarks_px(truth) + rng.normal(0, 0.5, (478, 2))
    weights = model.layout.weights("detector", 1.0, torch.float64).numpy()
    before = FrameState(head_rotation(13.0, -7.0, 4.0), truth.translation - [2.0, 0.0, 3.0], truth.coefficients * 0.9)
    before2 = FrameState(head_rotation(11.0, -6.0, 4.0), truth.translation - [4.0, 0.0, 6.0], truth.coefficients * 0.8)
    settings = TrackSettings(iterations=40, lambda_pose_velocity=0.01)
    state, _ = solve_frame(model, observed, weights, before, (before, before2), settings)
    terms = frame_terms(observed, weights, (before, before2), settings)
    assert all(isinstance(t, Term) for t in terms) and len(terms) == 7
    assert type(terms[0]) is type(landmark_pixel_term(torch.zeros(478, 2), torch.ones(478), 1.0))

    problem = FrameProblem(model, state, before)
    x0 = problem.start.clone()

    def total(x: torch.Tensor) -> float:
        p = problem.inputs(x[None])
        return float(sum(t.value(p)[0] for t in terms))

    best = total(x0)
    free = (x0 > problem.low + 1e-6) & (x0 < problem.high - 1e-6)
    scale = torch.ones(58, dtype=torch.float64)
    scale[:3] = 1e-3  # rad
    scale[6:] = 0.01
    for _ in range(20):
        dx = torch.as_tensor(rng.normal(0, 1, 58)) * scale * free
        assert total(x0 + dx) >= best - 1e-6 * max(best, 1.0)


def test_a_known_pose_and_expression_are_recovered(model):
    """From the rest pose and no expression, a turned, expressive head's exact points (0.3 px noise), the
    coefficients' prior all but off (it pulls them towards 0 by design): rotation within 0.5 degree,
    translation within 2 mm, coefficients within 0.03 mean."""
    truth = _truth(0)
    model.pick_contour(truth)
    rng = np.random.default_rng(3)
    observed = model.landmarks_px(truth) + rng.normal(0, 0.3, (478, 2))
    weights = model.layout.weights("detector", 1.0, torch.float64).numpy()
    start = FrameState(np.eye(3), np.array([0.0, 0.0, 600.0]))
    model.pick_contour(start)
    settings = TrackSettings(iterations=25, lambda_expressions=1e-4, lambda_gaze=1e-4, lambda_sparse=0.0)
    state, info = solve_frame(model, observed, weights, start, settings=settings)
    angle = np.degrees(np.arccos(np.clip((np.trace(state.rotation @ truth.rotation.T) - 1) / 2, -1, 1)))
    assert angle < 0.5, angle
    assert np.abs(state.translation - truth.translation).max() < 2.0
    assert np.abs(state.coefficients - truth.coefficients).mean() < 0.03
    assert info["rms_px"] < 1.0


def _frames(model, truths, noise_px, seed):
    """Each truth's points with independent noise, fitted alone (no temporal terms; a weak coefficients'
    prior, so that what is measured is the smoothing, not the prior's pull): states and information."""
    weights = model.layout.weights("detector", 1.0, torch.float64).numpy()
    rng = np.random.default_rng(seed)
    states, information = [], []
    for truth in truths:
        model.pick_contour(truth)
        observed = model.landmarks_px(truth) + rng.normal(0, noise_px, (478, 2))
        settings = TrackSettings(iterations=6, lambda_expressions=0.25, lambda_gaze=0.01, lambda_sparse=0.0)
        state, info = solve_frame(model, observed, weights, truth, settings=settings)
        states.append(state)
        information.append(info["information"])
    return states, np.stack(information)


def _smoothed(model, states, information):
    from pipeline.track.smooth import SmoothSettings, smooth_run

    return smooth_run(
        np.stack([s.rotation for s in states]),
        np.stack([s.translation for s in states]),
        np.stack([s.coefficients for s in states]),
        information,
        SmoothSettings(),
        model.low,
        model.high,
    )


def _second_difference_rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean((values[2:] - 2 * values[1:-1] + values[:-2]) ** 2)))


def test_smoothing_holds_a_still_head_still(model):
    """One head seen in 40 frames with independent 1 px noise: smoothed, the coefficients' and the
    translation's second differences are at most a third of the frames fitted alone, and the coefficients
    are no further from the truth (within 0.002: the prior's pull towards 0 is the same in both)."""
    truth = _truth(5)
    states, information = _frames(model, [truth] * 40, 1.0, 4)
    _, t, c = _smoothed(model, states, information)
    alone_c = np.stack([s.coefficients for s in states])
    alone_t = np.stack([s.translation for s in states])
    assert _second_difference_rms(c) < _second_difference_rms(alone_c) / 3
    assert _second_difference_rms(t) < _second_difference_rms(alone_t) / 3
    assert np.abs(c - truth.coefficients).mean() <= np.abs(alone_c - truth.coefficients).mean() + 0.002


def test_smoothing_follows_a_steady_motion_without_lag(model):
    """The jaw opening steadily (0 to 0.6 over 30 frames) while the head turns 1 degree a frame: the smoothed
    track is centred on the frames' own results (a causal filter would trail them: negative on the way up),
    within 0.1 of the true jaw and 1 degree of the true yaw."""
    from rig.expressions import JAW_INDEX
    from rig.geometry import head_angles

    base = _truth(6)
    truths = []
    for k in range(30):
        c = base.coefficients.copy()
        c[JAW_INDEX] = 0.6 * k / 29
        truths.append(FrameState(head_rotation(-10.0 + k, -5.0, 2.0), base.translation, c))
    states, information = _frames(model, truths, 0.5, 7)
    r, _, c = _smoothed(model, states, information)
    alone = np.array([s.coefficients[JAW_INDEX] for s in states])
    lag = c[:, JAW_INDEX] - alone
    assert abs(lag[3:-3].mean()) < 0.01, lag
    jaw_error = c[:, JAW_INDEX] - np.array([t.coefficients[JAW_INDEX] for t in truths])
    assert np.abs(jaw_error).max() < 0.1, jaw_error
    yaw = np.array([head_angles(a)[0] for a in r])
    yaw_alone = np.array([head_angles(s.rotation)[0] for s in states])
    yaw_true = np.array([head_angles(t.rotation)[0] for t in truths])
    assert abs((yaw - yaw_alone)[3:-3].mean()) < 0.1 and np.abs(yaw - yaw_true).max() < 1.0


def test_bridge_interpolates_between_and_holds_at_the_ends():
    from pipeline.track.tracker import bridge

    n = 6
    rotations = np.stack([head_rotation(10.0 * k, 0.0, 0.0) for k in range(n)])
    translations = np.arange(n, dtype=float)[:, None] * np.ones(3)
    coefficients = np.arange(n, dtype=float)[:, None] * np.ones(52) / 10
    observed = np.array([False, True, False, False, True, False])
    r, t, c = rotations.copy(), translations.copy(), coefficients.copy()
    bridge(r, t, c, observed)
    np.testing.assert_allclose(t[2], translations[1] + (translations[4] - translations[1]) / 3)
    np.testing.assert_allclose(c[3], coefficients[1] + 2 * (coefficients[4] - coefficients[1]) / 3)
    np.testing.assert_allclose(r[2], head_rotation(20.0, 0.0, 0.0), atol=1e-9)  # slerp of 10 -> 40 degrees
    np.testing.assert_allclose(t[0], translations[1])
    np.testing.assert_allclose(c[5], coefficients[4])


def test_the_sparse_prior_keeps_unused_coefficients_at_zero(model):
    """A head with 8 coefficients moved, 0.5 px noise: the L1 prior (lambda_sparse) leaves more of the other 44 at
    exactly 0 than the squares alone, and holds the moved ones back less than squares of the same strength."""
    truth = _truth(8)
    model.pick_contour(truth)
    rng = np.random.default_rng(9)
    observed = model.landmarks_px(truth) + rng.normal(0, 0.5, (478, 2))
    weights = model.layout.weights("detector", 1.0, torch.float64).numpy()
    moved = truth.coefficients > 0
    results = {}
    for name, settings in {
        "squares": TrackSettings(iterations=20, lambda_expressions=3.0, lambda_sparse=0.0),
        "sparse": TrackSettings(iterations=20, lambda_expressions=1.0, lambda_sparse=0.5),
    }.items():
        state, _ = solve_frame(model, observed, weights, truth, settings=settings)
        results[name] = state.coefficients
    zeros = {k: int((v[~moved] == 0).sum()) for k, v in results.items()}
    shrink = {k: float((truth.coefficients - v)[moved].mean()) for k, v in results.items()}
    assert zeros["sparse"] > zeros["squares"], zeros
    assert shrink["sparse"] < shrink["squares"], shrink


def test_keyframes_are_the_most_different_poses():
    """Poses chosen by the nose's offset from the eyes: the frontal frame first, then the extremes; without
    points, evenly in time; unobserved frames are never chosen."""
    from pipeline.track.tracker import EYE_CORNERS, NOSE_TIP, choose_keyframes

    count = 40
    landmarks = np.zeros((count, 478, 2), np.float32)
    turn = np.sin(np.linspace(0, 2 * np.pi, count))  # left and right once
    landmarks[:, EYE_CORNERS[0]] = [-30.0, 0.0]
    landmarks[:, EYE_CORNERS[1]] = [30.0, 0.0]
    landmarks[:, NOSE_TIP, 0] = 20.0 * turn
    landmarks[:, NOSE_TIP, 1] = 30.0
    observed = np.ones(count, bool)
    observed[10] = False  # the largest turn one way is not seen: the next largest is taken
    chosen = choose_keyframes(observed, 3, landmarks)
    assert 10 not in chosen and len(chosen) == 3
    assert {int(np.argmin(turn)), int(np.argmax(np.where(observed, turn, -9)))} <= set(chosen)
    assert choose_keyframes(observed, 3) == [0, 20, 39]
