"""Photo fitting on synthetic renders of held-out heads with known truth (NoW-style), and its speed.

    .venv/bin/python benchmarks/bench_fit_photo.py [--neutral 5] [--expressive 5] [--first 20] [--seed 0]
                                                   [--json FILE]

One 384x384 photo per head (pipeline.synthetic.photos: yaw within +-30 deg, pitch +-10, roll +-5,
path-traced with a point light and a constant environment at 64 spp, random skin tone, hair colour
and background), the projected true landmarks + 1 px Gaussian noise, the true focal length. Every
fit is aligned to the true head by a similarity transform on the 51 inner landmarks, refined by
similarity ICP; then the face-region scan-to-mesh distance (median, mean, std per photo) and the
true vertex error are computed (pipeline.evaluation.photos). Rows: the full fit (``jnr``), its landmark-only
stage (``landmarks``, seconds = that stage alone) and the unfitted template (``template``), mean ±
sample std (ddof=1) over photos (pipeline.metrics). Heads from 20 on by default: the fit's
defaults were chosen on heads 0-5. ``--photometric`` adds the photometric stages to the ``jnr`` rows (off in
``jnr fit``'s defaults); ``--detected`` fits dlib's own detections on the renders; ``--landmarks
mediapipe`` MediaPipe's 478 points (the dense layout), ``--landmarks mediapipe68`` its 68 iBUG points.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.evaluation.photos import LANDMARK_SOURCES, evaluate_photos
from pipeline.metrics import summarize
from pipeline.photo.fit_config import FitPhotoConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--neutral", type=int, default=5, help="neutral photos (default 5)")
    parser.add_argument("--expressive", type=int, default=5, help="expressive photos (default 5)")
    parser.add_argument("--first", type=int, default=20, help="first held-out head (default 20)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None, help="write records, summary and settings here")
    parser.add_argument(
        "--photometric",
        action="store_true",
        help="the jnr rows with the photometric stages (off in jnr fit's defaults)",
    )
    parser.add_argument(
        "--detected",
        action="store_true",
        help="fit dlib's detections on the renders (HOG, then the CNN) instead of the true landmarks + 1 px noise "
        "(= --landmarks dlib)",
    )
    parser.add_argument(
        "--landmarks",
        choices=LANDMARK_SOURCES,
        default=None,
        help="the fit's landmarks: noisy (the true ones + 1 px, default), dlib, mediapipe (its 478 points, the dense "
        "layout) or mediapipe68 (its 68 iBUG points)",
    )
    args = parser.parse_args()
    torch.set_num_threads(2)

    def progress(r) -> None:
        print(
            f"  {r.kind:10s} {r.name:18s} yaw {r.yaw_deg:6.1f}  {r.method:9s} s2m median {r.s2m_median_mm:5.2f} "
            f"mean {r.s2m_mean_mm:5.2f} mm  vertex {r.vertex_mean_mm:5.2f} mm  pose {r.pose_error_deg:4.1f} deg  "
            f"landmarks {r.landmark_error_px:5.2f} px"
            f"  {r.seconds:5.1f} s",
            flush=True,
        )

    t0 = time.perf_counter()
    config = FitPhotoConfig()
    if args.photometric:
        config = replace(config, photometric=replace(config.photometric, enabled=True))
    ev = evaluate_photos(
        args.neutral,
        args.expressive,
        first=args.first,
        seed=args.seed,
        config=config,
        landmarks=args.landmarks or ("dlib" if args.detected else "noisy"),
        progress=progress,
    )
    wall = time.perf_counter() - t0
    print()
    print(ev.table_markdown())
    print()
    all_jnr = [r for r in ev.records if r.method == "jnr"]
    full = summarize(r.seconds for r in all_jnr)
    landmark_only = summarize(r.seconds for r in ev.records if r.method == "landmarks")
    template = {(r.name, r.kind): r.s2m_median_mm for r in ev.records if r.method == "template"}
    ratios = [r.s2m_median_mm / template[(r.name, r.kind)] for r in all_jnr]
    lm_ratios = [r.s2m_median_mm / template[(r.name, r.kind)] for r in ev.records if r.method == "landmarks"]
    print(
        f"goals: fit median <= 0.6 x template's: jnr {summarize(ratios).median:.2f} (worst photo {max(ratios):.2f}), "
        f"landmark fit {summarize(lm_ratios).median:.2f} (worst {max(lm_ratios):.2f}); no photo worse than the "
        f"template: jnr {sum(x > 1 for x in ratios)}, landmark fit {sum(x > 1 for x in lm_ratios)} worse; "
        f"landmark fit <= 0.3 s: median {landmark_only.median:.2f} s; "
        f"full fit <= 10 s: median {full.median:.1f} s, max {max(r.seconds for r in all_jnr):.1f} s"
    )
    print(
        f"wall {wall:.0f} s | torch threads {torch.get_num_threads()} | cpu_count {os.cpu_count()} | "
        f"{platform.processor() or platform.machine()} | python {platform.python_version()} | "
        f"torch {torch.__version__}"
    )
    print("command: " + " ".join(shlex.quote(a) for a in [sys.executable, *sys.argv]))
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "records": [asdict(r) for r in ev.records],
                    "summary": ev.summary(),
                    "settings": ev.settings,
                    "wall_s": wall,
                    "command": sys.argv,
                },
                indent=1,
                default=str,
            )
        )


if __name__ == "__main__":
    main()
