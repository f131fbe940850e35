import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.scan.registration import rigid_prealign
from rig.geometry import Similarity, vertex_normals
from rig.template import FACE_REGIONS


# 4 s each: the two large yaws in make test-slow
@pytest.mark.parametrize(
    "yaw", [pytest.param(-45.0, marks=pytest.mark.slow), 0.0, pytest.param(40.0, marks=pytest.mark.slow)]
)
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
        assert np.linalg.norm(al.transform.apply(v) - Similarity(rot, t).apply(v), axis=1).mean() < 4.0
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
