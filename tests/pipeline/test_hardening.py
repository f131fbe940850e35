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
    from pipeline.scan.fit import _clamp_joints
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
    clamped = _clamp_joints(state)
    assert list(clamped) == ["bottom_lip.scale_z"]
    assert clamped["bottom_lip.scale_z"] == pytest.approx([1.505, 1.5])
    values = {c.name: c.from_theta(float(t)) for c, t in zip(CHANNELS, state.theta.detach().double(), strict=True)}
    params_to_theta(values)  # inside every limit: no ParameterError
