"""Speed of the landmark fit (Levenberg-Marquardt, the default, against JNR's Adam schedule) on one photo's
68 landmarks, and where each ends.

    .venv/bin/python benchmarks/bench_landmark_fit.py [--heads 10] [--first 20] [--repeats 3] [--json FILE]

No rendering: held-out heads (``population_split("heldout")``, the same heads the photo benchmark renders)
are placed at a random pose (yaw within +-30 deg, pitch +-10, roll +-5, 600-750 mm away) in front of a
384 x 384 camera with focal 1.4 x 384, and their 68 landmarks (static embedding, jaw contour as seen from
the camera) are projected, plus 1 px Gaussian noise. Each fit is timed ``--repeats`` times after one
warm-up fit (the first fit in a process also loads the models); printed: median seconds per fit, LM
iterations, the final objective (landmark term + priors, the same for both solvers) and the mean
landmark error in pixels. Torch on 2 threads.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import finish, load_models

from landmarks.ibug68.contour import contour_vertex_ids
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.names import CHIN
from landmarks.ibug68.positions import landmark_positions
from pipeline.camera import camera_center_in_rig
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.landmark_fit import fit_landmarks
from pipeline.synthetic.population import population_split
from rig.geometry import RIG_TO_OPENCV, head_rotation

SIZE = 384
FOCAL = 1.4 * SIZE


def projected_landmarks(head: np.ndarray, asset, rng: np.random.Generator) -> np.ndarray:
    """``(68, 2)`` pixels of a rig-space head at a random pose, with 1 px noise."""
    rotation = head_rotation(rng.uniform(-30, 30), rng.uniform(-10, 10), rng.uniform(-5, 5))
    translation = np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(600, 750)])
    points = landmark_positions(head, ibug68_embedding(asset), asset.faces)[0]
    contour = contour_vertex_ids(head, asset.faces, camera_center_in_rig(rotation, translation), asset)
    for k in range(17):
        if k != CHIN:
            points[k] = head[contour[k]]
    cam = points @ (RIG_TO_OPENCV @ rotation).T + translation
    pixels = cam[:, :2] / cam[:, 2:] * FOCAL + (SIZE - 1) / 2.0
    return pixels + rng.standard_normal(pixels.shape)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--heads", type=int, default=10)
    parser.add_argument("--first", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    rig, neural = load_models()
    heads = population_split("heldout", 0).vertices[args.first : args.first + args.heads]
    rng = np.random.default_rng(args.seed)
    targets = [projected_landmarks(h, rig.asset, rng) for h in heads]
    base = FitPhotoConfig().landmarks
    solvers = {"lm": base, "adam": replace(base, solver="adam")}
    for config in solvers.values():  # warm-up: models, caches, the identity prior
        fit_landmarks(targets[0], SIZE, SIZE, focal=FOCAL, config=config, rig=rig, neural=neural)
    rows = {name: [] for name in solvers}
    for i, lm in enumerate(targets):
        for name, config in solvers.items():
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                fit = fit_landmarks(lm, SIZE, SIZE, focal=FOCAL, config=config, rig=rig, neural=neural)
                times.append(time.perf_counter() - t0)
            rows[name].append(
                {
                    "head": args.first + i,
                    "seconds": float(np.median(times)),
                    "iterations": [s.iterations for s in fit.stages],
                    "objective": fit.stages[-1].loss_end,
                    "landmark_error_px": float(fit.error_px.mean()),
                }
            )
            r = rows[name][-1]
            print(
                f"head {r['head']:3d} {name:4s} {r['seconds']:6.3f} s  iterations {r['iterations']}  "
                f"objective {r['objective']:7.3f}  landmarks {r['landmark_error_px']:5.2f} px",
                flush=True,
            )
    print()
    print(
        "| solver | median s per fit | max s | iterations (median, per stage) | objective (mean) "
        "| landmarks px (mean) |"
    )
    print("|---|---|---|---|---|---|")
    for name, rs in rows.items():
        secs = [r["seconds"] for r in rs]
        its = np.median(np.array([r["iterations"] for r in rs]), axis=0).tolist()
        print(
            f"| {name} | {np.median(secs):.3f} | {max(secs):.3f} | {its} | "
            f"{np.mean([r['objective'] for r in rs]):.3f} | {np.mean([r['landmark_error_px'] for r in rs]):.2f} |"
        )
    print(f"\ngoal: landmark fit <= 0.3 s: LM median {np.median([r['seconds'] for r in rows['lm']]):.3f} s")
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, {platform.processor() or platform.machine()}, "
        f"python {platform.python_version()}"
    )
    finish({"rows": rows}, args.json)


if __name__ == "__main__":
    main()
