"""``jnr track`` on synthetic clips with known truth (issue 28's validation): a held-out head of the synthetic
population wearing the rig's ARKit shapes on known curves (blinks, smiles, speech-like jaw motion, a still
segment) and turning (to +-35 degrees, nods), rendered at 640 x 480 (:mod:`pipeline.synthetic.clips`), tracked
from its frames (MediaPipe's points, as the command does), against the same frames fitted one by one as photos
(``fit_photo`` on the same dense points: every frame alone, the identity too).

    .venv/bin/python benchmarks/bench_track.py [--seconds 10] [--clips 1] [--cache DIR] [--json FILE]

Per clip: ARKit coefficient mean absolute error (all frames), head-pose error (degrees, the angle between the
fitted and the true head rotation, after the clip's median offset between the fitted identity's frame and the
true head's is taken out), face-region vertex error (mm, per frame after a rigid alignment of the fitted face to
the true one), jitter (RMS of the second difference of the fitted face's vertices in the camera frame on the still
segment, mm per frame^2), and frames per second per phase. The photo baseline fits every ``--photo-step``-th
frame for the errors and all frames of the still segment for the jitter. Goals: jitter <= 1/3 of the
independent fits', coefficient error no worse, pose <= 3 degrees, >= 10 frames/s (follow + fit) on 2 cores.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import finish  # noqa: E402

from pipeline.track.smooth import SmoothSettings  # noqa: E402
from pipeline.track.solver import TrackSettings  # noqa: E402
from pipeline.track.tracker import TrackConfig, track_clip  # noqa: E402


def face_ids(asset) -> np.ndarray:
    from rig.template import FACE_REGIONS

    ids = [asset.region_names.index(r) for r in FACE_REGIONS]
    return np.flatnonzero(np.isin(asset.regions, ids))


def camera_vertices(head: np.ndarray, coefficients: np.ndarray, rotations, translations, expression) -> np.ndarray:
    from pipeline.camera import RIG_TO_OPENCV
    from pipeline.synthetic.clips import expressive_vertices

    v = expressive_vertices(head, coefficients, expression)
    rot = np.einsum("ij,fjk->fik", RIG_TO_OPENCV, rotations)
    return np.einsum("fvk,fik->fvi", v, rot) + translations[:, None, :]


def coef_err_by_name(fitted: np.ndarray, true: np.ndarray) -> np.ndarray:
    """``(52,)`` mean absolute error of each coefficient over the frames."""
    return np.abs(np.clip(fitted, 0, 1) - true).mean(0)


def rigid_error(a: np.ndarray, b: np.ndarray) -> float:
    """Mean distance of ``a (N, 3)`` to ``b`` after the best rotation + translation of ``a``."""
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(u @ vt))
    r = (u @ np.diag([1, 1, d]) @ vt).T
    return float(np.linalg.norm((a - ca) @ r.T + cb - b, axis=1).mean())


def jitter(vertices: np.ndarray) -> float:
    """RMS of the second difference over frames of ``(F, N, 3)``, mm/frame^2."""
    second = vertices[2:] - 2 * vertices[1:-1] + vertices[:-2]
    return float(np.sqrt((second**2).sum(-1).mean()))


def pose_errors(fitted: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Degrees between fitted and true rotations after the median offset (the identities' frames differ)."""
    from scipy.spatial.transform import Rotation

    offsets = Rotation.from_matrix(np.einsum("fij,fkj->fik", true, fitted))  # true @ fitted^T
    median = Rotation.from_rotvec(np.median(offsets.as_rotvec(), axis=0))
    corrected = median * Rotation.from_matrix(fitted)
    return np.degrees((corrected * Rotation.from_matrix(true).inv()).magnitude())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--clips", type=int, default=1)
    parser.add_argument("--spp", type=int, default=8)
    parser.add_argument("--photo-step", type=int, default=10)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/jnr-bench-track"))
    parser.add_argument("--first", type=int, default=0, help="the first clip's number (clip 0 chose the settings)")
    parser.add_argument("--keyframes", type=int, default=TrackConfig.keyframes)
    parser.add_argument("--smooth", type=float, nargs=3, metavar=("COEF", "ROT_DEG", "TRANS_MM"))
    parser.add_argument("--lambda-expressions", type=float)
    parser.add_argument("--lambda-sparse", type=float)
    parser.add_argument(
        "--frame",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="any track.frame setting (TrackSettings' field, e.g. lambda_gaze=0.1); repeatable",
    )
    parser.add_argument("--keyframe-choice", default=TrackConfig.keyframe_choice, choices=("poses", "time"))
    parser.add_argument("--no-baseline", action="store_true", help="only jnr track (for choosing settings)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    frame_overrides = {}
    for item in args.frame:
        name, _, value = item.partition("=")
        if not hasattr(TrackSettings(), name) or not value:
            parser.error(f"--frame {item!r}: expected NAME=VALUE with NAME a TrackSettings field")
        frame_overrides[name] = type(getattr(TrackSettings(), name))(value)
    torch.set_num_threads(2)

    from landmarks.mediapipe.layout import mediapipe_layout
    from pipeline.photo.fit import FitPhotoConfig, fit_photo
    from pipeline.synthetic.clips import clip_truth, render_clip
    from pipeline.track.preview import posed_camera_vertices
    from pipeline.track.video import open_clip
    from rig.asset import load_asset
    from rig.expressions import EXPRESSION_NAMES, ExpressionModel
    from rig.model import JointRig

    asset = load_asset()
    expression = ExpressionModel(asset, dtype=torch.float64)
    faces_region = face_ids(asset)
    rows = []
    for k in range(args.first, args.first + args.clips):
        folder = args.cache / f"clip_{k}_{args.seconds:g}s_{args.fps:g}fps"
        truth = clip_truth(args.seconds, args.fps, seed=k)
        if not (folder / "truth.npz").is_file():
            t0 = time.perf_counter()
            render_clip(folder, truth, head_index=k, seed=100 + k, spp=args.spp)
            print(f"rendered clip {k}: {truth.frames} frames in {time.perf_counter() - t0:.0f} s")
        data = dict(np.load(folder / "truth.npz"))
        clip = open_clip(folder, fps=args.fps)
        frame = TrackSettings()
        if args.lambda_expressions is not None:
            frame = TrackSettings(lambda_expressions=args.lambda_expressions)
        if args.lambda_sparse is not None:
            frame = TrackSettings(lambda_expressions=frame.lambda_expressions, lambda_sparse=args.lambda_sparse)
        frame = dataclasses.replace(frame, **frame_overrides)
        smooth = SmoothSettings(*args.smooth) if args.smooth else SmoothSettings()
        config = TrackConfig(
            focal=float(data["focal"]),
            keyframes=args.keyframes,
            keyframe_choice=args.keyframe_choice,
            frame=frame,
            smooth=smooth,
        )
        result = track_clip(clip, config)
        still = slice(*[int(x) for x in data["still"]])
        true_cam = camera_vertices(
            data["head"], data["coefficients"], data["rotations"], data["translations"], expression
        )
        fitted_cam = posed_camera_vertices(result, np.arange(result.frames))
        face_err = np.array([rigid_error(f[faces_region], t[faces_region]) for f, t in zip(fitted_cam, true_cam)])
        coef_err = np.abs(np.clip(result.coefficients, 0, 1) - data["coefficients"]).mean(1)
        active = data["coefficients"].max(0) > 0.1  # the coefficients the clip moves
        gaze = np.array([n.startswith("eyeLook") for n in EXPRESSION_NAMES])
        pose_err = pose_errors(result.rotations, data["rotations"])
        track_row = {
            "clip": k,
            "method": "jnr track",
            "frames": result.frames,
            "lost": len(result.lost),
            "coef_mae": float(coef_err.mean()),
            "coef_mae_active": float(coef_err_by_name(result.coefficients, data["coefficients"])[active].mean()),
            "coef_mae_active_no_gaze": float(
                coef_err_by_name(result.coefficients, data["coefficients"])[active & ~gaze].mean()
            ),
            "pose_deg_mean": float(pose_err.mean()),
            "pose_deg_p95": float(np.percentile(pose_err, 95)),
            "face_mm": float(face_err.mean()),
            "jitter_mm_f2": jitter(fitted_cam[still][:, faces_region]),
            "true_jitter_mm_f2": jitter(true_cam[still][:, faces_region]),
            "fps_follow": result.frames / result.seconds["follow"],
            "fps_fit": result.frames / result.seconds["fit"],
            "fps_follow_fit": result.frames / (result.seconds["follow"] + result.seconds["fit"]),
            "identity_s": result.seconds["identity"],
        }
        worst = np.argsort(-coef_err_by_name(result.coefficients, data["coefficients"]))[:6]
        track_row["worst"] = {
            EXPRESSION_NAMES[i]: round(float(coef_err_by_name(result.coefficients, data["coefficients"])[i]), 3)
            for i in worst
        }
        rows.append(track_row)
        print(track_row)
        if args.no_baseline:
            continue

        # the baseline: frames fitted alone as photos, on the same dense points
        rig = JointRig()
        layout = mediapipe_layout(asset)
        photo_frames = sorted(set(range(still.start, still.stop)) | set(range(0, result.frames, args.photo_step)))
        photo_cam, photo_coef, photo_rot, seconds = {}, {}, {}, []
        frames = dict(clip.frames())
        for i in photo_frames:
            if not result.observed[i]:
                continue
            t0 = time.perf_counter()
            points = result.landmarks[i].astype(np.float64)
            from landmarks.mediapipe.ibug68_map import mesh_to_ibug68

            fit = fit_photo(
                frames[i],
                mesh_to_ibug68(points),
                focal=float(data["focal"]),
                rig=rig,
                dense=(points, layout),
                config=FitPhotoConfig(),
            )
            seconds.append(time.perf_counter() - t0)
            from pipeline.camera import RIG_TO_OPENCV

            v = fit.rig_vertices
            photo_cam[i] = v @ (RIG_TO_OPENCV @ fit.rotation).T + fit.translation
            photo_coef[i] = fit.expressions
            photo_rot[i] = fit.rotation
        idx = [i for i in photo_frames if i in photo_cam]
        still_idx = [i for i in range(still.start, still.stop) if i in photo_cam]
        err_idx = [i for i in idx if i % args.photo_step == 0]
        photo_face = [rigid_error(photo_cam[i][faces_region], true_cam[i][faces_region]) for i in err_idx]
        photo_pose = pose_errors(np.stack([photo_rot[i] for i in err_idx]), data["rotations"][err_idx])
        photo_row = {
            "clip": k,
            "method": "fit_photo per frame",
            "frames": len(idx),
            "coef_mae": float(np.mean([np.abs(photo_coef[i] - data["coefficients"][i]).mean() for i in err_idx])),
            "coef_mae_active": float(
                coef_err_by_name(np.stack([photo_coef[i] for i in err_idx]), data["coefficients"][err_idx])[
                    active
                ].mean()
            ),
            "coef_mae_active_no_gaze": float(
                coef_err_by_name(np.stack([photo_coef[i] for i in err_idx]), data["coefficients"][err_idx])[
                    active & ~gaze
                ].mean()
            ),
            "track_coef_mae_active_same_frames": float(
                coef_err_by_name(result.coefficients[err_idx], data["coefficients"][err_idx])[active].mean()
            ),
            "pose_deg_mean": float(photo_pose.mean()),
            "pose_deg_p95": float(np.percentile(photo_pose, 95)),
            "face_mm": float(np.mean(photo_face)),
            "jitter_mm_f2": jitter(np.stack([photo_cam[i][faces_region] for i in still_idx])),
            "fps_fit": 1.0 / float(np.mean(seconds)),
            "track_coef_mae_same_frames": float(coef_err[err_idx].mean()),
            "worst": {
                EXPRESSION_NAMES[i]: round(float(e), 3)
                for e, i in sorted(
                    zip(
                        coef_err_by_name(np.stack([photo_coef[i] for i in err_idx]), data["coefficients"][err_idx]),
                        range(52),
                    ),
                    reverse=True,
                )[:6]
            },
            "track_face_mm_same_frames": float(face_err[err_idx].mean()),
        }
        rows.append(photo_row)
        print(photo_row)

    print()
    print(
        "| clip | method | coef MAE (all / moved / moved but gaze) | pose ° mean / p95 | face mm "
        "| jitter mm/f² (still) | frames/s |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        fps = r.get("fps_follow_fit", r.get("fps_fit"))
        print(
            f"| {r['clip']} | {r['method']} | {r['coef_mae']:.3f} / {r['coef_mae_active']:.3f} / "
            f"{r['coef_mae_active_no_gaze']:.3f} | "
            f"{r['pose_deg_mean']:.2f} / {r['pose_deg_p95']:.2f} "
            f"| {r['face_mm']:.2f} | {r['jitter_mm_f2']:.4f} | {fps:.1f} |"
        )
    finish({"rows": rows}, args.json)


if __name__ == "__main__":
    main()
