"""The 68 embedded iBUG landmarks against the detector we use (issue 13).

    .venv/bin/python benchmarks/bench_landmark_offsets.py [--json benchmarks/results/landmark_offsets.json]
    .venv/bin/python benchmarks/bench_landmark_offsets.py --fit [--write]

Views: the neutral template (``rig.asset.load_asset()``) photographed by
:func:`pipeline.synthetic.photos.simulate.simulate_photo` -- path-traced at 384 x 384 px, 32 spp, with a random
skin tone, hair and brow colour (``synthesize_albedo``), point light + environment, background, focal
length (1.2-1.7 x 384 px) and distance (450-650 mm), drawn anew for every view from (seed, pose) --
at every (yaw, pitch) of the grid (default yaw -30..30 step 10, pitch -15, 0, 15, roll 0) for every
seed. dlib finds the 68 landmarks (:func:`landmarks.detect.detect_landmarks` with ``detector="dlib"``, the
detector the offsets are for); a view whose detected box does not contain the face counts as not found. The
embedded landmarks are projected with each photo's own camera: 17-67 from the static embedding, the jaw contour 0-16 as
that camera sees it (:func:`landmarks.ibug68.contour.contour_landmarks`, what the photo fit uses).

Offsets are ``detected - projected`` in image pixels (x right, y down), scaled to an inter-ocular
distance of 100 px: each view's pixels are multiplied by ``100 / (focal * IOD_mm / depth)``, ``IOD_mm``
the template's outer-eye-corner distance (the eyelid loops' lateral corners, measured on the asset:
89.0 mm on the ICT-shaped template) and ``depth``
the camera distance of their midpoint -- the frontal IOD at the face's depth, so turned heads are
not scaled up by their foreshortening. Per landmark: the mean dx, dy over the views where the face
was found, the norm of that mean (``bias``: what the embedding can remove) and the mean of the
per-view norms (``error``: the bias plus the detector's scatter). Regions average those over their
landmarks; ``inner`` is 17-67, ``overall`` all 68.

Two embeddings are scored on the same detections: ``heuristic`` (the geometric placement alone,
``ibug68_embedding(asset, corrected=False)``) and ``corrected`` (the default embedding, with the
committed ``LANDMARK_CORRECTIONS_MM`` and ``CONTOUR_ANGLES_DEG`` of :mod:`landmarks.ibug68.corrections`).

``--fit`` renders the fit views (``--fit-seeds``, default 0-7: other albedo, light, camera and
background draws than the evaluation's ``--seeds``, default 8-15) and prints new tables:

- ``LANDMARK_CORRECTIONS_MM`` (the chin and 17-67, left side and midline; the right side is their
  mirror image): for each landmark, among sample points of the surface the embedding snaps it onto
  (:func:`landmarks.ibug68.domains.snap_domain_points`, within 15 mm of the geometric placement), the one whose
  projections agree best with the detections of all fit views in the least-squares sense (pixels at
  IOD 100; the mirror partner's detections count too, against the mirrored point) -- the detections
  back-projected onto the template and combined over the poses. The row is that point minus the
  placement, mm in template space, rounded to 0.1 mm.
- ``CONTOUR_ANGLES_DEG`` (16..9), only with ``--fit-contour`` (otherwise the committed angles are kept: the
  angles refitted on the ICT-shaped template, 10.5-82.8 degrees, lowered the contour's bias on dlib by only
  0.26 px but made the landmark fit of the rig's own synthetic head unstable, a contour point jumping
  by 58 px, ``tests/pipeline/photo/test_landmark_fit.py``; the committed ones are issue 13's, fitted on
  MakeHuman's template): for each contour landmark (and its mirror partner), the frontal-outline
  vertex whose candidate line makes the dynamic contour agree best with the detections (least
  squares), kept in order along the outline and moving inwards (dynamic programming), as its direction in
  degrees.

``--write`` puts them into ``landmarks/ibug68/corrections.py``; then run without ``--fit`` to score them on the
evaluation views. Renders and detections are cached per grid in ``--cache`` (default the system temp
folder); ``--fresh`` re-renders. ``simulate_photo`` frames the face on the mean of the embedded landmarks;
here it is given the geometric placement for that, so the renders do not depend on the tables and
``--fit`` reproduces the committed tables exactly.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import hashlib
import json
import platform
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from landmarks.detect import detect_landmarks
from landmarks.detector import DetectionError
from landmarks.ibug68.contour import contour_landmarks
from landmarks.ibug68.corrections import CONTOUR_ANGLES_DEG, LANDMARK_CORRECTIONS_MM
from landmarks.ibug68.domains import snap_domain_points
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.names import CHIN, IBUG68_MIRROR, IBUG68_NAMES
from landmarks.ibug68.positions import landmark_positions
from pipeline.camera import RIG_TO_OPENCV, camera_center_in_rig
from pipeline.synthetic.photos import simulate
from pipeline.synthetic.photos.settings import PhotoSettings
from pipeline.synthetic.photos.simulate import simulate_photo
from rig.asset import load_asset

MODULE = Path(__file__).resolve().parents[1] / "landmarks" / "ibug68" / "corrections.py"
IOD_PX = 100.0
REGIONS = {
    "contour": list(range(17)),
    "brows": list(range(17, 27)),
    "nose": list(range(27, 36)),
    "eyes": list(range(36, 48)),
    "lips": list(range(48, 68)),
}
SETTINGS = {"width": 384, "height": 384, "spp": 32, "roll_deg_range": (0.0, 0.0)}
FAILURE_PX = 10.0
"""A detection whose 68 landmarks lie on average more than this (pixels at IOD 100, i.e. a normalised mean
error of 0.1, 300-W's usual failure threshold) from the committed embedding's projection is a *failed*
detection: counted, and left out of the offsets like a missed face (otherwise a few views with dlib's
landmarks off the face, up to 52 px, dominate the means)."""


def _floats(text: str) -> list[float]:
    return [float(t) for t in text.split(",") if t.strip()]


def _ints(text: str) -> list[int]:
    return [int(t) for t in text.split(",") if t.strip()]


def outer_eye_corners(asset) -> np.ndarray:
    """``(2, 3)`` the eyelid loops' lateral corners (the outer eye corners), mm, right then left."""
    v = asset.vertices
    corners = [v[loop[np.argmax(np.abs(v[loop, 0]))]] for loop in asset.eye_loops]
    return np.array(sorted(corners, key=lambda p: p[0]))


# --- renders and detections -----------------------------------------------------------------------------


@contextlib.contextmanager
def framed_on_geometric_placement():
    """``simulate_photo`` centres the face on the mean of the embedded landmarks; inside this block it uses
    the geometric placement (``corrected=False``), so the renders -- and the fit made from them -- do not
    depend on the committed corrections (a refit reproduces the table exactly)."""
    saved = simulate.ibug68_embedding, simulate.contour_landmarks
    simulate.ibug68_embedding = functools.partial(ibug68_embedding, corrected=False)
    simulate.contour_landmarks = functools.partial(contour_landmarks, corrected=False)
    try:
        yield
    finally:
        simulate.ibug68_embedding, simulate.contour_landmarks = saved


def render_and_detect(yaws, pitches, seeds, cache_dir: Path | None, fresh: bool, log=print) -> dict:
    """Photograph the template in every pose of the grid and detect; returns (and caches) per view the
    pose, camera and detection (``found`` False where dlib found no face)."""
    key = json.dumps({"yaw": yaws, "pitch": pitches, "seeds": seeds, "settings": repr(SETTINGS), "v": 3})
    digest = hashlib.sha1(key.encode()).hexdigest()[:12]
    cache = Path(tempfile.gettempdir() if cache_dir is None else cache_dir) / f"jnr_landmark_offsets_{digest}.npz"
    if cache.is_file() and not fresh:
        data = dict(np.load(cache, allow_pickle=False))
        if str(data["key"]) == key:
            log(f"detections from {cache} ({len(data['yaw'])} views)")
            return data
    asset = load_asset()
    settings = PhotoSettings(**SETTINGS)
    rows: dict[str, list] = {
        k: [] for k in ("yaw", "pitch", "seed", "rotation", "translation", "focal", "found", "detected", "box", "score")
    }
    t0 = time.perf_counter()
    for seed in seeds:
        for p, pitch in enumerate(pitches):
            for y, yaw in enumerate(yaws):
                # every view its own albedo, light, camera and background (from the seed and the pose's place)
                rng = np.random.default_rng([int(seed), p, y, 13])
                with framed_on_geometric_placement():
                    photo = simulate_photo(
                        asset.vertices, rng, settings, asset, yaw_deg=yaw, pitch_deg=pitch, roll_deg=0.0
                    )
                try:
                    det = detect_landmarks(photo.image, detector="dlib")
                    found, points, box, score = True, det.landmarks, det.box, det.score
                    cx, cy = photo.landmarks2d_true.mean(0)  # a false positive elsewhere is no detection
                    found = bool(box[0] <= cx <= box[2] and box[1] <= cy <= box[3])
                except DetectionError:
                    found, points, box, score = False, np.full((68, 2), np.nan), np.full(4, np.nan), np.nan
                for k, val in (
                    ("yaw", yaw),
                    ("pitch", pitch),
                    ("seed", seed),
                    ("rotation", photo.rotation),
                    ("translation", photo.translation),
                    ("focal", photo.focal),
                    ("found", found),
                    ("detected", points),
                    ("box", box),
                    ("score", score),
                ):
                    rows[k].append(val)
                log(
                    f"  seed {seed} pitch {pitch:+5.1f} yaw {yaw:+5.1f}: {'found' if found else 'NOT FOUND'}"
                    f"  ({time.perf_counter() - t0:.0f} s)"
                )
    data = {k: np.asarray(v) for k, v in rows.items()}
    data.update(key=np.asarray(key), width=np.asarray(SETTINGS["width"]), height=np.asarray(SETTINGS["height"]))
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, **data)
    return data


def project(points: np.ndarray, rotation, translation, focal, width, height) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 3)`` rig points -> ``(N, 2)`` 0-based OpenCV pixels and ``(N,)`` depths (mm)."""
    cam = points @ (RIG_TO_OPENCV @ rotation).T + translation
    uv = focal * cam[:, :2] / cam[:, 2:3] + np.array([(width - 1) / 2.0, (height - 1) / 2.0])
    return uv, cam[:, 2]


def view_scale(data: dict, i: int, asset) -> float:
    """Pixels -> pixels at IOD 100 for view ``i``."""
    eyes = outer_eye_corners(asset)
    _, depth = project(
        eyes.mean(0, keepdims=True),
        data["rotation"][i],
        data["translation"][i],
        float(data["focal"][i]),
        int(data["width"]),
        int(data["height"]),
    )
    iod_px = float(data["focal"][i]) * float(np.linalg.norm(eyes[1] - eyes[0])) / float(depth[0])
    return IOD_PX / iod_px


def projected(data: dict, i: int, asset, corrected: bool) -> np.ndarray:
    """``(68, 2)`` the embedded landmarks (contour: as the camera sees it) projected into view ``i``."""
    emb = ibug68_embedding(asset, corrected=corrected)
    points = landmark_positions(asset.vertices, emb, asset.faces)[0]
    centre = camera_center_in_rig(data["rotation"][i], data["translation"][i])
    points[:17] = contour_landmarks(
        torch.as_tensor(asset.vertices), asset.faces, centre, asset, corrected=corrected
    ).numpy()
    uv, _ = project(
        points,
        data["rotation"][i],
        data["translation"][i],
        float(data["focal"][i]),
        int(data["width"]),
        int(data["height"]),
    )
    return uv


def offsets(data: dict, asset, corrected: bool) -> np.ndarray:
    """``(N_found, 68, 2)`` detected - projected, pixels at IOD 100."""
    out = []
    for i in np.flatnonzero(data["found"]):
        out.append((data["detected"][i] - projected(data, i, asset, corrected)) * view_scale(data, i, asset))
    return np.asarray(out)


def summarize(off: np.ndarray) -> dict:
    mean = off.mean(0)
    bias = np.linalg.norm(mean, axis=1)
    error = np.linalg.norm(off, axis=2).mean(0)
    per = [
        {
            "index": k,
            "name": IBUG68_NAMES[k],
            "dx": round(float(mean[k, 0]), 2),
            "dy": round(float(mean[k, 1]), 2),
            "bias": round(float(bias[k]), 2),
            "error": round(float(error[k]), 2),
        }
        for k in range(68)
    ]
    regions = {
        name: {"bias": round(float(bias[ids].mean()), 2), "error": round(float(error[ids].mean()), 2)}
        for name, ids in REGIONS.items()
    }
    inner = list(range(17, 68))
    regions["inner"] = {"bias": round(float(bias[inner].mean()), 2), "error": round(float(error[inner].mean()), 2)}
    regions["overall"] = {"bias": round(float(bias.mean()), 2), "error": round(float(error.mean()), 2)}
    return {"landmarks": per, "regions": regions}


# --- the fit ----------------------------------------------------------------------------------------------


def fit_corrections(data: dict, asset, radius_mm: float = 15.0) -> dict[int, tuple[float, float, float]]:
    """The correction table (see the module docstring)."""
    emb = ibug68_embedding(asset, corrected=False)
    heuristic = landmark_positions(asset.vertices, emb, asset.faces)[0]
    found = np.flatnonzero(data["found"])
    views = [
        (
            data["rotation"][i],
            data["translation"][i],
            float(data["focal"][i]),
            int(data["width"]),
            int(data["height"]),
            view_scale(data, i, asset),
            data["detected"][i],
        )
        for i in found
    ]
    table = {}
    for k in [CHIN, *range(17, 68)]:
        j = IBUG68_MIRROR[k]
        if heuristic[k, 0] < -1e-9:  # right side: its left partner's row
            continue
        try:
            pts = snap_domain_points(asset, k)
        except KeyError:  # no freedom (the mouth loop's midline vertices)
            continue
        pts = pts[np.linalg.norm(pts - heuristic[k], axis=1) < radius_mm]
        cost = np.zeros(len(pts))
        for rotation, translation, focal, width, height, s, detected in views:
            uv, _ = project(pts, rotation, translation, focal, width, height)
            cost += (((uv - detected[k]) * s) ** 2).sum(1)
            if j != k:  # the partner's detections, for the mirrored candidate points
                uv, _ = project(pts * np.array([-1.0, 1.0, 1.0]), rotation, translation, focal, width, height)
                cost += (((uv - detected[j]) * s) ** 2).sum(1)
        delta = np.round(pts[int(np.argmin(cost))] - heuristic[k], 1)
        if j == k:
            delta[0] = 0.0
        table[k] = tuple(float(x) + 0.0 for x in delta)  # + 0.0: no -0.0
    return table


def fit_contour(data: dict, asset) -> tuple[float, ...]:
    """``CONTOUR_ANGLES_DEG`` (16..9): per left contour landmark (with its mirror partner), the frontal
    outline vertex whose line makes the dynamic contour agree best with the detections over all views
    (least squares), as its direction below the horizontal, rounded to 0.1 degrees; kept in order along
    the outline and moving inwards (x monotone, as iBUG's contour)."""
    # the contour's own construction (private to landmarks.ibug68)
    from landmarks.ibug68.outline import _contour_from_ids, _outline
    from rig.geometry import vertex_normals

    v, o = asset.vertices, _outline(asset)
    normals = vertex_normals(v, asset.faces)
    found = np.flatnonzero(data["found"])
    views = [
        (
            data["rotation"][i],
            data["translation"][i],
            float(data["focal"][i]),
            int(data["width"]),
            int(data["height"]),
            view_scale(data, i, asset),
            data["detected"][i],
            camera_center_in_rig(data["rotation"][i], data["translation"][i]),
        )
        for i in found
    ]
    cost = np.zeros((len(o.vertex_ids), 8))  # candidate outline vertex x landmark 16..9
    for c, vid in enumerate(o.vertex_ids):
        if vid == o.chin_id:
            cost[c] = np.inf
            continue
        ids = np.array([int(asset.mirror[vid])] * 8 + [o.chin_id] + [int(vid)] * 8)
        lines = _contour_from_ids(asset, ids).candidates
        for side, line in ((1, lines[16]), (-1, lines[0])):
            for rotation, translation, focal, width, height, s, detected, centre in views:
                to_cam = centre - v[line]
                facing = (normals[line] * to_cam).sum(1) / np.linalg.norm(to_cam, axis=1)
                pick = line[np.argmin(np.where(facing > 0, facing, np.inf))] if (facing > 0).any() else vid
                uv, _ = project(v[pick][None], rotation, translation, focal, width, height)
                for n, k in enumerate(range(16, 8, -1)):
                    kk = k if side == 1 else 16 - k
                    cost[c, n] += float((((uv[0] - detected[kk]) * s) ** 2).sum())
    # the best candidates in outline order and moving inwards (iBUG's contour runs from the ear to the chin,
    # x monotone: a path through the cost table, dynamic programming over the allowed predecessors)
    n_c = len(o.vertex_ids)
    x = np.abs(v[np.asarray(o.vertex_ids), 0])
    allowed = (np.arange(n_c)[:, None] < np.arange(n_c)[None, :]) & (x[:, None] > x[None, :])  # [prev, next]
    total, back = cost[:, 0].copy(), np.zeros((n_c, 8), int)
    for n in range(1, 8):
        options = np.where(allowed, total[:, None], np.inf)  # (prev, next)
        back[:, n] = np.argmin(options, axis=0)
        total = options[back[:, n], np.arange(n_c)] + cost[:, n]
    picks = [int(np.argmin(total))]
    for n in range(7, 0, -1):
        picks.append(int(back[picks[-1], n]))
    picks = picks[::-1]
    return tuple(round(float(o.angles[c]), 1) for c in picks)


def table_source(table: dict) -> str:
    lines = ["LANDMARK_CORRECTIONS_MM: dict[int, tuple[float, float, float]] = {"]
    for k, d in sorted(table.items()):
        lines.append(f"    {k}: ({d[0]:.1f}, {d[1]:.1f}, {d[2]:.1f}),  # {IBUG68_NAMES[k]}")
    lines.append("}")
    return "\n".join(lines)


# --- report -----------------------------------------------------------------------------------------------


def print_table(before: dict, after: dict) -> None:
    print(
        f"{'#':>2} {'landmark':24s} | {'heuristic: dx':>13} {'dy':>6} {'bias':>6} {'error':>6} | "
        f"{'corrected: dx':>13} {'dy':>6} {'bias':>6} {'error':>6}"
    )
    for b, a in zip(before["landmarks"], after["landmarks"]):
        print(
            f"{b['index']:2d} {b['name']:24s} | {b['dx']:13.1f} {b['dy']:6.1f} {b['bias']:6.1f} {b['error']:6.1f} | "
            f"{a['dx']:13.1f} {a['dy']:6.1f} {a['bias']:6.1f} {a['error']:6.1f}"
        )
    print()
    print(
        f"{'region':10s} | {'heuristic bias':>14} {'error':>6} | {'corrected bias':>14} {'error':>6}   (px at IOD 100)"
    )
    for name in before["regions"]:
        b, a = before["regions"][name], after["regions"][name]
        print(f"{name:10s} | {b['bias']:14.2f} {b['error']:6.2f} | {a['bias']:14.2f} {a['error']:6.2f}")


def write_tables(table: dict, angles: tuple[float, ...], path: Path = MODULE) -> None:
    """Replace the two tables' assignments in ``landmarks/ibug68/corrections.py``."""
    text = path.read_text(encoding="utf-8")
    start = text.index("LANDMARK_CORRECTIONS_MM: dict[int, tuple[float, float, float]] = {")
    end = text.index("\n}\n", start) + 3
    text = text[:start] + table_source(table) + "\n" + text[end:]
    start = text.index("CONTOUR_ANGLES_DEG: tuple[float, ...] = (")
    end = text.index("\n", start) + 1
    text = text[:start] + f"CONTOUR_ANGLES_DEG: tuple[float, ...] = {tuple(angles)}\n" + text[end:]
    path.write_text(text, encoding="utf-8")


def mark_failures(data: dict, asset) -> dict:
    """``data`` with ``found`` False (and ``failed`` True) for the detections :data:`FAILURE_PX` calls failed."""
    failed = np.zeros(len(data["found"]), bool)
    for i in np.flatnonzero(data["found"]):
        error = np.linalg.norm(data["detected"][i] - projected(data, i, asset, True), axis=1).mean()
        failed[i] = error * view_scale(data, i, asset) > FAILURE_PX
    return {**data, "found": data["found"] & ~failed, "failed": failed}


def describe(data: dict, seeds) -> dict:
    n_views, n_found = len(data["found"]), int(data["found"].sum())
    poses = sorted({(float(y), float(p)) for y, p in zip(data["yaw"], data["pitch"])})
    found_per_pose = {
        f"yaw {y:+.0f} pitch {p:+.0f}": int(
            sum(bool(f) for yy, pp, f in zip(data["yaw"], data["pitch"], data["found"]) if (yy, pp) == (y, p))
        )
        for y, p in poses
    }
    failed = data.get("failed", np.zeros(n_views, bool))
    missed = [
        {"yaw_deg": float(y), "pitch_deg": float(p), "seed": int(s)}
        for y, p, s, f, x in zip(data["yaw"], data["pitch"], data["seed"], data["found"], failed)
        if not f and not x
    ]
    return {
        "views": n_views,
        "views_found": n_found,
        "landmarks_failed": int(failed.sum()),
        "poses": len(poses),
        "seeds": list(seeds),
        "poses_found": sum(1 for n in found_per_pose.values() if n),
        "found_per_pose": found_per_pose,
        "missed": missed,
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--yaw", type=_floats, default=_floats("-30,-20,-10,0,10,20,30"), help="degrees")
    parser.add_argument("--pitch", type=_floats, default=_floats("-15,0,15"), help="degrees")
    parser.add_argument("--seeds", type=_ints, default=_ints("8,9,10,11,12,13,14,15"), help="evaluation seeds")
    parser.add_argument("--fit-seeds", type=_ints, default=_ints("0,1,2,3,4,5,6,7"), help="seeds of the fit views")
    parser.add_argument("--json", type=Path, default=None, help="write the report here")
    parser.add_argument("--cache", type=Path, default=None, help="folder of the renders/detections cache")
    parser.add_argument("--fresh", action="store_true", help="re-render even where the cache matches")
    parser.add_argument("--fit", action="store_true", help="fit and print new correction tables")
    parser.add_argument(
        "--write", action="store_true", help="with --fit: write them into landmarks/ibug68/corrections.py"
    )
    parser.add_argument(
        "--fit-contour",
        action="store_true",
        help="with --fit: refit CONTOUR_ANGLES_DEG too (by default the committed angles are kept: see the docstring)",
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    t0 = time.perf_counter()
    asset = load_asset()
    seeds = args.fit_seeds if args.fit else args.seeds
    data = mark_failures(render_and_detect(args.yaw, args.pitch, seeds, args.cache, args.fresh), asset)
    views = describe(data, seeds)
    print(
        f"views: {views['views']} rendered ({views['poses']} poses x {len(seeds)} seeds {seeds}), face found in "
        f"{views['views_found'] + views['landmarks_failed']}, its landmarks failed (NME > {FAILURE_PX / IOD_PX:g}) "
        f"in {views['landmarks_failed']} of them; poses with a detection: {views['poses_found']} / "
        f"{views['poses']}; missed: "
        + ", ".join(f"({m['yaw_deg']:+.0f}, {m['pitch_deg']:+.0f}, seed {m['seed']})" for m in views["missed"])
    )
    if args.fit:
        table = fit_corrections(data, asset)
        angles = fit_contour(data, asset) if args.fit_contour else tuple(CONTOUR_ANGLES_DEG)
        print(table_source(table))
        print(f"CONTOUR_ANGLES_DEG: tuple[float, ...] = {angles}" + ("" if args.fit_contour else "  (kept)"))
        if args.write:
            write_tables(table, angles)
            print(f"wrote the tables into {MODULE}")
        return
    before = summarize(offsets(data, asset, corrected=False))
    after = summarize(offsets(data, asset, corrected=True))
    print_table(before, after)
    wall = time.perf_counter() - t0
    command = " ".join(shlex.quote(a) for a in [sys.executable, *sys.argv])
    print(f"wall {wall:.0f} s | python {platform.python_version()} | command: {command}")
    if args.json:
        eyes = outer_eye_corners(asset)
        report = {
            "issue": 13,
            "units": f"pixels, detected minus projected (x right, y down), scaled to an inter-ocular distance of "
            f"{IOD_PX:.0f} px (outer eye corners, frontal, at the face's depth)",
            "iod_mm": round(float(np.linalg.norm(eyes[1] - eyes[0])), 2),
            "bias": "norm of the mean offset over the views where the face was found and the landmarks did not "
            f"fail (mean error over the 68 > {FAILURE_PX:g} px, NME 0.1, against the corrected embedding)",
            "error": "mean over those views of the offset's norm",
            "detector": "landmarks.detect.detect_landmarks (dlib HOG + shape_predictor_68_face_landmarks), defaults",
            "render": {
                "function": "pipeline.synthetic.photos.simulate.simulate_photo",
                **{k: list(v) if isinstance(v, tuple) else v for k, v in SETTINGS.items()},
            },
            "grid": {"yaw_deg": args.yaw, "pitch_deg": args.pitch, "roll_deg": 0.0},
            "evaluation": views,
            "fit_seeds": args.fit_seeds,
            "contour": (
                "0-16 as landmarks.ibug68.contour.contour_landmarks sees them from each camera (8, the chin, static)"
            ),
            "corrections_mm": {str(k): list(v) for k, v in sorted(LANDMARK_CORRECTIONS_MM.items())},
            "contour_angles_deg": list(CONTOUR_ANGLES_DEG),
            "heuristic": before,
            "corrected": after,
            "command": "benchmarks/bench_landmark_offsets.py " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
        }
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
