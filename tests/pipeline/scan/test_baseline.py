"""Tests of the trimesh non-rigid ICP baseline (pipeline/scan/baseline.py)."""

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from pipeline.scan.baseline import DEFAULT_STEPS, BaselineResult, nricp_baseline

ROTATION = Rotation.from_euler("yxz", [20.0, -10.0, 5.0], degrees=True).as_matrix()
TRANSLATION = np.array([15.0, -40.0, 650.0])


@pytest.fixture(scope="module")
def scan(asset):
    """A frontal partial scan of a known deformation: 5 mm bump on the nose tip (Gaussian, sigma 60 mm,
    along the normals), only faces facing +Z in the template frame, 0.2 mm noise, 6,000 points, then
    moved by a known rigid transform. Returns (cloud (N, 3), truth (V, 3), pre-aligned template (V, 3))."""
    V, F = asset.vertices, asset.faces
    normals = trimesh.Trimesh(V, F, process=False).vertex_normals
    tip = np.argmax(np.where(asset.region_mask("nose"), V[:, 2], -np.inf))
    d = np.linalg.norm(V - V[tip], axis=1)
    truth_rig = V + 5.0 * np.exp(-0.5 * (d / 60.0) ** 2)[:, None] * normals
    front_faces = (normals[:, 2] > 0.2)[F].all(axis=1)
    points, _ = trimesh.sample.sample_surface(trimesh.Trimesh(truth_rig, F[front_faces], process=False), 6000, seed=1)
    points = points + np.random.default_rng(2).normal(0.0, 0.2, points.shape)

    def to_cloud(x):
        return x @ ROTATION.T + TRANSLATION

    return to_cloud(points), to_cloud(truth_rig), to_cloud(V)


@pytest.fixture(scope="module")
def result(asset, scan):
    cloud, _, _ = scan
    res = nricp_baseline(
        asset.vertices, asset.faces, cloud, rotation=ROTATION, translation=TRANSLATION, max_points=5000
    )
    print(f"\nnricp_baseline: {res.seconds:.2f} s for a 5,000-point cloud, steps {res.steps}")
    return res


class TestNricpBaseline:
    def test_smoke_and_cardinality(self, asset, result):
        assert isinstance(result, BaselineResult)
        assert result.vertices.shape == asset.vertices.shape
        assert result.vertices.dtype == np.float64
        assert np.all(np.isfinite(result.vertices))
        assert result.seconds > 0
        assert result.steps == [list(row) for row in DEFAULT_STEPS]

    def test_front_face_moves_towards_truth(self, asset, scan, result):
        _, truth, prealigned = scan
        face = asset.region_mask("nose", "cheeks", "forehead")
        before = np.linalg.norm(prealigned - truth, axis=1)[face].mean()
        after = np.linalg.norm(result.vertices - truth, axis=1)[face].mean()
        assert after < 0.6 * before, (before, after)

    def test_unseen_side_stays_put(self, asset, scan, result):
        # The back of the head has no data; the distance threshold + anchors keep it near the template.
        _, truth, prealigned = scan
        back = asset.region_mask("scalp", "neck") & (asset.vertices[:, 2] < -20.0)
        assert np.linalg.norm(result.vertices - truth, axis=1)[back].mean() < 2.0

    def test_unit_free(self, asset, scan, result):
        # nricp_amberg normalises by the template's size: the same problem in metres gives the same fit.
        cloud, _, _ = scan
        res_m = nricp_baseline(
            asset.vertices,
            asset.faces,
            cloud / 1000.0,
            rotation=ROTATION,
            translation=TRANSLATION / 1000.0,
            scale=1e-3,
            distance_threshold_mm=0.01,
            max_points=5000,
        )
        assert np.abs(res_m.vertices * 1000.0 - result.vertices).max() < 1e-3

    def test_exceptions(self, asset, scan):
        cloud, _, _ = scan
        V, F = asset.vertices, asset.faces
        kw = dict(rotation=ROTATION, translation=TRANSLATION)
        bad_cloud = cloud.copy()
        bad_cloud[3, 1] = np.nan
        with pytest.raises(ValueError, match="cloud"):
            nricp_baseline(V, F, bad_cloud, **kw)
        with pytest.raises(ValueError, match="cloud"):
            nricp_baseline(V, F, cloud[:, :2], **kw)
        with pytest.raises(ValueError, match="template_vertices"):
            nricp_baseline(V[:, :2], F, cloud, **kw)
        with pytest.raises(ValueError, match="faces"):
            nricp_baseline(V, F[:, :2], cloud, **kw)
        with pytest.raises(ValueError, match="faces"):
            nricp_baseline(V, F + len(V), cloud, **kw)
        with pytest.raises(ValueError, match="rotation"):
            nricp_baseline(V, F, cloud, rotation=2 * ROTATION, translation=TRANSLATION)
        with pytest.raises(ValueError, match="translation"):
            nricp_baseline(V, F, cloud, rotation=ROTATION, translation=TRANSLATION[:2])
        with pytest.raises(ValueError, match="scale"):
            nricp_baseline(V, F, cloud, scale=-1.0, **kw)
        with pytest.raises(ValueError, match="cloud_normals"):
            nricp_baseline(V, F, cloud, cloud_normals=np.ones((3, 3)), **kw)
        with pytest.raises(ValueError, match="steps"):
            nricp_baseline(V, F, cloud, steps=[[0.01, 0.0, 0.0]], **kw)
        with pytest.raises(ValueError, match="distance_threshold_mm"):
            nricp_baseline(V, F, cloud, distance_threshold_mm=0.0, **kw)
        with pytest.raises(ValueError, match="pre-alignment"):  # cloud in metres, template in mm
            nricp_baseline(V, F, cloud / 1000.0, **kw)
