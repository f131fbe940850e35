import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.scan.registration import (
    MeshDistance,
    brute_force_distance,
    rigid_prealign,
    vertex_normals,
)
from rig.geometry import Similarity
from rig.template import FACE_REGIONS


def test_vertex_normals_point_out_of_the_template(asset):
    n = vertex_normals(asset.vertices, asset.faces)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    nose = asset.region_mask("nose")
    assert (n[nose, 2] > 0).mean() > 0.8  # the nose faces +Z
    top = asset.vertices[:, 1] > asset.vertices[:, 1].max() - 5
    assert (n[top, 1] > 0.8).all()  # the crown faces up


def test_mesh_distance_equals_brute_force(asset, rng):
    v, f = asset.vertices, asset.faces
    near = v[rng.choice(len(v), 300)] + rng.normal(0, 3, (300, 3))
    far = v[rng.choice(len(v), 40)] + rng.normal(0, 40, (40, 3))
    pts = np.vstack([near, far])
    d, closest, face = MeshDistance(v, f).query(pts)
    np.testing.assert_allclose(d, brute_force_distance(pts, v, f), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(closest - pts, axis=1), d, atol=1e-9)
    # the closest point lies on the reported triangle (barycentric coordinates in [0, 1])
    tri = v[f[face]]
    bary = np.linalg.lstsq(np.stack([tri[0, 0] - tri[0, 2], tri[0, 1] - tri[0, 2]], 1),
                           closest[0] - tri[0, 2], rcond=None)[0]
    assert bary.min() > -1e-6 and bary.sum() < 1 + 1e-6
    # points on the surface are at distance 0
    w = rng.dirichlet([1, 1, 1], 50)
    on = np.einsum("nc,ncd->nd", w, v[f[rng.choice(len(f), 50)]])
    assert MeshDistance(v, f).query(on)[0].max() < 1e-9


@pytest.mark.parametrize("yaw", [-45.0, 0.0, 40.0])
def test_rigid_prealign_finds_a_yawed_offset_partial_head(asset, rng, yaw):
    v, f = asset.vertices, asset.faces
    n = vertex_normals(v, f)
    rot = Rotation.from_euler("yxz", [yaw, 8, -5], degrees=True).as_matrix()
    t = np.array([-250.0, 120.0, 700.0])
    seen = (n @ (rot.T @ np.array([0.0, 0.0, 1.0]))) > 0.2  # what a camera on +Z sees
    cloud = Similarity(rot, t).apply(v[seen]) + rng.normal(0, 0.5, (seen.sum(), 3))
    normals = n[seen] @ rot.T
    for cn in (normals, None):
        al = rigid_prealign(cloud, cn, v, f, face_mask=asset.region_mask(*FACE_REGIONS))
        angle = np.degrees(np.linalg.norm(Rotation.from_matrix(al.rotation @ rot.T).as_rotvec()))
        assert angle < 5.0
        assert np.linalg.norm(al.transform.apply(v) - Similarity(rot, t).apply(v),
                              axis=1).mean() < 4.0
        assert al.inlier_fraction > 0.95


def test_rigid_prealign_with_landmarks_is_exact(asset):
    v, f = asset.vertices, asset.faces
    rot = Rotation.from_euler("yxz", [100, 0, 0], degrees=True).as_matrix()  # beyond any yaw search
    t = np.array([5.0, 6.0, 7.0])
    ids = np.array([10, 500, 1735, 2730, 4242])
    cloud = Similarity(rot, t).apply(v)
    al = rigid_prealign(cloud, None, v, f, landmarks=(v[ids], cloud[ids]))
    np.testing.assert_allclose(al.rotation, rot, atol=1e-6)
    assert al.rms_mm < 1e-6
