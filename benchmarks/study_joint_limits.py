"""What the rig can express on real-scan identities: where the fitting error sits and which channel limits
stop the fit (issue 25; JNR designed its joints by fitting scans and adjusting them).

On the ICT training heads (``population_split("train")``, similarity-normalised onto the template as
``jnr train`` gives them), with the rig's initial (painted) weights, three fits of eq. 7
(:func:`rig.skinning.joint_fit.fit_joints`, ``--iterations`` Adam steps):

- **current**: the channel limits of :mod:`rig.joints` (the limit penalty ``lambda_x`` on);
- **free**: no limit penalty (``lambda_x = 0``): how far each channel wants to go;
- **proposed** (with ``--propose``): every channel whose free fits leave its range in more than
  ``--outside`` of the heads gets the range widened to hold the free fits' 2.5-97.5 % percentiles (in the
  table's units, rounded outwards to 0.1); written to the JSON for review, not to the code.

Prints the point-to-point error (mm, mean over heads of each head's mean over all vertices) and its mean
per region for each fit, and per channel the fraction of heads outside its limits. The figures in
``docs/joints.md`` come from this script.

    .venv/bin/python benchmarks/study_joint_limits.py [--heads 85] [--iterations 400] [--propose]
        [--out benchmarks/results/joint_limits.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.synthetic.population import population_split, similarity_normalised  # noqa: E402
from rig.parameters import CHANNELS, theta_limits  # noqa: E402
from rig.skinning.joint_fit import fit_joints  # noqa: E402


def _fit(rig, targets, iterations, lambda_x, chunk=32):
    out = []
    for s in range(0, len(targets), chunk):
        out.append(fit_joints(rig, targets[s : s + chunk], iterations=iterations, lambda_x=lambda_x).theta)
    theta = torch.cat(out)
    with torch.no_grad():
        err = (rig(theta).vertices - targets).norm(dim=-1)  # (N, V)
    return theta.double().numpy(), err.double().numpy()


def _regions(err: np.ndarray, asset) -> dict[str, float]:
    return {
        name: round(float(err[:, asset.regions == k].mean()), 3)
        for k, name in enumerate(asset.region_names)
        if (asset.regions == k).any()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--heads", type=int, default=85)
    parser.add_argument("--iterations", type=int, default=400)
    parser.add_argument("--propose", action="store_true")
    parser.add_argument("--current-only", action="store_true", help="only the fit with the current limits")
    parser.add_argument("--outside", type=float, default=0.1)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "joint_limits.json")
    args = parser.parse_args()
    torch.set_num_threads(2)
    from rig.model import JointRig

    t0 = time.perf_counter()
    rig = JointRig()
    asset = rig.asset
    heads = population_split("train", first=args.heads).vertices
    targets = torch.as_tensor(similarity_normalised(heads, asset.vertices), dtype=rig.template.dtype)
    result: dict = {"command": " ".join(["benchmarks/study_joint_limits.py"] + sys.argv[1:]), "heads": len(heads)}
    low, high = (t.double().numpy() for t in theta_limits(torch.float64))
    fits = {}
    for name, lx in (("current", None), ("free", 0.0))[: 1 if args.current_only else 2]:
        theta, err = _fit(rig, targets, args.iterations, lx if lx is not None else 0.3)
        fits[name] = theta
        result[name] = {
            "mean_mm": round(float(err.mean()), 3),
            "std_mm": round(float(err.mean(1).std(ddof=1)), 3),
            "regions": _regions(err, asset),
        }
        print(name, result[name]["mean_mm"], result[name]["regions"], flush=True)
    if args.current_only:
        result["seconds"] = round(time.perf_counter() - t0, 1)
        args.out.write_text(json.dumps(result, indent=1) + "\n")
        return
    free = fits["free"]
    outside = ((free < low - 1e-9) | (free > high + 1e-9)).mean(0)
    lo_p, hi_p = np.percentile(free, 2.5, axis=0), np.percentile(free, 97.5, axis=0)
    channels = []
    for i, ch in enumerate(CHANNELS):
        channels.append(
            {
                "channel": ch.name,
                "limits": [round(float(low[i]), 3), round(float(high[i]), 3)],
                "free_p2.5_p97.5": [round(float(lo_p[i]), 3), round(float(hi_p[i]), 3)],
                "outside": round(float(outside[i]), 3),
            }
        )
    result["channels"] = sorted(channels, key=lambda c: -c["outside"])
    print("channels outside their limits in the free fits:")
    for c in result["channels"][:25]:
        if c["outside"] > 0:
            print(f"  {c['channel']:40s} {c['outside']:.2f}  limits {c['limits']}  free {c['free_p2.5_p97.5']}")
    result["seconds"] = round(time.perf_counter() - t0, 1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
