import numpy as np
import pytest
import torch

from landmarks.ibug68 import (
    CHIN,
    IBUG68_MIRROR,
    IBUG68_NAMES,
    LandmarkEmbedding,
    contour_candidates,
    contour_landmarks,
    ibug68_embedding,
    landmark_positions,
)
from rig.lbs import ShapeError

# Verified visually (front and three-quarter previews) before pinning.
GOLDEN_FACES = [3054, 4228, 5406, 6584, 7756, 8430, 8458, 8138, 8314, 8155, 8507, 8535, 7865, 6685, 5511, 4337,
                3159, 2577, 2414, 2420, 2594, 2599, 2608, 2613, 2451, 2457, 2630, 3107, 3947, 4787, 5290, 5622,
                5792, 5626, 5799, 5633, 3250, 3254, 3260, 3266, 3429, 3423, 3285, 3291, 3297, 3301, 3464, 3458,
                7126, 6963, 6798, 6802, 6809, 6980, 7153, 7653, 7649, 7642, 7638, 7634, 6958, 6966, 6970, 6977,
                6983, 7144, 7139, 7135]


@pytest.fixture(scope="module")
def emb(asset):
    return ibug68_embedding(asset)


@pytest.fixture(scope="module")
def pts(asset, emb):
    return landmark_positions(asset.vertices, emb, asset.faces)[0]


def test_golden_faces_and_shapes(emb):
    assert len(IBUG68_NAMES) == 68 == len(set(IBUG68_NAMES))
    assert isinstance(emb, LandmarkEmbedding)
    assert emb.faces.dtype == np.int64 and emb.barycentric.shape == (68, 3) and emb.barycentric.dtype == np.float64
    assert emb.faces.tolist() == GOLDEN_FACES
    assert ibug68_embedding() is ibug68_embedding()  # computed once per asset


def test_barycentric_weights_are_convex(emb):
    assert (emb.barycentric >= 0).all()
    np.testing.assert_allclose(emb.barycentric.sum(1), 1.0, atol=1e-12)


def test_mirror_pairs_are_exact_mirror_images(pts):
    assert sorted(IBUG68_MIRROR) == list(range(68))
    assert all(IBUG68_MIRROR[j] == i for i, j in enumerate(IBUG68_MIRROR))  # an involution
    np.testing.assert_allclose(pts[list(IBUG68_MIRROR)] * [-1, 1, 1], pts, atol=1e-6)
    for i, j in [(0, 16), (36, 45), (39, 42), (48, 54), (60, 64), (31, 35), (17, 26)]:
        assert IBUG68_MIRROR[i] == j
    midline = [i for i, j in enumerate(IBUG68_MIRROR) if i == j]
    assert midline == [8, 27, 28, 29, 30, 33, 51, 57, 62, 66]
    np.testing.assert_allclose(pts[midline, 0], 0.0, atol=1e-9)


def test_order_matches_ibug(asset, pts):
    x, y = pts[:, 0], pts[:, 1]
    assert (np.diff(x[:17]) > 0).all()  # jaw: subject's right (-X) to left
    assert x[0] < 0 < x[16] and y[8] == y[:17].min()  # chin lowest
    assert (np.diff(x[17:27]) > 0).all()  # brows: right outer .. right inner, left inner .. left outer
    assert (np.diff(y[27:31]) < 0).all()  # nose bridge top -> tip
    assert pts[30, 2] == pts[:, 2].max()  # tip is the most forward landmark
    assert (np.diff(x[31:36]) > 0).all()
    # right eye 36-41: 36 outer (most -X), 39 inner; upper lids above lower lids
    assert x[36] == x[36:42].min() and x[39] == x[36:42].max()
    assert x[45] == x[42:48].max() and x[42] == x[42:48].min()
    assert min(y[37], y[38]) > max(y[40], y[41]) and min(y[43], y[44]) > max(y[46], y[47])
    assert x[37] < x[38] and x[41] < x[40] and x[43] < x[44] and x[47] < x[46]
    # outer lip: 48 right corner, 49-53 upper right -> left, 54 left corner, 55-59 lower left -> right
    assert (np.diff(x[48:55]) > 0).all() and (np.diff(x[54:60]) < 0).all() and x[59] > x[48]
    assert (np.diff(x[60:65]) > 0).all() and (np.diff(x[[64, 65, 66, 67]]) < 0).all()
    assert y[51] > y[62] >= y[66] > y[57]  # outer upper above inner lips above outer lower
    # vertical order of the features
    assert y[17:27].min() > y[36:48].max() > y[36:48].min() > y[30] > y[48:68].max() > y[48:68].min() > y[8]
    # the eye and lip corners are the template's loop corners
    eye = np.asarray(asset.eye_loops[int(np.argmax(asset.vertices[asset.eye_loops[:, 0], 0]))])
    np.testing.assert_allclose(pts[45], asset.vertices[eye[np.argmax(asset.vertices[eye, 0])]])
    mouth = np.asarray(asset.mouth_loop)
    np.testing.assert_allclose(pts[64], asset.vertices[mouth[np.argmax(asset.vertices[mouth, 0])]])


def test_landmark_positions_torch_matches_numpy_and_has_gradients(asset, emb, pts):
    v = torch.tensor(np.stack([asset.vertices, asset.vertices * 1.1]), requires_grad=True)
    out = landmark_positions(v, emb, asset.faces)
    assert out.shape == (2, 68, 3) and out.dtype == torch.float64
    np.testing.assert_allclose(out[0].detach().numpy(), pts, atol=1e-12)
    np.testing.assert_allclose(out[1].detach().numpy(), pts * 1.1, atol=1e-9)
    out.sum().backward()
    np.testing.assert_allclose(v.grad.sum(dim=(0, 1)).numpy(), [136.0] * 3)  # each landmark's weights sum to 1
    vf = torch.tensor(asset.vertices, dtype=torch.float32)
    assert landmark_positions(vf, emb, torch.as_tensor(asset.faces)).shape == (1, 68, 3)
    with pytest.raises(ShapeError, match="landmark_positions: vertices"):
        landmark_positions(np.zeros((5, 2)), emb, asset.faces)


def _yaw_camera(deg, distance=600.0):
    t = np.deg2rad(deg)
    return [distance * np.sin(t), -30.0, distance * np.cos(t)]


def test_contour_frontal_stays_near_static_contour(asset, pts):
    v = torch.tensor(asset.vertices)
    out = contour_landmarks(v, asset.faces, _yaw_camera(0.0), asset)
    assert out.shape == (17, 3)
    # as seen from the front (x, y), within a few mm of the static contour; the chin exactly
    assert np.linalg.norm(out[:, :2].numpy() - pts[:17, :2], axis=1).max() < 8.0
    np.testing.assert_array_equal(out[CHIN].numpy(), pts[CHIN])
    cands = contour_candidates(asset)
    assert len(cands) == 17 and len(cands[CHIN]) == 0 and all(len(c) >= 5 for i, c in enumerate(cands) if i != CHIN)


def test_contour_far_side_moves_towards_visible_silhouette(asset, pts):
    v = torch.tensor(asset.vertices, requires_grad=True)
    out = contour_landmarks(v, asset.faces, _yaw_camera(30.0), asset)  # camera on the subject's left (+X)
    far = slice(1, 8)  # right side (-X) turns away from the camera
    # far-side points come forward (towards the face) and inwards
    assert (out[1:7, 2].detach().numpy() > pts[1:7, 2] + 10.0).all()  # 7, by the chin, is already in front
    assert (out[far, 0].detach().numpy() > pts[far, 0]).all()
    # they sit near the silhouette: normals almost perpendicular to the view direction
    from rig.geometry import vertex_normals
    n = vertex_normals(asset.vertices, asset.faces)
    cam = np.array(_yaw_camera(30.0))
    p = out.detach().numpy()
    ids = [int(np.argmin(np.linalg.norm(asset.vertices - q, axis=1))) for q in p[far]]
    view = (cam - p[far]) / np.linalg.norm(cam - p[far], axis=1, keepdims=True)
    assert np.abs((n[ids] * view).sum(1)).max() < 0.35
    out.sum().backward()  # differentiable w.r.t. the vertices
    assert v.grad.abs().sum() > 0
    # mirror: camera on the other side moves the other half
    other = contour_landmarks(v.detach(), asset.faces, _yaw_camera(-30.0), asset).numpy()
    np.testing.assert_allclose(other[::-1][far] * [-1, 1, 1], p[far], atol=1.0)


@pytest.mark.parametrize("yaw", [-35.0, -10.0, 0.0, 20.0, 40.0])
def test_contour_pick_equals_a_naive_search(asset, yaw):
    """The picked vertex per line is the naive choice: full-mesh vertex normals, smallest positive n . view."""
    from rig.geometry import vertex_normals

    rng = np.random.default_rng(int(yaw) + 50)
    v = asset.vertices + rng.normal(0.0, 0.3, asset.vertices.shape)  # a slightly bumpy head
    cam = np.array(_yaw_camera(yaw))
    out = contour_landmarks(torch.tensor(v), asset.faces, cam, asset).numpy()
    n = vertex_normals(v, asset.faces)
    static = landmark_positions(v, ibug68_embedding(asset), asset.faces)[0]
    for k, line in enumerate(contour_candidates(asset)):
        if k == CHIN:
            np.testing.assert_array_equal(out[k], static[CHIN])
            continue
        view = (cam - v[line]) / np.linalg.norm(cam - v[line], axis=1, keepdims=True)
        facing = (n[line] * view).sum(1)
        if (facing > 0).any():
            expected = line[np.argmin(np.where(facing > 0, facing, np.inf))]
            np.testing.assert_array_equal(out[k], v[expected])


def test_contour_checks_shapes(asset):
    with pytest.raises(ShapeError, match="camera_center"):
        contour_landmarks(torch.tensor(asset.vertices), asset.faces, [0.0, 1.0], asset)
    with pytest.raises(ShapeError, match="vertices"):
        contour_landmarks(asset.vertices, asset.faces, [0.0, 0.0, 600.0], asset)
