"""Where the photo fit loses the shape, per photo (issue 37): its error split into focal, pose, expression
leakage and identity, for the detector's own points and for the true points.

    .venv/bin/python benchmarks/diagnose_photo_fit.py [--first 20] [--heads 10] [--seed 0]
        [--sources true478,mediapipe] [--conditions default,true_focal,true_pose,no_expressions[,photometric]]
        [--set landmarks.prior.lambda_identity=0.1 ...] [--cache DIR] [--json FILE]

Photos: held-out heads ``first .. first + heads - 1`` (the fit's settings are chosen on heads 0-9, never on
these), each neutral and with one of ICT's expressions (outside the rig's ARKit span), rendered as in the photo
benchmark (path tracing, random skin, light, background, yaw +-30 deg) with the **focal length cycling over
1.0, 1.4, 2.0 and 3.0 x the image side** (the camera's distance scaled with it, so the face fills the frame
alike): portrait lenses are longer than the fit's default 1.4 x.

Sources: ``true478`` (the true head's MediaPipe-layout points projected, the outline on the silhouette, + 1 px
noise, fitted with ``dense_noise_px`` 1, their true error), ``mediapipe`` (MediaPipe's own 478 points detected on
the render), ``true68`` (iBUG-68 + 1 px), ``capacity`` (no points and no conditions: the rig's best fit of the
true head, its vertices known, :func:`rig.skinning.joint_fit.fit_joints` of the joint channels with the latent
at the prior's mean and no expression coefficients: the floor a fit from the photo can reach; its identity
error is the same fit of the true neutral head).

Conditions, each adding one piece of truth to the one before:

* ``default``: what ``jnr fit`` does (the default focal, solvePnP's pose, pose + joints + expressions fitted);
* ``true_focal``: the photo's true focal length;
* ``true_pose``: and the true head pose, held (stages without ``pose``);
* ``no_expressions``: and no expression coefficients (for the neutral photos that is the truth; for the
  expressive ones it shows what the expressions buy);
* ``photometric`` (not in the default list): ``default`` followed by the photometric stages (``jnr fit
  --photometric``, i.e. :func:`pipeline.photo.fit.fit_photo` with ``photometric.enabled``): what the pixels add.

Per fit: the face-region s2m median against the head as photographed (NoW-style, :func:`pipeline.evaluation.
photos.face_error`), the **identity error** (the fitted head with its expression coefficients set to 0 against
the true *neutral* head: what the fit learned of the person), the pose error (deg), each against the unfitted
template's. The differences between consecutive conditions are the error the focal, the pose and the
expressions cost; the expressive photos' identity error against the neutral photos' is the expression leakage.
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import finish, load_models  # noqa: E402

from landmarks.detect import detect_landmarks  # noqa: E402
from landmarks.detector import NoFaceError  # noqa: E402
from landmarks.mediapipe.layout import mediapipe_layout  # noqa: E402
from pipeline.camera import default_focal  # noqa: E402
from pipeline.config import load_config, parse_overrides  # noqa: E402
from pipeline.evaluation.photos import face_error, pose_error_deg  # noqa: E402
from pipeline.evaluation.scans import scan_seed  # noqa: E402
from pipeline.fitting.engine import Stage  # noqa: E402
from pipeline.fitting.state import head_vertices  # noqa: E402
from pipeline.photo.fit import fit_photo  # noqa: E402
from pipeline.photo.fit_config import FitPhotoConfig  # noqa: E402
from pipeline.photo.landmark_fit import fit_landmarks  # noqa: E402
from pipeline.synthetic.photos.settings import focal_settings  # noqa: E402
from pipeline.synthetic.photos.simulate import synthetic_photo, true_layout_points  # noqa: E402
from pipeline.synthetic.population import population_split  # noqa: E402
from rig.asset import load_asset  # noqa: E402
from rig.expressions import EXPRESSION_NAMES  # noqa: E402
from rig.parameters import NUM_PARAMETERS  # noqa: E402
from rig.skinning.neural import LATENT  # noqa: E402

FOCAL_FACTORS = (1.0, 1.4, 2.0, 3.0)
"""The photos' focal lengths over the image side, cycled over the heads (the default's 1.4 among them)."""
SOURCES = ("true478", "mediapipe", "true68", "capacity")
CAPACITY_ITERATIONS = 500
"""Adam steps of the ``capacity`` source's :func:`~rig.skinning.joint_fit.fit_joints` (from the rest pose)."""
CONDITIONS = ("default", "true_focal", "true_pose", "no_expressions", "photometric")


@dataclass
class Photo:
    """One rendered photo with its truth and its points per source (None: the detector found no face)."""

    name: str
    kind: str
    focal_factor: float
    photo: object
    neutral: np.ndarray
    points: dict
    detected68: np.ndarray | None = None
    """MediaPipe's 68 iBUG points (the photometric fit's face crop when its points are MediaPipe's)."""
    points3d: np.ndarray | None = None
    """MediaPipe's 478 points with their depth (``(478, 3)``), what the identity regressor reads
    (``--set landmarks.regression.enabled=true``)."""


def true_dense_points(photo, layout, faces, rng: np.random.Generator) -> np.ndarray:
    """The true head's points of ``layout`` (:func:`~pipeline.synthetic.photos.simulate.true_layout_points`) + 1 px
    Gaussian noise."""
    px = true_layout_points(photo, layout, faces)
    return px + rng.normal(0.0, 1.0, px.shape)


def make_photos(first: int, heads: int, seed: int, sources: tuple[str, ...], asset) -> list[Photo]:
    layout = mediapipe_layout(asset)
    neutral_heads = population_split("heldout", 0, first=first + heads).vertices
    photos = []
    for index in range(first, first + heads):
        factor = FOCAL_FACTORS[index % len(FOCAL_FACTORS)]
        for kind in ("neutral", "expressive"):
            photo = synthetic_photo(
                index,
                expressive=kind == "expressive",
                seed=scan_seed(seed, "diagnose-" + kind, index),
                settings=focal_settings(factor),
            )
            rng = np.random.default_rng(scan_seed(seed, "diagnose-noise-" + kind, index))
            points: dict = {}
            detected68 = points3d = None
            for source in sources:
                if source == "capacity":
                    continue  # needs no points
                if source == "true68":
                    points[source] = (photo.landmarks2d, None)
                elif source == "true478":
                    points[source] = (true_dense_points(photo, layout, asset.faces, rng), layout)
                else:
                    try:
                        face = detect_landmarks(photo.image, detector="mediapipe")
                    except NoFaceError:
                        points[source] = None
                        continue
                    points[source] = (face.dense[:, :2], layout)
                    detected68 = np.asarray(face.landmarks)
                    points3d = np.asarray(face.dense)
            neutral = np.asarray(neutral_heads[index])
            photos.append(Photo(photo.name, kind, factor, photo, neutral, points, detected68, points3d))
            print(f"  rendered {photo.name:20s} focal {factor:.1f} x  yaw {photo.yaw_deg:6.1f}", flush=True)
    return photos


def without(stages: tuple[Stage, ...], group: str) -> tuple[Stage, ...]:
    """The stages with ``group`` held (stages left with nothing free dropped)."""
    out = []
    for st in stages:
        free = tuple(g for g in st.free if g != group)
        if free:
            out.append(replace(st, free=free))
    return tuple(out)


def condition_config(config: FitPhotoConfig, condition: str, source: str):
    lm = config.landmarks
    if source.startswith("true"):  # the true points' own error: 1 px (the priors' reference)
        lm = replace(lm, dense_noise_px=1.0, noise_px=1.0)
    if condition in ("true_pose", "no_expressions"):
        lm = replace(lm, lm_stages=without(lm.lm_stages, "pose"))
    if condition == "no_expressions":
        lm = replace(lm, lm_stages=without(lm.lm_stages, "expressions"))
    return lm


def fit_photometric(photo, landmarks68, target, layout, config: FitPhotoConfig, rig, neural, points3d=None):
    """``default`` + the photometric stages: the landmark fit's fields (theta, z, expressions, rotation,
    translation, error_px) of the whole photo fit; ``landmarks68`` place its face crop (the source's own)."""
    config = replace(config, photometric=replace(config.photometric, enabled=True))
    dense = None if layout is None else (target, layout)
    fit = fit_photo(photo.image, landmarks68, config=config, rig=rig, neural=neural, dense=dense, points3d=points3d)
    return SimpleNamespace(
        theta=fit.theta,
        z=fit.z,
        expressions=fit.expressions,
        rotation=fit.rotation,
        translation=fit.translation,
        error_px=fit.landmark_fit.error_px,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--first", type=int, default=20, help="first held-out head (default 20)")
    parser.add_argument("--heads", type=int, default=10, help="heads, each photographed neutral and expressive")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sources", default="true478,mediapipe", help=f"comma-separated, of {list(SOURCES)}")
    parser.add_argument(
        "--conditions", default=",".join(CONDITIONS[:4]), help=f"comma-separated, of {list(CONDITIONS)}"
    )
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="FitPhotoConfig overrides")
    parser.add_argument(
        "--cache",
        type=Path,
        default=None,
        metavar="DIR",
        help="keep the rendered photos and their detected points in DIR (a pickle per --first/--heads/--seed/"
        "--sources) and reuse them: rendering and detection take ~10 s a photo, a fit 0.2 s",
    )
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    sources = tuple(s for s in args.sources.split(",") if s)
    conditions = tuple(c for c in args.conditions.split(",") if c)
    for s in sources:
        if s not in SOURCES:
            parser.error(f"unknown source {s!r}")
    for c in conditions:
        if c not in CONDITIONS:
            parser.error(f"unknown condition {c!r}")
    config = load_config(FitPhotoConfig, None, parse_overrides(args.set))
    rig, neural = load_models()
    asset = load_asset()
    t0 = time.perf_counter()
    photos = cached_photos(args.cache, args.first, args.heads, args.seed, sources, asset)
    template = head_vertices(rig, neural, np.zeros(NUM_PARAMETERS), np.zeros(LATENT), np.zeros(len(EXPRESSION_NAMES)))
    capacity = capacity_fits(photos, rig) if "capacity" in sources else {}
    records = []
    for ph in photos:
        p = ph.photo
        tmpl = face_error(template, p.gt_vertices, asset)["s2m_median_mm"]
        tmpl_id = face_error(template, ph.neutral, asset)["s2m_median_mm"]
        for source in sources:
            if source == "capacity":
                records.append(capacity_record(ph, capacity[ph.name], tmpl, tmpl_id, rig, neural, asset))
                continue
            if ph.points.get(source) is None:
                print(f"  {ph.name}: {source} found no face", flush=True)
                continue
            target, layout = ph.points[source]
            points3d = ph.points3d if source == "mediapipe" else None
            for condition in conditions:
                focal = default_focal(p.width, p.height) if condition == "default" else p.focal
                pose = (p.rotation, p.translation) if condition in ("true_pose", "no_expressions") else None
                t1 = time.perf_counter()
                if condition == "photometric":
                    lm_config = replace(config, landmarks=condition_config(config, "default", source))
                    own68 = p.landmarks2d if source.startswith("true") else ph.detected68
                    fit = fit_photometric(p, own68, target, layout, lm_config, rig, neural, points3d)
                else:
                    fit = fit_landmarks(
                        target,
                        p.width,
                        p.height,
                        focal=focal,
                        config=condition_config(config, condition, source),
                        rig=rig,
                        neural=neural,
                        layout=layout,
                        pose=pose,
                        points3d=points3d,
                    )
                seconds = time.perf_counter() - t1
                v = head_vertices(rig, neural, fit.theta, fit.z, fit.expressions)
                v_id = head_vertices(rig, neural, fit.theta, fit.z, np.zeros(len(EXPRESSION_NAMES)))
                s2m = face_error(v, p.gt_vertices, asset)["s2m_median_mm"]
                ident = face_error(v_id, ph.neutral, asset)["s2m_median_mm"]
                pose_err = pose_error_deg(
                    v, fit.rotation, fit.translation, p.gt_vertices, p.rotation, p.translation, asset
                )
                record = photo_record(
                    ph, source, condition, (s2m, tmpl), (ident, tmpl_id), pose_err, float(fit.error_px.mean()), seconds
                )
                records.append(record)
                print(
                    f"  {ph.name:20s} f {ph.focal_factor:.1f} {source:9s} {condition:14s} s2m {s2m:5.3f} "
                    f"(template {tmpl:5.3f}, x{s2m / tmpl:5.2f})  identity {ident:5.3f} (x{ident / tmpl_id:5.2f})  "
                    f"pose {pose_err:4.1f} deg  {seconds:4.1f} s",
                    flush=True,
                )
    wall = time.perf_counter() - t0
    summary = summarise(records, sources, conditions)
    print()
    print(table(summary))
    finish(
        {"records": records, "summary": summary, "settings": {**vars(args), "json": str(args.json)}, "wall_s": wall},
        args.json,
    )
    print(f"wall {wall:.0f} s")


def cached_photos(cache: Path | None, first: int, heads: int, seed: int, sources: tuple[str, ...], asset) -> list:
    """:func:`make_photos`, read from (or written to) ``cache`` when given: any cached set of the same photos
    (``first``, ``heads``, ``seed``) whose points include ``sources``' will do."""
    if cache is None:
        return make_photos(first, heads, seed, sources, asset)
    wanted = sorted(s for s in sources if s != "capacity")
    stem = f"photos_first{first}_heads{heads}_seed{seed}_"
    path = cache / f"{stem}{'+'.join(wanted) or 'none'}.pkl"
    for other in sorted(cache.glob(f"{stem}*.pkl")):
        if set(wanted) <= set(other.stem[len(stem) :].split("+")):
            path = other
            break
    layout = mediapipe_layout(asset)  # the layout holds functions: the pickle keeps the points only
    if path.exists():
        print(f"  photos from {path}", flush=True)
        with open(path, "rb") as f:
            stored = pickle.load(f)
        return [
            replace(
                ph,
                points={
                    k: None if v is None else (v, None if k == "true68" else layout)
                    for k, v in ph.points.items()
                    if k in wanted
                },
            )
            for ph in stored
        ]
    photos = make_photos(first, heads, seed, sources, asset)
    cache.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial")
    with open(partial, "wb") as f:
        pickle.dump(
            [replace(ph, points={k: None if v is None else v[0] for k, v in ph.points.items()}) for ph in photos], f
        )
    partial.replace(path)
    return photos


def capacity_fits(photos: list[Photo], rig) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    """The ``capacity`` source's joint channels per photo: the rig's best fit of the true head as photographed and
    of the true neutral head (:data:`CAPACITY_ITERATIONS` steps of :func:`~rig.skinning.joint_fit.fit_joints`, all
    photos in one batch), with each photo's share of the seconds."""
    import torch

    from rig.skinning.joint_fit import fit_joints

    t1 = time.perf_counter()
    targets = np.stack([v for ph in photos for v in (ph.photo.gt_vertices, ph.neutral)])
    theta = fit_joints(rig, torch.as_tensor(targets, dtype=rig.template.dtype), iterations=CAPACITY_ITERATIONS).theta
    theta = theta.double().numpy()
    seconds = (time.perf_counter() - t1) / max(len(photos), 1)
    return {ph.name: (theta[2 * i], theta[2 * i + 1], seconds) for i, ph in enumerate(photos)}


def capacity_record(ph: Photo, fits, tmpl: float, tmpl_id: float, rig, neural, asset) -> dict:
    """The ``capacity`` source's record of one photo (its :func:`capacity_fits`)."""
    theta, theta_neutral, seconds = fits
    none, no_z = np.zeros(len(EXPRESSION_NAMES)), np.zeros(LATENT)
    s2m = face_error(head_vertices(rig, neural, theta, no_z, none), ph.photo.gt_vertices, asset)["s2m_median_mm"]
    ident = face_error(head_vertices(rig, neural, theta_neutral, no_z, none), ph.neutral, asset)["s2m_median_mm"]
    print(
        f"  {ph.name:20s} f {ph.focal_factor:.1f} capacity  rig_best       s2m {s2m:5.3f} (template {tmpl:5.3f}, "
        f"x{s2m / tmpl:5.2f})  identity {ident:5.3f} (x{ident / tmpl_id:5.2f})",
        flush=True,
    )
    return photo_record(ph, "capacity", "rig_best", (s2m, tmpl), (ident, tmpl_id), None, None, seconds)  # no pose


def photo_record(
    ph: Photo, source: str, condition: str, face: tuple, identity: tuple, pose_err, landmark_px, seconds: float
) -> dict:
    """One record of the benchmark's JSON: ``face`` and ``identity`` are ``(fit, template)`` s2m medians (mm); the
    pose (deg) and landmark (px) errors are None where nothing was fitted to points."""
    (s2m, tmpl), (ident, tmpl_id) = face, identity
    return {
        "name": ph.name,
        "kind": ph.kind,
        "focal_factor": ph.focal_factor,
        "yaw_deg": float(ph.photo.yaw_deg),
        "source": source,
        "condition": condition,
        "s2m_median_mm": s2m,
        "template_mm": tmpl,
        "ratio": s2m / tmpl,
        "identity_mm": ident,
        "template_identity_mm": tmpl_id,
        "identity_ratio": ident / tmpl_id,
        "pose_error_deg": pose_err,
        "landmark_error_px": landmark_px,
        "seconds": seconds,
    }


def summarise(records: list[dict], sources, conditions) -> list[dict]:
    """Per source, condition and kind (``neutral``, ``expressive``, ``all``): photos, the median of the per-photo
    s2m ratios to the template, the mean s2m, the median identity ratio, photos worse than the template by more
    than 0.05 mm, the mean pose error."""
    rows = []
    for source in sources:
        for condition in ("rig_best",) if source == "capacity" else conditions:
            for kind in ("neutral", "expressive", "all"):
                rs = [
                    r
                    for r in records
                    if r["source"] == source and r["condition"] == condition and kind in ("all", r["kind"])
                ]
                if not rs:
                    continue
                rows.append(
                    {
                        "source": source,
                        "condition": condition,
                        "kind": kind,
                        "photos": len(rs),
                        "s2m_median_mm": float(np.mean([r["s2m_median_mm"] for r in rs])),
                        "template_mm": float(np.mean([r["template_mm"] for r in rs])),
                        "ratio_median": float(np.median([r["ratio"] for r in rs])),
                        "ratio_of_medians": float(
                            np.median([r["s2m_median_mm"] for r in rs]) / np.median([r["template_mm"] for r in rs])
                        ),
                        "identity_ratio_median": float(np.median([r["identity_ratio"] for r in rs])),
                        "worse_by_0.05": int(sum(r["s2m_median_mm"] > r["template_mm"] + 0.05 for r in rs)),
                        "worse": int(sum(r["s2m_median_mm"] > r["template_mm"] for r in rs)),
                        "pose_error_deg": None
                        if source == "capacity"
                        else float(np.mean([r["pose_error_deg"] for r in rs])),
                        "seconds": float(np.median([r["seconds"] for r in rs])),
                    }
                )
    return rows


def table(rows: list[dict]) -> str:
    lines = [
        "| points | condition | photos | kind | s2m median mm (mean) | template mm | fit / template (median ratio) "
        "| identity / template | worse than template (by > 0.05 mm) | pose error deg |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['source']} | {r['condition']} | {r['photos']} | {r['kind']} | {r['s2m_median_mm']:.3f} | "
            f"{r['template_mm']:.3f} | {r['ratio_median']:.2f} | {r['identity_ratio_median']:.2f} | "
            f"{r['worse']} ({r['worse_by_0.05']}) | "
            + ("-" if r["pose_error_deg"] is None else f"{r['pose_error_deg']:.2f}")
            + " |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
