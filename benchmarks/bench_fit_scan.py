"""Scan fitting on simulated depth scans of held-out heads: jnr vs trimesh's nricp_amberg (JNR Tables 2-3).

    .venv/bin/python benchmarks/bench_fit_scan.py [--neutral 5] [--expressive 5] [--seed 0] [--hires]
                                                  [--json FILE]

One simulated Kinect-like scan per head (noise, holes, ~1 % outliers, random pose); both methods fit
the same cloud from the same rigid pre-alignment. Prints a markdown table (rows method x kind):
scan-to-mesh distance over *all* scan points (outliers included, so the median is the robust
figure), the true per-vertex error over the face region (known correspondence), mean ± std over
scans, and the median seconds; then the machine and the command line. ``--hires`` uses a 640x576
camera (~15-20k points) instead of 320x288 (~3-5k).
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

from pipeline.evaluation.scans import evaluate_scans
from pipeline.metrics import STD_DDOF
from pipeline.scan.fit_config import FitScanConfig
from pipeline.synthetic.scans import DepthCamera

HIRES = DepthCamera(640, 576, 504.0, 504.0, 320.0, 288.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--neutral", type=int, default=5, help="neutral scans (default 5)")
    parser.add_argument("--expressive", type=int, default=5, help="expressive scans (default 5)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--hires", action="store_true", help="640x576 camera (~15-20k points)")
    parser.add_argument("--no-baseline", action="store_true", help="skip nricp_amberg")
    parser.add_argument("--json", type=Path, default=None, help="write records, summary and settings here")
    parser.add_argument(
        "--skinning",
        choices=("jnr", "asm", "both"),
        default="jnr",
        help="the head model of jnr's fit (FitScanConfig.skinning); both: one row each",
    )
    args = parser.parse_args()
    torch.set_num_threads(2)

    def progress(r) -> None:
        print(
            f"  {r.kind:10s} {r.name} {r.method:12s} {r.points:6d} pts  s2m median {r.s2m_median_mm:6.2f} mm  "
            f"vertex err {r.vertex_mean_mm:6.2f} mm (prealigned {r.prealign_vertex_mean_mm:6.2f})  "
            f"{r.seconds:6.1f} s",
            flush=True,
        )

    t0 = time.perf_counter()
    models = ("jnr", "asm") if args.skinning == "both" else (args.skinning,)
    ev = None
    for n, skinning in enumerate(models):
        part = evaluate_scans(
            args.neutral,
            args.expressive,
            seed=args.seed,
            camera=HIRES if args.hires else None,
            baseline=not args.no_baseline and n == 0,
            progress=progress,
            config=FitScanConfig(skinning=skinning),
        )
        ev = part if ev is None else replace(ev, records=ev.records + part.records)
    wall = time.perf_counter() - t0

    print()
    print(ev.table_markdown())
    print()
    print(
        "s2m: distance of every scan point (outliers included) to the fitted surface; vertex err: "
        "|fitted - true| per vertex with known correspondence (face region / seen face vertices / all); "
        f"mean ± std over scans (ddof={STD_DDOF}); seconds: median (nricp_amberg = shared prealign + nricp)."
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
