"""Named 3D landmarks on the template, for point clouds that come with landmarks (``--landmarks``).

Each landmark is one template vertex, found from the template's own structure (eye and mouth loops,
regions), so it follows the template if it is regenerated. Order and names are fixed
(:data:`LANDMARK_NAMES_3D`); a golden test pins the vertex ids. :func:`check_landmarks_3d` rejects
landmarks that cannot be a face on the cloud (coincident, wrongly scaled, not face-like or mirrored,
turned away from the scanner, off the cloud) before they steer a fit.

=====================  =========================================================
name                   vertex
=====================  =========================================================
left_eye_outer/inner   corners of the left (+X) eyelid loop (outer = larger |x|)
right_eye_inner/outer  the same on the right
nose_tip               the most forward nose vertex
mouth_left/right       the lip-loop corners
chin                   the lowest midline vertex of the chin region
=====================  =========================================================
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from rig.asset import RigAsset, load_asset
from rig.errors import InputError
from rig.template import rim_halves

LANDMARK_NAMES_3D: tuple[str, ...] = (
    "left_eye_outer",
    "left_eye_inner",
    "right_eye_inner",
    "right_eye_outer",
    "nose_tip",
    "mouth_left",
    "mouth_right",
    "chin",
)


class LandmarkError(InputError):
    """Unknown landmark names, too few landmarks, or landmarks that are not a plausible face on the cloud."""


def landmark_vertices(asset: RigAsset | None = None) -> dict[str, int]:
    """``{name: vertex id}`` of the 3D landmarks, in :data:`LANDMARK_NAMES_3D` order."""
    asset = load_asset() if asset is None else asset
    v = asset.vertices
    out: dict[str, int] = {}
    for side, loop in zip(("left", "right"), asset.eye_loops):
        upper, _ = rim_halves(v, loop)
        corners = upper[[0, -1]]
        outer = int(corners[np.argmax(np.abs(v[corners, 0]))])
        inner = int(corners[np.argmin(np.abs(v[corners, 0]))])
        out[f"{side}_eye_outer"], out[f"{side}_eye_inner"] = outer, inner
    nose = np.flatnonzero(asset.region_mask("nose"))
    out["nose_tip"] = int(nose[np.argmax(v[nose, 2])])
    corners = rim_halves(v, asset.mouth_loop)[0][[0, -1]]
    out["mouth_left"] = int(corners[np.argmax(v[corners, 0])])
    out["mouth_right"] = int(corners[np.argmin(v[corners, 0])])
    chin = np.flatnonzero(asset.region_mask("chin") & (np.abs(v[:, 0]) < 3.0))
    out["chin"] = int(chin[np.argmin(v[chin, 1])])
    return {name: out[name] for name in LANDMARK_NAMES_3D}


def match_landmarks(
    points: Mapping[str, np.ndarray], asset: RigAsset | None = None, minimum: int = 3
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """Pair named cloud landmarks with template vertices.

    Args:
        points: ``{name: (3,) position}`` in the cloud's frame, mm.
        minimum: fewest landmarks accepted (3 fix a similarity transform).

    Returns:
        ``(vertex_ids (L,), positions (L, 3), names)`` in :data:`LANDMARK_NAMES_3D` order.

    Raises:
        LandmarkError: an unknown name, or fewer than ``minimum`` landmarks.
    """
    ids = landmark_vertices(asset)
    unknown = sorted(set(points) - set(ids))
    if unknown:
        raise LandmarkError(f"unknown 3D landmark name(s) {unknown}; known: {list(LANDMARK_NAMES_3D)}")
    names = tuple(n for n in LANDMARK_NAMES_3D if n in points)
    if len(names) < minimum:
        raise LandmarkError(f"need at least {minimum} landmarks, got {len(names)} ({list(names)})")
    return (
        np.array([ids[n] for n in names], dtype=np.int64),
        np.array([np.asarray(points[n], float) for n in names]),
        names,
    )


# ------------------------------------------------------------------------------------------ plausibility
#
# The thresholds below were chosen from measurements of the 8 landmarks (and random subsets of 3-8) of
# the 100 held-out synthetic heads (pipeline.synthetic.expressive.expressive_split("heldout"), random expressions, and
# their neutral versions) against the template's: each set scaled by U(0.8, 1.25), turned by a uniformly
# random rotation, moved, with 0 or 3 mm Gaussian noise per coordinate (2600 sets per setting); and, for
# the cloud checks, the true landmarks (3 mm noise) on 90 simulated scans (pipeline.synthetic.scans,
# default holes and outliers, 320x288 and 640x576 cameras, a third of the heads yawed up to +-80 deg,
# stored or estimated normals; 61 landmark subsets per scan).

MIN_SEPARATION_MM = 5.0
"""Closest two landmarks may be, mm. Measured: at least 13.5 mm (two eye corners of a small head with
3 mm noise); 0 for coincident points."""
SCALE_RANGE = (0.5, 2.0)
"""Accepted scale of the similarity from the template's landmarks to the given ones. Measured on the
perturbed sets: 0.70-1.48 (the applied 0.8-1.25 times the heads' own size); a unit mistake gives 10 or
more (0.1 or less)."""
MAX_SHAPE_RESIDUAL = 0.35
"""Largest RMS residual of that similarity, as a fraction of the given landmarks' RMS radius (about
50 mm on a head). Measured: at most 0.24 on the perturbed sets (4 landmarks, 3 mm noise), 0.19 for
all 8; a reflection of all 8 leaves at least 0.43 (the nose tip is out of the plane of the others)."""
MAX_CLOUD_DISTANCE_MM = 75.0
"""Farthest a landmark may be from its nearest cloud point, mm. Measured with the true landmarks: 3 mm
median, 22 mm 95th percentile, 42 mm at most (50 mm on 40 other scans): a landmark in one of the scan's
holes. Landmarks in another frame than the cloud, or of another scan, are typically 100 mm or more off."""
MIN_FACING = 0.0
"""Smallest cosine between the face direction the landmarks give (the template's +Z turned by the
similarity) and the cloud's viewing direction (its mean normal), when the cloud has one: a face turned
more than 90 deg from the scanner cannot have been seen. Measured with the true landmarks: at least
+0.08 with 5 or more (heads turned up to 80 deg); below 0 for 0.2 % of the sets of 4 and 1 % of the
triples (nearly collinear ones, whose rotation is poorly determined). With left and right labels
swapped, this check and the shape check reject 100 % of the sets of 6-8, 97 % of 5, 89 % of 4 and
66 % of 3."""


@dataclass(frozen=True)
class LandmarkCheck:
    """What :func:`check_landmarks_3d` measured (for accepted landmarks)."""

    names: tuple[str, ...]
    """The landmarks checked, in the order given."""
    min_separation_mm: float
    """Distance of the closest two landmarks, mm."""
    scale: float
    """Scale of the best similarity from the reference landmarks to the given ones."""
    shape_residual: float
    """RMS residual of that similarity (a rotation), as a fraction of the given landmarks' RMS radius."""
    mirrored_residual: float
    """The same for the best similarity with a reflection (smaller than ``shape_residual`` when mirrored)."""
    facing: float | None
    """Cosine between the face direction and the cloud's viewing direction (None when not known)."""
    cloud_distance_mm: np.ndarray | None
    """``(L,)`` distance of each landmark to its nearest cloud point, mm (None without a cloud)."""


def fit_similarity(reference: np.ndarray, points: np.ndarray) -> tuple[float, np.ndarray, float, float]:
    """Best similarity ``points ~ s R reference + t`` (a rotation), and the residual of the best reflection.

    With ``A``, ``B`` the centred point sets, ``B^T A = U diag(d) V^T`` and ``sign = det U det V`` (the
    sign of ``det B^T A``, defined also for coplanar points where ``d3 = 0``), the best proper similarity
    (Umeyama 1991, the same as :meth:`rig.geometry.Similarity.fit`) is
    ``R = U diag(1, 1, sign) V^T``, ``s = (d1 + d2 + sign d3) / |A|^2``, leaving ``|B|^2 - s^2 |A|^2`` as
    the sum of squared residuals; the best improper one (``det R = -1``) has ``-sign d3`` instead.

    Args:
        reference: ``(L, 3)`` reference landmarks (e.g. the template's), mm, L >= 3.
        points: ``(L, 3)`` the same landmarks elsewhere, mm.

    Returns:
        ``(scale, rotation (3, 3), rms_proper, rms_improper)``: the proper similarity and the RMS
        residuals (mm) of both fits.

    Example:
        >>> ref = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
        >>> s, _, proper, improper = fit_similarity(ref, 2.0 * ref * [-1, 1, 1])  # scaled and mirrored
        >>> round(s, 3), round(improper, 9) == 0.0, proper > 0.3
        (1.556, True, True)
    """
    a = np.asarray(reference, dtype=np.float64)
    b = np.asarray(points, dtype=np.float64)
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    cross = b.T @ a
    u, d, vt = np.linalg.svd(cross)
    sign = 1.0 if np.linalg.det(u) * np.linalg.det(vt) >= 0 else -1.0
    var_a, var_b = max(float((a**2).sum()), 1e-300), float((b**2).sum())
    rms = [
        float(np.sqrt(max(var_b - (d[0] + d[1] + third) ** 2 / var_a, 0.0) / len(a)))
        for third in (sign * d[2], -sign * d[2])
    ]
    rotation = u @ np.diag([1.0, 1.0, sign]) @ vt
    return float((d[0] + d[1] + sign * d[2]) / var_a), rotation, rms[0], rms[1]


def check_landmarks_3d(
    points: np.ndarray,
    names: Sequence[str],
    *,
    reference: np.ndarray | None = None,
    asset: RigAsset | None = None,
    cloud: np.ndarray | None = None,
    view_direction: np.ndarray | None = None,
    source: str = "--landmarks",
) -> LandmarkCheck:
    """Reject 3D landmarks that cannot be this face on this cloud, with a one-line :class:`LandmarkError`.

    The checks, in order (the first failing one raises; thresholds and how they were chosen: the
    module's constants):

    1. **head-sized**: the scale of the best similarity from the reference landmarks is within
       :data:`SCALE_RANGE` (tested first only when the landmarks are face-shaped or distinct, so that
       a face in other units is reported as such and coincident points as in 2.).
    2. **distinct**: no two landmarks closer than :data:`MIN_SEPARATION_MM`.
    3. **face-like, not mirrored**: that similarity (a rotation, never a reflection) leaves an RMS residual
       of at most :data:`MAX_SHAPE_RESIDUAL` of the landmarks' RMS radius; the message says "mirrored"
       when a reflection would fit. A reflection is visible here only when the landmarks are not
       (nearly) coplanar: with the nose tip and 4 or more others; 3 landmarks always fit both ways.
    4. **facing the scanner** (with ``view_direction``): the face direction the similarity gives has a
       cosine of at least :data:`MIN_FACING` with it; this catches swapped left/right labels on
       (nearly) coplanar landmarks, where 3. cannot.
    5. **on the cloud** (with ``cloud``): every landmark within :data:`MAX_CLOUD_DISTANCE_MM` of a cloud
       point.

    Args:
        points: ``(L, 3)`` landmark positions, mm, in the cloud's frame (as :func:`match_landmarks` returns them).
        names: their names (:data:`LANDMARK_NAMES_3D`), in the same order.
        reference: ``(L, 3)`` the same landmarks on the head the fit starts from, in rig space (mm, +Z out
            of the face); default the template's vertices (:func:`landmark_vertices`).
        asset: the template (default :func:`rig.asset.load_asset`), used when ``reference`` is None.
        cloud: ``(N, 3)`` the cloud, mm, or None to skip check 5.
        view_direction: ``(3,)`` the direction the scanned surface faces (towards the scanner, e.g. the
            unit mean normal of a single-view scan), or None to skip check 4.
        source: how messages name the landmarks (e.g. the file).

    Returns:
        :class:`LandmarkCheck`.

    Raises:
        LandmarkError: the first check that fails, saying what was measured and what is accepted.

    Example:
        >>> from rig.asset import load_asset
        >>> asset = load_asset()
        >>> ids = landmark_vertices(asset)
        >>> marks = np.array([asset.vertices[i] for i in ids.values()])
        >>> round(check_landmarks_3d(marks * 1.1, list(ids)).scale, 3)
        1.1
        >>> check_landmarks_3d(marks[:3] * 0 + 1.0, list(ids)[:3])
        Traceback (most recent call last):
        ...
        landmarks.points3d.LandmarkError: --landmarks: 'left_eye_outer' and 'left_eye_inner' are 0 mm apart ...
    """
    points = np.asarray(points, dtype=np.float64)
    names = tuple(names)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) != len(names) or len(points) < 3:
        raise LandmarkError(
            f"check_landmarks_3d: points must be (L >= 3, 3) with one name each, got "
            f"{points.shape} and {len(names)} names"
        )
    if reference is None:
        asset = load_asset() if asset is None else asset
        ids = landmark_vertices(asset)
        reference = asset.vertices[[ids[n] for n in names]]
    reference = np.asarray(reference, dtype=np.float64)
    if reference.shape != points.shape:
        raise LandmarkError(f"check_landmarks_3d: reference must have shape {points.shape}, got {reference.shape}")

    gaps = np.linalg.norm(points[:, None] - points[None], axis=-1)
    gaps[np.diag_indices(len(points))] = np.inf
    i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
    separation = float(gaps[i, j])
    scale, rotation, proper, improper = fit_similarity(reference, points)
    radius = float(np.sqrt(((points - points.mean(axis=0)) ** 2).sum(axis=1).mean()))
    shape, mirrored = (proper / radius, improper / radius) if radius > 0 else (np.inf, np.inf)
    sized = SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]
    # A face of the wrong size is reported as such (units), even when its points are close together.
    if not sized and (shape <= MAX_SHAPE_RESIDUAL or separation >= MIN_SEPARATION_MM):
        raise LandmarkError(
            f"{source}: the landmarks are {scale:.3g} x the size of the template's (accepted "
            f"{SCALE_RANGE[0]:g}-{SCALE_RANGE[1]:g}); are they in the cloud's units?"
        )
    if separation < MIN_SEPARATION_MM:
        raise LandmarkError(
            f"{source}: {names[i]!r} and {names[j]!r} are {separation:.3g} mm apart (at least "
            f"{MIN_SEPARATION_MM:g} mm needed); the landmarks must be distinct points of the face"
        )
    if shape > MAX_SHAPE_RESIDUAL:
        if mirrored <= MAX_SHAPE_RESIDUAL:
            raise LandmarkError(
                f"{source}: the landmarks look mirrored: a reflection of the template's fits them "
                f"(residual {100 * mirrored:.0f} % of their size), no rotation does "
                f"({100 * shape:.0f} %, at most {100 * MAX_SHAPE_RESIDUAL:.0f} % accepted); are "
                f"left and right swapped, or is the file in a left-handed frame?"
            )
        raise LandmarkError(
            f"{source}: the landmarks are not face-like: after the best similarity to the "
            f"template's they are off by {100 * shape:.0f} % of their size (at most "
            f"{100 * MAX_SHAPE_RESIDUAL:.0f} % accepted); are they named correctly?"
        )
    facing = None
    if view_direction is not None:
        view = np.asarray(view_direction, dtype=np.float64)
        facing = float(rotation[:, 2] @ view / max(np.linalg.norm(view), 1e-300))
        if facing < MIN_FACING:
            angle = float(np.degrees(np.arccos(np.clip(facing, -1.0, 1.0))))
            raise LandmarkError(
                f"{source}: the landmarks turn the face {angle:.0f} deg away from the scanner"
                f" (the cloud's mean normal; at most 90 deg accepted); are left and right "
                f"swapped, the landmarks in another frame than the cloud, or too few and nearly "
                f"collinear to fix the face's rotation?"
            )
    distances = None
    if cloud is not None:
        distances, _ = cKDTree(np.asarray(cloud, dtype=np.float64)).query(points)
        far = int(np.argmax(distances))
        if distances[far] > MAX_CLOUD_DISTANCE_MM:
            raise LandmarkError(
                f"{source}: {names[far]!r} is {distances[far]:.3g} mm from the nearest cloud point "
                f"(at most {MAX_CLOUD_DISTANCE_MM:g} mm accepted); are the landmarks in the cloud's "
                f"units and frame?"
            )
    return LandmarkCheck(names, separation, scale, shape, mirrored, facing, distances)
