"""Where the photo fit's head pose goes wrong: the pose error on synthetic photos with known pose, and what
it depends on (issue 14: jnr's pitch was off by 7-9 degrees on real photos).

    .venv/bin/python benchmarks/bench_pose.py [--heads 8] [--first 0] [--json FILE]

Photos: held-out heads ``first..first+heads-1``, neutral, rendered as in the photo benchmark (yaw within
+-30 deg, pitch +-10, roll +-5, focal 1.2-1.7 x 384). The pose error is the camera-frame rotation between
the fitted face and the true face (:func:`pipeline.evaluation.photos.pose_error_angles`): its angle, and
its signed pitch (positive: the true face is tipped further down than the fitted one). Variants of the
landmark fit, each with the projected true landmarks + 1 px noise and with dlib's own detections on the
render: the default; the jaw contour left out (``contour_weight`` 0); the default focal (1.4 x 384)
instead of the true one; the previous prior (L_m = 100 towards the template); and the unfitted template
placed by solvePnP.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import finish, load_models

from landmarks.detect import detect_landmarks
from landmarks.detector import NoFaceError
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.positions import landmark_positions
from pipeline.camera import default_focal, solve_pose
from pipeline.evaluation.photos import pose_error_angles
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
    parser.add_argument("--heads", type=int, default=8)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    rig, neural = load_models()
    asset = rig.asset
    template = head_vertices(
        rig, neural, np.zeros(rig.num_parameters), np.zeros(LATENT), np.zeros(len(EXPRESSION_NAMES))
    )
    template_landmarks = landmark_positions(template, ibug68_embedding(asset), asset.faces)[0]
    base = FitPhotoConfig().landmarks
    variants = {
        "default": (base, False),
        "no jaw contour": (replace(base, contour_weight=0.0), False),
        "default focal": (base, True),
        "L_m 100 prior": (replace(base, prior=PriorWeights(lambda_m=100.0)), False),
    }
    rows: dict[str, list] = {}
    for i in range(args.first, args.first + args.heads):
        photo = synthetic_photo(i, seed=scan_seed(0, "photo-neutral", i))
        sources = {"true + 1 px": photo.landmarks2d}
        try:
            sources["dlib"] = detect_landmarks(photo.image, detector="dlib").landmarks
        except NoFaceError:
            pass
        for source, lm in sources.items():
            for name, (config, default) in variants.items():
                focal = default_focal(photo.width, photo.height) if default else photo.focal
                fit = fit_landmarks(lm, photo.width, photo.height, focal=focal, config=config, rig=rig, neural=neural)
                v = head_vertices(rig, neural, fit.theta, fit.z, fit.expressions)
                angles = pose_error_angles(
                    v, fit.rotation, fit.translation, photo.gt_vertices, photo.rotation, photo.translation, asset
                )
                rows.setdefault(f"{source} | {name}", []).append(angles)
            rot, trans = solve_pose(lm, template_landmarks, photo.width, photo.height, photo.focal)
            rows.setdefault(f"{source} | template + solvePnP", []).append(
                pose_error_angles(template, rot, trans, photo.gt_vertices, photo.rotation, photo.translation, asset)
            )
        print(
            photo.name,
            f"yaw {photo.yaw_deg:.1f} pitch {photo.pitch_deg:.1f}",
            {k: round(v[-1][0], 2) for k, v in rows.items()},
            flush=True,
        )
    print("\n| landmarks | fit | pose error deg (mean) | max | signed pitch deg (mean) | |pitch| (mean) | photos |")
    print("|---|---|---|---|---|---|---|")
    for key, values in rows.items():
        a = np.array(values)
        source, name = key.split(" | ")
        print(
            f"| {source} | {name} | {a[:, 0].mean():.2f} | {a[:, 0].max():.2f} | {a[:, 2].mean():+.2f} | "
            f"{np.abs(a[:, 2]).mean():.2f} | {len(a)} |"
        )
    finish({"rows": {k: np.asarray(v).tolist() for k, v in rows.items()}}, args.json)


if __name__ == "__main__":
    main()
