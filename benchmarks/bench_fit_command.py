"""Where the seconds of ``jnr fit PHOTO`` go: the whole command's wall time (fresh processes) and a breakdown
by phase (issue 26's goal: <= 3 s wall for a 512 x 512 portrait on 2 idle cores, the fit <= 0.5 s).

    .venv/bin/python benchmarks/bench_fit_command.py [--photo FILE] [--runs 3] [--json FILE]

Default photo: scikit-image's astronaut (512 x 512). *Wall*: ``jnr fit PHOTO --out DIR`` run ``--runs`` times
as a fresh process, from process start to exit (the default outputs, the default detector). *Breakdown*: one
more fresh process runs the same command in-process with timers around its phases: start-up (Python and
the imports the command needs before it reads the photo), read, detect, fit (landmark fit; the photometric
stages are off by default), and each output (the renders, the texture, the meshes, the glTF, the viewer,
the rest); what is not in a phase is listed as "other". The first command of a fresh machine also builds
caches (e.g. the expression shapes, ``rig.disk_cache``): a warm-up run comes first and is not counted.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import finish  # noqa: E402

# The driver run in a fresh process: timers around the command's phases (wrapping the functions it calls).
DRIVER = r"""
import json, sys, time
t_start = time.perf_counter()
timings = {}
def timed(module, name, label):
    import importlib
    mod = importlib.import_module(module)
    original = getattr(mod, name)
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            timings[label] = timings.get(label, 0.0) + time.perf_counter() - t0
    setattr(mod, name, wrapper)
from pipeline.cli import main
import pipeline.photo.photo_file, pipeline.photo.outputs, pipeline.photo.detection
timings["start-up (imports)"] = time.perf_counter() - t_start
timed("pipeline.photo.photo_file", "load_working_image", "read")
timed("pipeline.photo.photo_file", "photo_landmarks", "detect")
timed("pipeline.photo.photo_file", "fit_photo", "fit")
timed("pipeline.photo.outputs", "render_fit", "output: render (Mitsuba)")
timed("pipeline.photo.outputs", "texture_from_fit", "output: texture")
timed("pipeline.photo.outputs", "export_mesh", "output: OBJ + PLY")
timed("pipeline.photo.outputs", "write_skinned_head", "output: glTF")
timed("pipeline.photo.outputs", "write_fit_viewer", "output: viewer")
timed("pipeline.photo.outputs", "_save_png", "output: PNGs")
timed("pipeline.photo.photo_file", "write_photo_outputs", "outputs (all)")
code = main(["fit", sys.argv[1], "--out", sys.argv[2], "--quiet"])
timings["total"] = time.perf_counter() - t_start
print(json.dumps({"code": code, "timings": timings}))
"""


def _astronaut(folder: Path) -> Path:
    from PIL import Image
    from skimage import data

    path = folder / "astronaut.png"
    Image.fromarray(data.astronaut()).save(path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--photo", type=Path, default=None, help="default: scikit-image's astronaut")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    jnr = [sys.executable, "-m", "pipeline.cli"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        photo = args.photo or _astronaut(tmp)
        subprocess.run([*jnr, "fit", str(photo), "--out", str(tmp / "warm"), "--quiet"], check=True, env=env, cwd=ROOT)
        walls = []
        for k in range(args.runs):
            t0 = time.perf_counter()
            subprocess.run([*jnr, "fit", str(photo), "--out", str(tmp / f"run{k}"), "--quiet"], check=True, env=env)
            walls.append(time.perf_counter() - t0)
            print(f"run {k}: {walls[-1]:.2f} s wall", flush=True)
        out = subprocess.run(
            [sys.executable, "-c", DRIVER, str(photo), str(tmp / "phases")],
            check=True,
            env=env,
            capture_output=True,
            text=True,
        )
        result = json.loads(out.stdout.strip().splitlines()[-1])
    timings = result["timings"]
    outputs = timings.pop("outputs (all)")
    parts = [k for k in timings if k.startswith("output: ")]
    timings["output: other (JSON, CSV, landmarks, staging)"] = outputs - sum(timings[k] for k in parts)
    named = sum(v for k, v in timings.items() if k != "total")
    timings["other (config, checks, summary)"] = timings["total"] - named
    print(f"\njnr fit {photo.name}: wall {min(walls):.2f} s best, {sum(walls) / len(walls):.2f} s mean of {args.runs}")
    print("\n| phase | seconds |\n|---|---|")
    for key, value in timings.items():
        print(f"| {key} | {value:.2f} |")
    finish({"wall_s": walls, "phases_s": timings, "photo": str(args.photo or "astronaut")}, args.json)


if __name__ == "__main__":
    main()
