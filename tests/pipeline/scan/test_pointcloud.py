import json
import os
import warnings

import numpy as np
import pytest
import trimesh
from trimesh.exchange.ply import export_ply, load_ply

from pipeline.scan.pointcloud.cloud import CloudError, PointCloud
from pipeline.scan.pointcloud.error_colors import error_colors
from pipeline.scan.pointcloud.landmarks3d import read_landmarks3d
from pipeline.scan.pointcloud.normals import boundary_mask, estimate_normals
from pipeline.scan.pointcloud.read import read_point_cloud
from pipeline.scan.pointcloud.units import to_rig_frame
from pipeline.scan.pointcloud.validate import LARGE_CLOUD_POINTS, SUBSAMPLE_POINTS, count_distinct, validate_points
from pipeline.scan.pointcloud.write import write_point_cloud_ply
from rig.io import atomic

SEMI_AXES_MM = np.array([75.0, 110.0, 90.0])  # a head-sized ellipsoid, 150 x 220 x 180 mm


def fibonacci_sphere(n: int) -> np.ndarray:
    """``(n, 3)`` evenly spread unit vectors."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


@pytest.fixture(scope="module")
def ellipsoid():
    """Points (mm) and analytic unit normals of a head-sized ellipsoid."""
    unit = fibonacci_sphere(2000)
    points = unit * SEMI_AXES_MM
    normals = points / SEMI_AXES_MM**2
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", a, b), -1.0, 1.0)))


def write_ascii_ply(path, points, normals=None):
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    rows = points if normals is None else np.hstack([points, normals])
    header = ["ply", "format ascii 1.0", f"element vertex {len(points)}"] + [f"property double {p}" for p in props]
    body = "\n".join(" ".join(f"{v:.10g}" for v in row) for row in rows)
    path.write_text("\n".join(header + ["end_header", body]) + "\n")


def write_obj(path, points, normals=None):
    lines = ["# test obj"] + [f"v {x:.10g} {y:.10g} {z:.10g}" for x, y, z in points]
    if normals is not None:
        lines += [f"vn {x:.10g} {y:.10g} {z:.10g}" for x, y, z in normals]
    path.write_text("\n".join(lines) + "\n")


def write_table(path, points, normals=None, sep=" ", header=None):
    rows = points if normals is None else np.hstack([points, normals])
    lines = ["# exported by a scanner", "# second comment"] + ([header] if header else [])
    lines += [sep.join(f"{v:.10g}" for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")


# ------------------------------------------------------------------------------------------ round trips


@pytest.mark.parametrize("with_normals", [False, True])
@pytest.mark.parametrize("kind", ["ply_ascii", "ply_binary", "obj", "xyz", "txt_header", "csv_header", "npy"])
def test_round_trip_every_format(tmp_path, ellipsoid, kind, with_normals):
    points, normals = ellipsoid
    n = normals if with_normals else None
    ext = {
        "ply_ascii": ".ply",
        "ply_binary": ".ply",
        "obj": ".obj",
        "xyz": ".xyz",
        "txt_header": ".TXT",
        "csv_header": ".csv",
        "npy": ".npy",
    }[kind]
    path = tmp_path / f"cloud{ext}"
    if kind == "ply_ascii":
        write_ascii_ply(path, points, n)
    elif kind == "ply_binary":
        write_point_cloud_ply(path, points, normals=n)
    elif kind == "obj":
        write_obj(path, points, n)
    elif kind == "xyz":
        write_table(path, points, n)
    elif kind == "txt_header":
        write_table(path, points, n, sep="\t", header="x y z" + (" nx ny nz" if with_normals else ""))
    elif kind == "csv_header":
        write_table(path, points, n, sep=",", header="x,y,z" + (",nx,ny,nz" if with_normals else ""))
    else:
        np.save(path, points if n is None else np.hstack([points, n]))

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # mm input must not warn
        cloud = read_point_cloud(path)
    assert isinstance(cloud, PointCloud)
    assert cloud.path == os.fspath(path) and cloud.units == "mm" and cloud.scale_to_mm == 1.0
    assert cloud.points.dtype == np.float64 and cloud.points.shape == points.shape
    np.testing.assert_allclose(cloud.points, points, atol=1e-3)  # float32 in binary PLY
    if with_normals:
        assert cloud.normals is not None and cloud.normals.shape == points.shape
        np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-9)
        assert angle_deg(cloud.normals, normals).max() < 0.01
    else:
        assert cloud.normals is None


@pytest.mark.parametrize("stored_normals", [False, True])
def test_mesh_ply_uses_vertices_and_only_stored_normals(tmp_path, stored_normals):
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=100.0)
    path = tmp_path / "head.ply"
    path.write_bytes(export_ply(mesh, vertex_normal=stored_normals))
    cloud = read_point_cloud(path)
    np.testing.assert_allclose(cloud.points, mesh.vertices, atol=1e-3)
    if stored_normals:
        assert angle_deg(cloud.normals, mesh.vertex_normals).max() < 0.1
    else:
        assert cloud.normals is None


def test_obj_normals_ignored_when_counts_differ(tmp_path, ellipsoid):
    points, normals = ellipsoid
    path = tmp_path / "mesh.obj"
    write_obj(path, points, normals[:-10])
    cloud = read_point_cloud(path)
    assert cloud.normals is None
    np.testing.assert_allclose(cloud.points, points, atol=1e-6)


def test_npy_with_wrong_columns_or_pickle_is_rejected(tmp_path, ellipsoid):
    points, _ = ellipsoid
    np.save(tmp_path / "four.npy", np.hstack([points, points[:, :1]]))
    with pytest.raises(CloudError, match=r"3 columns .* or 6"):
        read_point_cloud(tmp_path / "four.npy")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(CloudError, match="obj.npy"):
        read_point_cloud(tmp_path / "obj.npy")


# ---------------------------------------------------------------------------------------------- units


def test_metres_detected_and_converted_with_warning(tmp_path, ellipsoid):
    points, _ = ellipsoid
    np.save(tmp_path / "m.npy", points / 1000.0)
    with pytest.warns(UserWarning, match=r"m; converted .*--units"):
        cloud = read_point_cloud(tmp_path / "m.npy")
    assert cloud.units == "m" and cloud.scale_to_mm == 1000.0
    np.testing.assert_allclose(cloud.points, points, atol=1e-9)


def test_centimetres_detected_and_converted_with_warning(ellipsoid):
    points, _ = ellipsoid
    with pytest.warns(UserWarning, match="cm"):
        cloud = validate_points(points / 10.0)
    assert cloud.units == "cm" and cloud.scale_to_mm == 10.0 and cloud.path == ""
    np.testing.assert_allclose(cloud.points, points, atol=1e-9)


def test_explicit_units_are_applied_and_size_checked(ellipsoid):
    points, _ = ellipsoid
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cloud = validate_points(points / 1000.0, units="m")
    assert cloud.units == "m" and cloud.scale_to_mm == 1000.0
    np.testing.assert_allclose(cloud.points, points, atol=1e-9)
    # a 2 mm-wide "head" once taken as mm: rejected with the size it got
    with pytest.raises(CloudError, match=r"units='mm' the cloud is 2.* mm across"):
        validate_points(points / 100.0, units="mm")
    with pytest.raises(CloudError, match="units must be one of"):
        validate_points(points, units="inch")


@pytest.mark.parametrize("factor", [20.0, 0.02])
def test_cloud_that_is_not_head_sized_is_rejected(ellipsoid, factor):
    points, _ = ellipsoid
    with pytest.raises(CloudError, match=r"across, which is not head-sized in mm, cm or m; is it a head\?") as info:
        validate_points(points * factor)
    low, high = np.percentile(points * factor, [1.0, 99.0], axis=0)
    assert f"the cloud is {(high - low).max():.4g} across" in str(info.value)


def test_auto_units_ignore_outliers(ellipsoid):
    """A few stray points far away (1 % of the cloud at most) do not change the detected units."""
    points, _ = ellipsoid
    stray = np.full((10, 3), 5000.0)
    cloud = validate_points(np.vstack([points, stray]))
    assert cloud.units == "mm"


# --------------------------------------------------------------------------------------- bad clouds


def test_non_finite_rows_rejected_with_count(ellipsoid):
    points, _ = ellipsoid
    bad = points.copy()
    bad[[3, 50, 51], [0, 1, 2]] = [np.nan, np.inf, -np.inf]
    bad[51, 0] = np.nan  # same row twice: still one row
    with pytest.raises(CloudError, match=rf"3 of {len(points)} points have NaN or infinite"):
        validate_points(bad)


def test_non_finite_rows_in_file_rejected(tmp_path, ellipsoid):
    points, _ = ellipsoid
    bad = points.copy()
    bad[7, 2] = np.nan
    write_table(tmp_path / "scan.xyz", bad)
    with pytest.raises(CloudError, match=r"scan.xyz: 1 of \d+ points"):
        read_point_cloud(tmp_path / "scan.xyz")


def test_empty_cloud_rejected(tmp_path):
    with pytest.raises(CloudError, match="the cloud is empty"):
        validate_points(np.zeros((0, 3)))
    (tmp_path / "empty.xyz").write_text("# nothing\nx y z\n")
    with pytest.raises(CloudError, match="the cloud is empty"):
        read_point_cloud(tmp_path / "empty.xyz")


def test_too_few_distinct_points_rejected(ellipsoid):
    points, _ = ellipsoid
    repeated = np.repeat(points[:100], 10, axis=0)  # 1000 rows, 100 distinct
    with pytest.raises(CloudError, match="100 distinct points, at least 500"):
        validate_points(repeated)
    assert len(validate_points(repeated, min_points=100).points) == 1000


@pytest.mark.parametrize("shape", [(1000,), (1000, 2), (10, 3, 3)])
def test_wrong_shape_rejected_with_shape(shape):
    with pytest.raises(CloudError, match=rf"\(N, 3\), got \({shape[0]},"):
        validate_points(np.ones(shape))


def test_bad_normals(ellipsoid):
    points, normals = ellipsoid
    with pytest.raises(CloudError, match=r"normals must have the points' shape"):
        validate_points(points, normals[:-1])
    broken = normals.copy()
    broken[0, 0] = np.nan
    with pytest.raises(CloudError, match="1 normals have NaN"):
        validate_points(points, broken)
    zero = normals.copy()
    zero[5] = 0.0
    with pytest.warns(UserWarning, match="1 normals have zero length"):
        assert validate_points(points, zero).normals is None
    scaled = validate_points(points, normals * 7.0).normals
    np.testing.assert_allclose(scaled, normals, atol=1e-12)


def test_unknown_extension_lists_supported(tmp_path):
    (tmp_path / "scan.stl").write_text("solid x\n")
    with pytest.raises(CloudError, match=r"\.ply, \.obj, \.xyz, \.txt, \.csv, \.npy"):
        read_point_cloud(tmp_path / "scan.stl")


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_point_cloud(tmp_path / "nope.ply")


@pytest.mark.parametrize("ext", [".ply", ".obj", ".xyz", ".npy"])
def test_random_bytes_are_a_cloud_error(tmp_path, ext):
    path = tmp_path / f"noise{ext}"
    path.write_bytes(np.random.default_rng(0).bytes(4000))
    with pytest.raises(CloudError, match=f"noise{ext}") as info:
        read_point_cloud(path)
    assert info.value.__cause__ is not None  # re-raised from the parser's error


def test_truncated_binary_files_are_cloud_errors(tmp_path, ellipsoid):
    points, _ = ellipsoid
    path = tmp_path / "cut.ply"
    write_point_cloud_ply(path, points)
    path.write_bytes(path.read_bytes()[:-500])
    with pytest.raises(CloudError, match="cut.ply"):
        read_point_cloud(path)
    np.save(tmp_path / "cut.npy", points)
    (tmp_path / "cut.npy").write_bytes((tmp_path / "cut.npy").read_bytes()[:-500])
    with pytest.raises(CloudError, match="cut.npy"):
        read_point_cloud(tmp_path / "cut.npy")


@pytest.mark.parametrize(
    "name, text",
    [
        ("ragged.xyz", "1 2 3\n4 5\n"),
        ("words.csv", "x,y,z\n1,2,3\na,b,c\n"),
        ("bad.obj", "v 1 2 three\n"),
        ("short.obj", "v 1 2\n"),
    ],
)
def test_unparseable_text_files_are_cloud_errors(tmp_path, name, text):
    (tmp_path / name).write_text(text)
    with pytest.raises(CloudError, match=name):
        read_point_cloud(tmp_path / name)


# ---------------------------------------------------------------------------------------------- frames


def test_opencv_frame_flips_y_and_z(tmp_path, ellipsoid):
    points, normals = ellipsoid
    np.save(tmp_path / "cam.npy", np.hstack([points, normals]))
    cloud = read_point_cloud(tmp_path / "cam.npy", frame="opencv")
    np.testing.assert_allclose(cloud.points, points * [1.0, -1.0, -1.0], atol=1e-9)
    np.testing.assert_allclose(cloud.normals, normals * [1.0, -1.0, -1.0], atol=1e-9)
    np.testing.assert_allclose(read_point_cloud(tmp_path / "cam.npy").points, points, atol=1e-9)
    with pytest.raises(CloudError, match="frame must be one of"):
        read_point_cloud(tmp_path / "cam.npy", frame="z-up")
    assert to_rig_frame(np.array([1.0, 2.0, 3.0]), "opencv").tolist() == [1.0, -2.0, -3.0]


# ------------------------------------------------------------------------------------- normals, border


def test_estimate_normals_match_sphere_and_point_outward():
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(5000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = 100.0 * directions + [10.0, -20.0, 5.0]
    normals = estimate_normals(points)
    assert normals.shape == (5000, 3) and normals.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    errors = angle_deg(normals, directions)
    assert errors.mean() < 3.0, errors.mean()
    assert errors.max() < 90.0  # every normal points outward


def test_estimate_normals_face_the_viewpoint():
    u, v = np.meshgrid(np.linspace(-100, 100, 40), np.linspace(-100, 100, 40))
    plane = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], axis=1)
    towards_camera = estimate_normals(plane, viewpoint=np.array([0.0, 0.0, -500.0]))
    np.testing.assert_allclose(towards_camera, np.tile([0.0, 0.0, -1.0], (len(plane), 1)), atol=1e-9)
    with pytest.raises(CloudError, match=r"viewpoint must have shape \(3,\)"):
        estimate_normals(plane, viewpoint=np.zeros(2))
    with pytest.raises(CloudError, match=r"\(N, 3\), got \(1600, 2\)"):
        estimate_normals(plane[:, :2])


def precision_recall(found: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    hits = (found & truth).sum()
    return hits / max(found.sum(), 1), hits / truth.sum()


def test_boundary_mask_finds_grid_rim_and_hole():
    u, v = np.meshgrid(np.arange(40.0), np.arange(40.0))
    grid = np.stack([u.ravel(), v.ravel(), 0.01 * (u.ravel() - 20.0) ** 2], axis=1)  # gently curved
    radius = np.hypot(grid[:, 0] - 19.5, grid[:, 1] - 19.5)
    keep = radius > 6.0
    grid, radius = grid[keep], radius[keep]
    outer = (grid[:, 0] == 0) | (grid[:, 0] == 39) | (grid[:, 1] == 0) | (grid[:, 1] == 39)
    hole_rim = radius < 7.0
    assert hole_rim.sum() > 20
    precision, recall = precision_recall(boundary_mask(grid), outer | hole_rim)
    assert precision > 0.9 and recall > 0.9, (precision, recall)


def test_boundary_mask_finds_rim_of_a_sphere_cap():
    points = 100.0 * fibonacci_sphere(8000)
    cap = points[points[:, 2] > 30.0]
    spacing = np.sqrt(4 * np.pi * 100.0**2 / 8000)
    height_above_cut = cap[:, 2] - 30.0
    found = boundary_mask(cap)
    rim = height_above_cut < 0.5 * spacing
    near_rim = height_above_cut < 2.0 * spacing
    assert found[rim].mean() > 0.9  # recall on the outermost ring
    assert near_rim[found].mean() > 0.95  # precision: flagged points lie at the cut
    assert not boundary_mask(points).any()  # a closed sphere has no border


# --------------------------------------------------------------------------------------------- colours


def test_error_colors_endpoints_nan_and_default_vmax():
    colours = error_colors(np.array([0.0, 0.5, 1.0, 5.0, np.nan, -1.0]), vmax_mm=1.0)
    assert colours.dtype == np.uint8 and colours.shape == (6, 3)
    blue, yellow, red, grey = colours[0], colours[1], colours[2], colours[4]
    assert blue[2] > blue[0] and red[0] > 200 and red[2] < 60
    assert yellow[0] > 200 and yellow[1] > 200 and yellow[2] < yellow[0]
    assert (colours[3] == red).all() and (colours[5] == blue).all()
    assert (grey == 128).all()
    distances = np.linspace(0.0, 10.0, 101)  # 95th percentile = 9.5 mm
    default = error_colors(distances)
    assert (default[95:] == default[-1]).all() and (default[94] != default[-1]).any()
    assert (error_colors(np.array([np.nan, np.nan])) == 128).all()
    with pytest.raises(ValueError, match="vmax_mm"):
        error_colors(distances, vmax_mm=0.0)


# ---------------------------------------------------------------------------------------------- writer


def test_ply_writer_is_atomic_and_writes_scalars_and_colours(tmp_path, ellipsoid):
    points, normals = ellipsoid
    errors = np.linspace(0.0, 3.0, len(points))
    colours = error_colors(errors)
    path = tmp_path / "errors.ply"
    path.write_text("old")
    write_point_cloud_ply(path, points, colors=colours, normals=normals, scalars={"error_mm": errors})
    assert os.listdir(tmp_path) == ["errors.ply"]  # replaced in place, no temporary file left
    with open(path, "rb") as fh:
        raw = load_ply(fh)["metadata"]["_ply_raw"]["vertex"]
    assert list(raw["properties"]) == ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "error_mm"]
    np.testing.assert_allclose(raw["data"]["error_mm"], errors, atol=1e-6)
    np.testing.assert_array_equal(raw["data"]["red"], colours[:, 0])
    cloud = read_point_cloud(path)
    np.testing.assert_allclose(cloud.points, points, atol=1e-3)
    assert angle_deg(cloud.normals, normals).max() < 0.01


def test_ply_writer_leaves_old_file_and_no_temp_on_failure(tmp_path, ellipsoid, monkeypatch):
    points, _ = ellipsoid
    path = tmp_path / "out.ply"
    path.write_text("old")

    def failing_move(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(atomic, "rename_exchange", failing_move)  # the move over the old file fails
    with pytest.raises(OSError, match="disk full"):
        write_point_cloud_ply(path, points)
    assert os.listdir(tmp_path) == ["out.ply"] and path.read_text() == "old"


def test_ply_writer_validates_lengths(tmp_path, ellipsoid):
    points, normals = ellipsoid
    path = tmp_path / "x.ply"
    with pytest.raises(ValueError, match=r"normals must have shape \(2000, 3\)"):
        write_point_cloud_ply(path, points, normals=normals[:5])
    with pytest.raises(ValueError, match=r"colors must have shape"):
        write_point_cloud_ply(path, points, colors=np.zeros((5, 3), np.uint8))
    with pytest.raises(ValueError, match=r"colors must be integers in 0-255"):
        write_point_cloud_ply(path, points, colors=np.full((2000, 3), 300))
    with pytest.raises(ValueError, match=r"scalars\['e'\] must have shape \(2000,\)"):
        write_point_cloud_ply(path, points, scalars={"e": np.zeros(3)})
    with pytest.raises(ValueError, match="not a valid PLY property name"):
        write_point_cloud_ply(path, points, scalars={"error mm": np.zeros(2000)})
    with pytest.raises(ValueError, match="clashes"):
        write_point_cloud_ply(path, points, scalars={"x": np.zeros(2000)})
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------------------------------- landmarks


def test_read_landmarks3d_both_layouts(tmp_path):
    wrapped = {"landmarks": {"nose_tip": [1, 2.5, 110.0], "chin": [0.0, -90.0, 80.0]}}
    (tmp_path / "a.json").write_text(json.dumps(wrapped))
    (tmp_path / "b.json").write_text(json.dumps(wrapped["landmarks"]))
    for name in ("a.json", "b.json"):
        landmarks = read_landmarks3d(tmp_path / name)
        assert list(landmarks) == ["nose_tip", "chin"]
        assert landmarks["nose_tip"].dtype == np.float64 and landmarks["nose_tip"].shape == (3,)
        np.testing.assert_array_equal(landmarks["nose_tip"], [1.0, 2.5, 110.0])


@pytest.mark.parametrize(
    "text, message",
    [
        ("{not json", "not valid JSON"),
        ('{"landmarks": {"nose_tip": [1, 2]}}', "'nose_tip' must be a list of 3 numbers"),
        ('{"chin": [1, "2", 3]}', "'chin' must be a list of 3 numbers"),
        ('{"chin": [1, 2, NaN]}', "'chin' has a non-finite"),
        ('{"landmarks": {}}', "no landmarks"),
        ("[[1, 2, 3]]", "expected"),
    ],
)
def test_read_landmarks3d_bad_files(tmp_path, text, message):
    path = tmp_path / "lm.json"
    path.write_text(text)
    with pytest.raises(CloudError, match=message) as info:
        read_landmarks3d(path)
    assert "lm.json" in str(info.value)


def test_read_landmarks3d_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_landmarks3d(tmp_path / "none.json")


# ------------------------------------------------------------------------------------ large clouds


def test_count_distinct_equals_np_unique(rng):
    points = np.round(rng.normal(size=(3000, 3)), 1)
    points[:10] = [0.0, -0.0, 1.0]
    assert count_distinct(points) == len(np.unique(points, axis=0))
    assert count_distinct(points[:1]) == 1


def test_clouds_up_to_the_threshold_are_kept_as_given(ellipsoid):
    points, normals = ellipsoid
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no subsampling warning
        kept = validate_points(points, normals, large_cloud_points=len(points))
    np.testing.assert_array_equal(kept.points, points)
    assert kept.input_points == len(points)
    assert PointCloud(points, None, "", "mm", 1.0).input_points == len(points)  # old constructors still work
    with pytest.warns(UserWarning, match=f"{len(points)} points: kept a random 1000 of them"):
        reduced = validate_points(
            points, normals, large_cloud_points=len(points) - 1, subsample_points=1000, min_points=100
        )
    assert reduced.input_points == len(points) and len(reduced.points) == 1000
    with pytest.raises(CloudError, match="subsample_points"):
        validate_points(points, large_cloud_points=10, subsample_points=0)
    assert LARGE_CLOUD_POINTS == 200_000 and SUBSAMPLE_POINTS == 50_000  # as documented


@pytest.mark.parametrize("ext", [".npy", ".ply"])
def test_a_million_point_file_is_subsampled_uniformly_in_file_order(tmp_path, ellipsoid, rng, ext):
    points, normals = ellipsoid
    n = 1_200_000
    pick = rng.integers(len(points), size=n)
    dense = (points[pick] + rng.normal(0.0, 1.0, (n, 3))) / 1000.0  # metres: the units are found on all points
    stray = rng.random(n) < 0.02  # 2 % outliers, 50 mm out
    dense[stray] *= 1.0 + 50.0 / np.linalg.norm(dense[stray] * 1000.0, axis=1, keepdims=True)
    path = tmp_path / f"dense{ext}"
    if ext == ".npy":
        np.save(path, np.hstack([dense, normals[pick]]))
    else:
        write_point_cloud_ply(path, dense, normals=normals[pick])
        dense = dense.astype(np.float32).astype(np.float64)
    with pytest.warns(UserWarning, match="1200000 points: kept a random 50000 of them"):
        cloud = read_point_cloud(path)
    assert cloud.input_points == n and len(cloud.points) == SUBSAMPLE_POINTS and cloud.units == "m"
    # a subset of the file's rows, in file order, with their own normals
    rows = {tuple(p): i for i, p in enumerate(np.round(dense * 1000.0, 6))}
    index = np.array([rows[tuple(p)] for p in np.round(cloud.points, 6)])
    assert (np.diff(index) > 0).all()
    np.testing.assert_allclose(cloud.normals, normals[pick[index]], atol=1e-6)
    assert abs(stray[index].mean() - 0.02) < 0.003  # the share of outliers is kept
    np.testing.assert_array_equal(read_point_cloud(path).points, cloud.points)  # seeded: the same every time


def test_large_cloud_with_few_distinct_points_is_rejected_from_the_subsample(ellipsoid):
    points, _ = ellipsoid
    repeated = np.tile(points[:300], (LARGE_CLOUD_POINTS // 300 + 1, 1))
    with pytest.raises(CloudError, match="has 300 distinct points among 50000 drawn at random from its 200100"):
        validate_points(repeated)
