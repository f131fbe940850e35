"""The static jaw contour: the frontal outline of the face's side, the 17 contour vertices on it, and per
contour landmark the line of candidate vertices the dynamic contour picks from."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from landmarks.ibug68.corrections import CONTOUR_ANGLES_DEG
from landmarks.ibug68.names import CHIN
from rig.asset import RigAsset, cached_per_asset

_SIDE_REGIONS = ("cheeks", "jaw", "chin")

_LINE_HALF_WIDTH_MM = 5.0
"""Half-width of a candidate line across the cheek (frontal projection), mm: wide enough that every line
holds a vertex near the frontal silhouette. Measured on the template (ICT mean shape, rig v3) from a
frontal camera: the least ``n . view`` of the facing vertices on the worst line is 0.11 with 5 mm (0.43
with the 3 mm that suited MakeHuman's shape, where it was 0.13: on the ICT jaw the lines of 3 mm jump
from the jowl, z = 58 mm, to under the jaw)."""


@dataclass(frozen=True)
class _Outline:
    vertex_ids: np.ndarray  # the frontal outline of the left half, from the horizontal down to the chin
    angles: np.ndarray  # each vertex's direction from the centre, degrees below the horizontal (~0 .. 90)
    centre: np.ndarray  # (2,) contour centre (x, y)
    allowed: np.ndarray  # vertex ids the contour may use (cheeks, jaw, chin; front half)
    chin_id: int


@dataclass(frozen=True)
class _ContourData:
    vertex_ids: np.ndarray  # (17,) static contour vertices (left half placed, right mirrored)
    directions: np.ndarray  # (17, 2) outward frontal directions (x, y) from the contour centre
    centre: np.ndarray  # (2,) contour centre (x, y)
    candidates: tuple[np.ndarray, ...]  # per contour point: vertex ids front -> back (empty for the chin)


@cached_per_asset
def _outline(asset: RigAsset) -> _Outline:
    v, mirror = asset.vertices, asset.mirror
    eye_outer = [int(loop[np.argmax(np.abs(v[loop, 0]))]) for loop in asset.eye_loops]
    centre = np.array([0.0, float(np.mean(v[eye_outer, 1]))])
    chin = np.flatnonzero(asset.region_mask("chin") & (mirror == np.arange(len(v))))
    chin_id = int(chin[np.argmin(v[chin, 1])])
    allowed = np.flatnonzero(asset.region_mask(*_SIDE_REGIONS) & (v[:, 2] > 0.0))
    # The frontal outline of the left half: for each angle from horizontal (0) to straight down (-90 deg),
    # the allowed vertex projecting farthest from the centre within a narrow angular sector.
    rel = v[allowed, :2] - centre
    ang = np.arctan2(rel[:, 1], rel[:, 0])
    radius = np.linalg.norm(rel, axis=1)
    outline = []
    for a in np.deg2rad(np.linspace(0.0, -90.0, 91)):
        sector = np.flatnonzero((np.abs(ang - a) < np.deg2rad(2.0)) & (rel[:, 0] >= 0.0))
        if len(sector):
            outline.append(int(allowed[sector[np.argmax(radius[sector])]]))
    outline = [i for k, i in enumerate(outline) if k == 0 or i != outline[k - 1]]
    outline = np.array(outline[:-1] + [chin_id]) if outline[-1] != chin_id else np.array(outline)
    rel = v[outline, :2] - centre
    angles = -np.rad2deg(np.arctan2(rel[:, 1], rel[:, 0]))
    return _Outline(outline, angles, centre, allowed, chin_id)


def _contour_ids(asset: RigAsset, corrected: bool) -> np.ndarray:
    """``(17,)`` the static contour vertices: the left half from the outline, the right half mirrored."""
    o, v = _outline(asset), asset.vertices
    if corrected and CONTOUR_ANGLES_DEG:
        if len(CONTOUR_ANGLES_DEG) != 8:
            raise RuntimeError(f"ibug68: CONTOUR_ANGLES_DEG needs 8 angles (16..9), has {len(CONTOUR_ANGLES_DEG)}")
        left_half = [int(o.vertex_ids[np.argmin(np.abs(o.angles - a))]) for a in CONTOUR_ANGLES_DEG]
    else:
        # 9 equal arc-length steps along the outline (frontal projection): 16 (eye corners' height) .. 8 (chin).
        seg = np.linalg.norm(np.diff(v[o.vertex_ids, :2], axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        left_half = [int(o.vertex_ids[int(np.argmin(np.abs(s - t)))]) for t in np.linspace(0.0, s[-1], 9)][:8]
    left_ids = [o.chin_id] + left_half[::-1]  # 8..16
    return np.array([int(asset.mirror[i]) for i in left_ids[:0:-1]] + left_ids, np.int64)


def _contour_from_ids(asset: RigAsset, ids: np.ndarray) -> _ContourData:
    """The dynamic contour's candidate lines for static contour vertices ``ids`` (17; the chin gets none)."""
    v, o = asset.vertices, _outline(asset)
    centre, cand_pool = o.centre, o.allowed
    # Candidate lines: allowed vertices near the plane through the centre spanned by the outward frontal
    # direction and +Z (a slice across the cheek from the front towards the ear), sorted front to back.
    directions = v[ids, :2] - centre
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    candidates = []
    for k in range(len(ids)):
        if k == CHIN:
            candidates.append(np.zeros(0, np.int64))
            continue
        d = directions[k]
        rel = v[cand_pool, :2] - centre
        along, across = rel @ d, rel @ np.array([-d[1], d[0]])
        near = cand_pool[(np.abs(across) < _LINE_HALF_WIDTH_MM) & (along > 0.5 * (v[ids[k], :2] - centre) @ d)]
        line = np.unique(np.concatenate([near, [ids[k]]]))
        candidates.append(line[np.argsort(-v[line, 2])])
    return _ContourData(np.asarray(ids, np.int64), directions, centre, tuple(candidates))


@cached_per_asset
def _contour(asset: RigAsset) -> _ContourData:
    return _contour_from_ids(asset, _contour_ids(asset, corrected=True))


@cached_per_asset
def _contour_heuristic(asset: RigAsset) -> _ContourData:
    return _contour_from_ids(asset, _contour_ids(asset, corrected=False))
