"""rig.accessory: closest points against brute force, the transfer against fields with known values,
smoothing and pruning, posing against a naive loop and known motions, signed distance against a sphere."""

import math

import numpy as np
import pytest
import torch

from rig.accessory import (
    AccessoryError,
    channel_reach,
    contact_attenuation,
    joint_motion_distance,
    keep_largest,
    outer_skin_face_ids,
    outer_skin_faces,
    pose_accessory,
    reduce_influences,
    rigid_attachment,
    signed_distance,
    smooth_over_points,
    transfer_skinning,
)
from rig.errors import ShapeError
from rig.geometry import closest_points_on_triangles, closest_surface_points, surface_values
from rig.lbs import skin_vertices
from rig.parameters import params_to_theta


@pytest.fixture(scope="module")
def skin(asset):
    return outer_skin_faces(asset)


def _points_on_faces(asset, faces, rng, n):
    """``n`` random points inside random skin triangles, their faces and barycentric coordinates."""
    face = rng.integers(0, len(faces), n)
    bary = rng.dirichlet([2.0, 2.0, 2.0], n)
    return np.einsum("nc,ncd->nd", bary, asset.vertices[faces[face]]), face, bary


def _face_normals(vertices, faces):
    n = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_outer_skin_excludes_eyes_and_mouth(asset, skin):
    ids = outer_skin_face_ids(asset)
    np.testing.assert_array_equal(asset.faces[ids], skin)
    hidden = asset.region_mask("eyeballs", "eye_pockets", "mouth_interior", "teeth", "tongue")
    assert not hidden[skin].any() and len(skin) > 0.6 * len(asset.faces)


def test_closest_points_equal_brute_force(asset, skin, rng):
    v = asset.vertices
    points = np.concatenate(
        [
            rng.uniform(-120, 120, (40, 3)) + [0, 0, 20],  # around and inside the head
            _points_on_faces(asset, skin, rng, 20)[0] + rng.normal(0, 3, (20, 3)),
        ]
    )
    found = closest_surface_points(points, v, skin, k=2)  # k = 2: most points need the widening passes
    for p, d, q in zip(points, found.distance, found.closest):
        all_q = closest_points_on_triangles(p[None], v[skin[:, 0]], v[skin[:, 1]], v[skin[:, 2]])
        best = np.sqrt(((all_q - p) ** 2).sum(-1)).min()
        assert d == pytest.approx(best, abs=1e-9)
        assert np.linalg.norm(q - p) == pytest.approx(d, abs=1e-9)
    corners = v[skin[found.face]]
    np.testing.assert_allclose(np.einsum("nc,ncd->nd", found.barycentric, corners), found.closest, atol=1e-8)


def test_vertex_on_the_surface_gets_exactly_the_interpolated_weights_and_offsets(asset, skin, rng):
    points, face, bary = _points_on_faces(asset, skin, rng, 50)
    weights = rng.dirichlet(np.ones(6), len(asset.vertices))
    targets = rng.normal(0, 2, (3, len(asset.vertices), 3))
    out = transfer_skinning(asset.vertices, skin, weights, targets, points, smoothing_mm=0.0, max_influences=None)
    assert out.distance.max() < 1e-9
    corners = skin[face]
    np.testing.assert_allclose(out.weights, np.einsum("nc,ncj->nj", bary, weights[corners]), atol=1e-9)
    np.testing.assert_allclose(out.morph_targets, np.einsum("nc,encd->end", bary, targets[:, corners]), atol=1e-9)


def test_transfer_of_a_linear_field_off_the_surface(asset, skin, rng):
    """Weights linear in position: the transfer of a point lifted along its face's normal is the field at the
    point it was lifted from (known truth, independent of the barycentric code)."""
    scalp = asset.region_mask("scalp")
    top = np.flatnonzero(scalp[skin].all(1) & (asset.vertices[skin].mean(1)[:, 1] > 80))  # convex crown faces
    face = rng.choice(top, 30, replace=False)
    bary = rng.dirichlet([3.0, 3.0, 3.0], 30)
    base = np.einsum("nc,ncd->nd", bary, asset.vertices[skin[face]])
    lifted = base + 2.0 * _face_normals(asset.vertices, skin[face])
    y = asset.vertices[:, 1]
    t = (y - y.min()) / np.ptp(y)
    weights = np.stack([t, 1.0 - t], 1)
    out = transfer_skinning(asset.vertices, skin, weights, None, lifted, smoothing_mm=0.0)
    tb = (base[:, 1] - y.min()) / np.ptp(y)
    np.testing.assert_allclose(out.weights, np.stack([tb, 1.0 - tb], 1), atol=1e-9)
    np.testing.assert_allclose(out.distance, 2.0, atol=1e-9)
    assert out.morph_targets.shape == (0, 30, 3)


def test_contact_attenuation_of_the_expression_offsets(asset, skin, rng):
    scalp = asset.region_mask("scalp")
    top = np.flatnonzero(scalp[skin].all(1) & (asset.vertices[skin].mean(1)[:, 1] > 90))
    face = rng.choice(top, 4, replace=False)
    base = asset.vertices[skin[face]].mean(1)
    normal = _face_normals(asset.vertices, skin[face])
    heights = np.array([0.0, 4.0, 7.5, 12.0])
    points = base + heights[:, None] * normal
    targets = np.tile([[0.0, 3.0, 0.0]], (2, len(asset.vertices), 1))
    out = transfer_skinning(asset.vertices, skin, asset.weights, targets, points, falloff_mm=10.0, smoothing_mm=0.0)
    np.testing.assert_allclose(out.morph_targets[:, :, 1], np.tile([3.0, 3.0, 1.5, 0.0], (2, 1)), atol=1e-9)
    np.testing.assert_allclose(
        contact_attenuation(np.array([0.0, 5.0, 6.0, 9.0, 10.0]), 10.0),
        [1.0, 1.0, 1 - (0.2**2 * (3 - 0.4)), 1 - (0.8**2 * (3 - 1.6)), 0.0],
    )
    assert (contact_attenuation(np.array([0.0, 3.0]), 0.0) == 0).all()


def test_smoothing_against_a_naive_loop(rng):
    x = rng.uniform(0, 40, (60, 3))
    values = rng.dirichlet(np.ones(5), 60)
    sigma = 6.0
    out = smooth_over_points(x, values, sigma)
    for i in range(len(x)):
        d = np.linalg.norm(x - x[i], axis=1)
        g = np.where(d <= 3 * sigma, np.exp(-0.5 * (d / sigma) ** 2), 0.0)
        np.testing.assert_allclose(out[i], g @ values / g.sum(), atol=1e-12)
    np.testing.assert_allclose(out.sum(1), 1.0)
    np.testing.assert_array_equal(smooth_over_points(x, values, 0.0), values)
    np.testing.assert_allclose(smooth_over_points(x, values, math.inf), np.tile(values.mean(0), (60, 1)))


def test_keep_largest_is_continuous_and_keeps_sparse_rows(rng):
    sparse = np.array([[0.5, 0.3, 0.2, 0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(keep_largest(sparse, 4), sparse)
    row = np.array([[0.4, 0.2, 0.15, 0.125 + 1e-7, 0.125 - 1e-7, 0.0]])
    swapped = row.copy()
    swapped[0, 3:5] = row[0, [4, 3]]  # the 4th and 5th change places
    a, b = keep_largest(row, 4), keep_largest(swapped, 4)
    assert (a > 0).sum() == 4 and np.abs(a - b).max() < 1e-5  # hard pruning would jump by 0.12
    w = keep_largest(rng.dirichlet(np.ones(10), 100), 4)
    assert ((w > 0).sum(1) <= 4).all() and np.allclose(w.sum(1), 1.0)


def test_joint_motion_distance_follows_the_tree(asset):
    reach = channel_reach(52)
    d = joint_motion_distance(asset.parents, reach)
    n = asset.joint_names.index
    assert reach[n("crown")] == 40.0 and reach[n("left_crown_outer")] == 3.0 and reach[n("ears")] == 0.0
    assert d[n("crown"), n("left_crown_outer")] == 3.0 and d[n("crown"), n("cranium")] == 40.0
    assert d[n("ears"), n("skull_root")] == 0.0  # a joint without channels moves as its parent
    assert d[n("left_ear_position"), n("right_ear_position")] == 48.0
    np.testing.assert_array_equal(d, d.T)
    for a, b, c in np.random.default_rng(0).integers(0, 52, (200, 3)):
        assert d[a, c] <= d[a, b] + d[b, c] + 1e-9  # a path metric


def test_reduce_influences_moves_weight_to_the_joint_that_moves_alike(asset, rig64):
    """Known truth: ``ears`` has no channels, so weight moved from it to ``skull_root`` poses the same; what the
    floor (5 %) shares among the other kept joints moves the point 0.08 mm here, renormalising 0.87 mm."""
    d = joint_motion_distance(asset.parents, channel_reach(52))
    n = asset.joint_names.index
    row = np.zeros((1, 52))
    row[0, [n("skull_root"), n("crown"), n("left_eye_socket"), n("nose_tip"), n("ears")]] = [0.3, 0.25, 0.2, 0.15, 0.1]
    cut = reduce_influences(row, 4, d)
    assert cut[0, n("ears")] == 0.0 and (cut > 0).sum() == 4 and cut.sum() == pytest.approx(1.0)
    theta = params_to_theta(
        {"crown.translate_y": 30.0, "skull_root.rotate_x": 20.0, "nose_tip.scale": 1.2, "left_eye_socket.scale": 1.4},
        dtype=torch.float64,
    )[None]
    _, transforms = rig64.joint_transforms(theta)
    point = torch.tensor([[20.0, 40.0, 60.0]], dtype=torch.float64)
    full = skin_vertices(point, torch.as_tensor(row), transforms)
    assert torch.linalg.norm(skin_vertices(point, torch.as_tensor(cut), transforms) - full) < 0.15
    renormalised = skin_vertices(point, torch.as_tensor(keep_largest(row, 4)), transforms)
    assert torch.linalg.norm(renormalised - full) > 0.5


def test_reduce_influences_is_continuous(asset, rng):
    d = joint_motion_distance(asset.parents, channel_reach(52))
    row = np.zeros((1, 52))
    row[0, :6] = [0.4, 0.2, 0.15, 0.125 + 1e-7, 0.125 - 1e-7, 0.0]
    swapped = row.copy()
    swapped[0, 3:5] = row[0, [4, 3]]  # the 4th and 5th change places
    assert np.abs(reduce_influences(row, 4, d) - reduce_influences(swapped, 4, d)).max() < 1e-5
    w = rng.dirichlet(np.ones(52) * 0.2, 200)
    out = reduce_influences(w, 4, d)
    assert ((out > 0).sum(1) <= 4).all() and np.allclose(out.sum(1), 1.0) and (out >= 0).all()
    sparse = keep_largest(w, 3)
    np.testing.assert_allclose(reduce_influences(sparse, 4, d), sparse, atol=1e-15)


def test_transfer_keeps_at_most_four_influences_summing_to_one(asset, skin, rng):
    points = _points_on_faces(asset, skin, rng, 200)[0] + rng.normal(0, 4, (200, 3))
    for distance in (None, joint_motion_distance(asset.parents, channel_reach(52))):
        out = transfer_skinning(
            asset.vertices, skin, asset.weights, None, points, smoothing_mm=10.0, joint_distance=distance
        )
        assert ((out.weights > 0).sum(1) <= 4).all()
        np.testing.assert_allclose(out.weights.sum(1), 1.0, atol=1e-12)
        assert (out.weights >= 0).all()


def test_pose_accessory_against_a_naive_loop(asset, skin, rig64, rng):
    points = _points_on_faces(asset, skin, rng, 40)[0] + rng.normal(0, 2, (40, 3))
    targets = rng.normal(0, 1, (52, len(asset.vertices), 3))
    out = transfer_skinning(asset.vertices, skin, asset.weights, targets, points)
    theta = params_to_theta(
        {"crown.translate_y": 20.0, "skull_root.rotate_x": 10.0, "nose_tip.scale": 1.2}, dtype=torch.float64
    )[None]
    c = torch.as_tensor(rng.uniform(0, 1, (1, 52)))
    _, transforms = rig64.joint_transforms(theta)
    posed = pose_accessory(points, out, transforms, c)[0].numpy()
    a = transforms[0].numpy()
    for i in range(len(points)):
        rest = points[i] + np.einsum("e,ek->k", c[0].numpy(), out.morph_targets[:, i])
        m = sum(out.weights[i, j] * a[j] for j in range(a.shape[0]))
        np.testing.assert_allclose(posed[i], (m @ np.r_[rest, 1.0])[:3], atol=1e-9)


def test_points_on_the_skin_move_with_it(asset, skin, rig64, rng):
    """At rest the accessory stays put; under a skull turn and joint edits a point on the skin (not the neck,
    whose triangles are large) stays within 0.2 mm of the posed skin: LBS of an interpolated point is
    quadratic inside a triangle, the posed skin linear (measured on 3000 points: 0.13 mm on the scalp,
    0.05 on the forehead, 0.01 elsewhere; 0.52 on the neck)."""
    head_faces = skin[~asset.region_mask("neck")[skin].any(1)]
    points = _points_on_faces(asset, head_faces, rng, 300)[0]
    out = transfer_skinning(asset.vertices, skin, asset.weights, None, points, smoothing_mm=0.0, max_influences=None)
    theta = torch.stack(
        [
            params_to_theta(p, dtype=torch.float64)
            for p in (
                {},
                {"skull_root.rotate_x": 20.0, "skull_root.rotate_y": -10.0},
                {"crown.translate_y": 30.0, "cranium.scale_x": 1.1, "nose_root_a.translate_z": 8.0},
            )
        ]
    )
    with torch.no_grad():
        head = rig64(theta)
        posed = pose_accessory(points, out, head.skinning).numpy()
    np.testing.assert_allclose(posed[0], points, atol=1e-9)
    for i in (1, 2):
        surface = surface_values(head.vertices[i].numpy(), skin, out.anchors)
        assert np.linalg.norm(posed[i] - surface, axis=1).max() < 0.2


def test_rigid_attachment_is_one_joint(asset, skin, rng):
    points = _points_on_faces(asset, skin, rng, 10)[0]
    out = transfer_skinning(asset.vertices, skin, asset.weights, np.zeros((2, len(asset.vertices), 3)), points)
    rigid = rigid_attachment(out, 2)
    assert (rigid.weights[:, 2] == 1).all() and rigid.weights.sum() == 10 and not rigid.morph_targets.any()
    with pytest.raises(AccessoryError):
        rigid_attachment(out, 52)


def test_signed_distance_to_a_sphere():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=50.0)
    rng = np.random.default_rng(3)
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = rng.uniform(30.0, 70.0, 200)
    sd = signed_distance(d * r[:, None], sphere.vertices, sphere.faces)
    np.testing.assert_allclose(sd, r - 50.0, atol=0.2)  # the icosphere's facets lie up to 0.16 mm inside the sphere
    assert (np.sign(sd) == np.sign(r - 50.0)).all() or np.abs(r - 50.0).min() < 0.2


def test_bad_input(asset, skin):
    v = asset.vertices
    with pytest.raises(ShapeError, match="accessory_vertices"):
        transfer_skinning(v, skin, asset.weights, None, np.zeros((4, 2)))
    with pytest.raises(AccessoryError, match="non-finite"):
        transfer_skinning(v, skin, asset.weights, None, np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(ShapeError, match="head_weights"):
        transfer_skinning(v, skin, asset.weights[:10], None, np.zeros((1, 3)))
    with pytest.raises(AccessoryError, match="falloff_mm"):
        transfer_skinning(v, skin, asset.weights, None, np.zeros((1, 3)), falloff_mm=-1.0)
    with pytest.raises(AccessoryError, match="faces"):
        transfer_skinning(v, skin + len(v), asset.weights, None, np.zeros((1, 3)))
    out = transfer_skinning(v, skin, asset.weights, None, np.zeros((1, 3)))
    with pytest.raises(ShapeError, match="skinning_transforms"):
        pose_accessory(np.zeros((1, 3)), out, torch.zeros(1, 3, 4, 4, dtype=torch.float64))
