"""Where each of MediaPipe's 478 points lies on the template (issue 26): ``landmarks/mediapipe/embedding_table.npz``.

    .venv/bin/python benchmarks/fit_mediapipe_embedding.py [--write] [--json FILE] [--fresh] [--cache DIR]

Views: synthetic photos (:func:`pipeline.synthetic.photos.simulate.simulate_photo`, path-traced at 384 x 384
px, 32 spp, random albedo, light, camera, background per view), roll 0. *Fit* views: the rig's template and
the ``test`` split's heads 0-2, each at yaw -40..40 step 10 with the pitch cycling through -15, 0, 15 (36
views). *Evaluation* views: the template again with other draws and the ``test`` heads 3-5 (identities the
fit never saw), six views each, yaw drawn in each sixth of -40..40, pitch uniform in -15..15 (24 views).
MediaPipe (:class:`landmarks.mediapipe.detector.MediaPipeDetector`, default options) gives the 478 points;
a view without a detected face whose box contains the true face (the centre of its true iBUG points) is
skipped. Pixels are scaled per view to an inter-ocular distance of 100 (the head's outer eye corners,
frontal at their depth, as ``bench_landmark_offsets.py``).

The fit, per point (every camera is known):

1. *Triangulate* on each fit head, in that head's rig frame: linear DLT over its fit views, then
   Gauss-Newton on the reprojection error (pixels at IOD 100). Its RMS residual is the point's
   *triangulation residual*.
2. *Contour* (sliding) points: MediaPipe's outline follows the silhouette, so such a point's rays do not
   meet in one place across yaws. A point is flagged when its triangulation residual, averaged over the fit
   heads and with its mirror partner, exceeds :data:`CONTOUR_RESIDUAL_PX`, and it lies on the periphery of
   the layout: it or its partner in the outer :data:`PERIPHERY_LAYERS` convex-hull layers of the frontal
   views' 468 points. A point's partner: the template's triangulated point nearest to its mirror image.
3. *Onto the surface*: on each head the closest surface point to its triangulated point among the allowed
   faces (no vertex in a hidden region, :data:`HIDDEN_REGIONS`; the irises 468-477 on the eyeballs' front
   faces only, normal within 60 degrees of +Z), as face + barycentric weights. Those faces and their
   one-ring are candidates; on each, the barycentric point (applied to each head's own vertices: the table
   is shared by every head in the template's topology) whose projections agree best with the detections of
   *all* fit views of all heads is solved (Gauss-Newton in the triangle); the best candidate wins, and the
   search moves to the winner's one-ring until it stays. Contour points are placed the same way on the
   near-frontal fit views only (|yaw| <= 10): a frontal start, not a fixed point.
4. *Offsets*: the distance from each head's triangulated point to its surface (mm, mean over the heads),
   and the fit views' RMS reprojection error of the placed point.

Evaluation, on the evaluation views: per point the error (pixels at IOD 100) between MediaPipe's point
and the projection of the embedded point; ``sigma_px`` is its RMS over the views (for contour points the
frontal start's error: they are reported separately). *Before* is a naive placement: for each point the
template vertex (allowed as above, facing the camera) nearest to the ray through MediaPipe's point in the
template's frontal fit view (:func:`naive_placement`). Regions are the template regions of the embedded
faces (brows, eyelids as eyes, nose, lips; the rest of the face as ``other``), the irises and the contour
points.

``--write`` writes ``landmarks/mediapipe/embedding_table.npz``; ``--json`` the figures. Renders are cached in
``--cache`` (default: the system temp folder); ``--fresh`` re-renders (60 renders: 27 s on 2 cores, 36 s in
all; from the cache about 10 s).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from landmarks.ibug68.positions import landmark_positions
from landmarks.mediapipe.detector import MediaPipeDetector
from landmarks.mediapipe.embedding import EMBEDDING_TABLE, DenseEmbedding, write_embedding_table
from pipeline.camera import RIG_TO_OPENCV
from pipeline.synthetic.photos.settings import PhotoSettings
from pipeline.synthetic.photos.simulate import simulate_photo
from pipeline.synthetic.population import population_split
from rig.asset import load_asset
from rig.geometry import closest_surface_points, face_normals, vertex_normals

SETTINGS = {"width": 384, "height": 384, "spp": 32, "roll_deg_range": (0.0, 0.0)}
FIT_HEADS = ("template", "test_0", "test_1", "test_2")
FIT_YAWS = (-40.0, -30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0, 40.0)
FIT_PITCHES = (-15.0, 0.0, 15.0)
EVAL_HEADS = ("template", "test_3", "test_4", "test_5")
EVAL_VIEWS = 6
"""Evaluation views per head: yaw stratified over -40..40 degrees (one draw in each sixth), pitch uniform in
-15..15, other albedo, light, camera and background draws than any fit view (another random stream)."""
N_POINTS = 478
IRISES = np.arange(468, 478)
IOD_PX = 100.0
HIDDEN_REGIONS = ("eyeballs", "mouth_interior", "teeth", "tongue", "eye_pockets")
IRIS_FRONT_COS = 0.5
"""Iris points go on eyeball faces whose normal is within 60 degrees of +Z (the eyes look ahead)."""
CONTOUR_RESIDUAL_PX = 6.0
PERIPHERY_LAYERS = 2
FRONTAL_YAW_DEG = 10.0
DLIB_CORRECTED = {"bias": 1.64, "error": 4.35, "inner_bias": 1.00, "inner_error": 3.52}
"""docs/landmarks.md: dlib's 68 points against the corrected iBUG embedding (issue 25), px at IOD 100."""
MEDIAPIPE_FACE_OVAL = (
    10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377,
    152, 148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109,
)  # fmt: skip
"""MediaPipe's ``FACEMESH_FACE_OVAL`` (36 points), used only to compare with the points flagged here."""
REGION_OF = {"brows": "brows", "eyelids": "eyes", "nose": "nose", "lips": "lips"}


def head_vertices(heads, asset) -> dict[str, np.ndarray]:
    """``name -> (V, 3)`` mm: ``template`` is the rig's template, ``test_i`` the ``test`` split's head ``i``."""
    test_ids = [int(h.split("_")[1]) for h in heads if h != "template"]
    test = population_split("test", 0, asset, first=max(test_ids) + 1) if test_ids else None
    return {h: asset.vertices if h == "template" else test.vertices[int(h.split("_")[1])] for h in heads}


def view_plan(role: str) -> list[tuple[str, float, float, list[int]]]:
    """``(head, yaw, pitch, seed)`` of each view of the ``fit`` or ``eval`` set."""
    plan = []
    if role == "fit":
        for h, head in enumerate(FIT_HEADS):
            for y, yaw in enumerate(FIT_YAWS):
                plan.append((head, yaw, FIT_PITCHES[(h + y) % len(FIT_PITCHES)], [h, y, 26, 0]))
    else:
        for h, head in enumerate(EVAL_HEADS):
            draw = np.random.default_rng([h, 26, 1])
            for j in range(EVAL_VIEWS):
                yaw = -40.0 + 80.0 * (j + draw.uniform()) / EVAL_VIEWS
                plan.append((head, round(yaw, 1), round(float(draw.uniform(-15.0, 15.0)), 1), [h, j, 26, 1]))
    return plan


def render_views(role: str, cache_dir: Path | None, fresh: bool, log=print) -> dict[str, np.ndarray]:
    """Photograph the views of ``role`` (:func:`view_plan`); returns (and caches) per view ``images
    (N, H, W, 3)`` uint8, ``truth (N, 68, 2)`` px (the true iBUG points, to check a detection's box),
    ``rotation (N, 3, 3)``, ``translation (N, 3)`` mm, ``focal (N,)`` px, ``head``, ``yaw``, ``pitch``."""
    plan = view_plan(role)
    key = json.dumps({"plan": plan, "settings": repr(SETTINGS), "v": 1})
    cache = (
        Path(cache_dir or tempfile.gettempdir())
        / f"jnr_mediapipe_embedding_{hashlib.sha1(key.encode()).hexdigest()[:12]}.npz"
    )
    if cache.is_file() and not fresh:
        data = dict(np.load(cache, allow_pickle=False))
        if str(data["key"]) == key:
            log(f"{role}: {len(data['yaw'])} renders from {cache}")
            return data
    asset = load_asset()
    vertices = head_vertices(sorted({p[0] for p in plan}), asset)
    settings = PhotoSettings(**SETTINGS)
    rows: dict[str, list] = {
        k: [] for k in ("images", "truth", "rotation", "translation", "focal", "head", "yaw", "pitch")
    }
    start = time.perf_counter()
    for head, yaw, pitch, seed in plan:
        for attempt in range(10):  # a draw that puts the face partly outside the image is drawn again
            try:
                photo = simulate_photo(
                    vertices[head],
                    np.random.default_rng([*seed, attempt]),
                    settings,
                    asset,
                    yaw_deg=yaw,
                    pitch_deg=pitch,
                    roll_deg=0.0,
                )
                break
            except ValueError:
                continue
        else:
            raise RuntimeError(f"no draw of 10 fits {head} at yaw {yaw}, pitch {pitch} into the image")
        values = (photo.image, photo.landmarks2d_true, photo.rotation, photo.translation, photo.focal, head, yaw, pitch)
        for name, value in zip(rows, values):
            rows[name].append(value)
    log(f"{role}: rendered {len(plan)} views in {time.perf_counter() - start:.0f} s")
    data = {k: np.asarray(v) for k, v in rows.items()}
    data.update(key=np.asarray(key), width=np.asarray(SETTINGS["width"]), height=np.asarray(SETTINGS["height"]))
    data["render_s"] = np.asarray(time.perf_counter() - start)
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, **data)
    return data


def detect_dense(images: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``(N, 478, 2)`` MediaPipe's points per view, OpenCV pixels; NaN where no detected face's box contains
    the true face (the centre of its true iBUG points)."""
    detector = MediaPipeDetector()
    dense = np.full((len(images), N_POINTS, 2), np.nan)
    for i, (image, points) in enumerate(zip(images, truth)):
        cx, cy = points.mean(axis=0)
        for face in detector.detect(image):
            left, top, right, bottom = face.box
            if left <= cx <= right and top <= cy <= bottom:
                dense[i] = face.dense[:, :2]
                break
    return dense


def camera_matrices(data: dict) -> np.ndarray:
    """``(N, 3, 4)`` projection matrices: rig mm -> homogeneous OpenCV pixels."""
    centre = np.array([(int(data["width"]) - 1) / 2.0, (int(data["height"]) - 1) / 2.0])
    out = []
    for rotation, translation, focal in zip(data["rotation"], data["translation"], data["focal"]):
        intrinsics = np.array([[focal, 0.0, centre[0]], [0.0, focal, centre[1]], [0.0, 0.0, 1.0]])
        out.append(intrinsics @ np.hstack([RIG_TO_OPENCV @ rotation, translation[:, None]]))
    return np.asarray(out)


IOD_PX = 100.0


def outer_eye_corners(vertices: np.ndarray, asset) -> np.ndarray:
    """``(2, 3)`` the eyelid loops' lateral corners of a head in the template's topology, mm."""
    return np.array([vertices[loop[np.argmax(np.abs(asset.vertices[loop, 0]))]] for loop in asset.eye_loops])


def view_scales(cams: np.ndarray, heads, vertices: dict, asset) -> np.ndarray:
    """``(N,)`` pixels -> pixels at an inter-ocular distance of 100 (outer eye corners, frontal at their depth)."""
    out = []
    for cam, head in zip(cams, heads):
        eyes = outer_eye_corners(vertices[str(head)], asset)
        depth = cam[2, :3] @ eyes.mean(0) + cam[2, 3]
        out.append(IOD_PX * depth / (cam[0, 0] * np.linalg.norm(eyes[1] - eyes[0])))
    return np.asarray(out)


def project(points: np.ndarray, cams: np.ndarray) -> np.ndarray:
    """``points (N, P, 3)`` or ``(P, 3)`` rig mm, ``cams (N, 3, 4)`` -> ``(N, P, 2)`` px."""
    points = np.broadcast_to(points, (len(cams), *points.shape[-2:]))
    h = np.einsum("nij,npj->npi", cams[:, :, :3], points) + cams[:, None, :, 3]
    return h[..., :2] / h[..., 2:]


def triangulate(uv: np.ndarray, cams: np.ndarray, scale: np.ndarray, steps: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares 3D points of ``uv (n, P, 2)`` px seen by ``cams (n, 3, 4)``: linear DLT, then
    Gauss-Newton on the reprojection error weighted by ``scale (n,)``. Returns ``(P, 3)`` mm and the RMS
    residual ``(P,)`` (pixels at IOD 100)."""
    rows = np.concatenate(
        [uv[..., 0:1] * cams[:, None, 2] - cams[:, None, 0], uv[..., 1:2] * cams[:, None, 2] - cams[:, None, 1]]
    )  # (2n, P, 4)
    rows = rows / np.linalg.norm(rows, axis=2, keepdims=True)
    _, _, vt = np.linalg.svd(rows.transpose(1, 0, 2))
    x = vt[:, -1, :3] / vt[:, -1, 3:]
    for _ in range(steps):
        h = np.einsum("nij,pj->npi", cams[:, :, :3], x) + cams[:, None, :, 3]
        u = h[..., :2] / h[..., 2:]
        jac = (cams[:, None, :2, :3] - u[..., None] * cams[:, None, 2:3, :3]) / h[..., 2:, None]  # (n, P, 2, 3)
        jac = jac * scale[:, None, None, None]
        res = (u - uv) * scale[:, None, None]
        jtj = np.einsum("npki,npkj->pij", jac, jac)
        jtr = np.einsum("npki,npk->pi", jac, res)
        x = x - np.linalg.solve(jtj, jtr[..., None])[..., 0]
    res = (project(x, cams) - uv) * scale[:, None, None]
    return x, np.sqrt((res**2).sum(2).mean(0))


# --- the fit ----------------------------------------------------------------------------------------------


def allowed_faces(asset) -> tuple[np.ndarray, np.ndarray]:
    """``(skin, iris)`` face ids: faces with no vertex in :data:`HIDDEN_REGIONS`, and the eyeballs' front faces."""
    hidden = asset.region_mask(*HIDDEN_REGIONS)[asset.faces]
    eyeball = asset.region_mask("eyeballs")[asset.faces].all(1)
    normals = face_normals(asset.vertices, asset.faces)
    facing = normals[:, 2] / np.linalg.norm(normals, axis=1)
    return np.flatnonzero(~hidden.any(1)), np.flatnonzero(eyeball & (facing > IRIS_FRONT_COS))


def hull_layers(points: np.ndarray, count: int) -> np.ndarray:
    """``(P,)`` convex-hull peeling layer of each 2D point (1 the outermost; 0 inside the first ``count``)."""
    layer, rest = np.zeros(len(points), int), np.arange(len(points))
    for n in range(1, count + 1):
        hull = ConvexHull(points[rest]).vertices
        layer[rest[hull]] = n
        rest = np.delete(rest, hull)
    return layer


def frontal_layout(dense: np.ndarray, yaws: np.ndarray) -> np.ndarray:
    """``(468, 2)`` the mean of the yaw-0 views' mesh points, each view centred and scaled to unit RMS."""
    views = dense[np.abs(yaws) < 1e-6, :468]
    views = views - views.mean(1, keepdims=True)
    views = views / np.sqrt((views**2).sum(2).mean(1))[:, None, None]
    return views.mean(0)


def mirror_partners(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(P,)`` the point nearest to each point's mirror image (x -> -x) and ``(P,)`` whether that is mutual."""
    _, partner = cKDTree(points).query(points * np.array([-1.0, 1.0, 1.0]))
    return partner, partner[partner] == np.arange(len(points))


def one_ring(faces: np.ndarray, face_ids, allowed: np.ndarray) -> np.ndarray:
    """The allowed faces sharing a vertex with any of ``face_ids``."""
    corners = np.unique(faces[np.asarray(face_ids)])
    return np.intersect1d(np.flatnonzero(np.isin(faces, corners).any(1)), allowed)


def best_on_faces(face_ids, corners, cams, scale, uv, steps: int = 8):
    """The point on one of the faces that best reprojects onto ``uv (n, 2)`` px over ``n`` views.

    ``corners (n, F, 3, 3)`` mm: each candidate face's corners on the head of each view; ``cams (n, 3, 4)``;
    ``scale (n,)``. Gauss-Newton on the barycentric weights in each face (kept inside it). Returns
    ``(face id, barycentric (3,), cost)`` -- cost the sum of squared errors in pixels at IOD 100."""
    edges = np.stack([corners[:, :, 1] - corners[:, :, 0], corners[:, :, 2] - corners[:, :, 0]], -1)  # (n,F,3,2)
    w = np.full((len(face_ids), 2), 1.0 / 3.0)

    def residual(w):
        x = corners[:, :, 0] + np.einsum("nfcj,fj->nfc", edges, w)
        h = np.einsum("nij,nfj->nfi", cams[:, :, :3], x) + cams[:, None, :, 3]
        u = h[..., :2] / h[..., 2:]
        return (u - uv[:, None]) * scale[:, None, None], u, h

    for _ in range(steps):
        r, u, h = residual(w)
        d_uv = (cams[:, None, :2, :3] - u[..., None] * cams[:, None, 2:3, :3]) / h[..., 2:, None]
        jac = np.einsum("nfij,nfjk->nfik", d_uv, edges) * scale[:, None, None, None]
        jtj = np.einsum("nfki,nfkj->fij", jac, jac) + 1e-9 * np.eye(2)
        w = w - np.linalg.solve(jtj, np.einsum("nfki,nfk->fi", jac, r)[..., None])[..., 0]
        full = np.clip(np.column_stack([1.0 - w.sum(1), w]), 0.0, None)
        w = (full / full.sum(1, keepdims=True))[:, 1:]
    cost = (residual(w)[0] ** 2).sum((0, 2))
    j = int(np.argmin(cost))
    bary = np.clip(np.array([1.0 - w[j].sum(), *w[j]]), 0.0, None)
    return int(face_ids[j]), bary / bary.sum(), float(cost[j])


def place_point(k: int, starts, allowed, faces, stacked, views: dict, rounds: int = 4):
    """Point ``k``'s face and barycentric weights: the best of :func:`best_on_faces` over ``starts`` and their
    one-ring, the search moved to the winner's one-ring until it stays. ``stacked (H, V, 3)`` the heads;
    ``views``: ``head (n,)`` index into ``stacked``, ``cams``, ``scale``, ``uv (n, 478, 2)``."""
    tested, best = set(), (None, None, np.inf)
    candidates = one_ring(faces, starts, allowed)
    for _ in range(rounds):
        new = np.array(sorted(set(candidates.tolist()) - tested), dtype=np.int64)
        if new.size == 0:
            break
        tested.update(new.tolist())
        corners = stacked[:, faces[new]][views["head"]]  # (n, F, 3, 3)
        found = best_on_faces(new, corners, views["cams"], views["scale"], views["uv"][:, k])
        if found[2] < best[2]:
            best = found
        candidates = one_ring(faces, [best[0]], allowed)
    return best


def naive_placement(uv: np.ndarray, cam: np.ndarray, asset) -> DenseEmbedding:
    """The *before* placement from one view (``uv (478, 2)`` px, ``cam (3, 4)``) of the template: per point
    the allowed template vertex (as the fit's faces) nearest to the ray through it -- of the vertices facing
    the camera, the one projected nearest to ``uv``."""
    v, faces = asset.vertices, asset.faces
    centre = -np.linalg.solve(cam[:, :3], cam[:, 3])
    facing = (vertex_normals(v, faces) * (centre - v)).sum(1) > 0
    projected = project(v, cam[None])[0]
    vertex_face = np.full(len(v), -1)
    vertex_face[faces[::-1].ravel()] = np.repeat(np.arange(len(faces))[::-1], 3)  # a face of each vertex
    out_faces, out_bary = np.zeros(N_POINTS, np.int64), np.zeros((N_POINTS, 3))
    for ids, allowed in zip((np.arange(468), IRISES), allowed_faces(asset)):
        candidates = np.unique(faces[allowed])
        candidates = candidates[facing[candidates]]
        for k in ids:
            vid = candidates[np.argmin(np.linalg.norm(projected[candidates] - uv[k], axis=1))]
            out_faces[k] = vertex_face[vid]
            out_bary[k, list(faces[vertex_face[vid]]).index(vid)] = 1.0
    return DenseEmbedding(out_faces, out_bary, np.zeros(N_POINTS, bool), np.zeros(N_POINTS))


# --- the figures ------------------------------------------------------------------------------------------


def view_set(data: dict, dense: np.ndarray, heads: tuple[str, ...], vertices: dict, asset) -> dict:
    """The found views of a set as arrays: ``head`` (index into ``heads``), ``cams``, ``scale``, ``uv``, ``yaw``."""
    found = np.isfinite(dense[:, 0, 0])
    cams = camera_matrices(data)[found]
    names = data["head"][found]
    return {
        "head": np.array([heads.index(str(h)) for h in names]),
        "cams": cams,
        "scale": view_scales(cams, names, vertices, asset),
        "uv": dense[found],
        "yaw": data["yaw"][found],
        "pitch": data["pitch"][found],
    }


def reprojection_offsets(embedding, stacked: np.ndarray, faces: np.ndarray, views: dict) -> np.ndarray:
    """``(n, 478, 2)`` detected - projected embedded points per view, pixels at IOD 100."""
    positions = landmark_positions(stacked, embedding, faces)[views["head"]]  # (n, 478, 3)
    uv = np.stack([project(p, c[None])[0] for p, c in zip(positions, views["cams"])])
    return (views["uv"] - uv) * views["scale"][:, None, None]


def point_regions(embedding, asset, contour: np.ndarray) -> np.ndarray:
    """``(478,)`` report region of each point: its face's template region (by weight) mapped through
    :data:`REGION_OF` (else ``other``), ``irises``, or ``contour``."""
    names = np.array(asset.region_names)[asset.regions[asset.faces[embedding.faces]]]  # (478, 3)
    out = []
    for k in range(N_POINTS):
        weights: dict[str, float] = {}
        for name, w in zip(names[k], embedding.barycentric[k]):
            weights[name] = weights.get(name, 0.0) + float(w)
        out.append(REGION_OF.get(max(weights, key=weights.get), "other"))
    out = np.array(out, dtype=object)
    out[IRISES] = "irises"
    out[contour] = "contour"
    return out


def region_summary(errors: np.ndarray, regions: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> dict:
    """Per region: points, ``error`` (mean per-view norm) and ``bias`` (norm of the mean offset), px at IOD
    100, from ``errors (n, 478, 2)``; ``extra`` per-point arrays are averaged too."""
    out = {}
    groups = [(name, regions == name) for name in ("brows", "eyes", "nose", "lips", "other", "irises", "contour")]
    groups += [("all but contour", regions != "contour"), ("all", np.ones(N_POINTS, bool))]
    for name, mask in groups:
        norms = np.linalg.norm(errors[:, mask], axis=2)
        row = {
            "points": int(mask.sum()),
            "error": round(float(norms.mean()), 2),
            "bias": round(float(np.linalg.norm(errors[:, mask].mean(0), axis=1).mean()), 2),
        }
        for key, values in (extra or {}).items():
            row[key] = round(float(values[mask].mean()), 2)
        out[name] = row
    return out


def fit_embedding(asset, fit: dict, stacked: np.ndarray, log=print) -> tuple[DenseEmbedding, dict]:
    """The embedding from the fit views (``sigma_px`` still zero) and the per-point fit figures."""
    faces = asset.faces
    skin, iris = allowed_faces(asset)
    n_heads = len(stacked)
    points, residual = np.zeros((n_heads, N_POINTS, 3)), np.zeros((n_heads, N_POINTS))
    for h in range(n_heads):
        sel = fit["head"] == h
        points[h], residual[h] = triangulate(fit["uv"][sel], fit["cams"][sel], fit["scale"][sel])
    # contour: triangulation residual (mean over heads, with the mirror partner) on the layout's periphery
    partner, _ = mirror_partners(points[0])
    pair_residual = (residual.mean(0) + residual.mean(0)[partner]) / 2.0
    layers = np.append(hull_layers(frontal_layout(fit["uv"], fit["yaw"]), PERIPHERY_LAYERS), np.zeros(10, int))
    periphery = (layers > 0) | (layers[partner] > 0)  # a point or its mirror partner (irises: neither)
    contour = (pair_residual > CONTOUR_RESIDUAL_PX) & periphery
    log(f"contour points: {int(contour.sum())} (residual > {CONTOUR_RESIDUAL_PX} px, hull layers 1-{PERIPHERY_LAYERS})")
    # onto each head's surface, then the best place over all heads' views
    starts, offset = np.zeros((n_heads, N_POINTS), np.int64), np.zeros((n_heads, N_POINTS))
    for h in range(n_heads):
        for ids, allowed in ((slice(0, 468), skin), (IRISES, iris)):
            found = closest_surface_points(points[h][ids], stacked[h], faces[allowed])
            starts[h, ids], offset[h, ids] = allowed[found.face], found.distance
    frontal = {k: v[np.abs(fit["yaw"]) <= FRONTAL_YAW_DEG] for k, v in fit.items()}
    out_faces, out_bary = np.zeros(N_POINTS, np.int64), np.zeros((N_POINTS, 3))
    for k in range(N_POINTS):
        views = frontal if contour[k] else fit
        out_faces[k], out_bary[k], _ = place_point(k, starts[:, k], iris if k >= 468 else skin, faces, stacked, views)
    embedding = DenseEmbedding(out_faces, out_bary, contour, np.zeros(N_POINTS))
    fit_rms = np.sqrt((np.linalg.norm(reprojection_offsets(embedding, stacked, faces, fit), axis=2) ** 2).mean(0))
    figures = {
        "triangulation_px": residual.mean(0),
        "pair_residual_px": pair_residual,
        "hull_layer": layers,
        "offset_mm": offset.mean(0),
        "fit_rms_px": fit_rms,
    }
    return embedding, figures


def figures_of(asset, embedding, fit_figures: dict, after: np.ndarray, before: np.ndarray, ev: dict) -> dict:
    """The record: per region before/after, the contour points against MediaPipe's oval, the mirror gaps
    (mm, between each non-contour point's mirror image and its mutual partner), per point figures."""
    regions = point_regions(embedding, asset, embedding.contour)
    extra = {k: fit_figures[k] for k in ("offset_mm", "fit_rms_px")}
    positions = landmark_positions(asset.vertices, embedding, asset.faces)[0]
    partner, mutual = mirror_partners(positions)
    gap = np.linalg.norm(positions * np.array([-1.0, 1.0, 1.0]) - positions[partner], axis=1)
    pairs = mutual & (partner != np.arange(N_POINTS)) & ~embedding.contour & ~embedding.contour[partner]
    flagged = np.flatnonzero(embedding.contour)
    per_view = np.linalg.norm(after[:, ~embedding.contour], axis=2).mean(1)
    return {
        "regions_px_at_iod100": {
            "before": region_summary(before, regions),
            "after": region_summary(after, regions, extra),
        },
        "all_but_contour_per_view": {
            "template, other draws": round(float(per_view[ev["head"] == 0].mean()), 2),
            "test heads 3-5": round(float(per_view[ev["head"] > 0].mean()), 2),
            "min": round(float(per_view.min()), 2),
            "max": round(float(per_view.max()), 2),
        },
        "dlib_corrected_ibug68": DLIB_CORRECTED,
        "contour": {
            "threshold_px": CONTOUR_RESIDUAL_PX,
            "periphery_hull_layers": PERIPHERY_LAYERS,
            "count": int(flagged.size),
            "in_mediapipe_face_oval": int(np.isin(flagged, MEDIAPIPE_FACE_OVAL).sum()),
            "flagged_not_in_oval": [int(k) for k in flagged if k not in MEDIAPIPE_FACE_OVAL],
            "oval_not_flagged": [int(k) for k in MEDIAPIPE_FACE_OVAL if k not in flagged],
            "indices": flagged.tolist(),
        },
        "mirror_gap_mm": {
            "points": int(pairs.sum()),
            "median": round(float(np.median(gap[pairs])), 2),
            "p95": round(float(np.percentile(gap[pairs], 95)), 2),
            "max": round(float(gap[pairs].max()), 2),
        },
        "points": {
            "region": regions.tolist(),
            "sigma_px": np.round(embedding.sigma_px, 2).tolist(),
            "bias_px": np.round(np.linalg.norm(after.mean(0), axis=1), 2).tolist(),
            **{k: np.round(v, 2).tolist() for k, v in fit_figures.items()},
        },
    }


def print_report(record: dict) -> None:
    regions = record["regions_px_at_iod100"]
    print(f"{'region':16s} {'points':>6} | {'before: bias':>12} {'error':>6} | {'after: bias':>11} {'error':>6} "
          f"{'offset mm':>9} {'fit rms':>7}   (px at IOD 100, evaluation views)")  # fmt: skip
    for name, b in regions["before"].items():
        a = regions["after"][name]
        print(
            f"{name:16s} {a['points']:6d} | {b['bias']:12.2f} {b['error']:6.2f} | {a['bias']:11.2f} {a['error']:6.2f} "
            f"{a['offset_mm']:9.2f} {a['fit_rms_px']:7.2f}"
        )
    print(f"all but contour, mean error per view: {record['all_but_contour_per_view']}")
    print(f"dlib against the corrected iBUG-68 embedding (docs/landmarks.md): {record['dlib_corrected_ibug68']}")
    contour = record["contour"]
    print(f"contour: {contour['count']} flagged, {contour['in_mediapipe_face_oval']} of them on MediaPipe's 36-point "
          f"oval; oval points not flagged: {contour['oval_not_flagged']}")  # fmt: skip
    print(f"mirror gaps of non-contour pairs, mm: {record['mirror_gap_mm']}")
    print(f"seconds: {record['seconds']}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help=f"write {EMBEDDING_TABLE.name}")
    parser.add_argument("--json", type=Path, default=None, help="write the figures to this file")
    parser.add_argument("--fresh", action="store_true", help="re-render the views")
    parser.add_argument("--cache", type=Path, default=None, help="folder of the cached renders")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    asset = load_asset()
    data = {role: render_views(role, args.cache, args.fresh) for role in ("fit", "eval")}
    t_render = time.perf_counter() - start
    dense = {role: detect_dense(d["images"], d["truth"]) for role, d in data.items()}
    vertices = head_vertices(sorted(set(FIT_HEADS + EVAL_HEADS)), asset)
    fit = view_set(data["fit"], dense["fit"], FIT_HEADS, vertices, asset)
    ev = view_set(data["eval"], dense["eval"], EVAL_HEADS, vertices, asset)
    found = {"fit": len(fit["head"]), "evaluation": len(ev["head"])}
    renders = {"fit": len(data["fit"]["yaw"]), "evaluation": len(data["eval"]["yaw"])}
    print(f"MediaPipe found the face in {found} of {renders} views")
    eval_stacked = np.stack([vertices[h] for h in EVAL_HEADS])

    t_fit = time.perf_counter()
    embedding, fit_figures = fit_embedding(asset, fit, np.stack([vertices[h] for h in FIT_HEADS]))
    t_fit = time.perf_counter() - t_fit
    after = reprojection_offsets(embedding, eval_stacked, asset.faces, ev)
    sigma = np.sqrt((np.linalg.norm(after, axis=2) ** 2).mean(0))
    embedding = DenseEmbedding(embedding.faces, embedding.barycentric, embedding.contour, sigma)
    frontal = int(np.flatnonzero((fit["head"] == 0) & (fit["yaw"] == 0) & (fit["pitch"] == 0))[0])
    before = reprojection_offsets(
        naive_placement(fit["uv"][frontal], fit["cams"][frontal], asset), eval_stacked, asset.faces, ev
    )

    record = {"renders": renders, "found": found, **figures_of(asset, embedding, fit_figures, after, before, ev)}
    rendered = sum(float(d["render_s"]) for d in data.values())  # as measured when the renders were made
    record["seconds"] = {
        "render": round(rendered, 1),
        "render_cached": t_render < 0.5 * rendered,
        "detect_fit_measure": round(time.perf_counter() - start - t_render, 1),
        "fit": round(t_fit, 1),
    }
    print_report(record)
    if args.write:
        write_embedding_table(embedding, asset, EMBEDDING_TABLE)
        print(f"wrote {EMBEDDING_TABLE}")
    if args.json:
        record.update(
            settings={"render": repr(SETTINGS), "fit_heads": FIT_HEADS, "eval_heads": EVAL_HEADS},
            machine=f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
            command=sys.argv,
        )
        args.json.write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
