"""The whole capacity table (``jnr eval capacity``, every row): the rig's skinning variants, the PCA shape
model and ASM's ablation, error over heads, model size in floats and fitting seconds per head.

    .venv/bin/python benchmarks/bench_capacity.py [--limit N] [--models jnr,pca,asm] [--oracle]
                                                  [--splits test heldout] [--json FILE | --no-json]

Runs :func:`pipeline.evaluation.capacity.evaluate_capacity` with its default iteration counts on the
``test`` (7) and ``heldout`` (100) heads, prints the table (``jnr eval capacity``'s) and the machine, and
writes the result, the machine and the command to ``benchmarks/results/capacity_bench.json`` (``--json``). Torch on 2
threads. The full run takes tens of minutes on 2 cores (the rig's neural rows dominate); ``--limit N``
fits only each split's first ``N`` heads (a check that everything runs, not figures to quote: the fits
run in chunks of up to 20 heads, so seconds per head with 2 heads are several times those of a full
run). The load average before and after is recorded: seconds measured on a busy machine are upper
bounds.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import finish

from pipeline.cli.evaluate import capacity_table, parse_models
from pipeline.evaluation.capacity import CapacitySettings, evaluate_capacity


def machine() -> dict:
    """What the seconds were measured on."""
    return {
        "processor": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--limit", type=int, default=None, help="only each split's first N heads")
    parser.add_argument("--models", type=parse_models, default=parse_models("all"), help="jnr,pca,asm (default: all)")
    parser.add_argument("--splits", nargs="+", default=["test", "heldout"])
    parser.add_argument("--oracle", action="store_true", help="also the per-head optimal weights row")
    parser.add_argument("--asm-iterations", type=int, default=None)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "capacity_bench.json")
    parser.add_argument("--no-json", action="store_true", help="write no JSON")
    args = parser.parse_args()
    torch.set_num_threads(2)
    load_before = os.getloadavg()
    start = time.perf_counter()
    last = [start]

    def progress(stage: str, done: int, total: int) -> None:
        now = time.perf_counter()
        print(
            f"  {stage}: {done}/{total}, {now - last[0]:.1f} s since the last report ({now - start:.0f} s so far)",
            file=sys.stderr,
            flush=True,
        )
        last[0] = now

    settings = CapacitySettings(asm_iterations=args.asm_iterations)
    result = evaluate_capacity(
        tuple(args.splits), settings, limit=args.limit, progress=progress, oracle=args.oracle, models=args.models
    )
    total = time.perf_counter() - start
    print(capacity_table(result))
    print(f"\ntotal {total:.0f} s; " + ", ".join(f"{k} {v}" for k, v in machine().items()))
    load = {
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
    print(f"load average (1, 5, 15 min) before {load['load_average_before']}, after {load['load_average_after']}")
    payload = {
        **result,
        "limit": args.limit,
        "total_seconds": round(total, 1),
        "machine": {**machine(), **load},
        "date": time.strftime("%Y-%m-%d %H:%M %Z"),
    }
    finish(payload, None if args.no_json else args.json)


if __name__ == "__main__":
    main()
