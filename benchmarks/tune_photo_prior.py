"""Choose the weight of the identity prior in the photo fit on synthetic validation photos.

    .venv/bin/python benchmarks/tune_photo_prior.py [--heads 6] [--weights 0.01 0.03 0.1 0.3 1]
                                                   [--adam] [--json FILE]

Validation photos: held-out heads 0..heads-1, neutral and expressive (the photo benchmark and the README's
table use heads 20 on), rendered as in ``benchmarks/bench_fit_photo.py`` (path tracing, point light +
environment, random skin and background, 1 px landmark noise, true focal). For each weight of
``landmarks.prior.lambda_identity`` the landmark fit (Levenberg-Marquardt, the default) is scored
NoW-style (pipeline.evaluation.photos): s2m median over the face region, true vertex error, the
camera-frame pose error; also the previous prior (L_m = 100 towards the template) with LM and, with
``--adam``, with JNR's Adam schedule. Printed: per weight the mean over photos, the worst ratio to the
unfitted template's s2m median, and the mean landmark fit time. ``--detected`` fits dlib's detections on
the renders instead (what a real photo gives).
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

from landmarks.detect import detect_landmarks
from landmarks.detector import NoFaceError
from pipeline.evaluation.photos import face_error, pose_error_deg
from pipeline.evaluation.scans import scan_seed
from pipeline.fitting.priors import PriorWeights
from pipeline.fitting.state import head_vertices
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.landmark_fit import fit_landmarks
from pipeline.synthetic.photos.simulate import synthetic_photo
from rig.expressions import EXPRESSION_NAMES
from rig.skinning.neural import LATENT


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--heads", type=int, default=6)
    parser.add_argument("--weights", type=float, nargs="+", default=[0.01, 0.03, 0.1, 0.3, 1.0])
    parser.add_argument("--adam", action="store_true", help="also the previous prior with JNR's Adam schedule")
    parser.add_argument(
        "--detected",
        action="store_true",
        help="fit dlib's detections on the renders (HOG, then the CNN) instead of the true "
        "landmarks + 1 px noise; photos without a detection are left out",
    )
    parser.add_argument(
        "--contour-weight",
        type=float,
        default=None,
        help="landmarks.contour_weight for every fit (default: the config's)",
    )
    parser.add_argument(
        "--weighting",
        choices=("contour", "detector"),
        default=None,
        help="landmarks.landmark_weighting for every fit (default: the config's)",
    )
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    rig, neural = load_models()
    template = head_vertices(
        rig, neural, np.zeros(rig.num_parameters), np.zeros(LATENT), np.zeros(len(EXPRESSION_NAMES))
    )
    base = FitPhotoConfig().landmarks
    if args.contour_weight is not None:
        base = replace(base, contour_weight=args.contour_weight)
    if args.weighting is not None:
        base = replace(base, landmark_weighting=args.weighting)
    configs = {
        f"identity {w:g}": replace(base, prior=replace(base.prior, lambda_m=0.0, lambda_identity=w))
        for w in args.weights
    }
    configs["L_m 100 (LM)"] = replace(base, prior=PriorWeights(lambda_m=100.0))
    if args.adam:
        configs["L_m 100 (Adam)"] = replace(base, solver="adam", prior=PriorWeights(lambda_m=100.0))
    rows: dict[str, list] = {"template": []}
    for kind in ("neutral", "expressive"):
        for i in range(args.heads):
            photo = synthetic_photo(i, expressive=kind == "expressive", seed=scan_seed(0, "photo-" + kind, i))
            target = photo.landmarks2d
            if args.detected:
                try:
                    target = detect_landmarks(photo.image, detector="dlib").landmarks
                except NoFaceError:
                    print(photo.name, "no face found by dlib: left out", flush=True)
                    continue
            rows["template"].append(
                {"name": photo.name, "s2m": face_error(template, photo.gt_vertices)["s2m_median_mm"]}
            )
            for name, config in configs.items():
                t0 = time.perf_counter()
                fit = fit_landmarks(
                    target, photo.width, photo.height, focal=photo.focal, config=config, rig=rig, neural=neural
                )
                seconds = time.perf_counter() - t0
                v = head_vertices(rig, neural, fit.theta, fit.z, fit.expressions)
                err = face_error(v, photo.gt_vertices)
                rows.setdefault(name, []).append(
                    {
                        "name": photo.name,
                        "s2m": err["s2m_median_mm"],
                        "vertex": err["vertex_mean_mm"],
                        "pose": pose_error_deg(
                            v, fit.rotation, fit.translation, photo.gt_vertices, photo.rotation, photo.translation
                        ),
                        "px": float(fit.error_px.mean()),
                        "seconds": seconds,
                    }
                )
            print(photo.name, {k: round(v[-1]["s2m"], 3) for k, v in rows.items()}, flush=True)
    t = np.array([r["s2m"] for r in rows["template"]])
    print("\n| prior | s2m median mm (mean) | worst / template | vertex mm | pose deg | landmarks px | seconds |")
    print("|---|---|---|---|---|---|---|")
    print(f"| template (no fit) | {t.mean():.3f} | 1.00 | | | | |")
    for name, rs in rows.items():
        if name == "template":
            continue
        s2m = np.array([r["s2m"] for r in rs])
        print(
            f"| {name} | {s2m.mean():.3f} | {(s2m / t).max():.2f} | {np.mean([r['vertex'] for r in rs]):.3f} | "
            f"{np.mean([r['pose'] for r in rs]):.2f} | {np.mean([r['px'] for r in rs]):.2f} | "
            f"{np.mean([r['seconds'] for r in rs]):.2f} |"
        )
    finish({"rows": rows}, args.json)


if __name__ == "__main__":
    main()
