"""Does the photometric stage improve the geometry over the landmark fit? Its two light models on the
synthetic validation photos.

    .venv/bin/python benchmarks/compare_light_models.py [--heads 6] [--models directional sh] [--json FILE]

Validation photos: held-out heads 0..heads-1, neutral (as ``benchmarks/tune_photo_prior.py``), rendered
with a point light and a constant environment (the fit's light models are ambient + one directional
light, and second-order spherical harmonics). Per photo and light model: the full fit (landmark fit, then
the photometric stages of ``FitPhotoConfig`` with ``enabled=True``) against its own landmark fit and the
unfitted template, NoW-style s2m median and true vertex error (mm), the final photometric residual
(mean Charbonnier, linear RGB) and the seconds of the whole fit.
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
from pipeline.evaluation.scans import scan_seed
from pipeline.fitting.state import head_vertices
from pipeline.photo.fit import fit_photo
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.synthetic.photos.simulate import synthetic_photo
from rig.expressions import EXPRESSION_NAMES
from rig.skinning.neural import LATENT


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--heads", type=int, default=6)
    parser.add_argument("--models", nargs="+", default=["directional", "sh"])
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    rig, neural = load_models()
    template = head_vertices(
        rig, neural, np.zeros(rig.num_parameters), np.zeros(LATENT), np.zeros(len(EXPRESSION_NAMES))
    )
    base = FitPhotoConfig()
    rows: dict[str, list] = {}
    for i in range(args.heads):
        photo = synthetic_photo(i, seed=scan_seed(0, "photo-neutral", i))
        truth = photo.gt_vertices
        rows.setdefault("template", []).append(face_error(template, truth))
        for model in args.models:
            config = replace(base, photometric=replace(base.photometric, enabled=True, light_model=model))
            t0 = time.perf_counter()
            fit = fit_photo(photo.image, photo.landmarks2d, focal=photo.focal, config=config, rig=rig, neural=neural)
            seconds = time.perf_counter() - t0
            lfit = fit.landmark_fit
            if model == args.models[0]:
                rows.setdefault("landmark fit", []).append(
                    face_error(head_vertices(rig, neural, lfit.theta, lfit.z, lfit.expressions), truth)
                )
            rows.setdefault(model, []).append(
                {**face_error(fit.rig_vertices, truth), "seconds": seconds, "photo": fit.stages[-1].metrics["photo"]}
            )
        print(photo.name, {k: round(v[-1]["s2m_median_mm"], 3) for k, v in rows.items()}, flush=True)
    print("\n| fit | s2m median mm (mean) | vertex mm (mean) | photo residual | seconds (median) |")
    print("|---|---|---|---|---|")
    for name, rs in rows.items():
        photo = f"{np.mean([r['photo'] for r in rs]):.4f}" if "photo" in rs[0] else ""
        secs = f"{np.median([r['seconds'] for r in rs]):.1f}" if "seconds" in rs[0] else ""
        print(
            f"| {name} | {np.mean([r['s2m_median_mm'] for r in rs]):.3f} | "
            f"{np.mean([r['vertex_mean_mm'] for r in rs]):.3f} | {photo} | {secs} |"
        )
    finish({"rows": rows}, args.json)


if __name__ == "__main__":
    main()
