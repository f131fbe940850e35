import numpy as np
import pytest
import torch

from landmarks.ibug68.contour import contour_candidates, contour_landmarks
from landmarks.ibug68.corrections import CONTOUR_ANGLES_DEG, LANDMARK_CORRECTIONS_MM
from landmarks.ibug68.domains import snap_domain_points
from landmarks.ibug68.embedding import LandmarkEmbedding, _build_embedding, ibug68_embedding
from landmarks.ibug68.names import CHIN, IBUG68_MIRROR, IBUG68_NAMES
from landmarks.ibug68.outline import _outline
from landmarks.ibug68.placement import _outer_lip_ring
from landmarks.ibug68.positions import landmark_positions
from rig.lbs import ShapeError

# Verified visually (front and side previews of the MakeHuman head, and dlib's detections on renders:
# benchmarks/bench_landmark_offsets.py) before pinning.
GOLDEN_FACES = [
    3479,
    2809,
    1163,
    1237,
    1175,
    1058,
    1272,
    993,
    1504,
    5323,
    5602,
    5389,
    5504,
    5567,
    5492,
    7134,
    7793,
    323,
    3430,
    291,
    1479,
    284,
    4624,
    5809,
    4630,
    7746,
    4662,
    170,
    169,
    2528,
    334,
    389,
    455,
    424,
    4794,
    4728,
    1649,
    1625,
    1660,
    1635,
    1629,
    3128,
    5963,
    5988,
    5952,
    5976,
    7447,
    5956,
    3287,
    601,
    604,
    589,
    4945,
    4941,
    7603,
    4959,
    4975,
    922,
    634,
    619,
    2271,
    694,
    680,
    5035,
    6598,
    5032,
    845,
    692,
]

MIDLINE = [8, 27, 28, 29, 30, 33, 51, 57, 62, 66]


@pytest.fixture(scope="module")
def emb(asset):
    return ibug68_embedding(asset)


@pytest.fixture(scope="module")
def pts(asset, emb):
    return landmark_positions(asset.vertices, emb, asset.faces)[0]


@pytest.fixture(scope="module")
def heuristic_pts(asset):
    return landmark_positions(asset.vertices, ibug68_embedding(asset, corrected=False), asset.faces)[0]


def _distance_to_loop(vertices, loop, p):
    a = vertices[np.asarray(loop)]
    b = np.roll(a, -1, axis=0)
    t = np.clip(((p - a) * (b - a)).sum(1) / ((b - a) ** 2).sum(1), 0.0, 1.0)
    return float(np.linalg.norm(a + t[:, None] * (b - a) - p, axis=1).min())


def test_golden_faces_and_shapes(emb):
    assert len(IBUG68_NAMES) == 68 == len(set(IBUG68_NAMES))
    assert isinstance(emb, LandmarkEmbedding)
    assert emb.faces.dtype == np.int64 and emb.barycentric.shape == (68, 3) and emb.barycentric.dtype == np.float64
    assert emb.faces.tolist() == GOLDEN_FACES
    assert ibug68_embedding() is ibug68_embedding()  # computed once per asset
    assert ibug68_embedding(corrected=False) is ibug68_embedding(corrected=False)
    assert ibug68_embedding(corrected=False) is not ibug68_embedding()


@pytest.mark.parametrize("corrected", [True, False])
def test_barycentric_weights_are_convex(asset, corrected):
    emb = ibug68_embedding(asset, corrected=corrected)
    assert (emb.barycentric >= 0).all()
    np.testing.assert_allclose(emb.barycentric.sum(1), 1.0, atol=1e-12)


@pytest.mark.parametrize("corrected", [True, False])
def test_mirror_pairs_are_exact_mirror_images(asset, corrected):
    pts = landmark_positions(asset.vertices, ibug68_embedding(asset, corrected=corrected), asset.faces)[0]
    assert sorted(IBUG68_MIRROR) == list(range(68))
    assert all(IBUG68_MIRROR[j] == i for i, j in enumerate(IBUG68_MIRROR))  # an involution
    np.testing.assert_allclose(pts[list(IBUG68_MIRROR)] * [-1, 1, 1], pts, atol=1e-9)
    for i, j in [(0, 16), (36, 45), (39, 42), (48, 54), (60, 64), (31, 35), (17, 26)]:
        assert IBUG68_MIRROR[i] == j
    assert [i for i, j in enumerate(IBUG68_MIRROR) if i == j] == MIDLINE
    assert (pts[MIDLINE, 0] == 0.0).all()  # exactly on the midline (on midline vertices / edges)
    # the right side's faces are the mirror images of the left side's
    emb = ibug68_embedding(asset, corrected=corrected)
    for i, j in enumerate(IBUG68_MIRROR):
        if i != j:
            assert sorted(asset.mirror[asset.faces[emb.faces[i]]].tolist()) == sorted(
                asset.faces[emb.faces[j]].tolist()
            )


def test_order_matches_ibug(pts):
    x, y = pts[:, 0], pts[:, 1]
    assert (np.diff(x[:17]) > 0).all()  # jaw: subject's right (-X) to left
    assert (np.diff(y[:9]) < 0).all() and (np.diff(y[8:17]) > 0).all()  # down to the chin and up again
    assert x[0] < 0 < x[16] and y[8] == y[:17].min()  # chin lowest
    assert (np.diff(x[17:27]) > 0).all()  # brows: right outer .. right inner, left inner .. left outer
    assert y[19] > max(y[17], y[21]) and y[24] > max(y[22], y[26])  # arched: the middle highest
    assert (np.diff(y[27:31]) < 0).all()  # nose bridge top -> tip
    assert pts[30, 2] == pts[:, 2].max()  # tip is the most forward landmark
    assert (np.diff(x[31:36]) > 0).all() and y[33] < min(y[31], y[35])  # nose base; subnasale lowest
    # right eye 36-41: 36 outer (most -X), 39 inner; upper lids above lower lids
    assert x[36] == x[36:42].min() and x[39] == x[36:42].max()
    assert x[45] == x[42:48].max() and x[42] == x[42:48].min()
    assert min(y[37], y[38]) > max(y[40], y[41]) and min(y[43], y[44]) > max(y[46], y[47])
    assert x[37] < x[38] and x[41] < x[40] and x[43] < x[44] and x[47] < x[46]
    # outer lip: 48 right corner, 49-53 upper right -> left, 54 left corner, 55-59 lower left -> right
    assert (np.diff(x[48:55]) > 0).all() and (np.diff(x[54:60]) < 0).all() and x[59] > x[48]
    assert (np.diff(x[60:65]) > 0).all() and (np.diff(x[[64, 65, 66, 67]]) < 0).all()
    assert y[51] > y[62] >= y[66] > y[57]  # outer upper above inner lips above outer lower
    assert y[50:53].min() > y[[49, 53]].max() > y[[48, 54]].max()  # the upper lip's border rises to the bow
    assert abs(x[54]) >= abs(x[64]) - 1.0  # the outer corners are not inside the inner ones
    # vertical order of the features
    assert y[17:27].min() > y[36:48].max() > y[36:48].min() > y[30] > y[48:68].max() > y[48:68].min() > y[8]


def test_each_landmark_lies_in_its_region(asset, emb, pts):
    v, f = asset.vertices, asset.faces
    face_regions = [set(np.asarray(asset.region_names)[asset.regions[f[emb.faces[k]]]]) for k in range(68)]
    for k in range(17, 27):
        assert "brows" in face_regions[k], (k, face_regions[k])
    for k in range(27, 36):
        assert "nose" in face_regions[k] or (k == 27 and face_regions[k] & {"forehead", "brows", "eyelids"}), k
    for k in range(48, 60):
        assert "lips" in face_regions[k], (k, face_regions[k])
    for k in range(17):
        assert face_regions[k] & {"cheeks", "jaw", "chin"}, (k, face_regions[k])
    assert "chin" in face_regions[CHIN]
    # eyes on the eyelid rims, the inner lip on the mouth loop
    right_eye, left_eye = sorted(range(2), key=lambda i: v[asset.eye_loops[i], 0].mean())
    for k in range(36, 48):
        loop = asset.eye_loops[right_eye if k < 42 else left_eye]
        assert _distance_to_loop(v, loop, pts[k]) < 1e-9, k
    for k in range(60, 68):
        assert _distance_to_loop(v, asset.mouth_loop, pts[k]) < 1e-9, k
    # the lips lie between the nose base and the chin, the outer lip outside the inner one
    assert pts[51, 1] > pts[62, 1] and pts[57, 1] < pts[66, 1] and pts[33, 1] > pts[51, 1] > pts[57, 1] > pts[CHIN, 1]


def test_committed_corrections_reproduce_the_embedding(asset, emb, pts, heuristic_pts):
    """Each row of the table moves the geometric placement onto a point of its surface (the fit picks
    surface points): the corrected landmark is the placement plus the row, up to the row's rounding."""
    assert LANDMARK_CORRECTIONS_MM, "the correction table is empty"
    for k, delta in LANDMARK_CORRECTIONS_MM.items():
        assert k == CHIN or 17 <= k < 68, k
        assert heuristic_pts[k, 0] >= 0.0, f"{k}: rows are for the left side and the midline only"
        assert len(delta) == 3 and all(round(d, 1) == d for d in delta), (k, delta)
        if IBUG68_MIRROR[k] == k:
            assert delta[0] == 0.0, k
        target = heuristic_pts[k] + np.asarray(delta)
        assert np.linalg.norm(pts[k] - target) < 0.1, (k, pts[k], target)  # 0.05 mm per axis of rounding
        j = IBUG68_MIRROR[k]
        np.testing.assert_allclose(pts[j], pts[k] * [-1, 1, 1], atol=1e-9)
    # landmarks without a row keep their placement (62 and 66: the mouth loop's midline vertices)
    rows = set(LANDMARK_CORRECTIONS_MM) | {IBUG68_MIRROR[k] for k in LANDMARK_CORRECTIONS_MM}
    for k in set(range(17, 68)) - rows:
        np.testing.assert_array_equal(pts[k], heuristic_pts[k])
    assert {62, 66}.isdisjoint(rows)
    # the contour angles are outline vertices' directions, in order along the outline
    outline = _outline(asset)
    assert len(CONTOUR_ANGLES_DEG) == 8 and list(CONTOUR_ANGLES_DEG) == sorted(CONTOUR_ANGLES_DEG)
    for k, angle in zip(range(16, 8, -1), CONTOUR_ANGLES_DEG):
        c = int(np.argmin(np.abs(outline.angles - angle)))
        assert abs(outline.angles[c] - angle) < 0.051
        np.testing.assert_array_equal(pts[k], asset.vertices[outline.vertex_ids[c]])
    # a pure function of the asset and the tables: rebuilt from scratch, the same faces and weights
    rebuilt = _build_embedding(asset, corrected=True)
    np.testing.assert_array_equal(rebuilt.faces, emb.faces)
    np.testing.assert_array_equal(rebuilt.barycentric, emb.barycentric)


def test_geometric_placement_sits_on_the_lip_rims_and_bow(asset, heuristic_pts):
    v, p = asset.vertices, heuristic_pts
    ring = _outer_lip_ring(asset)
    lips = asset.region_mask("lips")
    assert lips[ring].all() and len(ring) == len(asset.mouth_loop)
    for k in range(48, 60):
        assert _distance_to_loop(v, ring, p[k]) < 1e-9, k
    # 52 is the Cupid's bow peak: the highest point of the upper border left of the midline
    upper = ring[(v[ring, 1] > v[ring, 1].mean()) & (v[ring, 0] > 0)]
    assert p[52, 1] == v[upper, 1].max()
    np.testing.assert_allclose(p[[56, 63, 65], 0], p[52, 0])  # under the peak
    np.testing.assert_allclose(p[55, 0], p[53, 0])


def test_snap_domain_points(asset):
    for k in [CHIN, 22, 27, 34, 45, 54, 63]:
        q = snap_domain_points(asset, k)
        assert q.ndim == 2 and q.shape[1] == 3 and len(q) > 10
        if IBUG68_MIRROR[k] == k:
            assert (q[:, 0] == 0.0).all()
    with pytest.raises(KeyError):
        snap_domain_points(asset, 62)
    with pytest.raises(KeyError):
        snap_domain_points(asset, 17)  # right side: its left partner's domain


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


@pytest.mark.parametrize("corrected", [True, False])
def test_contour_frontal_stays_near_static_contour(asset, corrected):
    pts = landmark_positions(asset.vertices, ibug68_embedding(asset, corrected=corrected), asset.faces)[0]
    v = torch.tensor(asset.vertices)
    out = contour_landmarks(v, asset.faces, _yaw_camera(0.0), asset, corrected=corrected)
    assert out.shape == (17, 3)
    # as seen from the front (x, y), within a few mm of the static contour; the chin exactly
    assert np.linalg.norm(out[:, :2].numpy() - pts[:17, :2], axis=1).max() < 8.0
    np.testing.assert_array_equal(out[CHIN].numpy(), pts[CHIN])
    # in order down to the chin and up again (x only below the cheekbones: 0 and 1 are both on the near-
    # vertical outline by the ears, either may stick out further)
    x, y = out[:, 0].numpy(), out[:, 1].numpy()
    assert (np.diff(y[:9]) < 0).all() and (np.diff(y[8:]) > 0).all() and (np.diff(x[1:16]) > 0).all()
    cands = contour_candidates(asset, corrected=corrected)
    assert len(cands) == 17 and len(cands[CHIN]) == 0 and all(len(c) >= 5 for i, c in enumerate(cands) if i != CHIN)


def test_contour_far_side_moves_towards_visible_silhouette(asset, pts):
    v = torch.tensor(asset.vertices, requires_grad=True)
    out = contour_landmarks(v, asset.faces, _yaw_camera(30.0), asset)  # camera on the subject's left (+X)
    far = slice(1, 8)  # right side (-X) turns away from the camera
    p = out.detach().numpy()
    # far-side points come forward (towards the face) and inwards, as long as they are behind the chin's front
    static = pts[far]
    moved = static[:, 2] < pts[CHIN, 2] - 10.0
    assert moved[:3].all()
    assert (p[far][moved, 2] > static[moved, 2] + 5.0).all() and (p[far, 0] > static[:, 0] - 1.0).all()
    assert (p[far, 0] - static[:, 0])[:4].min() > 5.0  # the cheek's points (1-4) move well inwards
    # they sit near the silhouette: normals almost perpendicular to the view direction
    from rig.geometry import vertex_normals

    n = vertex_normals(asset.vertices, asset.faces)
    cam = np.array(_yaw_camera(30.0))
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


def test_contour_picks_need_only_the_support_vertices():
    """``contour_support_ids`` lists every vertex the pick reads: a mesh with only those filled in picks the same."""
    import torch as _torch

    from landmarks.ibug68.contour import contour_support_ids, contour_vertex_ids
    from rig.asset import load_asset
    from rig.geometry import head_rotation
    from rig.model import JointRig
    from rig.parameters import random_theta

    asset = load_asset()
    support = contour_support_ids(asset)
    assert 0 < len(support) < len(asset.vertices) // 2
    v = (
        JointRig(dtype=_torch.float64)(
            random_theta(_torch.Generator().manual_seed(2), 1, spread=0.4, dtype=_torch.float64)
        )
        .vertices[0]
        .numpy()
    )
    only = np.zeros_like(v)
    only[support] = v[support]
    for yaw in (-35.0, 0.0, 25.0):
        centre = head_rotation(yaw, 5.0, 0.0).T @ np.array([0.0, 0.0, 650.0])
        assert contour_vertex_ids(only, asset.faces, centre, asset) == contour_vertex_ids(v, asset.faces, centre, asset)
