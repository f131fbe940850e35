"""What large or bad inputs cost: ``jnr fit-scan`` on clouds of 1 M and 10 M points, head-like and random,
and ``jnr fit`` on a 10000 x 10000 photo.

    .venv/bin/python benchmarks/bench_large_inputs.py [--sizes 1000000 10000000] [--cases head random]
                                                      [--photo-sides 10000] [--photo-cases photo_jpeg]
                                                      [--timeout 900] [--jnr "CMD"] [--keep DIR] [--json FILE]

Each case writes one temporary input file and runs the command line on it in a subprocess
(``jnr fit-scan CLOUD --out TMPDIR --quiet`` for the clouds), reporting its exit status, wall seconds
and peak resident memory (GNU time's ``%M`` of that command, see :func:`run_command`). The cases:

- ``head``: a simulated 640x576 depth scan of a held-out head (``pipeline.synthetic.scans``, with
  normals, ~15-20k points) densified to N points by jittered copies (0.5 mm Gaussian), binary PLY
  with the normals; a dense scan, expected to be fitted (exit 0).
- ``head_xyz``: the same points without normals (``jnr fit-scan`` estimates them).
- ``random``: N points uniform in a 250 mm cube, no normals, binary PLY; expected to be rejected as
  not a head (exit 2).

- ``photo_jpeg`` / ``photo_png``: scikit-image's astronaut portrait upscaled (bicubic) to a square of
  the given side (JPEG quality 90 / PNG), fitted with detection and the full photometric schedule
  (exit 0); ``photo_jpeg_landmarks_only`` the same with ``--landmarks-only``.

A case is a function ``(size, folder, rng) -> argv`` (size: points for clouds, the side in pixels for
photos); add one to :data:`CASES` or :data:`PHOTO_CASES`. Prints a markdown table, the machine and the
command line; ``--json`` also writes the records.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.scan.pointcloud.write import write_point_cloud_ply


@dataclass(frozen=True)
class Record:
    """One run: the case, its input size, what the command did and what it cost."""

    case: str
    points: int
    input_mb: float
    exit_code: int
    wall_s: float
    peak_rss_mb: float
    fitted_points: int | None
    """Points in the fit's ``report.json`` (after any reduction), None when nothing was written."""
    message: str
    """The last line the command wrote to stderr or stdout."""


# ------------------------------------------------------------------------------------------------ cases


def _head_scan_points() -> tuple[np.ndarray, np.ndarray]:
    """``(M, 3)`` points and normals (mm, +Y up) of one simulated 640x576 scan of held-out head 0."""
    from pipeline.synthetic.expressive import expressive_split
    from pipeline.synthetic.scans import DepthCamera, simulate_scan
    from rig.asset import load_asset

    asset = load_asset()
    head = expressive_split("heldout", n=1).vertices[0]
    scan = simulate_scan(head, asset.faces, rng=0, camera=DepthCamera(640, 576, 504.0, 504.0, 320.0, 288.0))
    return scan.points, scan.normals


def case_head(n: int, folder: Path, rng: np.random.Generator) -> list[str]:
    """A dense head scan: jittered copies of a simulated scan's points (normals copied), binary PLY."""
    base, base_normals = _head_scan_points()
    pick = np.arange(n) % len(base)
    points = base[pick] + rng.normal(0.0, 0.5, size=(n, 3))
    path = folder / f"head_{n}.ply"
    write_point_cloud_ply(path, points, normals=base_normals[pick])
    return ["fit-scan", str(path), "--out", str(folder / "out_head"), "--quiet"]


def case_head_xyz(n: int, folder: Path, rng: np.random.Generator) -> list[str]:
    """The dense head scan of :func:`case_head` without normals (x y z only), binary PLY."""
    base, _ = _head_scan_points()
    points = base[np.arange(n) % len(base)] + rng.normal(0.0, 0.5, size=(n, 3))
    path = folder / f"head_xyz_{n}.ply"
    write_point_cloud_ply(path, points)
    return ["fit-scan", str(path), "--out", str(folder / "out_head_xyz"), "--quiet"]


def case_random(n: int, folder: Path, rng: np.random.Generator) -> list[str]:
    """Uniform noise in a 250 mm cube (head-sized in mm, so only the fit can reject it), binary PLY."""
    path = folder / f"random_{n}.ply"
    write_point_cloud_ply(path, rng.uniform(-125.0, 125.0, size=(n, 3)))
    return ["fit-scan", str(path), "--out", str(folder / "out_random"), "--quiet"]


CASES: dict[str, Callable[[int, Path, np.random.Generator], list[str]]] = {
    "head": case_head,
    "head_xyz": case_head_xyz,
    "random": case_random,
}


def _portrait(side: int, path: Path) -> None:
    from PIL import Image
    from skimage import data

    Image.fromarray(data.astronaut()).resize((side, side), Image.BICUBIC).save(path, quality=90)


def case_photo_jpeg(side: int, folder: Path, rng: np.random.Generator) -> list[str]:
    """The astronaut upscaled to ``side x side``, JPEG; detection + the full fit."""
    _portrait(side, folder / "photo.jpg")
    return ["fit", str(folder / "photo.jpg"), "--out", str(folder / "out_photo"), "--quiet"]


def case_photo_jpeg_landmarks_only(side: int, folder: Path, rng: np.random.Generator) -> list[str]:
    """As :func:`case_photo_jpeg` with ``--landmarks-only`` (no photometric stages)."""
    _portrait(side, folder / "photo.jpg")
    return ["fit", str(folder / "photo.jpg"), "--out", str(folder / "out_photo"), "--quiet", "--landmarks-only"]


def case_photo_png(side: int, folder: Path, rng: np.random.Generator) -> list[str]:
    """The astronaut upscaled to ``side x side``, PNG (decoded at full size, then reduced)."""
    _portrait(side, folder / "photo.png")
    return ["fit", str(folder / "photo.png"), "--out", str(folder / "out_photo"), "--quiet"]


PHOTO_CASES: dict[str, Callable[[int, Path, np.random.Generator], list[str]]] = {
    "photo_jpeg": case_photo_jpeg,
    "photo_jpeg_landmarks_only": case_photo_jpeg_landmarks_only,
    "photo_png": case_photo_png,
}


# ----------------------------------------------------------------------------------------------- runner


GNU_TIME = "/usr/bin/time"


def run_command(argv: list[str], folder: Path, timeout_s: float) -> tuple[int, float, float, str]:
    """Run ``argv``, return ``(exit code, wall s, peak RSS MB, last output line)``; -9 when killed at the timeout.

    The peak is measured by GNU time (``/usr/bin/time -f %M``) when it exists: Linux keeps a process's
    memory high-water mark across ``exec``, so ``wait4`` on a child forked from this (large: it has just
    written the input) process would report this process's memory as the child's. Without GNU time the
    ``wait4`` figure is printed, an upper bound."""
    peak_file = folder / "peak_kb.txt"
    wrapper = [GNU_TIME, "-f", "%M", "-o", str(peak_file)] if os.path.exists(GNU_TIME) else []
    with open(folder / "stdout.txt", "wb") as out, open(folder / "stderr.txt", "wb") as err:
        t0 = time.perf_counter()
        child = subprocess.Popen(wrapper + argv, stdout=out, stderr=err, start_new_session=True)
        deadline = t0 + timeout_s
        while True:
            pid, status, usage = os.wait4(child.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() > deadline:
                os.killpg(child.pid, 9)
                pid, status, usage = os.wait4(child.pid, 0)
                break
            time.sleep(0.05)
        wall = time.perf_counter() - t0
    child.returncode = os.waitstatus_to_exitcode(status)  # so Popen does not wait again
    peak_kb = float(usage.ru_maxrss)  # KiB on Linux
    if wrapper and peak_file.is_file():
        numbers = [line for line in peak_file.read_text().splitlines() if line.strip().isdigit()]
        peak_kb = float(numbers[-1]) if numbers else peak_kb
    lines = [
        line
        for name in ("stderr.txt", "stdout.txt")
        for line in (folder / name).read_text(errors="replace").splitlines()
        if line.strip() and not line.startswith("Command exited with non-zero status")
    ]
    message = lines[-1].strip() if lines else ""
    return child.returncode, wall, peak_kb / 1024.0, message


def run_case(name: str, n: int, jnr: list[str], timeout_s: float, keep: Path | None, seed: int) -> Record:
    """Write the case's input in a temporary folder, run it, delete the folder (unless ``keep``)."""
    folder = Path(tempfile.mkdtemp(prefix=f"bench_{name}_{n}_", dir=keep))
    try:
        args = {**CASES, **PHOTO_CASES}[name](n, folder, np.random.default_rng(seed))
        size = sum(p.stat().st_size for p in folder.iterdir() if p.is_file()) / 2**20
        code, wall, rss, message = run_command(jnr + args, folder, timeout_s)
        fitted = None
        reports = list(folder.glob("out_*/report.json"))
        if reports:
            fitted = json.loads(reports[0].read_text())["input"].get("points")
        if code == -9:
            message = f"killed after {timeout_s:g} s"
        return Record(name, n, size, code, wall, rss, fitted, message[:120])
    finally:
        if keep is None:
            shutil.rmtree(folder, ignore_errors=True)


def table(records: list[Record]) -> str:
    rows = [
        "| case | points (clouds) / side px (photos) | input MB | exit | wall s | peak RSS MB | fitted points | "
        "message |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in records:
        rows.append(
            f"| {r.case} | {r.points:,} | {r.input_mb:.0f} | {r.exit_code} | {r.wall_s:.1f} | "
            f"{r.peak_rss_mb:.0f} | {'' if r.fitted_points is None else f'{r.fitted_points:,}'} | "
            f"{r.message.replace('|', '/')} |"
        )
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1_000_000, 10_000_000], help="points per cloud")
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES))
    parser.add_argument("--photo-sides", type=int, nargs="*", default=[10000], help="side of the square photos, px")
    parser.add_argument("--photo-cases", nargs="*", choices=sorted(PHOTO_CASES), default=list(PHOTO_CASES))
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds before a run is killed (default 900)")
    parser.add_argument(
        "--jnr",
        default=str(ROOT / ".venv" / "bin" / "jnr"),
        help="the jnr command line to run (default: the venv's jnr)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", type=Path, default=None, help="keep the inputs and outputs under this folder")
    parser.add_argument("--json", type=Path, default=None, help="also write the records here")
    args = parser.parse_args()
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    jnr = shlex.split(args.jnr)
    records = []
    runs = [(name, n) for n in args.sizes for name in args.cases]
    runs += [(name, side) for side in args.photo_sides for name in args.photo_cases]
    for name, n in runs:
        record = run_case(name, n, jnr, args.timeout, args.keep, args.seed)
        print(
            f"  {name:8s} {n:>11,d}: exit {record.exit_code}, {record.wall_s:7.1f} s, "
            f"{record.peak_rss_mb:6.0f} MB  {record.message}",
            flush=True,
        )
        records.append(record)
    print()
    print(table(records))
    print()
    print(
        "wall: the whole subprocess (start-up, reading, fit, outputs); peak RSS: GNU time's %M of the command "
        "(else wait4's ru_maxrss, an upper bound); inputs are written before the clock starts."
    )
    print(
        f"cpu_count {os.cpu_count()} | {platform.processor() or platform.machine()} | "
        f"python {platform.python_version()} | numpy {np.__version__}"
    )
    print("command: " + " ".join(shlex.quote(a) for a in [sys.executable, *sys.argv]))
    if args.json:
        args.json.write_text(json.dumps({"records": [asdict(r) for r in records], "command": sys.argv}, indent=1))


if __name__ == "__main__":
    main()
