"""Multi-view uncalibrated reconstruction on synthetic views with known truth (issue 15, ASM 4.2 / Table 6).

    .venv/bin/python benchmarks/bench_multiview.py [--heads 5] [--first 20] [--photometric] [--asm]
                                                   [--landmarks ibug68|mediapipe|detected] [--set KEY=VALUE ...]
                                                   [--json benchmarks/results/multiview_bench.json] [--figure FILE.png]
    .venv/bin/python benchmarks/bench_multiview.py --merge RUN1.json RUN2.json
                                                   --json benchmarks/results/multiview_bench.json

Per held-out head ``first..first+heads-1``: 10 views (:func:`pipeline.synthetic.multiview.synthetic_views`:
the same head and albedo, yaw within ±60°, pitch ±10°, roll ±5°, focal 1.2-1.7 x 384 px per view, small
MakeHuman expressions per view, the projected true landmarks + 1 px noise; path-traced at 16 samples per
pixel when ``--photometric`` needs the images). The fits are uncalibrated: every view starts from the
default focal (1.4 x 384 px). Scored: the NoW-style face-region scan-to-mesh median
(:func:`pipeline.evaluation.photos.face_error`: similarity alignment on the inner landmarks, ICP, face
regions) of the fitted identity without expression against the true head without expression.

Rows: 1 view (the best of the 10 single-view fits, an oracle pick; their mean; the most frontal view's, the one a
user would pick), 3, 5, 10 views (the first k of the 10), and every view found against the best single view on the
same heads (with ``--landmarks detected`` a view count's row leaves out the heads where MediaPipe found fewer
views). Columns: ``jnr`` (the landmark refinement, :func:`pipeline.photo.multiview.fit_multiview`), ``jnr +
photometric`` (with the photometric consistency, ``--photometric``), ``asm`` (``--asm``; its 1-view row is the ASM
pipeline on the view that was best for jnr).
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

from bench_pose_detectors import dense_points
from common import finish, load_models

from landmarks.mediapipe.layout import mediapipe_layout
from pipeline.config import ConfigError, load_config, parse_overrides
from pipeline.evaluation.photos import face_error
from pipeline.fitting.state import head_vertices
from pipeline.photo.multiview import MultiViewConfig, fit_multiview
from pipeline.photo.multiview_config import INDEPENDENT_VIEWS
from pipeline.synthetic.multiview import MultiViewSettings, synthetic_views
from pipeline.synthetic.photos.settings import PhotoSettings

VIEW_COUNTS = (3, 5, 10)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--heads", type=int, default=5)
    parser.add_argument("--first", type=int, default=20)
    parser.add_argument("--views", type=int, nargs="+", default=list(VIEW_COUNTS))
    parser.add_argument("--photometric", action="store_true", help="also the fits with photometric consistency")
    parser.add_argument("--asm", action="store_true", help="also the ASM identity model")
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--asm-register-iterations", type=int, default=100)
    parser.add_argument("--asm-iterations", type=int, default=60)
    parser.add_argument(
        "--landmarks",
        choices=("ibug68", "mediapipe", "detected"),
        default="ibug68",
        help="the views' true landmarks + 1 px: iBUG's 68 (default) or MediaPipe's 478 (the dense layout, its "
        "outline picked on each view's silhouette, fitted with their true error: dense_noise_px 1); or 'detected': "
        "MediaPipe's own 478 points on the rendered views (views where it finds no face are left out)",
    )
    parser.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="a multi-view setting (MultiViewConfig, as jnr fit --views --set), after the --landmarks defaults; "
        "e.g. --set view_correlation=0 --set view_yaw_deg=0 (the views' terms summed, as before issue 37)",
    )
    parser.add_argument("--json", type=Path)
    parser.add_argument("--figure", type=Path, help="grey renders (front, side) of the first head's fits")
    parser.add_argument("--merge", type=Path, nargs="+", help="only merge the records of these runs' JSON files")
    args = parser.parse_args()
    if args.merge:
        merge(args.merge, args.json)
        return
    rig, neural = load_models()
    settings = MultiViewSettings(photo=PhotoSettings(spp=args.spp))
    overrides: dict = {}
    if args.landmarks != "detected":  # the true points + 1 px: their own error, independent between views
        overrides.update(INDEPENDENT_VIEWS)
    if args.landmarks == "mediapipe":
        overrides["landmarks.dense_noise_px"] = 1.0
    overrides.update(parse_overrides(args.set))
    try:
        base = load_config(MultiViewConfig, None, overrides)
    except ConfigError as exc:
        parser.error(str(exc))
    methods = {"jnr": base}
    if args.photometric:
        methods["jnr + photometric"] = replace(base, photometric=replace(base.photometric, enabled=True))
    if args.asm:
        methods["asm"] = replace(
            base,
            skinning="asm",
            asm=replace(base.asm, register_iterations=args.asm_register_iterations, iterations=args.asm_iterations),
        )
    most = max(args.views)
    records = []
    for head in range(args.first, args.first + args.heads):
        t0 = time.perf_counter()
        views = synthetic_views(head, most, settings=settings, render=args.photometric or args.landmarks == "detected")
        truth = views.neutral_vertices
        lms, layouts, points3d = [p.landmarks2d for p in views.photos], None, None
        if args.landmarks == "detected":
            layout = mediapipe_layout(rig.asset)
            found = [(p, _detected(p.image)) for p in views.photos]
            views = replace(views, photos=tuple(p for p, d in found if d is not None))
            lms = [d[:, :2] for _, d in found if d is not None]
            points3d = [d for _, d in found if d is not None]  # with MediaPipe's depth: the identity regressor's
            layouts = [layout] * len(lms)
            print(f"  head {head}: MediaPipe found {len(lms)} of {len(found)} views", flush=True)
        elif args.landmarks == "mediapipe":
            layout = mediapipe_layout(rig.asset)
            rng = np.random.default_rng([head, 478])
            lms = [dense_points(p, layout, rig.asset.faces, rng) for p in views.photos]
            layouts = [layout] * len(lms)
        sizes = [(p.width, p.height) for p in views.photos]
        images = [p.image for p in views.photos] if args.photometric else None
        all_fit = fit_multiview(
            lms, sizes, rig=rig, neural=neural, config=base, min_views=1, layouts=layouts, points3d=points3d
        )
        singles = all_fit.single_view_fits
        single_errors = [
            face_error(head_vertices(rig, neural, s.theta, np.zeros(50), np.zeros(52)), truth)["s2m_median_mm"]
            for s in singles
        ]
        best = int(np.argmin(single_errors))
        frontal = int(np.argmin(np.abs(views.yaw_deg)))
        if head == args.first:
            shown = {
                "truth": truth,
                "best single view": head_vertices(rig, neural, singles[best].theta, np.zeros(50), np.zeros(52)),
            }
        records.append(
            {
                "head": head,
                "views": 1,
                "method": "jnr",
                "s2m_median_mm": single_errors[best],
                "mean_single_mm": float(np.mean(single_errors)),
                "best_view": best,
                # the view a user would pick without the truth: the most frontal one (its true yaw)
                "frontal_single_mm": single_errors[frontal],
                "frontal_view": frontal,
                "yaw_deg": views.yaw_deg.tolist(),
            }
        )
        for name, config in methods.items():
            counts = [(n, list(range(n))) for n in args.views if n <= len(lms)]  # detected: the views found
            if name == "jnr" and len(lms) > 1 and len(lms) not in args.views:  # every head has an all-views row
                counts.append((len(lms), list(range(len(lms)))))
            if name != "jnr":
                counts = [(1, [best])] + counts
            for n, index in counts:
                t1 = time.perf_counter()
                fit = (
                    all_fit
                    if (name == "jnr" and n == len(lms))
                    else fit_multiview(
                        [lms[i] for i in index],
                        [sizes[i] for i in index],
                        rig=rig,
                        neural=neural,
                        config=config,
                        images=None if images is None else [images[i] for i in index],
                        min_views=1,
                        single_view_fits=tuple(singles[i] for i in index),
                        layouts=None if layouts is None else [layouts[i] for i in index],
                        points3d=None if points3d is None else [points3d[i] for i in index],
                    )
                )
                err = face_error(fit.identity_vertices, truth)
                if head == args.first and n > 1 and n in (min(args.views), most):
                    shown[f"{name}, {n} views"] = fit.identity_vertices
                records.append(
                    {
                        "head": head,
                        "views": n,
                        "all_views": n == len(lms),
                        "method": name,
                        "s2m_median_mm": err["s2m_median_mm"],
                        "vertex_mean_mm": err["vertex_mean_mm"],
                        "landmarks_px": fit.mean_error_px,
                        "seconds": time.perf_counter() - t1,
                    }
                )
                print(
                    f"head {head} {name:18s} {n:2d} views: {err['s2m_median_mm']:.3f} mm "
                    f"({time.perf_counter() - t1:.1f} s)",
                    flush=True,
                )
        print(
            f"head {head}: best single {single_errors[best]:.3f}, mean single {np.mean(single_errors):.3f} "
            f"({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )

    if args.figure:
        figure(shown, args.figure)
    payload = summarise(records, list(methods), [1, *args.views])
    print(payload["markdown"])
    finish(
        {
            **payload,
            "records": records,
            "settings": {
                "heads": list(range(args.first, args.first + args.heads)),
                "spp": args.spp,
                "photometric": args.photometric,
                "asm": args.asm,
                "asm_register_iterations": args.asm_register_iterations,
                "asm_iterations": args.asm_iterations,
                "views": settings.__dict__ | {"photo": settings.photo.__dict__},
            },
        },
        args.json,
    )


def _detected(image):
    """MediaPipe's 478 points ``(478, 3)`` on one view (pixels and its relative depth), or None when it finds no
    face."""
    from landmarks.detect import detect_landmarks
    from landmarks.detector import NoFaceError

    try:
        return np.asarray(detect_landmarks(image, detector="mediapipe").dense, np.float64)
    except NoFaceError:
        return None


def summarise(records: list[dict], names: list[str], counts: list[int]) -> dict:
    """The table (mean ± sample std over heads of the s2m median, per view count and method)."""
    rows = []
    for n in counts:
        row = {"views": n}
        for name in names:
            values = [r["s2m_median_mm"] for r in records if r["views"] == n and r["method"] == name]
            row[name] = (
                (
                    float(np.mean(values)),
                    float(np.std(values, ddof=1)) if len(values) > 1 else float("nan"),
                    len(values),
                )
                if values
                else None
            )
        rows.append(row)
    mean_single = float(np.mean([r["mean_single_mm"] for r in records if "mean_single_mm" in r]))
    lines = ["| views | " + " | ".join(f"{n} s2m median mm" for n in names) + " |", "|" + "---|" * (len(names) + 1)]
    for row in rows:
        label = "1 (best single view)" if row["views"] == 1 else str(row["views"])
        cells = [f"{row[n][0]:.3f} ± {row[n][1]:.3f}" if row[n] else "—" for n in names]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append(f"| 1 (mean single view) | {mean_single:.3f} |" + " |" * (len(names) - 1))
    frontal = [r["frontal_single_mm"] for r in records if "frontal_single_mm" in r]
    if frontal:  # (runs before issue 37's view weights did not record it)
        lines.append(f"| 1 (the most frontal view) | {np.mean(frontal):.3f} |" + " |" * (len(names) - 1))
    # every view found against the best single view on the same heads (a view count's row leaves out the heads
    # where the detector found fewer views)
    best = {r["head"]: r["s2m_median_mm"] for r in records if r["views"] == 1 and "best_view" in r}
    all_views = {}
    for name in names:
        found = [
            r for r in records if r.get("all_views") and r["method"] == name and r["views"] > 1 and r["head"] in best
        ]
        if found:
            fit = np.array([r["s2m_median_mm"] for r in found])
            single = np.array([best[r["head"]] for r in found])
            views = [r["views"] for r in found]
            all_views[name] = {
                "heads": len(found),
                "mean_views": float(np.mean(views)),
                "s2m_median_mm": float(fit.mean()),
                "best_single_mm": float(single.mean()),
                "better_heads": int((fit < single).sum()),
            }
            pad = " |" * (len(names) - 1)
            lines.append(
                f"| all views found ({np.mean(views):.1f} on average), {name}: {fit.mean():.3f} against the best "
                f"single view's {single.mean():.3f} on the same {len(found)} heads, better on {(fit < single).sum()} |"
                f"{pad}"
            )
    heads = sorted({r["head"] for r in records})
    per_head = [
        "| head | model | " + " | ".join(f"{n} view{'s' if n > 1 else ''}" for n in counts) + " |",
        "|" + "---|" * (len(counts) + 2),
    ]
    for head in heads:
        for name in names:
            cells = []
            for n in counts:
                value = [r["s2m_median_mm"] for r in records if (r["head"], r["method"], r["views"]) == (head, name, n)]
                cells.append(f"{value[0]:.3f}" if value else "—")
            per_head.append(f"| {head} | {name} | " + " | ".join(cells) + " |")
    return {
        "table": rows,
        "mean_single_view_mm": mean_single,
        "frontal_single_view_mm": float(np.mean(frontal)) if frontal else None,
        "all_views": all_views,
        "markdown": "\n".join(lines),
        "per_head_markdown": "\n".join(per_head),
    }


def merge(paths: list[Path], json_path: Path | None) -> None:
    """One table from the records of several runs (e.g. heads 20-22 and 23-25 run separately)."""
    import json

    runs = [json.loads(Path(p).read_text()) for p in paths]
    records = [r for run in runs for r in run["records"]]
    names = list(dict.fromkeys(r["method"] for r in records))
    counts = sorted({r["views"] for r in records})
    payload = summarise(records, names, counts)
    print(payload["markdown"] + "\n\n" + payload["per_head_markdown"])
    finish(
        {
            **payload,
            "records": records,
            "runs": [{"command": run.get("command"), "settings": run.get("settings")} for run in runs],
        },
        json_path,
    )


def figure(meshes: dict, path: Path) -> None:
    """One column per mesh (front above, side below), grey, with its label."""
    import cv2

    from render.preview import render_preview, save_png
    from rig.asset import load_asset

    asset = load_asset()
    faces = asset.faces[~asset.region_mask("mouth_interior", "eye_pockets", "teeth", "tongue")[asset.faces].all(1)]
    kw = dict(size=(260, 320), spp=32, distance=620.0, target=(0.0, -25.0, 15.0))
    columns = []
    for label, v in meshes.items():
        tiles = [render_preview(np.asarray(v), faces, view=view, **kw) for view in ("front", "side")]
        column = np.ascontiguousarray(np.concatenate(tiles, 0))
        cv2.putText(column, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (20, 20, 20), 1, cv2.LINE_AA)
        columns.append(column)
    save_png(np.concatenate(columns, 1), path)


if __name__ == "__main__":
    main()
