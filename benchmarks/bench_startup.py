"""Start-up time of the ``jnr`` command: ``jnr --version``, ``jnr --help`` and every sub-command's ``--help``.

Each command runs as a fresh process (the console script of the venv) ``--repeat`` times; the median and the
worst wall time are printed, with the heavy libraries each one imported (torch, mitsuba, drjit, dlib, cv2:
none should be, a parser needs none of them). Target: under 0.5 s for ``--version`` and ``--help`` on 2 cores.

    .venv/bin/python benchmarks/bench_startup.py [--repeat 7] [--json benchmarks/results/startup.json]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from common import finish

ROOT = Path(__file__).resolve().parents[1]

COMMANDS = (
    ("--version",),
    ("--help",),
    ("fit", "--help"),
    ("fit-scan", "--help"),
    ("animate", "--help"),
    ("accessory", "--help"),
    ("rig", "export", "--help"),
    ("eval", "photos", "--help"),
    ("demo", "--help"),
)
HEAVY = ("torch", "mitsuba", "drjit", "dlib", "cv2", "scipy", "kornia")
PROBE = (
    "import sys, runpy\n"
    "sys.argv = ['jnr', *sys.argv[1:]]\n"
    "try:\n"
    "    runpy.run_module('pipeline.cli', run_name='__main__')\n"
    "except SystemExit:\n"
    "    pass\n"
    "print('HEAVY=' + ','.join(m for m in {heavy!r} if m in sys.modules), file=sys.stderr)\n"
)


def jnr_executable() -> str:
    """The venv's ``jnr`` console script beside this Python."""
    candidate = Path(sys.executable).with_name("jnr")
    return str(candidate) if candidate.exists() else "jnr"


def time_command(args: tuple[str, ...], repeat: int) -> list[float]:
    """Wall seconds of ``jnr ARGS`` in a fresh process, ``repeat`` times."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run([jnr_executable(), *args], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return times


def heavy_imports(args: tuple[str, ...]) -> list[str]:
    """The heavy libraries that ``jnr ARGS`` imports."""
    result = subprocess.run(
        [sys.executable, "-c", PROBE.format(heavy=HEAVY), *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    line = next((x for x in result.stderr.splitlines() if x.startswith("HEAVY=")), "HEAVY=?")
    return [m for m in line.removeprefix("HEAVY=").split(",") if m]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=7, help="runs per command (default 7)")
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = parser.parse_args()
    rows = []
    print(f"{'command':28s} {'median s':>9s} {'max s':>7s}  heavy imports")
    for command in COMMANDS:
        times = time_command(command, args.repeat)
        heavy = heavy_imports(command)
        rows.append(
            {
                "command": "jnr " + " ".join(command),
                "median_s": statistics.median(times),
                "max_s": max(times),
                "heavy": heavy,
            }
        )
        print(f"{rows[-1]['command']:28s} {statistics.median(times):9.3f} {max(times):7.3f}  {', '.join(heavy) or '-'}")
    finish({"rows": rows, "repeat": args.repeat, "cpus": os.cpu_count()}, args.json)


if __name__ == "__main__":
    main()
