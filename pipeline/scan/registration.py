"""Geometry for registering the rig to point clouds: closest points among the faces around a vertex (the
fit's fast local search; exact point-to-mesh distances are :func:`rig.geometry.closest_surface_points`), and
the robust rigid pre-alignment of a head mesh to a cloud.

Conventions: millimetres; a similarity transform maps rig space to the cloud's frame as
``x_cloud = scale * R @ x_rig + t``; every array is float64 numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from rig.geometry import (
    Similarity,
    barycentric,
    closest_points_on_triangles,
    head_rotation,
    vertex_normals,
)

# ----------------------------------------------------------------------------------------------------
# Mesh geometry
# ----------------------------------------------------------------------------------------------------


def incident_faces(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """``(V, W)`` ids of the faces around each vertex (padded with -1)."""
    faces = np.asarray(faces, dtype=np.int64)
    order = np.argsort(faces.ravel(), kind="stable")
    vert_of = faces.ravel()[order]
    counts = np.bincount(vert_of, minlength=num_vertices)
    table = -np.ones((num_vertices, max(int(counts.max()), 1)), dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    table[vert_of, np.arange(len(order)) - np.repeat(starts, counts)] = order // 3
    return table


def closest_on_one_ring(
    points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, incident: np.ndarray, nearest: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest surface points among the faces around each point's nearest vertex.

    Args:
        points: ``(N, 3)``; vertices: ``(V, 3)``; faces: ``(F, 3)``; incident: :func:`incident_faces`;
        nearest: ``(N,)`` id of each point's nearest vertex.

    Returns:
        ``(face (N,), bary (N, 3), closest (N, 3))``: ``closest = sum_i bary_i * vertices[faces[face, i]]``.
    """
    cand = incident[nearest]  # (N, W), -1 padded (a few pole vertices make W large: work on the valid pairs)
    rows, cols = np.nonzero(cand >= 0)
    face_of = cand[rows, cols]
    tri = vertices[faces[face_of]]  # (M, 3, 3)
    q = closest_points_on_triangles(points[rows], tri[:, 0], tri[:, 1], tri[:, 2])
    d2 = ((q - points[rows]) ** 2).sum(-1)
    order = np.lexsort((d2, rows))  # by point, then by distance
    first = order[np.r_[0, np.flatnonzero(np.diff(rows[order])) + 1]]
    face = face_of[first]
    closest = q[first]
    t = vertices[faces[face]]
    bary = np.clip(barycentric(closest, t[:, 0], t[:, 1], t[:, 2]), 0.0, 1.0)
    bary /= bary.sum(1, keepdims=True)
    return face, bary, closest


# ----------------------------------------------------------------------------------------------------
# Rigid pre-alignment
# ----------------------------------------------------------------------------------------------------


SCALE_BOUNDS = (0.85, 1.2)
"""The scales :func:`rigid_prealign` allows the head model (a head 15 % smaller to 20 % larger than the rig's)."""
INLIER_MM = 8.0
"""A cloud point within this distance (mm) of the aligned head model is an inlier."""


@dataclass(frozen=True)
class RigidAlignment:
    """Result of :func:`rigid_prealign`: rig space -> cloud frame, ``x = scale * R @ x_rig + t``.

    Attributes:
        rotation: ``(3, 3)``; translation: ``(3,)`` mm; scale: unitless.
        rms_mm: RMS distance of the inlier points (within ``inlier_mm``) after alignment.
        inlier_fraction: fraction of (subsampled) cloud points within ``inlier_mm`` of the model.
        hypotheses: number of initial orientations tried.
        score: the truncated-quadratic score of the chosen hypothesis (lower is better), mm^2.
    """

    rotation: np.ndarray
    translation: np.ndarray
    scale: float
    rms_mm: float
    inlier_fraction: float
    hypotheses: int
    score: float

    @property
    def transform(self) -> Similarity:
        """The alignment as a :class:`rig.geometry.Similarity` (rig space -> cloud frame)."""
        return Similarity(self.rotation, self.translation, self.scale)


def view_direction(normals: np.ndarray, min_length: float = 0.3) -> np.ndarray | None:
    """The direction towards the sensor of a single-view scan: the mean of its ``(N, 3)`` unit normals (which
    face the sensor), normalised; None when the mean is shorter than ``min_length`` (a cloud all around the
    head has no one viewing direction)."""
    mean = np.asarray(normals, float).mean(0)
    length = float(np.linalg.norm(mean))
    return mean / length if length > min_length else None


def _trimmed_icp(
    cloud: np.ndarray,
    cloud_n: np.ndarray | None,
    tree: cKDTree,
    model_n: np.ndarray,
    model_v: np.ndarray,
    rot: np.ndarray,
    t: np.ndarray,
    scale: float,
    iterations: int,
    trim: float,
    with_scale: bool,
    scale_bounds: tuple[float, float],
    min_normal_dot: float,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Point-to-point trimmed ICP of the cloud onto the model; returns ``(R, t, scale, score)``."""
    for it in range(iterations + 1):
        q = Similarity(rot, t, scale).apply_inverse(cloud)
        d, j = tree.query(q)
        ok = np.ones(len(q), bool)
        if cloud_n is not None:
            ok &= (cloud_n @ rot * model_n[j]).sum(1) >= min_normal_dot
        score = float(np.mean(np.where(ok, np.minimum(d, 10.0) ** 2, 100.0)))
        if it == iterations:
            break
        if ok.sum() < 10:
            break
        keep = ok & (d <= np.quantile(d[ok], trim))
        fitted = Similarity.fit(model_v[j[keep]], cloud[keep], with_scale=with_scale)
        r, tt, s = fitted.rotation, fitted.translation, fitted.scale
        if with_scale:
            s = float(np.clip(s, *scale_bounds))
            if not scale_bounds[0] < s < scale_bounds[1]:
                tt = (cloud[keep] - s * model_v[j[keep]] @ r.T).mean(0)
        rot, t, scale = r, tt, s
    return rot, t, scale, score


def pose_hypotheses(
    model_v: np.ndarray,
    model_n: np.ndarray,
    centroid: np.ndarray,
    face_centroid: np.ndarray,
    mean_n: np.ndarray | None,
    *,
    landmarks: tuple[np.ndarray, np.ndarray] | None,
    with_scale: bool,
    scale_bounds: tuple[float, float],
    yaw_step_deg: float,
    pitches_deg: tuple[float, ...],
    rolls_deg: tuple[float, ...],
    facing_min: float,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The starts of :func:`rigid_prealign`: ``(rotation (3, 3), translation (3,) mm, scale)`` for every
    yaw, pitch and roll whose face turns towards the viewer (``mean_n``, the cloud's mean normal, when
    known), placed so that the centroid of the model part facing the viewer meets the cloud's
    ``centroid``; or the one similarity of the ``landmarks`` (model points, cloud points)."""
    if landmarks is not None:
        src, dst = (np.asarray(a, float) for a in landmarks)
        s = Similarity.fit(src, dst, with_scale=with_scale)
        return [(s.rotation, s.translation, float(np.clip(s.scale, *scale_bounds)) if with_scale else 1.0)]
    candidates: list[tuple[np.ndarray, np.ndarray, float]] = []
    for yaw in np.arange(0.0, 360.0, yaw_step_deg):
        for pitch in pitches_deg:
            for roll in rolls_deg:
                rot = head_rotation(yaw, pitch, roll)
                face_dir = rot @ np.array([0.0, 0.0, 1.0])
                if mean_n is not None and face_dir @ mean_n < facing_min:
                    continue  # the face would point (nearly) away from the viewer
                if mean_n is not None:
                    facing = (model_n @ (rot.T @ mean_n)) > 0.3
                    c_model = model_v[facing].mean(0) if facing.sum() > 50 else face_centroid
                else:
                    c_model = face_centroid
                candidates.append((rot, centroid - rot @ c_model, 1.0))
    return candidates


def _rank_coarse(
    points: np.ndarray,
    normals: np.ndarray | None,
    candidates: list[tuple[np.ndarray, np.ndarray, float]],
    tree: cKDTree,
    model_n: np.ndarray,
    model_v: np.ndarray,
    iterations: int,
    trim: float,
    scale_bounds: tuple[float, float],
    min_dot: float,
) -> list[tuple[float, np.ndarray, np.ndarray, float]]:
    """Each start after rigid trimmed ICP on the coarse ``(n, 3)`` mm points: ``(score, R, t, scale)``, best first."""
    scored = []
    for rot, t, s in candidates:
        r, tt, ss, score = _trimmed_icp(
            points,
            normals,
            tree,
            model_n,
            model_v,
            rot,
            t,
            s,
            iterations,
            trim,
            False,
            scale_bounds,
            min_dot,
        )
        scored.append((score, r, tt, ss))
    scored.sort(key=lambda x: x[0])
    return scored


def _refine_best(
    points: np.ndarray,
    normals: np.ndarray | None,
    best_coarse: list[tuple[float, np.ndarray, np.ndarray, float]],
    tree: cKDTree,
    model_n: np.ndarray,
    model_v: np.ndarray,
    vertical_shifts_mm: tuple[float, ...],
    iterations: int,
    trim: float,
    with_scale: bool,
    scale_bounds: tuple[float, float],
    min_dot: float,
) -> tuple[float, np.ndarray, np.ndarray, float]:
    """The best ``(score, R, t, scale)`` of ICP on the fine ``(n, 3)`` mm points from each start and vertical shift."""
    best = None
    # Refine the best few, each also shifted along the head's vertical axis (ICP on a partial face
    # can settle with the face slid up or down by a feature, e.g. the chin matched to the mouth).
    for _score0, r, tt, ss in best_coarse:
        for shift in vertical_shifts_mm:
            r1, t1, s1, score = _trimmed_icp(
                points,
                normals,
                tree,
                model_n,
                model_v,
                r,
                tt + shift * (r @ np.array([0.0, 1.0, 0.0])),
                ss,
                iterations,
                trim,
                with_scale,
                scale_bounds,
                min_dot,
            )
            if best is None or score < best[0]:
                best = (score, r1, t1, s1)
    return best


def _inlier_fit(
    points: np.ndarray, tree: cKDTree, rot: np.ndarray, t: np.ndarray, s: float, inlier_mm: float
) -> tuple[float, float]:
    """RMS distance (mm; inf if none) of the ``(n, 3)`` points within ``inlier_mm`` of the model, and their share."""
    q = Similarity(rot, t, s).apply_inverse(points)
    d, _ = tree.query(q)
    d = d * s
    inl = d <= inlier_mm
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    return rms, float(inl.mean())


def rigid_prealign(
    cloud: np.ndarray,
    cloud_normals: np.ndarray | None,
    model_vertices: np.ndarray,
    model_faces: np.ndarray,
    *,
    face_mask: np.ndarray | None = None,
    seed: int = 0,
    yaw_step_deg: float = 20.0,
    pitches_deg: tuple[float, ...] = (-20.0, 0.0, 20.0),
    rolls_deg: tuple[float, ...] = (0.0,),
    coarse_points: int = 1500,
    coarse_iterations: int = 15,
    fine_points: int = 5000,
    fine_iterations: int = 40,
    trim: float = 0.8,
    with_scale: bool = True,
    scale_bounds: tuple[float, float] = SCALE_BOUNDS,
    inlier_mm: float = INLIER_MM,
    landmarks: tuple[np.ndarray, np.ndarray] | None = None,
    vertical_shifts_mm: tuple[float, ...] = (0.0, -30.0, 30.0),
    facing_min: float = 0.3,
    refine_best: int = 3,
) -> RigidAlignment:
    """Robust rigid (similarity) alignment of a head mesh to a partial scan.

    Nothing is assumed about where the cloud is or which way the face points about the vertical: the
    model is tried in every yaw (``yaw_step_deg`` apart, the whole circle) at a few pitches and rolls,
    each hypothesis placed so that the centroid of the model part facing the viewer meets the cloud's
    centroid and refined by trimmed ICP (normals must agree when the cloud has them); the best by a
    truncated-quadratic score is refined on more points, with the scale if ``with_scale``. The cloud's
    +Y is taken as roughly up (within the pitches and rolls tried). With ``landmarks`` (model points,
    cloud points, each ``(L, 3)``, L >= 3) the landmarks' similarity replaces the search.

    Args:
        cloud: ``(N, 3)`` mm; cloud_normals: optional ``(N, 3)`` unit normals facing the viewer.
        model_vertices: ``(V, 3)`` rig-space vertices; model_faces: ``(F, 3)``.
        face_mask: optional ``(V,)`` bool of the face region (centroid fallback when the cloud has no
            dominant viewing direction).
        vertical_shifts_mm: offsets along the head's vertical axis tried when refining the best
            hypotheses.
        refine_best: how many of the best coarse hypotheses are refined.
        facing_min: hypotheses whose face direction has a smaller cosine with the cloud's mean normal
            (the viewing direction of a single-view scan) are skipped.

    Returns:
        :class:`RigidAlignment`.
    """
    rng = np.random.default_rng(seed)
    cloud = np.asarray(cloud, float)
    model_v = np.asarray(model_vertices, float)
    model_n = vertex_normals(model_v, model_faces)
    tree = cKDTree(model_v)

    def pick(n: int) -> np.ndarray:
        return np.sort(rng.choice(len(cloud), size=n, replace=False)) if len(cloud) > n else np.arange(len(cloud))

    coarse = pick(coarse_points)
    fine = pick(fine_points)
    cn_all = None if cloud_normals is None else np.asarray(cloud_normals, float)
    min_dot = 0.2
    mean_n = None if cn_all is None else view_direction(cn_all)
    centroid = cloud.mean(0)
    face_centroid = model_v[face_mask].mean(0) if face_mask is not None else model_v.mean(0)

    candidates = pose_hypotheses(
        model_v,
        model_n,
        centroid,
        face_centroid,
        mean_n,
        landmarks=landmarks,
        with_scale=with_scale,
        scale_bounds=scale_bounds,
        yaw_step_deg=yaw_step_deg,
        pitches_deg=pitches_deg,
        rolls_deg=rolls_deg,
        facing_min=facing_min,
    )
    cn_coarse = None if cn_all is None else cn_all[coarse]
    scored = _rank_coarse(
        cloud[coarse], cn_coarse, candidates, tree, model_n, model_v, coarse_iterations, trim, scale_bounds, min_dot
    )
    cn_fine = None if cn_all is None else cn_all[fine]
    score, rot, t, s = _refine_best(
        cloud[fine],
        cn_fine,
        scored[:refine_best],
        tree,
        model_n,
        model_v,
        vertical_shifts_mm,
        fine_iterations,
        trim,
        with_scale,
        scale_bounds,
        min_dot,
    )
    rms, inlier_fraction = _inlier_fit(cloud[fine], tree, rot, t, s, inlier_mm)
    return RigidAlignment(rot, t, float(s), rms, inlier_fraction, len(candidates), float(score))


def face_coverage(
    cloud_tree,
    alignment: RigidAlignment,
    model_vertices: np.ndarray,
    model_faces: np.ndarray,
    face_mask: np.ndarray,
    view_dir: np.ndarray | None,
    radius_mm: float = INLIER_MM,
) -> float:
    """The share of the aligned head model's face that the cloud covers: the face vertices (``face_mask``)
    facing the sensor (``view_dir``, all of them for None) with a cloud point within ``radius_mm``.

    The inlier fraction of :class:`RigidAlignment` asks the opposite question (how much of the cloud lies
    on the head): a cloud shrunk by wrong units lies on a patch of the head and scores well there, but
    covers half of the face or less (``docs/fit_scan.md``, "Checks of the frame and units").

    Args:
        cloud_tree: a ``scipy.spatial.cKDTree`` of the ``(N, 3)`` cloud, mm.
        alignment: rig space -> cloud frame; model_vertices: ``(V, 3)`` rig space, mm; model_faces: ``(F, 3)``.
        face_mask: ``(V,)`` bool; view_dir: ``(3,)`` unit direction towards the sensor, or None.

    Returns:
        A fraction in [0, 1] (0 when no face vertex faces the sensor).
    """
    v = alignment.transform.apply(np.asarray(model_vertices, float))
    keep = np.asarray(face_mask, bool).copy()
    if view_dir is not None:
        keep &= vertex_normals(v, model_faces) @ view_dir > 0.3
    if not keep.any():
        return 0.0
    d, _ = cloud_tree.query(v[keep])
    return float((d <= radius_mm).mean())
