import json
import shutil

import pytest

from pipeline.config import load_config
from pipeline.photo.files import (
    fit_photo_file,
    fit_photo_files,
    output_names,
    sidecar_landmarks,
)
from pipeline.photo.fit import FitPhotoConfig
from pipeline.photo.outputs import OUTPUT_FILES
from rig.errors import InputError

# A few landmark steps and no photometric stages: a fit of a second or two.
FAST = {"photometric": {"enabled": False}, "landmarks": {"stages": [{"name": "a", "free": ["pose", "joints"], "iterations": 5}]}}


@pytest.fixture(scope="module")
def fast_config():
    return load_config(FitPhotoConfig, None, FAST)


def test_fit_photo_file_writes_the_outputs_and_uses_the_callers_models(tmp_path, photo_dir, fast_config,
                                                                        monkeypatch):
    from rig.model import JointRig
    from rig.skinning.neural import load_neural

    out = tmp_path / "fit"
    summary = fit_photo_file(photo_dir / "face0.png", out, config=fast_config, landmarks=photo_dir / "face0.pts",
                             command="test")
    assert summary["output"] == str(out) and summary["photo"] == str(photo_dir / "face0.png")
    assert 0 < summary["mean_error_px"] < 10 and 0 < summary["nme"] < 0.3
    assert summary["seconds"] >= summary["fit_seconds"] > 0
    assert set(OUTPUT_FILES) <= {p.name for p in out.iterdir()}
    report = json.loads((out / "report.json").read_text())
    assert report["input"]["landmarks"] == str(photo_dir / "face0.pts") and report["command"] == "test"
    assert report["landmarks"]["mean_error_px"] == pytest.approx(summary["mean_error_px"])
    with pytest.raises(InputError, match="exists"):  # an existing output needs force
        fit_photo_file(photo_dir / "face0.png", out, config=fast_config, landmarks=photo_dir / "face0.pts")

    # the caller's (float32) models: used for the fit and the files, nothing reloaded, the same bytes
    rig = JointRig()
    neural = load_neural(rig)[0]
    monkeypatch.setattr("pipeline.photo.outputs.load_neural", lambda *a, **k: pytest.fail("reloaded"))
    again = tmp_path / "again"
    fit_photo_file(photo_dir / "face0.png", again, config=fast_config, landmarks=photo_dir / "face0.pts",
                   rig=rig, neural=neural, command="test")
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
    results = fit_photo_files(photos, tmp_path / "out", folders=[folder], config=fast_config, landmarks="auto",
                              progress=lambda stage, done, total: seen.append((stage, done, total)))
    assert [r.photo for r in results] == [str(p) for p in photos]
    good, bad = results
    assert good.error is None and good.summary["output"] == str(tmp_path / "out" / "b")
    assert bad.summary is None and bad.bad_input and "a.png" in bad.error
    assert seen == [("photos", 1, 2), ("photos", 2, 2)]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["b"]
    assert output_names(["x/face.png", "y/face.jpg", "z/other.png"]) == ["face_0", "face_1", "other"]
