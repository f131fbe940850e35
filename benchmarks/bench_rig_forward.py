"""Rig forward pass (parameters -> vertices) against a FLAME-sized linear blendshape model, same run.

    .venv/bin/python benchmarks/bench_rig_forward.py [--batch 32] [--repeats 200] [--threads N]

Prints the median seconds of each and their ratio (rig / blendshapes). Goal: ratio <= 1.0.
The blendshape model is FLAME's size: 5,023 vertices x 400 random basis vectors, evaluated as one
batched matmul ``mean + coeffs @ basis`` (what FLAME's shape+expression blend costs).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import torch

from rig.model import JointRig
from rig.parameters import random_theta


def median_seconds(fn, repeats: int, warmup: int = 10) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    rig = JointRig(dtype=torch.float32)
    theta = random_theta(torch.Generator().manual_seed(0), args.batch, spread=0.3)
    g = torch.Generator().manual_seed(0)
    n_vertices, n_basis = 5023, 400
    basis = torch.randn(n_basis, n_vertices * 3, generator=g)
    mean = torch.randn(n_vertices * 3, generator=g)
    coeffs = torch.randn(args.batch, n_basis, generator=g)

    with torch.inference_mode():

        def rig_fn():
            return rig(theta).vertices

        def flame_fn():
            return torch.addmm(mean, coeffs, basis).view(args.batch, n_vertices, 3)

        # Interleave the two so that machine noise hits both alike.
        rig_t, flame_t = [], []
        for _ in range(5):
            rig_t.append(median_seconds(rig_fn, args.repeats // 5))
            flame_t.append(median_seconds(flame_fn, args.repeats // 5))
    rig_s, flame_s = statistics.median(rig_t), statistics.median(flame_t)
    result = {
        "batch": args.batch,
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "cpu": platform.processor() or platform.machine(),
        "rig_vertices": rig.num_vertices,
        "rig_joints": rig.num_joints,
        "rig_forward_median_s": round(rig_s, 5),
        "flame_blendshape_median_s": round(flame_s, 5),
        "ratio_rig_over_flame": round(rig_s / flame_s, 3),
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
