import csv
import json
import shutil

import pytest

from pipeline.config import load_config
from pipeline.head.folders import PHOTO_FOLDER
from pipeline.photo.batch import fit_photo_files, output_names
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.inputs import sidecar_landmarks
from pipeline.photo.photo_file import fit_photo_faces, fit_photo_file
from pipeline.photo.summary import SUMMARY_COLUMNS
from rig.errors import InputError

# A few landmark steps and no photometric stages: a fit of a second or two.
FAST = {
    "photometric": {"enabled": False},
    "landmarks": {"stages": [{"name": "a", "free": ["pose", "joints"], "iterations": 5}]},
}


def _shared_three() -> list[str]:
    """The folder run's one copy of three.js (its pages link to it), when three.js is vendored."""
    from pipeline.viewer import SHARED_THREE_FILE, fit_viewer_ready

    return [SHARED_THREE_FILE] if fit_viewer_ready() else []


@pytest.fixture(scope="module")
def fast_config():
    return load_config(FitPhotoConfig, None, FAST)


def test_fit_photo_file_writes_the_outputs_and_uses_the_callers_models(tmp_path, photo_dir, fast_config, monkeypatch):
    from rig.model import JointRig
    from rig.skinning.neural import load_neural

    out = tmp_path / "fit"
    summary = fit_photo_file(
        photo_dir / "face0.png", out, config=fast_config, landmarks=photo_dir / "face0.pts", command="test"
    )
    assert summary["output"] == str(out) and summary["photo"] == str(photo_dir / "face0.png")
    assert 0 < summary["mean_error_px"] < 10 and 0 < summary["nme"] < 0.3
    assert summary["seconds"] >= summary["fit_seconds"] > 0
    assert set(PHOTO_FOLDER.required) <= {p.name for p in out.iterdir()}
    report = json.loads((out / "report.json").read_text())
    assert report["input"]["landmarks"] == str(photo_dir / "face0.pts") and report["command"] == "test"
    assert report["landmarks"]["mean_error_px"] == pytest.approx(summary["mean_error_px"])
    with pytest.raises(InputError, match="exists"):  # an existing output needs force
        fit_photo_file(photo_dir / "face0.png", out, config=fast_config, landmarks=photo_dir / "face0.pts")

    # the caller's (float32) models: used for the fit and the files, nothing reloaded, the same bytes
    rig = JointRig()
    neural = load_neural(rig)[0]
    for where in ("rig.head_model.load_neural", "pipeline.photo.fit.load_neural"):  # the outputs' and the fit's
        monkeypatch.setattr(where, lambda *a, **k: pytest.fail("reloaded"))
    again = tmp_path / "again"
    fit_photo_file(
        photo_dir / "face0.png",
        again,
        config=fast_config,
        landmarks=photo_dir / "face0.pts",
        rig=rig,
        neural=neural,
        command="test",
    )
    for name in ("mesh.obj", "mesh.ply", "mesh.glb", "params.json", "overlay.png", "render.png", "landmarks.pts"):
        assert (again / name).read_bytes() == (out / name).read_bytes(), name


def test_fit_photo_file_refuses_bad_arguments_before_the_fit(tmp_path, photo_dir, fast_config):
    with pytest.raises(InputError, match="cannot be used with --landmarks"):
        fit_photo_file(photo_dir / "face0.png", tmp_path / "o", landmarks=photo_dir / "face0.pts", face=0)
    lonely = tmp_path / "lonely.png"
    shutil.copy(photo_dir / "face0.png", lonely)
    with pytest.raises(InputError, match="no .pts/.json/.csv file beside"):
        fit_photo_file(lonely, tmp_path / "o", landmarks="auto", config=fast_config)
    assert sidecar_landmarks(photo_dir / "face0.png") == photo_dir / "face0.pts"
    assert not (tmp_path / "o").exists()


def test_fit_photo_files_reports_each_photo(tmp_path, photo_dir, fast_config):
    folder = tmp_path / "photos"
    folder.mkdir()
    shutil.copy(photo_dir / "face1.png", folder / "b.png")
    shutil.copy(photo_dir / "face1.pts", folder / "b.pts")
    (folder / "a.png").write_bytes(b"\x89PNG broken")
    (folder / "a.pts").write_text("")
    photos = [folder / "b.png", folder / "a.png"]
    seen = []
    results = fit_photo_files(
        photos,
        tmp_path / "out",
        folders=[folder],
        config=fast_config,
        landmarks="auto",
        progress=lambda stage, done, total: seen.append((stage, done, total)),
    )
    assert [r.photo for r in results] == [str(p) for p in photos]
    good, bad = results
    assert good.error is None and good.summary["output"] == str(tmp_path / "out" / "b")
    assert bad.summary is None and bad.bad_input and "a.png" in bad.error
    assert seen == [("photos", 1, 2), ("photos", 2, 2)]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["b", "summary.csv", *_shared_three()]
    # summary.csv: one row per photo in the order given, the failure with its message
    rows = _rows(tmp_path / "out" / "summary.csv")
    assert [(r["photo"], r["status"], r["output"]) for r in rows] == [
        (str(folder / "b.png"), "ok", str(tmp_path / "out" / "b")),
        (str(folder / "a.png"), "error", ""),
    ]
    assert rows[1]["error"] == bad.error and float(rows[1]["seconds"]) >= 0
    assert float(rows[0]["mean_error_px"]) == pytest.approx(good.summary["mean_error_px"], abs=1e-3)
    assert output_names(["x/face.png", "y/face.jpg", "z/other.png"]) == ["face_0", "face_1", "other"]


def _rows(path):
    with open(path, newline="") as handle:
        assert handle.readline().strip() == ",".join(SUMMARY_COLUMNS)
        handle.seek(0)
        return list(csv.DictReader(handle))


def test_fit_photo_files_with_every_face(tmp_path, two_faces_photo, fast_config):
    from PIL import Image

    from pipeline.files import OutputError

    folder = tmp_path / "photos"
    folder.mkdir()
    shutil.copy(two_faces_photo, folder / "two.png")
    Image.new("RGB", (120, 90), (128, 128, 128)).save(folder / "blank.png")
    out = tmp_path / "out"
    results = fit_photo_files(
        [folder / "two.png", folder / "blank.png"],
        out,
        folders=[folder],
        config=fast_config,
        face="all",
        detector="hog",
        command="test",
    )
    # a row per face of two.png, then the blank photo's failure (no face: 0 found)
    assert [(r.face, r.faces_found, r.error is None) for r in results] == [(0, 2, True), (1, 2, True), (None, 0, False)]
    assert "no face found" in results[2].error and results[2].bad_input
    assert [r.output for r in results] == [str(out / "two" / "face_0"), str(out / "two" / "face_1"), None]
    assert results[0].face_box != results[1].face_box and results[0].face_score > 0
    rows = _rows(out / "summary.csv")
    assert [(r["face"], r["status"], r["faces_found"]) for r in rows] == [
        ("0", "ok", "2"),
        ("1", "ok", "2"),
        ("", "error", "0"),
    ]
    assert _rows(out / "two" / "summary.csv") == rows[:2]  # the photo's own folder lists its faces too
    for k in (0, 1):
        report = json.loads((out / "two" / f"face_{k}" / "report.json").read_text())
        assert report["input"]["face_index"] == k and report["command"] == "test"
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv", *_shared_three(), "two"]

    # nothing is replaced without force (or resume); force replaces only a summary.csv jnr wrote, checked first
    with pytest.raises(OutputError, match="exists"):
        fit_photo_files([folder / "blank.png"], out, folders=[folder], config=fast_config, face="all", resume=False)
    (out / "summary.csv").write_text("my,own,table\n")
    with pytest.raises(OutputError, match="not a summary jnr wrote"):
        fit_photo_files([folder / "blank.png"], out, folders=[folder], config=fast_config, face="all", force=True)
    assert (out / "summary.csv").read_text() == "my,own,table\n"


def test_fit_photo_faces_refuses_before_writing(tmp_path, fast_config):
    from PIL import Image

    from landmarks.detector import NoFaceError

    blank = tmp_path / "blank.png"
    Image.new("RGB", (120, 90), (128, 128, 128)).save(blank)
    with pytest.raises(NoFaceError, match="blank.png: no face found"):
        fit_photo_faces(blank, tmp_path / "o", config=fast_config, detector="hog")
    with pytest.raises(InputError, match="fit_photo_faces"):
        fit_photo_file(blank, tmp_path / "o", face="all")
    with pytest.raises(InputError, match="cannot be used with --landmarks"):
        fit_photo_files([blank], tmp_path / "o", face="all", landmarks="auto")
    assert [p.name for p in tmp_path.iterdir()] == ["blank.png"]
