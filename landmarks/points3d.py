"""Named 3D landmarks on the template, for point clouds that come with landmarks (``--landmarks``).

Each landmark is one template vertex, found from the template's own structure (eye and mouth loops,
regions), so it follows the template if it is regenerated. Order and names are fixed
(:data:`LANDMARK_NAMES_3D`); a golden test pins the vertex ids.

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

from typing import Mapping

import numpy as np

from rig.asset import RigAsset, load_asset

LANDMARK_NAMES_3D: tuple[str, ...] = (
    "left_eye_outer", "left_eye_inner", "right_eye_inner", "right_eye_outer",
    "nose_tip", "mouth_left", "mouth_right", "chin",
)


class LandmarkError(ValueError):
    """Unknown landmark names or too few landmarks."""


def landmark_vertices(asset: RigAsset | None = None) -> dict[str, int]:
    """``{name: vertex id}`` of the 3D landmarks, in :data:`LANDMARK_NAMES_3D` order."""
    asset = load_asset() if asset is None else asset
    v = asset.vertices
    out: dict[str, int] = {}
    for side, loop in zip(("left", "right"), asset.eye_loops):
        loop = np.asarray(loop)
        corners = loop[[0, len(loop) // 2]]
        outer = int(corners[np.argmax(np.abs(v[corners, 0]))])
        inner = int(corners[np.argmin(np.abs(v[corners, 0]))])
        out[f"{side}_eye_outer"], out[f"{side}_eye_inner"] = outer, inner
    nose = np.flatnonzero(asset.region_mask("nose"))
    out["nose_tip"] = int(nose[np.argmax(v[nose, 2])])
    mouth = np.asarray(asset.mouth_loop)
    corners = mouth[[0, len(mouth) // 2]]
    out["mouth_left"] = int(corners[np.argmax(v[corners, 0])])
    out["mouth_right"] = int(corners[np.argmin(v[corners, 0])])
    chin = np.flatnonzero(asset.region_mask("chin") & (np.abs(v[:, 0]) < 3.0))
    out["chin"] = int(chin[np.argmin(v[chin, 1])])
    return {name: out[name] for name in LANDMARK_NAMES_3D}


def match_landmarks(points: Mapping[str, np.ndarray], asset: RigAsset | None = None,
                    minimum: int = 3) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
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
    return (np.array([ids[n] for n in names], dtype=np.int64),
            np.array([np.asarray(points[n], float) for n in names]), names)
