"""Issue 29's defects (../shared/notes/reliability-review-2026-12.md), each reproduced and shown fixed: what the
user put into an output folder survives ``--force`` (D1, D2), derived output names stay inside ``--out`` and
never clash (D3, D24)."""

from __future__ import annotations

import json
import os

import pytest

from pipeline.cli import main
from pipeline.files import OUTPUT_MARKER, OutputError, foreign_entries, is_jnr_output, staged_folder
from tests.pipeline.conftest import fast_fit_args


def _write(out, force=False, name="mesh.obj"):
    with staged_folder(out, force) as tmp:
        (tmp / name).write_text("jnr's")
        (tmp / "report.json").write_text("{}")


def test_the_marker_lists_what_jnr_wrote(tmp_path):
    out = tmp_path / "o"
    _write(out)
    marker = json.loads((out / OUTPUT_MARKER).read_text())
    assert marker["written_by"] == "jnr" and marker["files"] == ["mesh.obj", "report.json"]
    assert is_jnr_output(out) and foreign_entries(out) == []


def test_force_refuses_a_folder_holding_the_users_files_and_keeps_everything(tmp_path):
    """D1: a note and a sub-folder the user put into jnr's output: --force is one line naming them; the old
    output and the user's entries are all still there, nothing staged is left."""
    out = tmp_path / "o"
    _write(out)
    (out / "notes.txt").write_text("my notes")
    (out / "my_edits").mkdir()
    (out / "my_edits" / "a.obj").write_text("x")
    with pytest.raises(OutputError, match=r"holds what jnr did not write \(my_edits, notes.txt\)"):
        _write(out, force=True, name="new.obj")
    assert sorted(p.name for p in out.iterdir()) == [OUTPUT_MARKER, "mesh.obj", "my_edits", "notes.txt", "report.json"]
    assert (out / "notes.txt").read_text() == "my notes" and (out / "my_edits" / "a.obj").read_text() == "x"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]
    # once the user's entries are moved out, --force replaces jnr's files
    (out / "notes.txt").unlink()
    (out / "my_edits" / "a.obj").unlink()
    (out / "my_edits").rmdir()
    _write(out, force=True, name="new.obj")
    assert sorted(p.name for p in out.iterdir()) == [OUTPUT_MARKER, "new.obj", "report.json"]


def test_a_marker_anyone_could_write_is_not_trusted(tmp_path):
    """D2: ``{}`` in .jnr-output beside a thesis: not jnr's folder, --force refuses it."""
    out = tmp_path / "o"
    (out / "data").mkdir(parents=True)
    (out / "data" / "thesis.tex").write_text("precious")
    (out / OUTPUT_MARKER).write_text("{}")
    assert not is_jnr_output(out)
    with pytest.raises(OutputError, match="a folder jnr did not write"):
        _write(out, force=True)
    assert (out / "data" / "thesis.tex").read_text() == "precious"


def test_an_older_marker_without_a_list_keeps_what_was_added_after_it(tmp_path):
    """A folder of jnr before the list: what was changed after its marker is taken for the user's."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "mesh.obj").write_text("jnr's")
    (out / OUTPUT_MARKER).write_text(json.dumps({"written_by": "jnr", "command": "jnr fit"}))
    old = (out / OUTPUT_MARKER).stat().st_mtime - 60
    os.utime(out / "mesh.obj", (old, old))
    os.utime(out / OUTPUT_MARKER, (old + 1, old + 1))
    (out / "notes.txt").write_text("mine")
    assert foreign_entries(out) == ["notes.txt"]
    with pytest.raises(OutputError, match="notes.txt"):
        _write(out, force=True)


def test_jnr_fit_force_keeps_the_users_note(capsys, tmp_path, photo_dir):
    """D1 through the command: exit 2, one line, the note and the old fit kept."""
    out = tmp_path / "fit"
    args = ["fit", str(photo_dir / "face0.png"), "--landmarks", str(photo_dir / "face0.pts"), "--out", str(out)]
    assert main(args + fast_fit_args()) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    (out / "notes.txt").write_text("my notes")
    capsys.readouterr()
    assert main(args + fast_fit_args("--force")) == 2
    err = capsys.readouterr().err
    assert "notes.txt" in err and len(err.strip().splitlines()) == 1, err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == {**before, "notes.txt": b"my notes"}


def test_derived_names_stay_inside_out_and_never_clash(tmp_path):
    """D3: stems '..' and '.' (photos '...jpg', '..jpg'), a newline, a leading '-': safe names inside --out.
    D24: a.jpg, a.png and a_1.jpg got a_0, a_1 and a_1: now unique; the run's own file names are not taken."""
    from pipeline.photo.batch import output_names

    photos = ["ph/...jpg", "ph/..jpg", "ph/a.jpg", "ph/a.png", "ph/a_1.jpg", "ph/x\ny.jpg", "ph/-rf.jpg"]
    names = output_names([*photos, "ph/summary.csv.png", "ph/three.jnr.js.jpg"], ("summary.csv", "three.jnr.js"))
    assert names == ["photo_0", "photo_1", "a_2", "a_3", "a_1", "x_y", "_-rf", "summary.csv_", "three.jnr.js_"]
    assert len(set(names)) == len(names)
    out = tmp_path / "out"
    for name in names:
        assert (out / name).resolve().parent == out.resolve()
    assert output_names(["a.jpg", "b.jpg", "a_1.jpg", "a.png"]) == ["a_0", "b", "a_1", "a_3"]
    assert output_names(["a_0.jpg", "a.jpg", "a.png"]) == ["a_0", "a_1", "a_2"]
    clash = output_names(["a_1.jpg", "a.jpg", "a.png"])
    assert clash == ["a_1", "a_1_", "a_2"] and len(set(clash)) == 3


def test_a_scan_fit_writes_joint_values_its_readers_accept(tmp_path):
    """D6: the scan fit's soft limit penalty left channels outside their limits (bottom_lip.scale_z 1.505 > 1.5)
    and jnr rig edit / animate refused its params.json: the channels are projected onto their limits at the
    end (the mesh written from them), and listed in report.json."""
    import numpy as np
    import torch

    from pipeline.fitting.state import ScanState
    from rig.expressions import ExpressionModel
    from rig.model import JointRig
    from rig.parameters import CHANNELS, params_to_theta, theta_limits

    rig = JointRig()
    state = ScanState(rig, None, ExpressionModel(rig.asset), np.eye(3), np.zeros(3), 1.0)
    low, high = theta_limits(torch.float64)
    index = [c.name for c in CHANNELS].index("bottom_lip.scale_z")
    theta = torch.zeros(len(CHANNELS), dtype=torch.float64)
    theta[index] = high[index] + 0.005
    state.load(theta.numpy(), np.zeros(50), np.zeros(52))
    clamped = state.finish()
    assert list(clamped) == ["bottom_lip.scale_z"]
    assert clamped["bottom_lip.scale_z"] == pytest.approx([1.505, 1.5])
    values = {c.name: c.from_theta(float(t)) for c, t in zip(CHANNELS, state.theta.detach().double(), strict=True)}
    params_to_theta(values)  # inside every limit: no ParameterError


@pytest.mark.parametrize("size", [(1, 1), (1, 400), (31, 200)])
def test_a_photo_too_small_for_a_detector_is_one_line(capsys, tmp_path, size):
    """D7: a 1x1 PNG aborted inside dlib's CNN (exit -7, a C++ assertion), a 1 x 4000 one segfaulted: now a
    photo with a side under 32 px is refused before any detector sees it."""
    from PIL import Image

    photo = tmp_path / "tiny.png"
    Image.new("RGB", size, (128, 100, 90)).save(photo)
    code = main(["fit", str(photo), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "too small to find a face" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("joints", [[1, 2], "nose", 3])
def test_a_fit_whose_joints_are_not_an_object_is_one_line(capsys, tmp_path, joints):
    """D8: a params.json whose joints is a list or a string was an AttributeError traceback."""
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"format": "jnr-params/2", "fit": "photo", "model": "jnr", "joints": joints}))
    code = main(["rig", "edit", str(path), "--out", str(tmp_path / "e.obj")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not (tmp_path / "e.obj").exists()


def test_deeply_nested_files_are_one_line(capsys, tmp_path):
    """D9: nested JSON in a parameter file and nested YAML in --config were RecursionError tracebacks."""
    deep_json = tmp_path / "p.json"
    deep_json.write_text("[" * 100_000 + "]" * 100_000)
    code = main(["rig", "edit", str(deep_json), "--out", str(tmp_path / "e.obj")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    deep_yaml = tmp_path / "deep.yaml"
    deep_yaml.write_text("a: " + "[" * 100_000 + "]" * 100_000 + "\n")
    from PIL import Image

    Image.new("RGB", (64, 64), (120, 100, 90)).save(tmp_path / "p.png")
    code = main(["fit", str(tmp_path / "p.png"), "--config", str(deep_yaml), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "nested too deeply" in err and len(err.strip().splitlines()) == 1, err


def test_photometric_and_outputs_options_keep_the_users_settings(capsys, tmp_path):
    """D18: --photometric replaced the whole photometric group, dropping every --set photometric.* (an invalid
    one was silently ignored); --outputs/--units did the same to --set outputs.*."""
    from pipeline.cli import build_parser
    from pipeline.cli.common import CliError, load_fit_photo_config

    def config(*extra):
        return load_fit_photo_config(build_parser().parse_args(["fit", "p.png", "--out", "o", *extra]))

    c = config("--photometric", "--set", "photometric.spp=7", "--outputs", "mesh", "--set", "outputs.units=m")
    assert c.photometric.enabled and c.photometric.spp == 7
    assert c.outputs.files == "mesh" and c.outputs.units == "m"
    with pytest.raises(CliError, match="render_size"):
        config("--photometric", "--set", "photometric.render_size=0")


def test_a_newline_in_the_command_keeps_config_yaml_readable(tmp_path):
    """D4: a photo named 'a\\nlandmarks: 5\\n.jpg' put live YAML into config.yaml's header comment."""
    from pipeline.config import dump_config, load_config
    from pipeline.photo.fit_config import FitPhotoConfig

    path = tmp_path / "config.yaml"
    dump_config(FitPhotoConfig(), path, command="jnr fit 'a\nlandmarks: 5\n.jpg' --out o")
    assert load_config(FitPhotoConfig, path) == FitPhotoConfig()
    assert "# Made by: jnr fit 'a\\nlandmarks: 5\\n.jpg' --out o" in path.read_text()


@pytest.mark.parametrize("kind", ["uint16", "int32", "float01"])
def test_wide_greyscale_photos_are_read_as_they_mean(tmp_path, kind):
    """D19: a 16-bit greyscale PNG came out almost white (Pillow clips at 255), a float TIFF in [0, 1] black:
    now both read as the 8-bit picture they hold."""
    import numpy as np
    from PIL import Image

    from landmarks.images import load_working_image

    grey = np.tile(np.arange(0, 256, 1, dtype=np.uint8), (32, 1))
    if kind == "uint16":
        Image.fromarray(grey.astype(np.uint16) * 257).save(tmp_path / "g.png")
        path = tmp_path / "g.png"
    elif kind == "int32":
        Image.fromarray(grey.astype(np.int32) * 257, "I").save(tmp_path / "g.tif")
        path = tmp_path / "g.tif"
    else:
        Image.fromarray(grey.astype(np.float32) / 255.0, "F").save(tmp_path / "g.tif")
        path = tmp_path / "g.tif"
    image = load_working_image(path).image
    assert image.shape == (32, 256, 3)
    assert np.abs(image[..., 0].astype(int) - grey).max() <= 1


def _fifo(path):
    os.mkfifo(path)
    return path


def test_pipes_and_devices_are_refused_before_they_are_read(capsys, tmp_path):
    """D14, D15: a FIFO named x.ply blocked fit-scan forever, x.xyz -> /dev/zero grew until the memory was
    gone, a FIFO as curves blocked animate: each is one line, exit 2, nothing written."""
    cloud = _fifo(tmp_path / "x.ply")
    zero = tmp_path / "z.xyz"
    zero.symlink_to("/dev/zero")
    for clip in (cloud, zero):
        code = main(["fit-scan", str(clip), "--out", str(tmp_path / "o"), "--quiet"])
        err = capsys.readouterr().err
        assert code == 2 and "not a regular file" in err and len(err.strip().splitlines()) == 1, err
    from pipeline.head.curves import CurvesError, read_curves

    with pytest.raises(CurvesError, match="not a regular file"):
        read_curves(_fifo(tmp_path / "c.csv"))
    from pipeline.head.params import ParamsFileError, load_params_file

    with pytest.raises(ParamsFileError, match="not a regular file"):
        load_params_file(_fifo(tmp_path / "params.json"))
    assert not (tmp_path / "o").exists()


def test_files_an_input_names_are_not_opened(tmp_path, caplog):
    """D13, D14: a PLY cloud whose header names TextureFile /dev/zero was opened (and a traceback logged);
    an accessory OBJ whose mtllib names a FIFO hung: a cloud needs no texture, an accessory's material is
    optional, neither is opened."""
    import numpy as np

    from pipeline.accessory.inputs import read_accessory
    from pipeline.scan.pointcloud.read import read_point_cloud
    from rig.asset import load_asset

    rng = np.random.default_rng(0)
    points = rng.normal(0, 60, (500, 3))
    header = "ply\nformat ascii 1.0\ncomment TextureFile /dev/zero\nelement vertex 500\n"
    header += "property float x\nproperty float y\nproperty float z\nend_header\n"
    (tmp_path / "c.ply").write_text(header + "\n".join(" ".join(f"{v:.3f}" for v in p) for p in points) + "\n")
    import logging

    with caplog.at_level(logging.DEBUG):
        cloud = read_point_cloud(tmp_path / "c.ply", units="mm")
    assert len(cloud.points) == 500
    assert not [r for r in caplog.records if "image" in r.getMessage()], caplog.text
    asset = load_asset()
    _fifo(tmp_path / "hang.mtl")
    eye = np.asarray(asset.vertices)[np.asarray(asset.vertices)[:, 2].argmax()]  # the nose tip: on the skin
    v = eye + np.array([[0.0, 0, 2], [10, 0, 2], [0, 10, 2]])
    text = "mtllib hang.mtl\n" + "".join(f"v {a:.3f} {b:.3f} {c:.3f}\n" for a, b, c in v) + "f 1 2 3\n"
    (tmp_path / "acc.obj").write_text(text)
    accessory = read_accessory(tmp_path / "acc.obj", asset)
    assert accessory.faces.shape == (1, 3)


def test_preview_frame_counts_are_bounded():
    """D11, D16: a curve spanning 0 to 1e9 s asked numpy for 89 GiB of clock, 1e6 rows at 12 fps rendered for
    hours: the preview renders at most MAX_PREVIEW_FRAMES, spread over the take."""
    import numpy as np

    from pipeline.animation.keyframes import MAX_PREVIEW_FRAMES, _frame_indices

    rows = _frame_indices(np.array([0.0, 1e9]), 12.0)
    assert rows.tolist() == [0, 1]
    long = _frame_indices(np.arange(1_000_000) / 30.0, 12.0)
    assert len(long) == MAX_PREVIEW_FRAMES and long[0] == 0 and long[-1] == 999_999
    short = _frame_indices(np.arange(60) / 30.0, 12.0)  # 2 s at 12 fps: the clock as before
    assert len(short) == 24


@pytest.mark.parametrize("fps", ["inf", "nan", "0", "1000"])
def test_preview_fps_out_of_range_is_one_line(capsys, tmp_path, fps):
    code = main(["animate", str(tmp_path), "example", "--out", str(tmp_path / "a.glb"), "--preview-fps", fps])
    err = capsys.readouterr().err
    assert code == 2 and "--preview-fps" in err and len(err.strip().splitlines()) == 1, err


def test_a_photo_named_twice_is_fitted_once(tmp_path, caplog):
    """D33: the same photo twice on the command line, or a folder plus a photo inside it, was fitted twice
    (and left workers behind): inputs are taken once by their real path, with one log line."""
    import logging

    from PIL import Image

    from pipeline.photo.inputs import photo_inputs

    folder = tmp_path / "ph"
    folder.mkdir()
    for name in ("a.png", "b.png"):
        Image.new("RGB", (40, 40)).save(folder / name)
    (tmp_path / "link.png").symlink_to(folder / "a.png")
    with caplog.at_level(logging.WARNING):
        photos, folders = photo_inputs([folder / "a.png", folder, folder / "a.png", tmp_path / "link.png"])
    assert photos == [folder / "a.png", folder / "b.png"] and folders == [folder]
    assert "3 photo(s) named more than once" in caplog.text


@pytest.mark.parametrize(
    "args, message",
    [
        (["fit", "x.jpg", "--focal", "abc", "--out", "o"], "jnr fit: argument --focal: invalid float value: 'abc'"),
        (["fitt"], "invalid choice: 'fitt'"),
        (["fit", "x.jpg"], "the following arguments are required: --out"),
    ],
)
def test_argument_errors_are_one_line(capsys, args, message):
    """D28: argparse printed a usage block before its error: now one ``jnr: error:`` line, exit 2."""
    with pytest.raises(SystemExit) as exit_info:
        main(args)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and err.startswith("jnr: error: ") and message in err, err
    assert len(err.strip().splitlines()) == 1


def test_a_binary_landmarks_file_is_named_in_one_line(tmp_path):
    """D26: a landmarks file that is not UTF-8 text exited 1 with a codec message that did not name it."""
    from landmarks.formats import read_landmarks

    path = tmp_path / "bin.pts"
    path.write_bytes(b"\xff\xd8\xff\xe0" + bytes(range(256)))
    with pytest.raises(ValueError, match=r"bin\.pts.*not a text file"):
        read_landmarks(path)


def test_names_reach_terminals_and_spreadsheets_inert(capsys, tmp_path):
    """D5: a photo name with an escape sequence was printed raw (it could clear the terminal), and one named
    ``=1+2.jpg`` became a formula cell of summary.csv: escapes are printed as text, formula-like cells get a
    leading ``'`` that jnr's own reader takes off again."""
    from pipeline.cli.common import printable
    from pipeline.photo.summary import PhotoFileResult, read_summary, summary_csv

    assert printable("x\x1b[2J.jpg") == "x\\x1b[2J.jpg" and printable("a\nb") == "a b"
    rows = [PhotoFileResult("=1+2.jpg", error="=1+2.jpg: no face found", seconds=1.0, bad_input=True)]
    text = summary_csv(rows)
    assert "'=1+2.jpg" in text and "\n=" not in text and ",=" not in text
    path = tmp_path / "summary.csv"
    path.write_text(text)
    row = read_summary(path)[0]
    assert row["photo"] == "=1+2.jpg" and row["error"] == "=1+2.jpg: no face found"


def _rest_fit_params() -> dict:
    """A scan fit's params.json of the rest head (what jnr fit-scan writes, without running a fit)."""
    import numpy as np

    from pipeline.head.params import params_payload
    from rig.head_model import create

    model = create("jnr")
    params = model.params(np.zeros(107), np.zeros(50), np.zeros(52))
    pose = {"rotation_matrix": np.eye(3).tolist(), "translation_mm": [0.0, 0.0, 0.0], "scale": 1.0}
    return params_payload(model, params, fit="scan", pose=pose, input={"units": "mm", "scale_to_mm": 1.0})


@pytest.mark.parametrize(
    "change, culprit",
    [
        (lambda d: d["joints"].update({"nose_tip.translate_z": True}), "'nose_tip.translate_z' must be a number"),
        (lambda d: d["joints"].update({"nose_tip.translate_z": "1.0"}), "'nose_tip.translate_z' must be a number"),
        (lambda d: d["expressions"].update({"jawOpen": "0.5"}), "'jawOpen': value must be a number"),
        (lambda d: d["latent_z"].__setitem__(3, 1e30), "latent_z[3] = 1e+30 is outside [-6, 6]"),
        (lambda d: d["latent_z"].__setitem__(0, True), "latent_z[0] must be a finite number"),
        (lambda d: d["latent_z"].__setitem__(7, "nan"), "latent_z[7] must be a finite number"),
        (lambda d: d["latent_z"].__setitem__(2, float("nan")), "latent_z[2] must be a finite number"),
        (lambda d: d.update({"foo": 1}), "unknown key(s) ['foo']"),
    ],
)
def test_a_fits_parameters_are_numbers_of_the_right_kind_and_range(capsys, tmp_path, change, culprit):
    """D23: true, "1.0", a latent of 1e30 and unknown keys were accepted (exit 0, a head far from the fit's)."""
    data = _rest_fit_params()
    path = tmp_path / "params.json"
    path.write_text(json.dumps(data))
    assert main(["rig", "edit", str(path), "--out", str(tmp_path / "ok.obj")]) == 0  # the file as written
    capsys.readouterr()
    change(data)
    path.write_text(json.dumps(data))
    code = main(["rig", "edit", str(path), "--out", str(tmp_path / "e.obj")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and culprit in err and str(path) in err, err
    assert not (tmp_path / "e.obj").exists()


def test_settings_are_never_negative_and_never_given_twice(capsys, tmp_path):
    """D23: negative weights and iteration counts, and a YAML key given twice (the last won), were accepted."""
    from pipeline.config import ConfigError, load_config
    from pipeline.photo.fit_config import FitPhotoConfig
    from pipeline.scan.fit_config import FitScanConfig

    for key in ("landmarks.prior.lambda_identity", "landmarks.lm.max_iterations", "photometric.spp"):
        with pytest.raises(ConfigError, match=rf"{key.split('.')[-1]}: must not be negative, got -5"):
            load_config(FitPhotoConfig, None, {key: -5})
    with pytest.raises(ConfigError, match=r"stages\[0\]\.iterations: must not be negative"):
        load_config(FitScanConfig, None, {"stages": [{"name": "a", "free": ["pose"], "iterations": -1}]})
    assert load_config(FitScanConfig, None, {"correspondences.min_facing": -0.1}).correspondences.min_facing == -0.1
    dup = tmp_path / "dup.yaml"
    dup.write_text("seed: 1\nprior:\n  lambda_m_end: 0.1\n  lambda_m_end: 0.2\n")
    with pytest.raises(ConfigError, match=r"'lambda_m_end' is given twice \(again on line 4\)"):
        load_config(FitScanConfig, dup)
    code = main(["fit-scan", "x.ply", "--set", "prior.lambda_m_end=-1", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == "jnr: error: FitScanConfig.prior.lambda_m_end: must not be negative, got -1"


# --------------------------------------------------------------------- signals, debris, long names (D12, D27, D29, D31)

_SLOW_EXPORT = """
import sys, time
from pathlib import Path
import pipeline.edit
def slow_mesh(path, *a, **k):
    Path(path).write_text("partial")
    print("WRITING", flush=True)
    time.sleep(120)
pipeline.edit.export_mesh = slow_mesh
import pipeline.cli as cli
sys.argv = ["jnr", *sys.argv[1:]]
cli.run()
"""


def _slow_export(tmp_path, name="out.obj"):
    import subprocess
    import sys

    from tests.pipeline.test_bad_input import REPO

    argv = ["rig", "export", "--format", "obj", "--out", str(tmp_path / name)]
    proc = subprocess.Popen(
        [sys.executable, "-c", _SLOW_EXPORT, *argv], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "WRITING"
    return proc


@pytest.mark.parametrize("sig", ["SIGHUP", "SIGQUIT"])
def test_a_closed_terminal_or_sigquit_leaves_nothing_behind(tmp_path, sig):
    """D27: SIGHUP and SIGQUIT killed jnr while writing and left the hidden staging folder."""
    import signal

    proc = _slow_export(tmp_path)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out.jnr")]  # staged now
    proc.send_signal(getattr(signal, sig))
    assert proc.wait(30) == 128 + getattr(signal, sig)
    err = proc.stderr.read().strip()
    assert err == f"jnr: terminated ({sig}); nothing half-written was left behind", err
    assert list(tmp_path.iterdir()) == []


def test_what_a_killed_command_left_the_next_run_removes(tmp_path, capsys):
    """D27: after SIGKILL the staging file stayed for ever (only folder runs cleaned theirs); now every staging
    removes its output's temporaries whose process is gone and that no process holds locked."""
    import signal

    proc = _slow_export(tmp_path)
    left = [p for p in tmp_path.iterdir() if p.name.startswith(".out.jnr")]
    proc.send_signal(signal.SIGKILL)
    proc.wait(30)
    assert left and all(p.exists() for p in left)  # SIGKILL cannot be caught
    other = tmp_path / ".other.jnr999999-abcdefgh.tmp.obj"  # another output's: not touched
    other.write_text("x")
    assert main(["rig", "export", "--format", "obj", "--out", str(tmp_path / "out.obj")]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [other.name, "out.obj"]


def test_a_temporary_a_live_process_holds_is_kept(tmp_path):
    from rig.io import atomic

    with atomic.staged_folder(tmp_path / "o") as tmp:
        fake = tmp_path / tmp.name.replace(f".jnr{os.getpid()}-", ".jnr999999-")
        tmp.rename(fake)  # as if a process of another PID namespace wrote it, still locked by us
        assert atomic.remove_stale_temporaries(tmp_path) == [] and fake.exists()
        fake.rename(tmp)
    assert (tmp_path / "o").is_dir() and [p.name for p in tmp_path.iterdir()] == ["o"]


def test_a_signal_wrapped_by_python_is_still_the_signal(capsys, monkeypatch, tmp_path):
    """D12: SIGTERM inside a class body (a lazy import) surfaced as RuntimeError('Error calling __set_name__')."""
    from pipeline.signals import Terminated

    def wrapped(args):
        try:
            raise Terminated("terminated by signal 15", 15)
        except Terminated as exc:
            raise RuntimeError("Error calling __set_name__ on 'Field' instance") from exc

    import pipeline.cli.rig as rig_cli

    monkeypatch.setattr(rig_cli, "cmd_rig_export", wrapped)  # the parser takes it when main builds it
    assert main(["rig", "export", "--format", "obj", "--out", str(tmp_path / "x.obj")]) == 143
    assert capsys.readouterr().err.strip() == "jnr: terminated (SIGTERM); nothing half-written was left behind"


def test_ctrl_c_before_the_command_starts_is_one_line(tmp_path):
    """D12: Ctrl-C in the first seconds printed a KeyboardInterrupt traceback."""
    import subprocess
    import sys

    from tests.pipeline.test_bad_input import REPO

    code = "import pipeline.cli as c\ndef boom(**k): raise KeyboardInterrupt\nc.main = boom\nc.run()"
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 130 and proc.stderr.strip() == "jnr: interrupted", proc.stderr


def test_a_long_out_name_is_staged_under_a_short_one(tmp_path, capsys):
    """D29: a 250-byte --out was refused after the fit ('File name too long': the staging name added
    characters); a 256-byte one ended with exit 1."""
    name = "o" * 246 + ".obj"
    assert main(["rig", "export", "--format", "obj", "--out", str(tmp_path / name)]) == 0
    assert [p.name for p in tmp_path.iterdir()] == [name]
    capsys.readouterr()
    too_long = "o" * 252 + ".obj"
    assert main(["rig", "export", "--format", "obj", "--out", str(tmp_path / too_long)]) == 2
    assert "256 bytes long" in capsys.readouterr().err


def test_ctrl_c_keeps_an_output_a_worker_finished(tmp_path):
    """D31: Ctrl-C just after a worker moved o/a into place removed o/ (and o/a) as 'nothing of ours'."""
    from pipeline.photo.batch import _remove_if_nothing_finished

    out = tmp_path / "o"
    (out / "a").mkdir(parents=True)
    (out / "a" / "report.json").write_text("{}")
    (out / "three.jnr.js").write_text("x")
    _remove_if_nothing_finished(out)
    assert (out / "a" / "report.json").exists()
    (out / "a" / "report.json").unlink()
    (out / "a").rmdir()
    (out / ".b.jnr1-abcdefgh.tmp").mkdir()
    _remove_if_nothing_finished(out)
    assert not out.exists()


def test_a_disk_that_fills_during_a_folder_run_still_gets_its_summary(capsys, tmp_path, photo_dir, monkeypatch):
    """D25: when the disk filled, every later photo was refused (the free-space check, 16 MB since issue 38) and
    so was summary.csv: the run ended with one line and no record of which photos were fitted. The summary needs
    1 MB."""
    import csv
    import shutil
    from collections import namedtuple

    out = tmp_path / "o"
    usage = namedtuple("usage", "total used free")
    real = shutil.disk_usage

    def filling(path):
        first_done = any((out / name / "report.json").exists() for name in ("face0", "face1"))
        return usage(real(path).total, 0, (10 if first_done else 500) * 2**20)

    monkeypatch.setattr(shutil, "disk_usage", filling)
    code = main(["fit", str(photo_dir), "--jobs", "1", "--out", str(out), *fast_fit_args()])
    err = capsys.readouterr().err
    assert code != 0
    with open(out / "summary.csv", newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 2, rows
    done = [r for r in rows if not r.get("error")]
    refused = [r for r in rows if r.get("error")]
    assert len(done) == 1 and len(refused) == 1, rows
    assert "only 10 MB free" in refused[0]["error"] and "jnr needs 16 MB" in refused[0]["error"]
    assert "Traceback" not in err


def test_a_pipe_a_device_or_a_folder_is_named_as_such_not_as_missing(capsys, tmp_path):
    """D30: a FIFO, a device or a folder given as a photo, --config or --landmarks was "... not found"."""
    from PIL import Image

    Image.new("RGB", (64, 64), (120, 100, 90)).save(tmp_path / "p.png")
    (tmp_path / "folder.pts").mkdir()
    zero = tmp_path / "zero.yaml"
    zero.symlink_to("/dev/zero")
    photo = str(tmp_path / "p.png")
    cases = [
        (["fit", str(_fifo(tmp_path / "f.jpg"))], "f.jpg: not a regular file (a pipe or a device?)"),
        (["fit", photo, "--config", str(zero)], "zero.yaml: not a regular file (a pipe or a device?)"),
        (["fit", photo, "--landmarks", str(_fifo(tmp_path / "f.pts"))], "f.pts: not a regular file"),
        (["fit", photo, "--landmarks", str(tmp_path / "folder.pts")], "folder.pts: is a folder; expected the landmark"),
        (["fit", str(tmp_path / "missing.jpg")], "image file not found"),
    ]
    for argv, message in cases:
        code = main([*argv, "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and message in err, (argv, err)
    assert not (tmp_path / "o").exists()


def test_unknown_3d_landmark_names_name_the_file(capsys, tmp_path):
    """D30: "unknown 3D landmark name(s)" did not say which file."""
    import numpy as np

    from rig.asset import load_asset

    head = load_asset().vertices
    np.save(tmp_path / "head.npy", head[head[:, 2] > 0])
    marks = tmp_path / "marks.json"
    marks.write_text(json.dumps({"nose_tipp": [0, 0, 100], "chin": [0, -80, 80], "mouth_left": [20, -50, 90]}))
    code = main(["fit-scan", str(tmp_path / "head.npy"), "--landmarks", str(marks), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith(f"jnr: error: {marks}: unknown 3D landmark name(s) ['nose_tipp']"), err


def test_a_fit_folders_broken_texture_is_left_out_with_a_warning(tmp_path):
    """D30: a texture.png that was not a PNG (or a PNG signature before garbage) ended in exit 1 from the
    glTF writer, not naming the file; now the head is written untextured and the warning names it."""
    import io

    from PIL import Image

    from pipeline.head.fitted import read_fit_folder

    (tmp_path / "params.json").write_text(json.dumps(_rest_fit_params()))
    buffer = io.BytesIO()
    Image.new("RGB", (8, 8), (200, 150, 120)).save(buffer, format="PNG")
    (tmp_path / "texture.png").write_bytes(buffer.getvalue())
    assert read_fit_folder(tmp_path).texture == buffer.getvalue()
    for broken in (b"hello", b"\x89PNG\r\n\x1a\ngarbage", buffer.getvalue()[:40]):
        (tmp_path / "texture.png").write_bytes(broken)
        with pytest.warns(UserWarning, match=r"texture.png is not a PNG file"):
            assert read_fit_folder(tmp_path).texture is None


def test_fits_keep_the_latent_within_what_its_readers_accept(rig32):
    """D23's other side: a fit's latent Z is projected into ±LATENT_LIMIT after every step (Adam) and bounded
    in the least-squares solver, so every fit writes a latent its readers accept."""
    import torch

    from pipeline.fitting.state import FitState
    from rig.expressions import ExpressionModel
    from rig.skinning.neural import LATENT_LIMIT, load_neural

    neural, _ = load_neural(rig32)
    state = FitState(rig32, neural, ExpressionModel(rig32.asset), torch.eye(3).numpy())
    low, high = state.limits("z")
    assert torch.all(low == -LATENT_LIMIT) and torch.all(high == LATENT_LIMIT)
    with torch.no_grad():
        state.z.copy_(torch.linspace(-20.0, 20.0, state.z.numel()))
    state.project(("pose",))
    assert state.z.abs().max() == 20.0  # only what a stage frees is projected
    state.project(("latent",))
    assert state.z.abs().max() == LATENT_LIMIT and state.z[25] == torch.linspace(-20.0, 20.0, 50)[25]


def test_a_one_photo_fit_prints_an_escape_in_the_name_as_text(capsys, tmp_path, photo_dir):
    """Issue 38: ``jnr fit`` on one photo printed ``fitted x<ESC>[2J.jpg`` raw (every summary line goes to the
    terminal through one filter now, not only the folder run's)."""
    import shutil

    from pipeline.cli import main
    from tests.pipeline.conftest import fast_fit_args

    photo = tmp_path / "x\x1b[2J.png"
    shutil.copy(photo_dir / "face0.png", photo)
    assert main(["fit", str(photo), "--out", str(tmp_path / "out"), "--outputs", "minimal", *fast_fit_args()]) == 0
    printed = capsys.readouterr().out
    assert "\x1b" not in printed and "x\\x1b[2J.png" in printed


def test_a_photos_output_needs_16_mb_free_not_64(capsys, tmp_path, photo_dir, monkeypatch):
    """Issue 38: the 64 MB rule refused a fit whose outputs are 5.5 MB; 20 MB free is enough now."""
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    real = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(real(path).total, 0, 20 * 2**20))
    code = main(["fit", str(photo_dir / "face0.png"), "--out", str(tmp_path / "o"), *fast_fit_args()])
    assert code == 0, capsys.readouterr().err


def test_a_folder_run_stopped_midway_still_writes_its_summary(tmp_path, photo_dir):
    """Issue 38: a folder run stopped (Ctrl-C, SIGTERM) after its first photo wrote no summary.csv; it lists
    the photo fitted and the one the stop left, then the stop goes on."""
    import csv

    from pipeline.photo.batch import fit_photo_files
    from pipeline.photo.task import fit_photo_task

    def stopped_after_one(tasks):
        yield fit_photo_task(tasks[0])
        raise KeyboardInterrupt

    photos = [photo_dir / "face0.png", photo_dir / "face1.png"]
    out = tmp_path / "o"
    from pipeline.config import load_config, parse_overrides
    from pipeline.photo.fit_config import FitPhotoConfig

    stages = "landmarks.stages=[{name: a, free: [pose, joints], iterations: 5}]"
    config = load_config(FitPhotoConfig, None, parse_overrides([stages, "outputs.files=minimal"]))
    with pytest.raises(KeyboardInterrupt):
        fit_photo_files(photos, out, config=config, run=stopped_after_one)
    with open(out / "summary.csv", newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["photo"].endswith(n) for r, n in zip(rows, ("face0.png", "face1.png"), strict=True)] == [True, True]
    assert not rows[0]["error"] and "not fitted: the run was stopped first" in rows[1]["error"]
    assert (out / "face0" / "report.json").is_file() and not (out / "face1").exists()
