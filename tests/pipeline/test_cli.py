import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from pipeline.cli import main
from pipeline.viewer import fit_viewer_ready
from rig.parameters import params_to_theta
from tests.pipeline.conftest import fast_fit_args
from tests.support.gltf_reader import read_skinned_gltf


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_rig_info_json(capsys, asset):
    code, out, _ = run(capsys, "rig", "info", "--json")
    assert code == 0
    info = json.loads(out)
    assert info["vertices"] == len(asset.vertices) and info["faces"] == len(asset.faces)
    assert info["joints"] == 52 and info["free_parameters"] == 107  # Table 1's 105 + the neck's 2 (issue 25)
    assert info["skinning_floats"] == len(asset.weight_free)
    assert info["model_floats"] == 3 * len(asset.vertices) + 3 * 52 + len(asset.weight_free)


def test_rig_edit_writes_the_edited_head(capsys, tmp_path, rig64):
    params = {"nose_tip.translate_z": 8.0, "crown.translate_y": 20.0, "left_cheek.scale": 1.2}
    (tmp_path / "p.json").write_text(json.dumps({"joints": params}))
    out = tmp_path / "edited.obj"
    code, _, err = run(capsys, "rig", "edit", str(tmp_path / "p.json"), "--out", str(out))
    assert code == 0, err
    loaded = trimesh.load(out, process=False)
    expected = rig64(params_to_theta(params, dtype=torch.float64)[None]).vertices[0].numpy()
    assert np.abs(np.asarray(loaded.vertices)[: len(expected)] - expected).max() < 1e-5


def test_gltf_export_reimports_with_same_vertices_and_52_joints(capsys, tmp_path, asset, rig64):
    params = {"nose_tip.translate_z": 8.0, "left_ear_rotate_scale.rotate_z": -20.0}
    (tmp_path / "p.json").write_text(json.dumps(params))
    out = tmp_path / "rig.glb"
    code, _, err = run(
        capsys, "rig", "export", "--format", "gltf", "--out", str(out), "--params", str(tmp_path / "p.json")
    )
    assert code == 0, err
    back = read_skinned_gltf(out)
    expected = rig64(params_to_theta(params, dtype=torch.float64)[None]).vertices[0].numpy()
    # the edited head is the file's bind mesh (what a reader that does not skin loads), float32 in metres
    assert np.abs(back["vertices"] - expected).max() < 1e-3
    assert list(back["joint_names"]) == list(asset.joint_names) and len(back["joint_names"]) == 52
    assert np.array_equal(back["parents"], asset.parents)
    # Skinning the file's rest mesh with its own node transforms reproduces the edited head.
    world = np.zeros((52, 4, 4))
    for k, p in enumerate(back["parents"]):
        world[k] = back["local_matrices"][k] if p < 0 else world[p] @ back["local_matrices"][k]
    A = world @ back["inverse_bind_matrices"]
    V = back["vertices"]
    posed = np.zeros_like(V)
    for slot in range(4):
        j, w = back["joints"][:, slot], back["weights"][:, slot]
        posed += w[:, None] * (np.einsum("vij,vj->vi", A[j, :3, :3], V) + A[j, :3, 3])
    assert np.abs(posed - expected).max() < 1e-2


@pytest.mark.parametrize(
    "content, message",
    [
        ('{"joints": {"nose_tip.translate_q": 1}}', "unknown rig parameter"),
        ('{"joints": {"crown.translate_y": 400}}', "outside its limits"),
        ("{oops", "not valid JSON"),
    ],
)
def test_bad_parameter_file_is_a_clear_error(capsys, tmp_path, content, message):
    (tmp_path / "p.json").write_text(content)
    out = tmp_path / "e.ply"
    code, _, err = run(capsys, "rig", "edit", str(tmp_path / "p.json"), "--out", str(out))
    assert code == 2 and message in err and "Traceback" not in err
    assert not out.exists()


def test_missing_file_and_existing_output(capsys, tmp_path):
    code, _, err = run(capsys, "rig", "edit", str(tmp_path / "nope.json"), "--out", str(tmp_path / "e.obj"))
    assert code == 2 and "not found" in err
    (tmp_path / "p.json").write_text("{}")
    (tmp_path / "e.obj").write_text("keep me")
    code, _, err = run(capsys, "rig", "edit", str(tmp_path / "p.json"), "--out", str(tmp_path / "e.obj"))
    assert code == 2 and "--force" in err
    assert (tmp_path / "e.obj").read_text() == "keep me"
    code, _, err = run(capsys, "rig", "edit", str(tmp_path / "p.json"), "--out", str(tmp_path / "e.stl"))
    assert code == 2 and "format" in err


def test_clamp_option_warns_and_clamps(capsys, tmp_path):
    (tmp_path / "p.json").write_text('{"crown.translate_y": 400}')
    with pytest.warns(UserWarning, match="clamped"):
        code, _, err = run(capsys, "rig", "edit", str(tmp_path / "p.json"), "--out", str(tmp_path / "e.ply"), "--clamp")
    assert code == 0, err


@pytest.mark.slow  # three rig builds (18 s): in `make test-slow`, which CI runs, so the suite stays under 8 min
def test_rig_build_check_matches_committed_asset(capsys, tmp_path):
    code, out, _ = run(capsys, "rig", "build", "--check")
    assert code == 0 and "identical" in out
    code, _, err = run(capsys, "rig", "build", "--out", str(tmp_path / "a.npz"))
    assert code == 0, err
    code, out, _ = run(capsys, "rig", "build", "--check", "--out", str(tmp_path / "a.npz"))
    assert code == 0


@pytest.mark.slow  # 10 s of the fast suite's 6 minutes: CI's make test-slow runs it
def test_demo_writes_everything(capsys, tmp_path, monkeypatch):
    """The demo's files and figures. Its first step, rebuilding the template from code (17 s), is what the slow
    test_rig_build_check_matches_committed_asset checks; here it returns the committed asset with one vertex
    moved by a known 0.25 mm, so the demo's comparison is still exercised."""
    import pipeline.demo
    from rig.asset import load_asset

    def moved_asset():
        asset = load_asset()
        vertices = asset.vertices.copy()
        vertices[17, 1] += 0.25
        return dataclasses.replace(asset, vertices=vertices)

    monkeypatch.setattr(pipeline.demo, "build_asset", moved_asset)
    monkeypatch.chdir(tmp_path)  # --out relative to the working directory
    out = tmp_path / "demo"
    code, stdout, err = run(capsys, "demo", "--out", "demo", "--spp", "2", "--quiet", *_fast()[:-1])
    assert code == 0, err
    for name in (
        "template.obj",
        "template.ply",
        "template.glb",
        "edited.obj",
        "edited.glb",
        "edited.png",
        "edited_params.json",
        "summary.json",
    ):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["rebuild_max_difference_mm"] == pytest.approx(0.25)
    assert summary["edit_max_displacement_mm"] > 1.0
    for fit in ("astronaut", "synthetic"):
        assert (out / fit / "overlay.png").stat().st_size > 0 and (out / fit / "params.json").is_file()
    assert summary["astronaut"]["nme"] < 0.2  # 5 landmark steps here; the full fit reaches 0.03
    report = json.loads((out / "astronaut" / "report.json").read_text())
    found = report["input"]
    assert found["detector"] == "mediapipe" and found["detector_option"] == "auto"  # MediaPipe found it: no dlib run
    assert report["identity_prior"] == "regressed from the detector's 3D points"  # its depth reached the fit
    assert len(found["faces"]) == 1 and found["faces"][0]["box"] == found["face_box"] and found["face_index"] == 0
    assert 0 < summary["synthetic"]["s2m_median_mm"] < 2.0 and (out / "inputs" / "synthetic" / "truth.ply").is_file()
    assert "astronaut portrait" in stdout and "known truth" in stdout
    code, _, err = run(capsys, "demo", "--out", str(out), "--quiet")
    assert code == 2 and "--force" in err

    # every path the reports record exists after the command, also with the output moved elsewhere: inputs
    # are absolute, the demo's own files relative to the report's folder (tests/pipeline/test_report_paths.py)
    from tests.pipeline.test_report_paths import check_paths

    moved = tmp_path / "elsewhere" / "demo"
    moved.parent.mkdir()
    os.rename(out, moved)
    summary = json.loads((moved / "summary.json").read_text())
    assert summary["astronaut"]["photo"] == "inputs/astronaut.png" and summary["synthetic"]["output"] == "synthetic"
    checked = check_paths(moved / "summary.json", skip=(".output",))  # .output: where it was written
    assert {".astronaut.photo", ".astronaut.output", ".synthetic.photo", ".synthetic.truth"} <= checked
    assert Path(summary["output"]) == out.resolve()
    for name in ("astronaut", "synthetic"):
        checked = check_paths(moved / name / "report.json")
        assert ".input.photo" in checked and ".texture.file" in checked


# ----------------------------------------------------------------------------------------------------
# jnr fit PHOTO
# ----------------------------------------------------------------------------------------------------


def _fast(*extra):
    return fast_fit_args(*extra)


def test_fit_one_photo_with_a_landmarks_file(capsys, tmp_path, photo_dir):
    from pipeline.photo.outputs import mesh_from_photo_params

    out = tmp_path / "one"
    code, stdout, err = run(
        capsys,
        "fit",
        str(photo_dir / "face0.png"),
        "--landmarks",
        str(photo_dir / "face0.pts"),
        "--out",
        str(out),
        *_fast(),
    )
    assert code == 0, err
    assert "landmark error" in stdout
    report = json.loads((out / "report.json").read_text())
    assert report["input"]["landmarks"].endswith("face0.pts") and report["photometric_stages"] == []
    obj = trimesh.load(out / "mesh.obj", process=False)
    rebuilt = mesh_from_photo_params(out / "params.json")
    assert np.abs(np.asarray(obj.vertices)[: len(rebuilt)] - rebuilt).max() < 1e-3
    # existing output: an error, the folder untouched
    before = (out / "report.json").read_bytes()
    code, _, err = run(
        capsys,
        "fit",
        str(photo_dir / "face0.png"),
        "--landmarks",
        str(photo_dir / "face0.pts"),
        "--out",
        str(out),
        *_fast(),
    )
    assert code == 2 and "exists" in err and (out / "report.json").read_bytes() == before


@pytest.mark.parametrize(
    "case, message",
    [
        ("missing", "image file not found"),
        ("corrupt", "cannot read image"),
        ("blank", "no face found"),
        ("bad_landmarks", "n_points"),
        ("few_landmarks", "68"),
        ("bad_focal", "--focal"),
    ],
)
def test_fit_bad_inputs_exit_2_and_write_nothing(capsys, tmp_path, photo_dir, case, message):
    from PIL import Image

    photo, extra = photo_dir / "face0.png", []
    if case == "missing":
        photo = tmp_path / "nothere.png"
    elif case == "corrupt":
        photo = tmp_path / "corrupt.jpg"
        photo.write_bytes(b"\xff\xd8 not really a jpeg")
    elif case == "blank":
        photo = tmp_path / "blank.png"
        Image.fromarray(np.full((120, 160, 3), 128, np.uint8)).save(photo)
    elif case == "bad_landmarks":
        (tmp_path / "bad.pts").write_text("version: 1\nn_points: 3\n{\n1 2\n}\n")
        extra = ["--landmarks", str(tmp_path / "bad.pts")]
    elif case == "few_landmarks":
        (tmp_path / "few.csv").write_text("index,x,y\n0,1,2\n1,3,4\n")
        extra = ["--landmarks", str(tmp_path / "few.csv")]
    elif case == "bad_focal":
        extra = ["--landmarks", str(photo_dir / "face0.pts"), "--focal", "-5"]
    out = tmp_path / "out"
    code, _, err = run(capsys, "fit", str(photo), "--out", str(out), *_fast(*extra))
    assert code == 2, err
    assert message in err and "Traceback" not in err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_fit_face_index_out_of_range(capsys, tmp_path):
    from PIL import Image
    from skimage import data

    Image.fromarray(data.astronaut()).save(tmp_path / "astronaut.png")
    code, _, err = run(
        capsys, "fit", str(tmp_path / "astronaut.png"), "--face", "4", "--out", str(tmp_path / "o"), *_fast()
    )
    assert code == 2 and "--face must be 0..0" in err


def test_fit_a_folder_in_parallel_with_sidecar_landmarks(capsys, tmp_path, photo_dir):
    import shutil

    folder = tmp_path / "batch"
    shutil.copytree(photo_dir, folder)
    (folder / "broken.png").write_bytes(b"\x89PNG broken")
    out = tmp_path / "fits"
    code, stdout, err = run(
        capsys, "fit", str(folder), "--landmarks", "auto", "--jobs", "2", "--out", str(out), *_fast()
    )
    # the two good photos are fitted, the broken one is reported and makes the exit status 2
    assert code == 2 and "broken.png" in err
    shared = ["three.jnr.js"] if fit_viewer_ready() else []  # the run's one three.js, the pages link to it
    assert sorted(p.name for p in out.iterdir()) == ["face0", "face1", "summary.csv", *shared]
    for name in ("face0", "face1"):
        report = json.loads((out / name / "report.json").read_text())
        assert report["input"]["landmarks"].endswith(f"{name}.pts")
    assert "fitted 2 of 3 photos with 2 process(es)" in stdout
    import multiprocessing

    import psutil

    # no worker outlives the command (multiprocessing's resource tracker, a helper that ends with this process,
    # may be running)
    helpers = [c for c in psutil.Process().children() if "resource_tracker" not in " ".join(c.cmdline())]
    assert multiprocessing.active_children() == [] and helpers == []
    # summary.csv: a row per photo, the broken one with its error
    rows = _summary_rows(out / "summary.csv")
    assert [(Path(r["photo"]).name, r["status"]) for r in rows] == [
        ("broken.png", "error"),
        ("face0.png", "ok"),
        ("face1.png", "ok"),
    ]
    assert "broken.png" in rows[0]["error"] and rows[0]["output"] == "" and rows[0]["nme"] == ""
    for row in rows[1:]:
        report = json.loads((Path(row["output"]) / "report.json").read_text())
        assert float(row["mean_error_px"]) == pytest.approx(report["landmarks"]["mean_error_px"], abs=1e-3)
        assert float(row["nme"]) == pytest.approx(report["landmarks"]["nme_inter_ocular"], abs=1e-5)
        assert row["face"] == row["faces_found"] == "" and float(row["seconds"]) > 0  # landmarks from files
        # the fit alone (what stdout's "fitted ... in" gives) and the photo in all (detection, fit, outputs)
        assert float(row["fit_seconds"]) == pytest.approx(report["timings_s"]["total"], abs=0.01)
        assert float(row["seconds"]) >= float(row["fit_seconds"]) > 0


def _summary_rows(path):
    import csv

    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_fit_face_all_writes_every_face(capsys, tmp_path, two_faces_photo):
    from pipeline.head.folders import PHOTO_FOLDER
    from pipeline.photo.outputs import mesh_from_photo_params

    out = tmp_path / "faces"
    code, stdout, err = run(capsys, "fit", str(two_faces_photo), "--face", "all", "--out", str(out), *_fast())
    assert code == 0, err
    assert "fitted 2 of 2 faces" in stdout
    assert sorted(p.name for p in out.iterdir()) == [".jnr-output", "face_0", "face_1", "summary.csv"]
    rows = _summary_rows(out / "summary.csv")
    assert [(r["face"], r["status"], r["faces_found"], r["output"]) for r in rows] == [
        ("0", "ok", "2", str(out / "face_0")),
        ("1", "ok", "2", str(out / "face_1")),
    ]
    boxes = []
    for k, row in enumerate(rows):
        folder = out / f"face_{k}"
        assert set(PHOTO_FOLDER.required) <= {p.name for p in folder.iterdir()}
        report = json.loads((folder / "report.json").read_text())
        assert report["input"]["face_index"] == k and len(report["input"]["faces"]) == 2
        box = [float(row[f"box_{side}"]) for side in ("left", "top", "right", "bottom")]
        assert box == pytest.approx(report["input"]["face_box"], abs=0.05)
        boxes.append(box)
        assert float(row["nme"]) == pytest.approx(report["landmarks"]["nme_inter_ocular"], abs=1e-5)
        # the outputs re-load: the parameters rebuild the mesh that mesh.obj holds
        params = json.loads((folder / "params.json").read_text())
        assert params["format"] == "jnr-params/2" and params["fit"] == "photo" and params["model"] == "jnr"
        obj = trimesh.load(folder / "mesh.obj", process=False)
        rebuilt = mesh_from_photo_params(folder / "params.json")
        assert np.abs(np.asarray(obj.vertices)[: len(rebuilt)] - rebuilt).max() < 1e-3
    # largest first, as --face numbers them; the two boxes are the two portraits
    (l0, t0, r0, b0), (l1, t1, r1, b1) = boxes
    assert (r0 - l0) * (b0 - t0) > (r1 - l1) * (b1 - t1) and r0 < 256 <= l1
    # an existing output is refused, untouched
    before = (out / "summary.csv").read_bytes()
    code, _, err = run(capsys, "fit", str(two_faces_photo), "--face", "all", "--out", str(out), *_fast())
    assert code == 2 and "exists" in err and (out / "summary.csv").read_bytes() == before


@pytest.mark.parametrize(
    "case, message",
    [
        ("landmarks", "cannot be used with --landmarks"),
        ("landmarks_auto", "cannot be used with --landmarks"),
        ("not_a_number", "--face must be a face number"),
        ("no_face", "no face found"),
    ],
)
def test_fit_face_all_errors_are_one_line(capsys, tmp_path, photo_dir, case, message):
    from PIL import Image

    photo, args = photo_dir / "face0.png", ["--face", "all"]
    if case == "landmarks":
        args += ["--landmarks", str(photo_dir / "face0.pts")]
    elif case == "landmarks_auto":
        args += ["--landmarks", "auto"]
    elif case == "not_a_number":
        args = ["--face", "two"]
    elif case == "no_face":
        photo = tmp_path / "blank.png"
        Image.fromarray(np.full((120, 160, 3), 128, np.uint8)).save(photo)
    out = tmp_path / "out"
    code, stdout, err = run(capsys, "fit", str(photo), "--out", str(out), *_fast(*args))
    assert code == 2 and message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_fit_photometric_and_landmarks_only_contradict(capsys, tmp_path, photo_dir):
    out = tmp_path / "out"
    code, _, err = run(
        capsys,
        "fit",
        str(photo_dir / "face0.png"),
        "--landmarks",
        str(photo_dir / "face0.pts"),
        "--out",
        str(out),
        "--landmarks-only",
        "--photometric",
        "--quiet",
    )
    assert code == 2 and "--landmarks-only and --photometric contradict" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_version_and_progress_bars_only_on_a_terminal(capsys, monkeypatch):
    import io

    from pipeline.cli import package_version
    from pipeline.cli.common import StageBars, progress_bars_wanted

    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out.strip()
    assert out == f"jnr {package_version()}" and out.split()[1][0].isdigit()

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    assert progress_bars_wanted(Terminal()) and not progress_bars_wanted(io.StringIO())  # a log file: no bars
    monkeypatch.setenv("TQDM_DISABLE", "1")
    assert not progress_bars_wanted(Terminal())
    monkeypatch.setenv("TQDM_DISABLE", "0")
    assert progress_bars_wanted(Terminal())
    assert StageBars(disable=True).disable


def test_verbose_after_the_subcommand_and_stage_log_lines(caplog):
    import logging

    from pipeline.cli import build_parser
    from pipeline.cli.common import StageBars

    parser = build_parser()
    assert parser.parse_args(["rig", "info", "-v"]).verbose and parser.parse_args(["-v", "rig", "info"]).verbose
    assert parser.parse_args(["eval", "capacity", "--verbose"]).verbose
    assert not parser.parse_args(["rig", "info"]).verbose
    # --quiet likewise, before or after any sub-command, also those that draw no bars
    for argv in (
        ["--quiet", "fit", "a.png", "--out", "o"],
        ["fit", "a.png", "--out", "o", "--quiet"],
        ["--quiet", "rig", "info"],
        ["retarget", "a", "b", "--out", "c", "--quiet"],
    ):
        assert parser.parse_args(argv).quiet, argv
    assert not parser.parse_args(["fit", "a.png", "--out", "o"]).quiet
    bars = StageBars(disable=True)
    with caplog.at_level(logging.INFO, logger="jnr"):
        for i in range(1, 4):
            bars("joints", i, 3)
        bars("latent", 1, 2)
        bars.close()
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0].startswith("joints: 3/3 steps in ") and lines[1].startswith("latent: 1/2 steps in ")


def test_the_eval_progress_bar_counts_each_item_once_whatever_its_head_model(monkeypatch, capsys):
    """``jnr eval scans --set skinning=asm`` records ``asm_k2`` and the baseline, not ``jnr``: the bar counted
    only ``jnr`` records and never moved; it counts each scan or photo at its first record."""
    import argparse
    from types import SimpleNamespace

    import pipeline.cli.evaluate as evaluate

    seen = []

    class Bars:
        def __init__(self, quiet):
            pass

        def __call__(self, label, done, total):
            seen.append((done, total))

        def close(self):
            pass

    monkeypatch.setattr(evaluate, "StageBars", Bars)
    records = [
        SimpleNamespace(name=name, kind=kind, method=method)
        for name, kind in (("heldout_000", "neutral"), ("heldout_000", "expressive"))
        for method in ("asm_k2", "nricp_amberg")
    ]

    def run(progress):
        for record in records:
            progress(record)
        return SimpleNamespace(records=[], summary=dict, settings={}, table_markdown=lambda: "table")

    args = argparse.Namespace(neutral=1, expressive=1, quiet=True, out=None, json=False, force=False)
    assert evaluate._run_evaluation(args, "simulated scans", run) == 0
    assert seen == [(1, 2), (2, 2)]
