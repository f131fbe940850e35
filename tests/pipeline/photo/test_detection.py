"""``jnr fit`` with a registered detector (:mod:`landmarks.detector`): a fake one that returns known landmarks
is what the fit uses, end to end through the command line; unknown names are refused before any work."""

import json
import re

import numpy as np
import pytest

from landmarks.detector import DetectionError, FaceDetection, register_detector, unregister_detector
from landmarks.formats import read_landmarks
from pipeline.cli import main
from pipeline.photo.photo_file import fit_photo_file
from tests.pipeline.conftest import fast_fit_args


class KnownLandmarks:
    """A detector that finds one face with the landmarks it was given (and a smaller decoy face)."""

    name = "known"
    description = "known landmarks (a test's detector)"

    def __init__(self, points: np.ndarray):
        self.points = points
        self.images = []

    def detect(self, image):
        self.images.append(image.shape)
        box = np.array([*self.points.min(0), *self.points.max(0)])
        decoy = FaceDetection(np.array([0.0, 0.0, 4.0, 4.0]), 5.0, np.zeros((68, 2)), self.name)
        return [decoy, FaceDetection(box, 0.75, self.points, self.name)]


@pytest.fixture
def known(photo_dir):
    """``--detector known``: face0's landmarks (from its .pts file), registered for one test."""
    detector = KnownLandmarks(read_landmarks(photo_dir / "face0.pts"))
    register_detector("known", lambda: detector, summary="face0's landmarks")
    yield detector
    unregister_detector("known")


def test_jnr_fit_uses_the_registered_detectors_landmarks(capsys, tmp_path, photo_dir, known):
    out, reference = tmp_path / "detected", tmp_path / "from_file"
    code = main(
        [str(a) for a in ("fit", photo_dir / "face0.png", "--detector", "known", "--out", out, *fast_fit_args())]
    )
    _, err = capsys.readouterr()
    assert code == 0, err
    assert known.images == [(128, 128, 3)]  # the photo, once
    source = json.loads((out / "report.json").read_text())["input"]
    assert source["detector"] == source["detector_option"] == "known"
    assert source["landmarks"] == "known landmarks (a test's detector)"
    assert source["face_index"] == 0 and source["face_score"] == 0.75  # the larger face, not the decoy
    assert [f["score"] for f in source["faces"]] == [0.75, 5.0]
    assert source["face_box"] == pytest.approx([*known.points.min(0), *known.points.max(0)])
    # the input landmarks written are the detector's, and the fit is the one from the same landmarks in a file
    np.testing.assert_allclose(read_landmarks(out / "landmarks.pts"), known.points, atol=1e-9)
    code = main(
        [str(a) for a in ("fit", photo_dir / "face0.png", "--landmarks", photo_dir / "face0.pts", "--out", reference)]
        + fast_fit_args()
    )
    assert code == 0
    for name in ("landmarks_fitted.pts", "params.json", "mesh.obj"):
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name


def test_a_detector_that_finds_nothing_is_one_line(capsys, tmp_path, photo_dir):
    class Nothing:
        name, description = "nothing", "a detector that never finds a face"

        def detect(self, image):
            return []

    register_detector("nothing", Nothing)
    try:
        out = tmp_path / "o"
        code = main([str(a) for a in ("fit", photo_dir / "face0.png", "--detector", "nothing", "--out", out)])
    finally:
        unregister_detector("nothing")
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "face0.png: no face found in the image (a detector that never finds a face)" in err
    assert not out.exists()


def test_unknown_detectors_are_refused_before_any_work(capsys, tmp_path, photo_dir):
    with pytest.raises(SystemExit) as exit_info:  # argparse: the choices are the registered names
        main([str(a) for a in ("fit", photo_dir / "face0.png", "--detector", "yolo", "--out", tmp_path / "o")])
    assert exit_info.value.code == 2 and "invalid choice: 'yolo'" in capsys.readouterr().err
    with pytest.raises(DetectionError, match="fit_photo_file: unknown face detector 'yolo'; the detectors are hog"):
        fit_photo_file(photo_dir / "face0.png", tmp_path / "o", detector="yolo")
    assert not (tmp_path / "o").exists()


def _dense_points(photo_dir) -> np.ndarray:
    """``(478, 3)`` MediaPipe-layout points for face0.png: the template's embedded points seen in the pose
    that face0's 68 landmarks give (z: depth in the same pixel scale, as MediaPipe's)."""
    from landmarks.ibug68.embedding import ibug68_embedding
    from landmarks.ibug68.positions import landmark_positions
    from landmarks.mediapipe.layout import mediapipe_layout
    from pipeline.camera import RIG_TO_OPENCV, default_focal, solve_pose
    from rig.asset import load_asset

    asset = load_asset()
    lm = read_landmarks(photo_dir / "face0.pts")
    focal = default_focal(128, 128)
    rotation, translation = solve_pose(
        lm, landmark_positions(asset.vertices, ibug68_embedding(asset), asset.faces)[0], 128, 128, focal
    )
    points = landmark_positions(asset.vertices, mediapipe_layout(asset).embedding, asset.faces)[0]
    camera = points @ (RIG_TO_OPENCV @ rotation).T + translation
    uv = focal * camera[:, :2] / camera[:, 2:] + 63.5
    return np.c_[uv, focal * (camera[:, 2] - camera[:, 2].mean()) / camera[:, 2].mean()]


def test_dense_points_from_a_detector_or_a_478_point_file_fit_the_same(capsys, tmp_path, photo_dir):
    """A detector's 478 dense points are what the fit uses (report: ``fitted_layout``), the same as those points
    in a landmark file (without the identity read from the detector's depth, which a file does not have);
    ``landmarks.dense=false`` fits their 68 iBUG points instead; a 468-point file (no irises) fits too; a file of
    another count is one line."""
    from landmarks.formats import write_landmarks
    from landmarks.mediapipe.ibug68_map import mesh_to_ibug68

    dense = _dense_points(photo_dir)

    class Dense:
        name, description = "dense", "known dense points (a test's detector)"

        def detect(self, image):
            box = np.array([*dense[:, :2].min(0), *dense[:, :2].max(0)])
            return [FaceDetection(box, 0.9, mesh_to_ibug68(dense[:, :2]), self.name, dense=dense)]

    register_detector("dense", Dense, summary="known dense points")
    try:
        runs = {}
        write_landmarks(tmp_path / "p478.json", dense[:, :2])
        write_landmarks(tmp_path / "p468.csv", dense[:468, :2])
        write_landmarks(tmp_path / "p100.csv", dense[:100, :2])
        for name, args in (
            # without the identity read from the detector's depth (a file has none): the same fit as the file's
            ("detected", ["--detector", "dense", "--set", "landmarks.regression.enabled=false"]),
            ("file", ["--landmarks", tmp_path / "p478.json"]),
            ("ibug", ["--detector", "dense", "--set", "landmarks.dense=false"]),
            ("mesh", ["--landmarks", tmp_path / "p468.csv"]),
        ):
            out = tmp_path / name
            code = main([str(a) for a in ("fit", photo_dir / "face0.png", *args, "--out", out, *fast_fit_args())])
            assert code == 0, capsys.readouterr().err
            runs[name] = out
        reports = {k: json.loads((v / "report.json").read_text()) for k, v in runs.items()}
        assert {r["identity_prior"] for r in reports.values()} == {"population"}
        layouts = {k: r["input"]["fitted_layout"] for k, r in reports.items()}
        assert layouts == {"detected": "mediapipe", "file": "mediapipe", "ibug": "ibug68", "mesh": "mediapipe468"}
        # the dense points in 3D, mesh.obj's frame: all of them (478 / 468), on the fitted mesh's surface
        import trimesh

        from rig.geometry import closest_surface_points

        counts = {}
        for name, out in runs.items():
            path = out / "landmarks3d_mediapipe.json"
            counts[name] = len(json.loads(path.read_text())["points"]) if path.is_file() else None
        assert counts == {"detected": 478, "file": 478, "ibug": None, "mesh": 468}
        data = json.loads((runs["mesh"] / "landmarks3d_mediapipe.json").read_text())
        assert data["layout"] == "mediapipe468" and data["units"] == "mm"
        points = np.asarray(data["points"])
        mesh = trimesh.load(runs["mesh"] / "mesh.obj", process=False)
        distance = closest_surface_points(points, np.asarray(mesh.vertices), np.asarray(mesh.faces)).distance
        assert distance.max() <= 0.01, distance.max()
        for name in ("params.json", "mesh.obj", "landmarks.pts"):
            assert (runs["detected"] / name).read_bytes() == (runs["file"] / name).read_bytes(), name
        assert (runs["detected"] / "params.json").read_bytes() != (runs["ibug"] / "params.json").read_bytes()
        code = main(
            [str(a) for a in ("fit", photo_dir / "face0.png", "--landmarks", tmp_path / "p100.csv", "--out", "x")]
        )
        err = capsys.readouterr().err
        assert code == 2 and "expected 68 or 468 or 478 landmarks, got 100" in err and len(err.splitlines()) == 1
    finally:
        unregister_detector("dense")


def test_units_m_scales_the_obj_and_ply_and_nothing_else(capsys, tmp_path, photo_dir):
    """``--units m``: mesh.obj, mesh.ply and the mesh-frame landmarks in metres; every other file as with mm."""
    import trimesh

    runs = {}
    for units in ("mm", "m"):
        out = tmp_path / units / "fit"  # the same folder name: it is in viewer.html
        out.parent.mkdir()
        args = ("fit", photo_dir / "face0.png", "--landmarks", photo_dir / "face0.pts", "--out", out, "--units", units)
        code = main([str(a) for a in args] + fast_fit_args())
        assert code == 0, capsys.readouterr().err
        runs[units] = out
    mm, m = runs["mm"], runs["m"]
    for name in ("mesh.obj", "mesh.ply"):
        a = np.asarray(trimesh.load(mm / name, process=False).vertices)
        b = np.asarray(trimesh.load(m / name, process=False).vertices)
        np.testing.assert_allclose(b, a * 1e-3, atol=1e-6)
    assert "metres" in (m / "mesh.obj").read_text().splitlines()[0]
    mesh_mm = np.asarray(json.loads((mm / "landmarks3d_mesh.json").read_text())["points"])
    mesh_m = json.loads((m / "landmarks3d_mesh.json").read_text())
    assert mesh_m["units"] == "m"
    np.testing.assert_allclose(np.asarray(mesh_m["points"]), mesh_mm * 1e-3, atol=1e-9)
    changed = {"mesh.obj", "mesh.ply", "landmarks3d_mesh.json", "landmarks3d.pp", "landmarks_now.txt"}
    changed |= {"config.yaml", "report.json"}
    for path in sorted(mm.iterdir()):
        if path.name not in changed and path.is_file():
            assert path.read_bytes() == (m / path.name).read_bytes(), path.name
    assert json.loads((m / "report.json").read_text())["config"]["outputs"]["units"] == "m"


def test_verbose_logs_every_phase_with_its_seconds(tmp_path, photo_dir, caplog):
    """``-v``: reading, the landmarks, the fit and every output each get a log line with seconds."""
    import logging

    with caplog.at_level(logging.INFO):
        code = main(
            [str(a) for a in ("fit", photo_dir / "face0.png", "--landmarks", photo_dir / "face0.pts")]
            + ["--out", str(tmp_path / "out"), "-v", *fast_fit_args()]
        )
    assert code == 0
    text = "\n".join(r.getMessage() for r in caplog.records)
    for phase in (r"read 128 x 128 in \d+\.\d\d s", r"68 landmarks \(file\) in", r"fitted ibug68 points in"):
        assert re.search(phase, text), (phase, text)
    outputs = re.search(r"outputs in (\d+\.\d\d) s \((.*)\)", text)
    assert outputs is not None, text
    parts = dict(re.findall(r"(?:^|, )([a-z][a-z, ]*?) (\d+\.\d\d) s", outputs.group(2)))
    assert {"render", "texture", "glb", "viewer"} <= set(parts), parts
    assert sum(float(v) for v in parts.values()) == pytest.approx(float(outputs.group(1)), abs=0.05)


def test_outputs_sets_write_only_their_files_and_resume_with_them(capsys, tmp_path, photo_dir):
    """``--outputs minimal`` / ``mesh`` write exactly their files; a folder run resumed with the same set keeps
    the fits it made (complete for their set), and a fit made with another set counts as other settings."""
    from pipeline.head.folders import PHOTO_OUTPUT_SETS

    for name in ("minimal", "mesh"):
        out = tmp_path / name
        args = ("fit", photo_dir / "face0.png", "--landmarks", photo_dir / "face0.pts", "--out", out)
        code = main([str(a) for a in args] + ["--outputs", name, *fast_fit_args()])
        assert code == 0, capsys.readouterr().err
        assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == sorted(PHOTO_OUTPUT_SETS[name])
        assert json.loads((out / "report.json").read_text())["config"]["outputs"]["files"] == name
    # a folder of two photos (their .pts beside them), minimal, run twice: the second keeps both
    folder = tmp_path / "photos"
    folder.mkdir()
    for f in ("face0.png", "face0.pts", "face1.png", "face1.pts"):
        (folder / f).write_bytes((photo_dir / f).read_bytes())
    fits = tmp_path / "fits"
    run = ["fit", str(folder), "--landmarks", "auto", "--out", str(fits), "--outputs", "minimal", *fast_fit_args()]
    assert main(run) == 0
    capsys.readouterr()
    assert main(run) == 0
    stdout = capsys.readouterr().out
    assert "kept 2 (fitted earlier)" in stdout, stdout
    assert not (fits / "face0" / "mesh.obj").exists()


def test_the_detectors_depth_travels_and_a_files_2d_points_have_none():
    from pipeline.photo.detection import dense_fit_points

    detected = np.arange(478 * 3, dtype=float).reshape(478, 3)
    pixels, points3d = dense_fit_points(detected)
    assert np.array_equal(pixels, detected[:, :2]) and np.array_equal(points3d, detected)
    from_file = detected[:, :2].copy()
    pixels, points3d = dense_fit_points(from_file)
    assert np.array_equal(pixels, from_file) and points3d is None
