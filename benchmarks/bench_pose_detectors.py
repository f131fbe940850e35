"""How much of the photo fit's pose error is the detector's: the pose that the detected points give *with the
true 3D shape* (solvePnP of the true head's embedded points), against the fit's, per detector (issue 26).

    .venv/bin/python benchmarks/bench_pose_detectors.py [--neutral 6] [--expressive 6] [--first 0] [--json FILE]

Photos: held-out heads ``first..``, neutral and expressive, rendered as in the photo benchmark
(:func:`pipeline.evaluation.photos.evaluate_photos`'s photos: yaw within +-30 deg, pitch +-10, roll +-5).
Sources: the projected true points + 1 px noise (iBUG-68 and MediaPipe's 478, the latter's outline picked
on the silhouette as the fit picks it); dlib's 68 (HOG, then the CNN); MediaPipe's 478. Per source:

* ``pnp_true_shape``: the angle between the true head pose and solvePnP's pose of the *true* head's
  embedded points (the fixed ones: iBUG 17-67, MediaPipe's non-outline points) to the source's points,
  i.e. the pose error a fit that knew the shape exactly would make from these points;
* ``fit``: the landmark fit's pose error (:func:`pipeline.evaluation.photos.pose_error_angles`, the
  face regions' rotation in the camera frame), and its face-region s2m median (mm).

A photo a detector misses is listed and left out of that detector's rows.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import finish, load_models

from landmarks.detect import detect_landmarks
from landmarks.detector import NoFaceError
from landmarks.ibug68.positions import landmark_positions
from landmarks.layout import ibug68_layout
from landmarks.mediapipe.layout import mediapipe_layout
from pipeline.camera import solve_pose
from pipeline.evaluation.photos import face_error, pose_error_angles
from pipeline.evaluation.scans import scan_seed
from pipeline.fitting.state import head_vertices
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.landmark_fit import fit_landmarks
from pipeline.synthetic.photos.simulate import synthetic_photo, true_layout_points

SOURCES = ("true68", "true478", "dlib", "mediapipe")


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a @ b.T) - 1.0) / 2.0, -1.0, 1.0))))


def dense_points(photo, layout, faces: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The photo's MediaPipe-layout points (:func:`~pipeline.synthetic.photos.simulate.true_layout_points`) + 1 px
    noise."""
    return true_layout_points(photo, layout, faces) + rng.normal(0.0, 1.0, (layout.count, 2))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--neutral", type=int, default=6)
    parser.add_argument("--expressive", type=int, default=6)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    t_start = time.perf_counter()
    rig, neural = load_models()
    asset = rig.asset
    layouts = {"ibug68": ibug68_layout(asset), "mediapipe": mediapipe_layout(asset)}
    fixed = {name: np.setdiff1d(np.arange(lay.count), lay.pose_exclude) for name, lay in layouts.items()}
    config = FitPhotoConfig().landmarks
    records, missed = [], {s: [] for s in SOURCES}
    for kind, count in (("neutral", args.neutral), ("expressive", args.expressive)):
        for index in range(args.first, args.first + count):
            photo = synthetic_photo(
                index, expressive=kind == "expressive", seed=scan_seed(args.seed, "photo-" + kind, index)
            )
            rng = np.random.default_rng([args.seed, index, kind == "expressive"])
            points = {
                "true68": (photo.landmarks2d, "ibug68"),
                "true478": (dense_points(photo, layouts["mediapipe"], asset.faces, rng), "mediapipe"),
            }
            for source, detector in (("dlib", "dlib"), ("mediapipe", "mediapipe")):
                try:
                    face = detect_landmarks(photo.image, detector=detector)
                except NoFaceError:
                    missed[source].append(photo.name)
                    continue
                points[source] = (face.landmarks, "ibug68") if face.dense is None else (face.dense[:, :2], "mediapipe")
            for source, (lm, name) in points.items():
                layout = layouts[name]
                truth3 = landmark_positions(photo.gt_vertices, layout.embedding, asset.faces)[0]
                rot, _ = solve_pose(
                    lm[fixed[name]], truth3[fixed[name]], photo.width, photo.height, photo.focal, exclude=()
                )
                t0 = time.perf_counter()
                fit = fit_landmarks(
                    lm,
                    photo.width,
                    photo.height,
                    focal=photo.focal,
                    config=config,
                    rig=rig,
                    neural=neural,
                    layout=layout,
                )
                seconds = time.perf_counter() - t0
                vertices = head_vertices(rig, neural, fit.theta, fit.z, fit.expressions)
                pose = pose_error_angles(
                    vertices, fit.rotation, fit.translation, photo.gt_vertices, photo.rotation, photo.translation, asset
                )
                record = {
                    "name": photo.name,
                    "kind": kind,
                    "source": source,
                    "pnp_true_shape_deg": _angle(rot, photo.rotation),
                    "fit_pose_deg": pose[0],
                    "fit_yaw_pitch_roll_deg": list(pose[1:]),
                    "s2m_median_mm": face_error(vertices, photo.gt_vertices, asset)["s2m_median_mm"],
                    "seconds": seconds,
                }
                records.append(record)
                print(
                    f"{photo.name:22s} {source:10s} PnP with the true shape {record['pnp_true_shape_deg']:5.2f} deg | "
                    f"fit {record['fit_pose_deg']:5.2f} deg, s2m median {record['s2m_median_mm']:.3f} mm",
                    flush=True,
                )
    summary = {}
    print("\nsource      photos  PnP true shape deg (mean / max)  fit pose deg (mean / max)  s2m median mm (median)")
    for source in SOURCES:
        rows = [r for r in records if r["source"] == source]
        if not rows:
            continue
        pnp = np.array([r["pnp_true_shape_deg"] for r in rows])
        pose = np.array([r["fit_pose_deg"] for r in rows])
        s2m = np.array([r["s2m_median_mm"] for r in rows])
        summary[source] = {
            "photos": len(rows),
            "missed": missed[source],
            "pnp_true_shape_mean_deg": float(pnp.mean()),
            "pnp_true_shape_max_deg": float(pnp.max()),
            "fit_pose_mean_deg": float(pose.mean()),
            "fit_pose_max_deg": float(pose.max()),
            "s2m_median_mm": float(np.median(s2m)),
        }
        print(
            f"{source:10s} {len(rows):6d}  {pnp.mean():14.2f} / {pnp.max():5.2f}  {pose.mean():16.2f} / "
            f"{pose.max():5.2f}  {np.median(s2m):14.3f}   missed: {missed[source] or 'none'}"
        )
    settings = {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}
    print(f"wall time {time.perf_counter() - t_start:.0f} s")
    finish({"records": records, "summary": summary, "settings": settings}, args.json)


if __name__ == "__main__":
    main()
