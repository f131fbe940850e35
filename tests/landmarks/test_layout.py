"""Landmark layouts (:mod:`landmarks.layout`) and the dense layout's sliding contour
(:mod:`landmarks.mediapipe.contour`): the iBUG-68 layout reproduces the jaw contour it replaced, and the
contour lines pick the silhouette of a turned head."""

import numpy as np
import pytest
import torch

from landmarks.ibug68.contour import contour_landmarks
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.positions import landmark_positions
from landmarks.layout import IBUG68_CONTOUR, LayoutError, ibug68_layout
from landmarks.loss import CONTOUR_WEIGHT
from landmarks.mediapipe.contour import GRAZING, contour_lines, pick_contour
from rig.asset import load_asset
from rig.geometry import head_rotation, vertex_normals


@pytest.fixture(scope="module")
def asset():
    return load_asset()


def _camera(yaw_deg: float, distance: float = 600.0) -> np.ndarray:
    """A camera centre in rig space looking at the face from ``yaw_deg`` about +Y."""
    return head_rotation(yaw_deg, 0.0, 0.0) @ np.array([0.0, 0.0, distance])


@pytest.mark.parametrize("yaw", [-35.0, 0.0, 25.0])
def test_ibug68_layout_gives_the_old_dynamic_jaw_contour(asset, yaw):
    layout = ibug68_layout(asset)
    v = torch.as_tensor(asset.vertices, dtype=torch.float64)
    camera = _camera(yaw)
    static = landmark_positions(v, layout.embedding, asset.faces)[0]
    old = torch.cat([contour_landmarks(v, asset.faces, camera, asset), static[17:]])
    new = static.clone()
    new[torch.as_tensor(layout.contour)] = v[torch.as_tensor(layout.pick(v.numpy(), camera))]
    assert torch.equal(old, new)
    assert set(layout.contour.tolist()) == set(range(17)) - {8} and layout.pose_exclude == tuple(range(17))


def test_layout_checks_the_point_count(asset):
    layout = ibug68_layout(asset)
    assert layout.check(np.zeros((68, 2)), "f").shape == (68, 2)
    with pytest.raises(LayoutError, match="68 points"):
        layout.check(np.zeros((478, 2)), "f")
    w = layout.weights("contour", 0.25, torch.float64)
    assert w.shape == (68,) and torch.all(w[IBUG68_CONTOUR] == 0.25) and w[30] == 1.0


def test_contour_lines_pick_the_silhouette_of_a_turned_head(asset):
    # the jaw-line points of the static iBUG embedding as frontal contour points on both sides
    points = landmark_positions(asset.vertices, ibug68_embedding(asset), asset.faces)[0][[2, 4, 12, 14]]
    lines = contour_lines(asset, points)
    assert all(hi - lo >= 5 for lo, hi in lines.bounds)
    v = np.asarray(asset.vertices, np.float64)
    normals = vertex_normals(v, asset.faces)
    for yaw in (-30.0, 30.0):
        camera = _camera(yaw)
        picked = pick_contour(lines, v, camera)
        view = camera - v[picked]
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        grazing = np.abs((normals[picked] * view).sum(1))
        start_view = camera - v[lines.start]
        start_view /= np.linalg.norm(start_view, axis=1, keepdims=True)
        start_grazing = np.abs((normals[lines.start] * start_view).sum(1))
        # on the side turned away the points slide onto the silhouette; on the side turned towards the
        # camera they stay on their own skin vertex
        far = np.sign(points[:, 0]) != np.sign(camera[0])
        assert far.sum() == 2 and grazing[far].max() <= GRAZING, grazing
        assert np.all(start_grazing[far] > grazing[far])
        assert np.array_equal(picked[~far], lines.start[~far])
    # seen from the front the picks stay within a few mm of the points (on the face's frontal outline)
    front = pick_contour(lines, v, _camera(0.0))
    assert np.linalg.norm(v[front] - points, axis=1).max() < 12.0


def test_contour_lines_reject_bad_points(asset):
    with pytest.raises(ValueError, match="finite"):
        contour_lines(asset, np.array([[0.0, np.nan, 0.0]]))


def test_mediapipe_layout_has_478_points_weighted_by_scatter(asset):
    from landmarks.mediapipe.embedding import mediapipe_embedding
    from landmarks.mediapipe.layout import MIN_WEIGHT, mediapipe_layout

    layout = mediapipe_layout(asset)
    embedding = mediapipe_embedding(asset)
    assert layout.count == 478 and layout.name == "mediapipe"
    assert np.array_equal(layout.contour, np.flatnonzero(embedding.contour))
    assert layout.pose_exclude == tuple(layout.contour.tolist())
    assert layout.check(np.zeros((478, 2)), "f").shape == (478, 2)
    with pytest.raises(LayoutError, match="478 points"):
        layout.check(np.zeros((68, 2)), "f")
    w = layout.point_weights("detector", CONTOUR_WEIGHT)
    sigma = np.asarray(embedding.sigma_px)
    fixed = ~embedding.contour
    # the best placed points count fully, the most scattered least; more scatter never weighs more
    assert w[fixed].max() == 1.0 and MIN_WEIGHT <= w.min() < 0.5
    order = np.argsort(sigma[fixed])
    assert np.all(np.diff(w[fixed][order]) <= 1e-12)
    assert np.mean(w[fixed] == 1.0) == pytest.approx(0.25, abs=0.02)
    c = layout.point_weights("contour", 0.3)
    assert np.all(c[layout.contour] == 0.3) and np.all(c[fixed] == 1.0)
    with pytest.raises(ValueError, match="weighting"):
        layout.point_weights("uniform", 0.3)
    # the contour points start (seen from the front) near where the embedding puts them
    v = np.asarray(asset.vertices, np.float64)
    static = landmark_positions(v, embedding, asset.faces)[0][layout.contour]
    picked = v[layout.pick(v, _camera(0.0))]
    assert np.median(np.linalg.norm(picked - static, axis=1)) < 6.0
