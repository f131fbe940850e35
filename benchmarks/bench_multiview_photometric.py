"""Does photometric consistency between views help the multi-view fit? (issue 15; docs/multiview.md)

    .venv/bin/python benchmarks/bench_multiview_photometric.py [--heads 20 21] [--views 3 5] [--lambdas 5]
                                                               [--json benchmarks/results/multiview_photometric.json]

Per held-out head, the first k of its rendered synthetic views (:func:`pipeline.synthetic.multiview.synthetic_views`,
path-traced at 16 samples per pixel, 384 x 384, true landmarks + 1 px noise, default focal): the multi-view
landmark fit, then the same fit followed by the photometric-consistency stage
(:class:`pipeline.photo.multiview.PhotoConsistencyConfig`) for each ``lambda_pc``. Scored by the NoW-style
face-region scan-to-mesh median of the identity without expression (:func:`pipeline.evaluation.photos.face_error`).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import finish, load_models

from pipeline.evaluation.photos import face_error
from pipeline.photo.multiview import MultiViewConfig, fit_multiview
from pipeline.photo.multiview_config import INDEPENDENT_VIEWS
from pipeline.synthetic.multiview import MultiViewSettings, synthetic_views
from pipeline.synthetic.photos.settings import PhotoSettings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--heads", type=int, nargs="+", default=[20, 21])
    parser.add_argument("--views", type=int, nargs="+", default=[3, 5])
    parser.add_argument("--lambdas", type=float, nargs="+", default=[5.0])
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    rig, neural = load_models()
    # the true points + 1 px: their own error, independent between views (bench_multiview.py does the same)
    base = MultiViewConfig(**INDEPENDENT_VIEWS)
    records = []
    for head in args.heads:
        views = synthetic_views(head, max(args.views), settings=MultiViewSettings(photo=PhotoSettings(spp=args.spp)))
        for n in args.views:
            lms = [p.landmarks2d for p in views.photos[:n]]
            sizes = [(p.width, p.height) for p in views.photos[:n]]
            images = [p.image for p in views.photos[:n]]
            landmark_fit = fit_multiview(lms, sizes, rig=rig, neural=neural, config=base)
            before = face_error(landmark_fit.identity_vertices, views.neutral_vertices)["s2m_median_mm"]
            for lam in args.lambdas:
                t0 = time.perf_counter()
                config = replace(base, photometric=replace(base.photometric, enabled=True, lambda_pc=lam))
                fit = fit_multiview(
                    lms,
                    sizes,
                    images=images,
                    rig=rig,
                    neural=neural,
                    config=config,
                    single_view_fits=landmark_fit.single_view_fits,
                )
                after = face_error(fit.identity_vertices, views.neutral_vertices)["s2m_median_mm"]
                stage = fit.stages[-1]
                records.append(
                    {
                        "head": head,
                        "views": n,
                        "lambda_pc": lam,
                        "landmarks_only_mm": before,
                        "photometric_mm": after,
                        "one_minus_lncc_end": stage.metrics["one_minus_lncc"],
                        "photometric_seconds": stage.seconds,
                        "seconds": time.perf_counter() - t0,
                    }
                )
                print(
                    f"head {head} {n} views lambda_pc {lam:g}: {before:.3f} -> {after:.3f} mm "
                    f"(1 - LNCC {stage.metrics['one_minus_lncc']:.3f}, {stage.seconds:.0f} s)",
                    flush=True,
                )
    lines = [
        "| views | lambda_pc | landmarks only mm | + photometric consistency mm | change mm | photometric s |",
        "|---|---|---|---|---|---|",
    ]
    for n in args.views:
        for lam in args.lambdas:
            rs = [r for r in records if r["views"] == n and r["lambda_pc"] == lam]
            a = np.mean([r["landmarks_only_mm"] for r in rs])
            b = np.mean([r["photometric_mm"] for r in rs])
            lines.append(
                f"| {n} | {lam:g} | {a:.3f} | {b:.3f} | {b - a:+.3f} | "
                f"{np.median([r['photometric_seconds'] for r in rs]):.0f} |"
            )
    print("\n".join(lines))
    finish({"records": records, "markdown": "\n".join(lines), "heads": args.heads, "spp": args.spp}, args.json)


if __name__ == "__main__":
    main()
