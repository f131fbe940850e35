"""Fitting a data set: resuming a batch (kept outputs, leftovers of a killed run, refusals) and the Dask
backend (``--scheduler``), with real short fits of small synthetic photos."""

import csv
import fcntl
import json
import os
import shutil
import subprocess
import sys

import pytest

from pipeline.cli import main
from pipeline.config import load_config
from pipeline.files import OUTPUT_MARKER, OutputError
from pipeline.head.folders import PHOTO_FOLDER
from pipeline.photo.batch import fit_photo_files
from pipeline.photo.batch_folder import remove_leftovers
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.resume import earlier_output
from pipeline.photo.summary import SUMMARY_COLUMNS
from pipeline.photo.task import PhotoTask
from pipeline.viewer import fit_viewer_ready
from tests.pipeline.conftest import fast_fit_args

NUMBERS = ("mean_error_px", "nme", "faces_found", "box_left", "box_top", "box_right", "box_bottom", "face_score")


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def rows(path):
    with open(path, newline="", encoding="utf-8") as handle:
        assert handle.readline().strip() == ",".join(SUMMARY_COLUMNS)
        handle.seek(0)
        return list(csv.DictReader(handle))


def without(row, *columns):
    return {k: v for k, v in row.items() if k not in columns}


def mtimes(folder):
    return {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}


@pytest.fixture
def batch(tmp_path, photo_dir):
    """face0.png, face1.png (synthetic, with their .pts) and broken.png (a corrupt image with a .pts)."""
    folder = tmp_path / "photos"
    folder.mkdir()
    for name in ("face0", "face1"):
        shutil.copy(photo_dir / f"{name}.png", folder / f"{name}.png")
        shutil.copy(photo_dir / f"{name}.pts", folder / f"{name}.pts")
    (folder / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    shutil.copy(photo_dir / "face0.pts", folder / "broken.pts")
    return folder


def test_a_second_run_fits_only_what_is_missing(capsys, tmp_path, batch):
    out = tmp_path / "fits"
    fit = ["fit", batch, "--landmarks", "auto", "--jobs", "1", "--out", out, *fast_fit_args()]
    code, stdout, err = run(capsys, *fit)
    assert code == 2 and "broken.png" in err and "Traceback" not in err  # a corrupt image: exit status as before
    first = rows(out / "summary.csv")
    assert [(os.path.basename(r["photo"]), r["status"], r["kept"]) for r in first] == [
        ("broken.png", "error", "no"),
        ("face0.png", "ok", "no"),
        ("face1.png", "ok", "no"),
    ]
    assert "fitted 2 of 3 photos with 1 process(es); kept 0 (fitted earlier), 1 failed" in stdout
    face0 = mtimes(out / "face0")

    # face1's output is lost and a killed run left its staged folder and summary; a user's look-alike stays
    shutil.rmtree(out / "face1")
    (out / ".face1.abcd_123.tmp").mkdir()
    (out / ".face1.abcd_123.tmp" / "mesh.obj").write_text("half written")
    (out / ".summary.x1y2z3w4.tmp.csv").write_text("half written")
    (out / ".face1.notes").write_text("mine")
    code, stdout, err = run(capsys, *fit)
    assert code == 2 and "broken.png" in err  # the failed photo is tried again, and fails again
    assert "fitted 1 of 3 photos with 1 process(es); kept 1 (fitted earlier), 1 failed" in stdout
    assert "face0.png" not in stdout and "face1.png" in stdout  # only the fitted one is listed
    assert mtimes(out / "face0") == face0  # kept, untouched
    assert set(PHOTO_FOLDER.required) | {OUTPUT_MARKER} == {p.name for p in (out / "face1").iterdir()}
    shared = ["three.jnr.js"] if fit_viewer_ready() else []
    assert sorted(p.name for p in out.iterdir()) == [".face1.notes", "face0", "face1", "summary.csv", *shared]
    if shared:  # one three.js for the run: each page links to it instead of holding its own
        for name in ("face0", "face1"):
            page = (out / name / "viewer.html").read_text()
            assert 'src="../three.jnr.js"' in page and "data:text/javascript;base64" not in page
    second = rows(out / "summary.csv")
    assert [r["kept"] for r in second] == ["no", "yes", "no"]
    # the kept row is the first run's (numbers from report.json, seconds from the earlier summary); the
    # refitted one has the same numbers (the fit is deterministic), its own seconds
    assert without(second[1], "kept") == without(first[1], "kept")
    assert without(second[2], "kept", "seconds", "fit_seconds") == without(first[2], "kept", "seconds", "fit_seconds")
    assert without(second[0], "kept", "seconds", "fit_seconds") == without(first[0], "kept", "seconds", "fit_seconds")
    report = json.loads((out / "face0" / "report.json").read_text())
    assert float(second[1]["nme"]) == pytest.approx(report["landmarks"]["nme_inter_ocular"], abs=1e-5)

    # a run killed before its summary, with face0's output incomplete: face0 is fitted again and
    # replaced, face1 kept (its seconds unknown without the earlier summary)
    (out / "summary.csv").unlink()
    (out / "face0" / "mesh.glb").unlink()
    face1 = mtimes(out / "face1")
    code, stdout, err = run(capsys, *fit)
    assert code == 2 and "fitted 1 of 3 photos with 1 process(es); kept 1 (fitted earlier)" in stdout
    assert mtimes(out / "face1") == face1 and (out / "face0" / "mesh.glb").is_file()
    third = rows(out / "summary.csv")
    assert [r["kept"] for r in third] == ["no", "no", "yes"] and third[2]["seconds"] == ""
    assert without(third[2], "kept", "seconds", "fit_seconds") == without(first[2], "kept", "seconds", "fit_seconds")
    assert without(third[1], "kept", "seconds", "fit_seconds") == without(first[1], "kept", "seconds", "fit_seconds")

    # --force fits again what it is given (here one photo), complete or not
    code, stdout, _ = run(
        capsys,
        "fit",
        batch / "face1.png",
        batch / "broken.png",
        "--landmarks",
        "auto",
        "--jobs",
        "1",
        "--out",
        out,
        "--force",
        *fast_fit_args(),
    )
    assert code == 2 and "fitted 1 of 2 photos with 1 process(es); kept 0 (fitted earlier)" in stdout
    assert all(mtimes(out / "face1")[n] > face1[n] for n in PHOTO_FOLDER.required)
    assert [(os.path.basename(r["photo"]), r["kept"]) for r in rows(out / "summary.csv")] == [
        ("face1.png", "no"),
        ("broken.png", "no"),
    ]

    # the output of another photo of the same name is refused before any fit, everything kept as it is
    other = tmp_path / "other"
    other.mkdir()
    shutil.copy(batch / "face0.png", other / "face1.png")
    shutil.copy(batch / "face0.pts", other / "face1.pts")
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    code, _, err = run(
        capsys,
        "fit",
        other / "face1.png",
        batch / "face0.png",
        "--landmarks",
        "auto",
        "--jobs",
        "1",
        "--out",
        out,
        *fast_fit_args(),
    )
    assert code == 2 and "holds an earlier fit of another photo" in err and "--force" in err
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before


def test_what_jnr_did_not_write_is_still_refused(capsys, tmp_path, batch):
    out = tmp_path / "fits"
    out.mkdir()
    (out / "face1").mkdir()
    (out / "face1" / "mine.txt").write_text("mine")
    code, _, err = run(capsys, "fit", batch, "--landmarks", "auto", "--out", out, *fast_fit_args())
    assert code == 2 and "face1 is a folder jnr did not write" in err and err.count("\n") == 1
    assert sorted(p.name for p in out.rglob("*")) == ["face1", "mine.txt"]  # nothing fitted, nothing added
    shutil.rmtree(out / "face1")
    (out / "summary.csv").write_text("my,own,table\n")
    code, _, err = run(capsys, "fit", batch, "--landmarks", "auto", "--out", out, *fast_fit_args())
    assert code == 2 and "not a summary jnr wrote" in err
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv"]


def test_a_second_process_on_the_same_out_is_refused(tmp_path, batch):
    out = tmp_path / "fits"
    out.mkdir()
    fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as a running jnr fit holds it
        with pytest.raises(OutputError, match="another jnr fit is writing into"):
            fit_photo_files([batch / "face0.png"], out, landmarks="auto")
    finally:
        os.close(fd)
    assert list(out.iterdir()) == []


def test_remove_leftovers_takes_only_the_staged_temporaries(tmp_path):
    for name in (".a.abcdefgh.tmp", ".a.old.abcdefgh", ".b.abcdefgh.tmp", ".a.abcdefg.tmp", ".a.tmp", "a"):
        (tmp_path / name).mkdir()
    for name in (".summary.abcdefgh.tmp.csv", ".summary.abcdefgh.tmp", ".a.abcdefgh.tmp.csv"):
        (tmp_path / name).write_text("x")
    os.symlink(tmp_path / "a", tmp_path / ".a.zzzzzzzz.tmp")
    removed = remove_leftovers(tmp_path, ["a"])
    assert sorted(p.name for p in removed) == [".a.abcdefgh.tmp", ".a.old.abcdefgh", ".summary.abcdefgh.tmp.csv"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        ".a.abcdefg.tmp",
        ".a.abcdefgh.tmp.csv",
        ".a.tmp",
        ".a.zzzzzzzz.tmp",
        ".b.abcdefgh.tmp",
        ".summary.abcdefgh.tmp",
        "a",
    ]


def test_every_face_resumes_per_photo(tmp_path, two_faces_photo):
    config = load_config(
        FitPhotoConfig,
        None,
        {
            "photometric": {"enabled": False},
            "landmarks": {"stages": [{"name": "a", "free": ["pose", "joints"], "iterations": 5}]},
        },
    )
    folder = tmp_path / "photos"
    folder.mkdir()
    shutil.copy(two_faces_photo, folder / "two.png")
    out = tmp_path / "out"
    kwargs = dict(folders=[folder], config=config, face="all", detector="hog")
    first = fit_photo_files([folder / "two.png"], out, **kwargs)
    assert [(r.face, r.error, r.kept) for r in first] == [(0, None, False), (1, None, False)]
    before = {p: p.stat().st_mtime_ns for p in (out / "two").rglob("*")}
    with pytest.warns(UserWarning, match="kept 1 earlier output"):  # other settings: kept, with a warning
        again = fit_photo_files([folder / "two.png"], out, **{**kwargs, "detector": "auto"})
    assert [(r.face, r.error, r.kept) for r in again] == [(0, None, True), (1, None, True)]
    assert {p: p.stat().st_mtime_ns for p in (out / "two").rglob("*")} == before
    for a, b in zip(rows(out / "two" / "summary.csv"), rows(out / "summary.csv")):
        assert without(a, "kept") == without(b, "kept") and b["kept"] == "yes"
    # one face's folder incomplete: the photo's folder is fitted again (all its faces) and replaced
    task = PhotoTask(str(folder / "two.png"), str(out / "two"), config, face="all")
    assert earlier_output(task).state == "complete"
    (out / "two" / "face_1" / "params.json").unlink()
    assert earlier_output(task).state == "incomplete"
    # the folder of one face's fit where every face is asked for (or another photo's) is refused
    with pytest.raises(OutputError, match="holds an earlier fit of every face"):
        earlier_output(PhotoTask(str(folder / "two.png"), str(out / "two"), config))


# ------------------------------------------------------------------------------------------------ Dask


def test_a_dask_cluster_fits_what_the_local_run_fits(capsys, tmp_path, batch):
    from distributed import LocalCluster

    photos = [batch / "face0.png", batch / "face1.png"]
    local, remote = tmp_path / "local", tmp_path / "dask"
    code, _, err = run(capsys, "fit", *photos, "--landmarks", "auto", "--jobs", "1", "--out", local, *fast_fit_args())
    assert code == 0, err
    # workers as threads of this process (processes=True costs ~10 s more here: spawn, imports, shutdown)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        code, stdout, err = run(
            capsys,
            "fit",
            *photos,
            "--landmarks",
            "auto",
            "--out",
            remote,
            "--scheduler",
            cluster.scheduler_address,
            *fast_fit_args(),
        )
        assert code == 0, err
        assert "fitted 2 of 2 photos on the Dask cluster at inproc://" in stdout and "(2 worker(s))" in stdout
        code, stdout, err = run(
            capsys,
            "fit",
            *photos,
            "--landmarks",
            "auto",
            "--out",
            remote,
            "--scheduler",
            cluster.scheduler_address,
            *fast_fit_args(),
        )
        assert code == 0 and "fitted 0 of 2 photos" in stdout and "kept 2 (fitted earlier)" in stdout  # resumed
    for a, b in zip(rows(local / "summary.csv"), rows(remote / "summary.csv")):
        assert a["photo"] == b["photo"] and b["output"] == str(remote / os.path.basename(a["output"]))
        assert b["status"] == "ok" and {k: b[k] for k in NUMBERS} == {k: a[k] for k in NUMBERS}
    for name in ("face0", "face1"):
        assert {p.name for p in (remote / name).iterdir()} == set(PHOTO_FOLDER.required) | {OUTPUT_MARKER}
        ours, theirs = (json.loads((f / name / "params.json").read_text()) for f in (local, remote))
        assert ours["joints"].keys() == theirs["joints"].keys()
        assert max(abs(ours["joints"][k] - theirs["joints"][k]) for k in ours["joints"]) < 1e-4
        report = json.loads((remote / name / "report.json").read_text())
        assert report["input"]["photo"] == str(batch / f"{name}.png")


@pytest.mark.parametrize(
    "case, code, message",
    [
        ("bad_address", 2, "is not a Dask scheduler address"),
        ("unreachable", 1, "cannot reach the Dask scheduler at tcp://127.0.0.1:"),
        ("with_jobs", 2, "give one or the other"),
        ("one_photo", 2, "one photo, or --views, is fitted here"),
        ("not_installed", 1, "needs Dask's 'distributed' package"),
        ("no_workers", 1, "has no workers (waited 0.5 s); start some with `dask worker"),
    ],
)
def test_scheduler_errors_are_one_line_and_write_nothing(capsys, tmp_path, batch, monkeypatch, case, code, message):
    import socket
    from contextlib import ExitStack

    monkeypatch.setattr("pipeline.photo.dask_runner.DEFAULT_TIMEOUT_S", 0.5)
    with socket.socket() as sock:  # a port nothing listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    photos, extra = [batch], ["--scheduler", f"tcp://127.0.0.1:{port}"]
    if case == "bad_address":
        extra = ["--scheduler", "scheduler-without-port"]
    elif case == "with_jobs":
        extra += ["--jobs", "2"]
    elif case == "one_photo":
        photos = [batch / "face0.png"]
    elif case == "not_installed":
        monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    out = tmp_path / "fits"
    with ExitStack() as stack:
        if case == "no_workers":
            from distributed import LocalCluster

            cluster = stack.enter_context(LocalCluster(n_workers=0, processes=False, dashboard_address=None))
            extra = ["--scheduler", cluster.scheduler_address]
        got, _, err = run(capsys, "fit", *photos, "--landmarks", "auto", "--out", out, *extra, *fast_fit_args())
    assert got == code and message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_jnr_starts_without_dask():
    probe = (
        "import sys, pipeline.cli, pipeline.photo.batch, pipeline.photo.dask_runner; "
        "print(sorted(m for m in ('dask', 'distributed') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"
