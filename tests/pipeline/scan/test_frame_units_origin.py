"""Clouds that used to fit confidently wrong or crash (issue 29, D10, D20-D22): a wrong --frame, inches taken
for cm, clouds far from the origin (float64 fitted as well as at the origin, float32 that lost its detail)."""

import numpy as np
import pytest
import trimesh

from pipeline.cli import main
from pipeline.config import load_config
from pipeline.metrics import scan_to_mesh_distances
from pipeline.scan.fit import fit_scan
from pipeline.scan.fit_config import FitScanConfig
from pipeline.scan.outputs import mesh_from_params, write_scan_outputs
from pipeline.scan.pointcloud.cloud import CloudError
from pipeline.scan.pointcloud.read import read_point_cloud
from pipeline.scan.pointcloud.units import plausible_units
from pipeline.scan.pointcloud.validate import validate_points
from pipeline.scan.pointcloud.write import write_point_cloud_ply
from pipeline.synthetic.scans import ScanSettings, simulate_scan
from rig.io.ply import binary_ply, position_dtype

FAR = np.array([5.0e8, 5.0e9, 1.0e5])  # mm: UTM-like metres, as mm
SHORT = {"stages": [{"name": "joints", "free": ["pose", "joints"], "iterations": 3}]}


@pytest.fixture(scope="module")
def scan(asset):
    """A simulated depth scan of the template head (mm, +Y up, with normals)."""
    settings = ScanSettings(hole_fraction=(0.0, 0.0), outlier_fraction=0.0)
    return simulate_scan(asset.vertices, asset.faces, rng=5, settings=settings, yaw_deg=15.0)


def _refused(tmp_path, capsys, cloud_file, *extra):
    out = tmp_path / "out"
    before = sorted(p.name for p in tmp_path.iterdir())
    code = main(["fit-scan", str(cloud_file), "--out", str(out), "--quiet", *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no staging folder, nothing else
    return err[-1]


def test_a_cloud_given_in_the_wrong_frame_is_refused_upside_down(tmp_path, capsys, scan):
    path = tmp_path / "scan.ply"
    write_point_cloud_ply(path, scan.points, normals=scan.normals)
    line = _refused(tmp_path, capsys, path, "--frame", "opencv")  # the file is +Y up
    assert line.startswith(f"jnr: error: {path}: the cloud looks upside down") and "check --frame" in line


def test_inches_taken_for_centimetres_are_refused_with_the_evidence(tmp_path, capsys, scan):
    path = tmp_path / "inches.npy"
    np.save(path, scan.points / 25.4)
    assert plausible_units(np.ptp(scan.points, axis=0).max() / 25.4) == ["cm", "in"]
    line = _refused(tmp_path, capsys, path)
    assert "read as centimetres (detected)" in line and "read as inches" in line and "pass --units in" in line
    cloud = read_point_cloud(path, units="in")  # what the message proposes reads the head back in mm
    assert cloud.units == "in" and np.allclose(cloud.points, scan.points, atol=1e-9)


def test_float32_coordinates_that_lost_their_detail_far_from_the_origin_are_refused(tmp_path, capsys, scan):
    path = tmp_path / "far32.npy"
    np.save(path, (scan.points + 1e8).astype(np.float32))  # float32 at 1e8 mm: an 8 mm grid
    line = _refused(tmp_path, capsys, path)
    assert "stored as float32" in line and "resolves only 8 mm" in line
    with pytest.raises(CloudError, match="float32"):
        validate_points(scan.points + 1e8, stored_dtype=np.float32)
    # the same type near the origin, or float64 far away, is fine
    assert validate_points(scan.points.astype(np.float32), stored_dtype=np.float32).units == "mm"
    assert validate_points(scan.points + 1e8, stored_dtype=np.float64).units == "mm"


def test_a_georeferenced_float64_cloud_fits_as_at_the_origin_and_its_files_keep_the_precision(tmp_path, scan, asset):
    config = load_config(FitScanConfig, None, SHORT)
    near = validate_points(scan.points, scan.normals, units="mm")
    far = validate_points(scan.points + FAR, scan.normals, units="mm")
    fit_near, fit_far = fit_scan(near, config), fit_scan(far, config)  # the far one crashed (IndexError)
    assert np.abs(fit_far.vertices - FAR - fit_near.vertices).max() < 1e-3  # mm
    assert np.allclose(fit_far.translation - FAR, fit_near.translation, atol=1e-3)
    distances = scan_to_mesh_distances(far.points - FAR, fit_far.vertices - FAR, asset.faces)
    out = write_scan_outputs(tmp_path / "far", far, fit_far, distances, config=config)
    ply = trimesh.load(out / "mesh.ply", process=False)
    obj = trimesh.load(out / "mesh.obj", process=False)
    # float32 would have put the 4874 vertices on an 8 mm grid (about 1800 distinct ones)
    assert len(np.unique(ply.vertices, axis=0)) == len(asset.vertices)
    assert np.abs(ply.vertices - fit_far.vertices).max() < 1e-6 and np.abs(obj.vertices - fit_far.vertices).max() < 1e-6
    assert np.abs(mesh_from_params(out / "params.json") - fit_far.vertices).max() < 1e-3
    cloud = trimesh.load(out / "cloud_error.ply", process=False)
    assert np.abs(np.asarray(cloud.vertices) - far.points).max() < 1e-6


def test_ply_positions_are_float64_only_where_float32_would_lose_them(tmp_path):
    head = np.random.default_rng(0).uniform(-100.0, 100.0, (50, 3))
    assert position_dtype(head) == "<f4" and position_dtype(head / 1000) == "<f4"  # mm or m at the origin
    assert position_dtype(head + 1e8) == "<f8" and position_dtype(head / 1000 + 5e6) == "<f8"
    faces = np.array([[0, 1, 2], [2, 3, 4]])
    path = tmp_path / "t.ply"
    path.write_bytes(binary_ply([(c, "<f8", head[:, i] + 1e8) for i, c in enumerate("xyz")], faces, ("a comment",)))
    mesh = trimesh.load(path, process=False)
    assert np.array_equal(mesh.vertices, head + 1e8) and np.array_equal(mesh.faces, faces)
    with pytest.raises(ValueError):
        binary_ply([("x", "<f8", head[:, 0])], np.array([[0, 1, 50]]))
