"""pipeline.synthetic.scans: z-buffer depth rendering and simulated Kinect-like scans."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pipeline.synthetic.scans import (
    WORLD_TO_CAMERA,
    DepthCamera,
    ScanSettings,
    SyntheticScan,
    render_depth,
    simulate_scan,
)

CLEAN = ScanSettings(
    noise_mm_at_1m=0.0, noise_floor_mm=0.0, lateral_jitter_px=0.0, hole_fraction=(0.0, 0.0), outlier_fraction=0.0
)
HIRES = DepthCamera(width=640, height=576, fx=504.0, fy=504.0, cx=320.0, cy=288.0)


def _square(z=500.0, half=100.0):
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def _point_triangle_distance(p, tri):
    """Exact distance from points ``(N, 3)`` to triangles ``(N, K, 3, 3)`` (min over K), by sampling-free
    projection: plane distance when the projection is inside, else the nearest edge."""
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    p = p[:, None, :]

    def seg(x, y):
        d = y - x
        t = np.clip(((p - x) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0, 1)
        return np.linalg.norm(p - x - t[..., None] * d, axis=-1)

    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    dist_plane = ((p - a) * n).sum(-1)
    q = p - dist_plane[..., None] * n
    inside = (
        ((np.cross(b - a, q - a) * n).sum(-1) >= 0)
        & ((np.cross(c - b, q - b) * n).sum(-1) >= 0)
        & ((np.cross(a - c, q - c) * n).sum(-1) >= 0)
    )
    d = np.where(inside, np.abs(dist_plane), np.minimum(np.minimum(seg(a, b), seg(b, c)), seg(c, a)))
    return d.min(axis=1)


def _mesh_distance(points, vertices, faces, k=96):
    centroids = vertices[faces].mean(axis=1)
    _, idx = cKDTree(centroids).query(points, k=k)
    d = _point_triangle_distance(points, vertices[faces[idx]])
    for i in np.flatnonzero(d > 1e-3)[:200]:  # large faces may be missed by the centroid search: exact
        d[i] = _point_triangle_distance(points[i : i + 1], vertices[faces][None])[0]
    return d


def test_plane_depth_and_area():
    cam = DepthCamera()
    v, f = _square(500.0, 100.0)
    depth, fid = render_depth(v, f, cam)
    hit = np.isfinite(depth)
    np.testing.assert_allclose(depth[hit], 500.0, atol=1e-9)
    expected = (2 * 100.0 * cam.fx / 500.0) * (2 * 100.0 * cam.fy / 500.0)
    assert abs(hit.sum() - expected) / expected < 0.02
    assert set(np.unique(fid[hit])) == {0, 1} and (fid[~hit] == -1).all()


def test_tilted_plane_perspective_correct():
    """A tilted plane: every back-projected pixel lies on the plane (perspective-correct depth)."""
    cam = DepthCamera()
    v, f = _square(0.0, 80.0)
    tilt = np.radians(50.0)
    rot = np.array([[np.cos(tilt), 0, np.sin(tilt)], [0, 1, 0], [-np.sin(tilt), 0, np.cos(tilt)]])
    v = v @ rot.T + [0, 0, 600.0]
    depth, fid = render_depth(v, f, cam)
    vv, uu = np.nonzero(np.isfinite(depth))
    p = np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones_like(uu, float)], 1) * depth[vv, uu, None]
    n = rot @ [0, 0, 1.0]
    assert np.abs((p - [0, 0, 600.0]) @ n).max() < 1e-9


def test_projected_point_face_id():
    cam = DepthCamera()
    v, f = _square(400.0, 100.0)
    for face in (0, 1):
        centroid = v[f[face]].mean(axis=0)
        u = int(round(cam.fx * centroid[0] / centroid[2] + cam.cx))
        w = int(round(cam.fy * centroid[1] / centroid[2] + cam.cy))
        depth, fid = render_depth(v, f, cam)
        assert fid[w, u] == face


def test_template_pixels_on_their_faces(asset):
    """Each rendered pixel's back-projection lies inside the triangle its face id names."""
    cam = DepthCamera()
    v = (asset.vertices - [0, 0, 700.0]) @ WORLD_TO_CAMERA.T
    t0 = time.perf_counter()
    depth, fid = render_depth(v, asset.faces, cam)
    print(
        f"render_depth: template (4,978 vertices) at 320x288 in {1e3 * (time.perf_counter() - t0):.1f} ms, "
        f"{np.isfinite(depth).sum()} pixels"
    )
    vv, uu = np.nonzero(fid >= 0)
    p = np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones_like(uu, float)], 1) * depth[vv, uu, None]
    d = _point_triangle_distance(p, v[asset.faces[fid[vv, uu]]][:, None])
    assert d.max() < 1e-6
    # And the face is the nearest along the ray: the projected vertex centroids of visible faces agree.
    assert np.isfinite(depth).sum() > 2000


def test_clean_scan_on_mesh(asset):
    scan = simulate_scan(asset.vertices, asset.faces, rng=3, settings=CLEAN)
    assert isinstance(scan, SyntheticScan)
    assert scan.points.dtype == np.float64 and scan.points.shape[1] == 3
    np.testing.assert_allclose(scan.gt_vertices, asset.vertices @ scan.rotation.T + scan.translation)
    d = _mesh_distance(scan.points, scan.gt_vertices, asset.faces)
    assert d.max() < 0.01
    assert scan.hole_fraction == 0.0
    # Normals: unit, towards the camera.
    n = scan.normals
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    assert ((scan.camera_position - scan.points) * n).sum(axis=1).min() > 0


def test_noise_level(asset):
    settings = ScanSettings(hole_fraction=(0.0, 0.0), outlier_fraction=0.0, lateral_jitter_px=0.0)
    scan = simulate_scan(
        asset.vertices, asset.faces, rng=4, settings=settings, yaw_deg=0.0, pitch_deg=0.0, roll_deg=0.0
    )
    z = np.abs(scan.points[:, 2] - scan.camera_position[2])
    sigma = np.maximum(settings.noise_mm_at_1m * (z / 1000.0) ** 2, settings.noise_floor_mm)
    d = _mesh_distance(scan.points, scan.gt_vertices, asset.faces)
    # Axial noise seen along the (mostly camera-facing) surface normal: median |N(0, s)| = 0.674 s at most.
    expected = 0.6745 * np.median(sigma)
    assert 0.5 * expected < np.median(d) < 1.3 * expected


def test_holes_reduce_points(asset):
    base = ScanSettings(hole_fraction=(0.0, 0.0), outlier_fraction=0.0)
    holed = ScanSettings(hole_fraction=(0.25, 0.25), outlier_fraction=0.0)
    a = simulate_scan(asset.vertices, asset.faces, rng=5, settings=base)
    b = simulate_scan(asset.vertices, asset.faces, rng=5, settings=holed)
    assert 0.2 < b.hole_fraction < 0.32
    lost = 1.0 - len(b.points) / len(a.points)
    assert abs(lost - b.hole_fraction) < 0.08


def test_outliers_counted(asset):
    s = ScanSettings(outlier_fraction=0.05)
    scan = simulate_scan(asset.vertices, asset.faces, rng=6, settings=s)
    d = _mesh_distance(scan.points, scan.gt_vertices, asset.faces)
    assert (d > 10.0).mean() > 0.01


def test_visible_mask(asset):
    scan = simulate_scan(asset.vertices, asset.faces, rng=7, yaw_deg=0.0, pitch_deg=0.0, roll_deg=0.0)
    v = asset.vertices
    nose = asset.region_mask("nose")
    # the back of the head; the ICT-shaped neck flares at its bottom rim (x +-79 mm at z -60, y -144), whose
    # sides are on the silhouette seen from the front
    back = (v[:, 2] < -60.0) & (v[:, 1] > -130.0)
    assert scan.visible[nose].mean() > 0.8
    assert back.sum() > 200 and not scan.visible[back].any()


def test_yaw_changes_side(asset):
    left = simulate_scan(asset.vertices, asset.faces, rng=8, yaw_deg=40.0, pitch_deg=0.0, roll_deg=0.0)
    right = simulate_scan(asset.vertices, asset.faces, rng=8, yaw_deg=-40.0, pitch_deg=0.0, roll_deg=0.0)
    ears = asset.region_mask("ears")
    x = asset.vertices[:, 0]
    # Positive yaw turns the face towards +X: the subject's right ear (-X) faces the camera.
    assert left.visible[ears & (x < 0)].sum() > left.visible[ears & (x > 0)].sum()
    assert right.visible[ears & (x > 0)].sum() > right.visible[ears & (x < 0)].sum()
    for seed in range(3):
        s = simulate_scan(
            asset.vertices,
            asset.faces,
            rng=seed,
            pitch_deg=0.0,
            roll_deg=0.0,
            settings=ScanSettings(yaw_deg_range=(10.0, 20.0)),
        )
        yaw = np.degrees(np.arctan2(s.rotation[0, 2], s.rotation[2, 2]))
        assert 10.0 <= yaw <= 20.0


def test_deterministic(asset):
    a = simulate_scan(asset.vertices, asset.faces, rng=11)
    b = simulate_scan(asset.vertices, asset.faces, rng=np.random.default_rng(11))
    c = simulate_scan(asset.vertices, asset.faces, rng=12)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.normals, b.normals)
    assert a.points.shape != c.points.shape or not np.array_equal(a.points, c.points)


def test_point_counts(asset):
    low = [len(simulate_scan(asset.vertices, asset.faces, rng=s).points) for s in range(3)]
    high = [len(simulate_scan(asset.vertices, asset.faces, rng=s, camera=HIRES).points) for s in range(3)]
    print(f"points at 600 mm: 320x288 {low}, 640x576 {high}")
    assert 2000 < min(low) and max(low) < 8000
    assert 10000 < min(high) and max(high) < 40000


def test_no_normals_and_bad_input(asset):
    scan = simulate_scan(asset.vertices, asset.faces, rng=0, settings=ScanSettings(normals=False))
    assert scan.normals is None
    with pytest.raises(ValueError, match="vertices"):
        simulate_scan(asset.vertices[:, :2], asset.faces, rng=0)
    with pytest.raises(ValueError, match="faces"):
        render_depth(asset.vertices, asset.faces.astype(float))
    with pytest.raises(ValueError, match="hole_fraction"):
        simulate_scan(asset.vertices, asset.faces, rng=0, settings=ScanSettings(hole_fraction=(0.5, 0.2)))
