"""Fit the table that maps MediaPipe's 468-point face mesh to the 68 iBUG landmarks (landmarks/mediapipe/ibug68_map.py).

    .venv/bin/python benchmarks/fit_mediapipe_ibug_map.py [--write] [--fresh] [--cache DIR]

Views: synthetic photos (:func:`pipeline.synthetic.photos.simulate.simulate_photo`, path-traced at 384 x 384
px, 32 spp, random albedo, light, camera, background) of ICT heads at yaw -30, -15, 0, 15, 30 degrees, the
pitch cycling through -10, 0, 10, roll 0. Their true landmarks are ``photo.landmarks2d_true``: the
projections of the 68-point embedding jnr's photo fit uses (the jaw contour as the camera sees it), the
convention dlib's detector was matched to (issue 13). Fit views: the rig's template and the ``test``
split's heads 0-2 (20 views); evaluation views: ``test`` heads 3-5 (15 views), identities the fit never saw.

MediaPipe's pipeline (:class:`landmarks.mediapipe.detector.MediaPipeDetector`, default options) gives the
478 dense points of each view. Pixels are scaled per view to an inter-ocular distance of 100 (the true
outer eye corners, 36 and 45). For each landmark, the 8 mesh points nearest to it on average over the fit
views are candidates; for every triple of them the convex combination (weights >= 0, summing to 1) closest
to the true landmark over all fit views is solved exactly (least squares over the simplex: interior,
edges and corners), and the triple with the smallest residual is kept. ``--write`` puts the table into
``landmarks/mediapipe/ibug68_map.py``. The script prints the mean error per region on the fit and the
evaluation views (pixels at IOD 100) and, on ``skimage.data.astronaut()``, the distance between the mapped
points and dlib's 68 landmarks (pixels).

Renders are cached in ``--cache`` (default: the system temp folder); ``--fresh`` re-renders. About 30 s of
rendering on 2 cores, then a few seconds.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import skimage.data

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from landmarks.dlib_detector import HogDetector
from landmarks.mediapipe.detector import MediaPipeDetector
from landmarks.mediapipe.ibug68_map import mesh_to_ibug68
from pipeline.synthetic.photos.settings import PhotoSettings
from pipeline.synthetic.photos.simulate import simulate_photo
from pipeline.synthetic.population import population_split
from rig.asset import load_asset

MODULE = Path(__file__).resolve().parents[1] / "landmarks" / "mediapipe" / "ibug68_map.py"
SETTINGS = {"width": 384, "height": 384, "spp": 32, "roll_deg_range": (0.0, 0.0)}
YAWS = (-30.0, -15.0, 0.0, 15.0, 30.0)
PITCHES = (-10.0, 0.0, 10.0)
FIT_HEADS = ("template", "test_0", "test_1", "test_2")
EVAL_HEADS = ("test_3", "test_4", "test_5")
CANDIDATES = 8
IOD_PX = 100.0
REGIONS = {
    "contour": range(17),
    "brows": range(17, 27),
    "nose": range(27, 36),
    "eyes": range(36, 48),
    "lips": range(48, 68),
}
BEGIN, END = "# --- fitted table", "# --- end of fitted table ---"


def render_views(heads, cache_dir: Path | None, fresh: bool) -> dict[str, np.ndarray]:
    """Photograph each head at each yaw; returns (and caches) ``images (N, H, W, 3)``, ``truth (N, 68, 2)``,
    ``head``, ``yaw``, ``pitch``."""
    key = json.dumps({"heads": heads, "yaws": YAWS, "pitches": PITCHES, "settings": repr(SETTINGS), "v": 1})
    cache = (
        Path(cache_dir or tempfile.gettempdir())
        / f"jnr_mediapipe_map_{hashlib.sha1(key.encode()).hexdigest()[:12]}.npz"
    )
    if cache.is_file() and not fresh:
        print(f"renders from {cache}")
        return dict(np.load(cache))
    asset = load_asset()
    test = population_split("test", 0, asset)
    settings = PhotoSettings(**SETTINGS)
    rows: dict[str, list] = {"images": [], "truth": [], "head": [], "yaw": [], "pitch": []}
    start = time.perf_counter()
    for h, head in enumerate(heads):
        vertices = asset.vertices if head == "template" else test.vertices[int(head.split("_")[1])]
        for y, yaw in enumerate(YAWS):
            pitch = PITCHES[(h + y) % len(PITCHES)]
            rng = np.random.default_rng([h, y, 29, sum(map(ord, head))])
            photo = simulate_photo(vertices, rng, settings, asset, yaw_deg=yaw, pitch_deg=pitch, roll_deg=0.0)
            for name, value in zip(rows, (photo.image, photo.landmarks2d_true, head, yaw, pitch)):
                rows[name].append(value)
        print(f"  rendered {head} ({time.perf_counter() - start:.0f} s)")
    data = {k: np.asarray(v) for k, v in rows.items()}
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, **data)
    return data


def detect_dense(images: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 478, 2)`` MediaPipe's points per view (NaN where no face covers the true landmarks) and ``(N,)``
    found flags."""
    detector = MediaPipeDetector()
    dense = np.full((len(images), 478, 2), np.nan)
    for i, (image, points) in enumerate(zip(images, truth)):
        centre = points.mean(axis=0)
        for face in detector.detect(image):
            left, top, right, bottom = face.box
            if left <= centre[0] <= right and top <= centre[1] <= bottom:
                dense[i] = face.dense[:, :2]
                break
    return dense, np.isfinite(dense[:, 0, 0])


def simplex_least_squares(columns: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, float]:
    """The weights ``w >= 0``, ``sum(w) = 1`` minimising ``|columns @ w - target|^2``, and that residual.

    ``columns``: ``(M, 3)``; ``target``: ``(M,)``. Exact: every face of the triangle (its interior, three
    edges, three corners) is solved in closed form, the best feasible solution wins."""
    best_w, best_r = None, np.inf
    for support in ((0, 1, 2), (0, 1), (0, 2), (1, 2), (0,), (1,), (2,)):
        last = columns[:, support[-1]]
        if len(support) == 1:
            w_support = np.array([1.0])
        else:
            design = columns[:, support[:-1]] - last[:, None]
            free, *_ = np.linalg.lstsq(design, target - last, rcond=None)
            w_support = np.append(free, 1.0 - free.sum())
            if np.any(w_support < -1e-12):
                continue
        weights = np.zeros(3)
        weights[list(support)] = np.clip(w_support, 0.0, None)
        residual = float(np.sum((columns @ weights - target) ** 2))
        if residual < best_r:
            best_w, best_r = weights, residual
    return best_w, best_r


def fit_table(dense: np.ndarray, truth: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(68, 3)`` mesh indices and weights from the fit views: ``dense (N, 478, 2)``, ``truth (N, 68, 2)``
    pixels and ``scale (N,)`` (to IOD 100)."""
    mesh = dense[:, :468] * scale[:, None, None]
    target = truth * scale[:, None, None]
    indices = np.zeros((68, 3), dtype=np.int64)
    weights = np.zeros((68, 3))
    for k in range(68):
        distance = np.linalg.norm(mesh - target[:, k : k + 1], axis=2).mean(axis=0)  # (468,)
        candidates = np.argsort(distance)[:CANDIDATES]
        best = (np.inf, None, None)
        for triple in itertools.combinations(candidates, 3):
            columns = mesh[:, list(triple)].transpose(0, 2, 1).reshape(-1, 3)  # (N * 2, 3)
            w, residual = simplex_least_squares(columns, target[:, k].reshape(-1))
            if residual < best[0]:
                best = (residual, triple, w)
        order = np.argsort(-best[2])
        indices[k] = np.asarray(best[1])[order]
        weights[k] = np.round(best[2][order], 4)
        weights[k, 0] += 1.0 - weights[k].sum()  # rounding back onto the simplex
    return indices, weights


def mapped(dense: np.ndarray, indices: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``(N, 68, 2)`` the table applied to ``(N, 478, 2)``."""
    return np.einsum("kj,nkjd->nkd", weights, dense[:, indices])


def mesh_to_ibug68_batch(dense: np.ndarray) -> np.ndarray:
    """The committed table on ``(N, 478, 2)`` (NaN views stay NaN)."""
    return np.stack([mesh_to_ibug68(d) for d in dense])


def region_errors(error: np.ndarray) -> str:
    """``error (N, 68)`` -> 'region mean' text."""
    parts = [f"{name} {np.nanmean(error[:, list(r)]):.2f}" for name, r in REGIONS.items()]
    return ", ".join(parts) + f"; inner {np.nanmean(error[:, 17:]):.2f}, all {np.nanmean(error):.2f}"


def table_source(indices: np.ndarray, weights: np.ndarray) -> str:
    lines = [f"{BEGIN} (benchmarks/fit_mediapipe_ibug_map.py --write replaces this block) ---"]
    lines.append("# fmt: off")
    lines.append("IBUG68_MESH_INDICES = np.array([")
    for k in range(0, 68, 6):
        lines.append("    " + " ".join(f"[{a}, {b}, {c}]," for a, b, c in indices[k : k + 6]))
    lines.append("], dtype=np.int64)")
    lines.append("IBUG68_MESH_WEIGHTS = np.array([")
    for k in range(0, 68, 4):
        lines.append("    " + " ".join("[" + ", ".join(f"{w:.4f}" for w in row) + "]," for row in weights[k : k + 4]))
    lines.append("])")
    lines.append("# fmt: on")
    lines.append(END)
    return "\n".join(lines)


def astronaut_error(indices: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float]:
    """``(68,)`` pixels between the table's points and dlib's on the astronaut (HOG detector), and the
    inter-ocular distance of dlib's points (outer eye corners), pixels."""
    image = np.ascontiguousarray(skimage.data.astronaut())
    reference = HogDetector().detect(image)[0].landmarks
    dense = MediaPipeDetector().detect(image)[0].dense[None, :, :2]
    iod = float(np.linalg.norm(reference[36] - reference[45]))
    return np.linalg.norm(mapped(dense, indices, weights)[0] - reference, axis=1), iod


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help="write the table into landmarks/mediapipe/ibug68_map.py")
    parser.add_argument("--fresh", action="store_true", help="re-render the views")
    parser.add_argument("--cache", type=Path, default=None, help="folder of the cached renders")
    args = parser.parse_args(argv)

    sets = {}
    for name, heads in (("fit", FIT_HEADS), ("eval", EVAL_HEADS)):
        views = render_views(list(heads), args.cache, args.fresh)
        dense, found = detect_dense(views["images"], views["truth"])
        iod = np.linalg.norm(views["truth"][:, 36] - views["truth"][:, 45], axis=1)
        sets[name] = (dense, views["truth"], IOD_PX / iod, found)
        print(f"{name}: MediaPipe found {found.sum()} of {len(found)} faces")
    dense, truth, scale, found = sets["fit"]
    indices, weights = fit_table(dense[found], truth[found], scale[found])
    for name, (dense, truth, scale, found) in sets.items():
        error = np.linalg.norm(mapped(dense, indices, weights) - truth, axis=2) * scale[:, None]
        print(f"{name} views, px at IOD 100: {region_errors(error[found])}")
        current = np.linalg.norm(mesh_to_ibug68_batch(dense) - truth, axis=2) * scale[:, None]
        print(f"  the committed table: {region_errors(current[found])}")
    error, iod = astronaut_error(indices, weights)
    print(f"astronaut vs dlib, px (IOD {iod:.0f} px): {region_errors(error[None])}; max {error.max():.1f}")
    if args.write:
        source = MODULE.read_text()
        pattern = re.compile(re.escape(BEGIN) + ".*?" + re.escape(END), re.S)
        MODULE.write_text(pattern.sub(lambda _: table_source(indices, weights), source, count=1))
        print(f"wrote {MODULE}")
    else:
        print(table_source(indices, weights))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
