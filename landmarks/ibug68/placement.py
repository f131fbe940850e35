"""The geometric placement of the landmarks of the left side and the midline, from the template's own
structure (eyelid and lip loops, regions, the midline, geometric extremes); the table in
:mod:`landmarks.ibug68` says where each one goes."""

from __future__ import annotations

import numpy as np

from landmarks.ibug68.mesh import (
    _HIDDEN_REGIONS,
    _closest_point_on_faces,
    _crossing,
    _midline_path,
    _ordered_ring,
    _split_loop,
    _vertex_point,
)
from landmarks.ibug68.names import CHIN
from landmarks.ibug68.outline import _outline
from rig.asset import RigAsset
from rig.geometry import face_edges


def _outer_lip_ring(asset: RigAsset) -> np.ndarray:
    """The vermilion border: of the edge rings around the mouth loop (each one mesh ring further out), the
    outermost that lies wholly in the ``lips`` region; in loop order."""
    v, faces = asset.vertices, np.asarray(asset.faces, np.int64)
    hidden = asset.region_mask(*_HIDDEN_REGIONS)
    lips = asset.region_mask("lips")
    edges = np.unique(np.sort(face_edges(faces), 1), axis=0)
    nbrs: list[list[int]] = [[] for _ in range(len(v))]
    for a, b in edges:
        nbrs[a].append(int(b))
        nbrs[b].append(int(a))
    seen = np.zeros(len(v), bool)
    ring = np.asarray(asset.mouth_loop, np.int64)
    seen[ring] = True
    best = None
    while True:
        nxt = sorted({w for u in ring for w in nbrs[u] if not seen[w] and not hidden[w]})
        if not nxt or not lips[nxt].all():
            break
        seen[nxt] = True
        ring = np.array(nxt, np.int64)
        best = ring
    if best is None:
        raise RuntimeError("ibug68: no ring of lips vertices around the mouth loop")
    return _ordered_ring(faces, best)


_Placed = dict[int, tuple[int, np.ndarray]]
"""Landmark index -> ``(face, barycentric)``."""


def _placement(asset: RigAsset) -> _Placed:
    """The geometric placement of the left side and the midline (17-67; the chin), ``{k: (face, bary)}``."""
    points: _Placed = {CHIN: _vertex_point(asset.faces, _outline(asset).chin_id)}
    points.update(_left_eye(asset))
    outer_lip, x_peak = _outer_lip(asset)
    points.update(outer_lip)
    points.update(_inner_lip(asset, x_peak))
    points.update(_nose(asset))
    points.update(_left_brow(asset))
    return points


def _left_eye(asset: RigAsset) -> _Placed:
    """Left eye 42-47 (loop with +X): corners, and the lids at 1/3 and 2/3 of the corner-to-corner width."""
    v, faces = asset.vertices, asset.faces
    left_eye = int(np.argmax([v[loop, 0].mean() for loop in asset.eye_loops]))
    loop = np.asarray(asset.eye_loops[left_eye])
    inner, outer = int(loop[np.argmin(v[loop, 0])]), int(loop[np.argmax(v[loop, 0])])
    upper, lower = _split_loop(v, loop, inner, outer)
    xi, xo = v[inner, 0], v[outer, 0]
    points: _Placed = {}
    points[42] = _vertex_point(faces, inner)
    points[43] = _crossing(v, faces, upper, 0, xi + (xo - xi) / 3.0)
    points[44] = _crossing(v, faces, upper, 0, xi + 2.0 * (xo - xi) / 3.0)
    points[45] = _vertex_point(faces, outer)
    points[46] = _crossing(v, faces, lower, 0, xi + 2.0 * (xo - xi) / 3.0)
    points[47] = _crossing(v, faces, lower, 0, xi + (xo - xi) / 3.0)
    return points


def _outer_lip(asset: RigAsset) -> tuple[_Placed, float]:
    """Outer lip 48-59 on the vermilion border: corners (its x extremes), 51/57 on the midline, 52 the
    Cupid's bow peak (the border's highest point), 53 halfway (in x) from the peak to the corner; the
    lower lip's 56 and 55 under 52 and 53. Also returns the peak's x (mm), which the inner lip uses."""
    v, faces, mirror = asset.vertices, asset.faces, asset.mirror
    ring = _outer_lip_ring(asset)
    right_c, left_c = int(ring[np.argmin(v[ring, 0])]), int(ring[np.argmax(v[ring, 0])])
    upper, lower = _split_loop(v, ring, right_c, left_c)
    midline = mirror == np.arange(len(v))
    top = upper[(v[upper, 0] > 0.0) & ~midline[upper]]
    peak = int(top[np.argmax(v[top, 1])])
    x_peak, x_half = float(v[peak, 0]), 0.5 * float(v[peak, 0] + v[left_c, 0])
    points: _Placed = {}
    points[51] = _vertex_point(faces, int(upper[np.flatnonzero(midline[upper])[0]]))
    points[52] = _vertex_point(faces, peak)
    points[53] = _crossing(v, faces, upper, 0, x_half)
    points[54] = _vertex_point(faces, left_c)
    points[55] = _crossing(v, faces, lower, 0, x_half)
    points[56] = _crossing(v, faces, lower, 0, x_peak)
    points[57] = _vertex_point(faces, int(lower[np.flatnonzero(midline[lower])[0]]))
    return points, x_peak


def _inner_lip(asset: RigAsset, x_peak: float) -> _Placed:
    """Inner lip 60-67 on the mouth loop (the lips' rim): corners, midline, and under the bow peaks
    (``x_peak``, mm)."""
    v, faces = asset.vertices, asset.faces
    mouth = np.asarray(asset.mouth_loop)
    right_c, left_c = int(mouth[np.argmin(v[mouth, 0])]), int(mouth[np.argmax(v[mouth, 0])])
    upper, lower = _split_loop(v, mouth, right_c, left_c)
    points: _Placed = {}
    points[62] = _crossing(v, faces, upper, 0, 0.0)
    points[63] = _crossing(v, faces, upper, 0, x_peak)
    points[64] = _vertex_point(faces, left_c)
    points[65] = _crossing(v, faces, lower, 0, x_peak)
    points[66] = _crossing(v, faces, lower, 0, 0.0)
    return points


def _nose(asset: RigAsset) -> _Placed:
    """Nose: bridge 27-30 on the midline from the top of the upper eyelids to the tip; base 33-35 along the
    lower edge."""
    v, faces, mirror = asset.vertices, asset.faces, asset.mirror
    nose = asset.region_mask("nose")
    nose_ids = np.flatnonzero(nose)
    tip = int(nose_ids[np.argmax(v[nose_ids, 2])])
    y_top = float(max(v[np.asarray(lp), 1].max() for lp in asset.eye_loops))
    bridge = _midline_path(v, mirror, faces, v[tip, 1], y_top + 5.0, v[tip, 2] - 40.0)
    bridge = bridge[nose[bridge] | (v[bridge, 1] > y_top)]
    points: _Placed = {}
    for k, frac in enumerate((0.0, 1.0 / 3.0, 2.0 / 3.0)):
        points[27 + k] = _crossing(v, faces, bridge, 1, y_top + frac * (v[tip, 1] - y_top))
    points[30] = _vertex_point(faces, tip)
    front = nose_ids[(v[nose_ids, 2] > v[tip, 2] - 20.0) & (v[nose_ids, 1] < v[tip, 1])]
    half_width = v[front, 0].max()
    columella = front[mirror[front] == front]
    base = int(columella[np.argmin(v[columella, 1])])
    points[33] = _vertex_point(faces, base)
    for k, frac in ((34, 0.38), (35, 0.75)):
        # The lowest front vertex of the column not below the columella base (the ala's lower edge; the
        # nose region also covers the ala-cheek junction further down).
        gap = np.abs(v[front, 0] - frac * half_width)
        column = front[(gap <= gap.min() + 1.0) & (v[front, 1] >= v[base, 1] - 1.0)]
        points[k] = _vertex_point(faces, int(column[np.argmin(v[column, 1])]))
    return points


def _left_brow(asset: RigAsset) -> _Placed:
    """Left brow 22-26: the middle of the brow band at five evenly spaced x, projected onto brow faces."""
    v, faces = asset.vertices, asset.faces
    brows = np.flatnonzero(asset.region_mask("brows") & (v[:, 0] > 0.0))
    x_in, x_out = v[brows, 0].min() + 2.0, v[brows, 0].max() - 2.0
    brow_faces = np.flatnonzero(asset.region_mask("brows")[faces].all(1) & (v[faces, 0].min(1) > 0.0))
    points: _Placed = {}
    for k, x in zip(range(22, 27), np.linspace(x_in, x_out, 5)):
        near = brows[np.argsort(np.abs(v[brows, 0] - x), kind="stable")[:6]]  # the band's column at x
        target = np.array([x, 0.5 * (v[near, 1].min() + v[near, 1].max()), v[near, 2].max()])
        points[k] = _closest_point_on_faces(v, faces, brow_faces, target)
    return points
