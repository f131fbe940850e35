"""Every path a report records (report.json of a photo fit and of a scan fit, the demo's summary.json and
its fits' reports) points at a file that exists after the command, whatever the working directory was
then and is now: inputs as absolute paths, the command's own files relative to the report's folder."""

import json
import os
import re
from pathlib import Path

from pipeline.cli import main
from tests.pipeline.conftest import fast_fit_args

FILE_NAME = re.compile(r"\.(png|jpe?g|pts|json|csv|ply|obj|glb|mtl|yaml|npy|xyz|txt)$", re.IGNORECASE)
PATH_KEYS = ("output", "path", "photo", "photos", "truth", "landmarks", "file", "cloud")
"""Keys whose values are paths (a folder name such as ``"astronaut"`` has neither ``/`` nor a suffix)."""


def path_values(value, key=""):
    """``(key, text)`` of every string in a JSON value that looks like a path (no spaces, and a ``/``, a
    file name ending or a key of :data:`PATH_KEYS`), but the command lines."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from path_values(v, f"{key}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from path_values(v, f"{key}[{i}]")
    elif isinstance(value, str) and not key.endswith(".command") and " " not in value:
        if "/" in value or FILE_NAME.search(value) or re.sub(r"\[\d+\]$", "", key).split(".")[-1] in PATH_KEYS:
            yield key, value


def check_paths(report: Path, skip: tuple[str, ...] = ()) -> set[str]:
    """Assert that every path in ``report`` exists (relative ones from the report's folder), but those at
    the keys ``skip``; returns the keys checked."""
    checked = set()
    for key, text in path_values(json.loads(report.read_text())):
        if key in skip:
            continue
        target = Path(text) if os.path.isabs(text) else report.parent / text
        assert target.exists(), f"{report}: {key} = {text!r} does not exist"
        assert ".tmp" not in text, f"{report}: {key} = {text!r} names a staged temporary"
        checked.add(key)
    return checked


def test_photo_and_scan_reports_point_at_files_that_exist(capsys, tmp_path, photo_dir, monkeypatch, asset):
    from pipeline.scan.pointcloud.write import write_point_cloud_ply
    from pipeline.synthetic.scans import simulate_scan

    work, elsewhere = tmp_path / "work", tmp_path / "elsewhere"
    work.mkdir(), elsewhere.mkdir()
    scan = simulate_scan(asset.vertices, asset.faces, rng=3)
    write_point_cloud_ply(tmp_path / "scan.ply", scan.points, normals=scan.normals)
    (tmp_path / "short.yaml").write_text("stages:\n  - {name: coarse, free: [pose, expressions], iterations: 3}\n")
    monkeypatch.chdir(work)  # the inputs given relative to the working directory
    relative_photo = os.path.relpath(photo_dir / "face0.png")
    assert (
        main(
            [
                "fit",
                relative_photo,
                "--landmarks",
                os.path.relpath(photo_dir / "face0.pts"),
                "--out",
                "photo",
                *fast_fit_args(),
            ]
        )
        == 0
    )
    assert main(["fit-scan", "../scan.ply", "--out", "scan", "--config", "../short.yaml", "--quiet"]) == 0
    capsys.readouterr()
    monkeypatch.chdir(elsewhere)  # and read from another one
    assert {".input.photo", ".input.landmarks", ".texture.file"} <= check_paths(work / "photo" / "report.json")
    assert ".input.path" in check_paths(work / "scan" / "report.json")


# The demo's summary.json and its fits' reports are checked with check_paths in
# tests/pipeline/test_cli.py::test_demo_writes_everything (one demo run for both).
