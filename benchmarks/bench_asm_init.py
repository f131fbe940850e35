"""How well ASM's initial Gaussian mixtures (K = 2 / 3 / 5 per bone) reproduce the rig's painted weights.

ASM fits its GMMs to Blender's automatic weights; ours are fitted (``jnr train --asm-init``) to the rig's
painted initial weights on the skin UV island. Printed per K:

- the weight error on the skin island (RMS and largest, weight units, rows sum to 1);
- what it does to a posed head: the rig posed by random joint parameters (``rig.parameters.random_theta``,
  spread 0.5, 20 poses) with the GMM weights against the painted weights, mean and largest vertex
  distance in mm;
- the forward time of the full ASM model (GMM weights + dynamic binding + skinning) for a batch of 32.

Usage: ``.venv/bin/python benchmarks/bench_asm_init.py [--out benchmarks/results/asm_init_bench.json]``
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rig.lbs import channels_to_trs
from rig.model import JointRig
from rig.parameters import random_theta
from rig.skinning.asm import INIT_COMPONENTS, AdaptiveSkinning, AsmParameters, default_init_path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="benchmarks/results/asm_init_bench.json")
    parser.add_argument("--poses", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(max(1, torch.get_num_threads()))
    rig = JointRig(dtype=torch.float64)
    theta = random_theta(torch.Generator().manual_seed(0), batch=args.poses, spread=0.5).double()
    rotation, translation, scale = channels_to_trs(theta, rig.channel_joint, rig.channel_kind, rig.num_joints)
    tau = torch.cat([rotation * 180.0 / math.pi, translation, scale - 1.0], dim=-1)
    with torch.no_grad():
        painted_pose = rig(theta).vertices
    rows = []
    for K in INIT_COMPONENTS:
        model = AdaptiveSkinning(rig, components=K)
        p = AsmParameters(**{**model.initial(args.poses).as_dict(), "tau": tau})
        with torch.no_grad():
            w = model.gmm_weights(p.select(0))[0]
            err = w - model.painted[model.gmm_vertices]
            posed = model(p, dynamic_binding=True, gmm_weights=True).vertices
        dist = (posed - painted_pose).norm(dim=-1)
        model32 = AdaptiveSkinning(JointRig(dtype=torch.float32), components=K)
        p32 = model32.initial(32)
        with torch.no_grad():
            model32(p32)
            t0 = time.perf_counter()
            for _ in range(5):
                model32(p32)
            forward = (time.perf_counter() - t0) / 5
        with np.load(default_init_path()) as data:
            report = data[f"k{K}_report"]
        rows.append(
            {
                "K": K,
                "parameters_per_bone": 11 + 6 * K,
                "parameters": model.num_parameters,
                "weight_rms": round(float(err.pow(2).mean().sqrt()), 4),
                "weight_max": round(float(err.abs().max()), 3),
                "posed_mean_mm": round(float(dist.mean()), 3),
                "posed_max_mm": round(float(dist.max()), 2),
                "forward_batch32_s": round(forward, 3),
                "init_fit_seconds": round(float(report[2]), 1),
            }
        )
    print(
        f"{'K':>2s} {'floats/bone':>11s} {'floats':>7s} {'w RMS':>7s} {'w max':>6s} {'posed mean mm':>13s} "
        f"{'posed max mm':>12s} {'fwd B=32 s':>10s}"
    )
    for r in rows:
        print(
            f"{r['K']:2d} {r['parameters_per_bone']:11d} {r['parameters']:7d} {r['weight_rms']:7.4f} "
            f"{r['weight_max']:6.3f} {r['posed_mean_mm']:13.3f} {r['posed_max_mm']:12.2f} "
            f"{r['forward_batch32_s']:10.3f}"
        )
    result = {
        "rows": rows,
        "poses": args.poses,
        "machine": f"{platform.machine()}, {torch.get_num_threads()} threads",
        "torch": torch.__version__,
        "date": time.strftime("%Y-%m-%d"),
    }
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
