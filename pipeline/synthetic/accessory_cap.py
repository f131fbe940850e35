"""The example cap of :mod:`pipeline.synthetic.accessories`, generated from the template by code: a crown shell
over the scalp (inner surface 3 mm, outer 6 mm off the skin along its normals, joined at the edge), bounded by
a plane tilted from the forehead (front edge 50 mm above the eyes' level) to the occiput, and a brim in front
(:func:`cap_mesh`); closed, mirror-symmetric and clear of the outer skin. The crown's points are where rays
from inside the skull first meet the skin.

Rig space: mm, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.synthetic.accessory_parts import (
    _check_clear,
    _combine,
    _first_hits,
    _landmarks,
    _orient_outward,
    _skin,
    _skin_normals,
)

# The crown's edge plane y = a + b z: slope b (it rises 11 deg toward the front), through the midline forehead
# skin 45 mm above the eyeballs' centres (mid-forehead). The rays' origin inside the skull: the middle of the
# plane's front and back midline skin points, moved up and forward in the plane's frame. On the MakeHuman head
# these rules give the plane y = 34.6 + 0.194 z (it had y = 34.4 + 0.194 z: front edge y = 50 at z = 80, back
# y = 15 at z = -100) and the origin (0, 35.0, -10.0) mm.
_CAP_SLOPE = 0.194
_CAP_FRONT_ABOVE_EYES = 45.0  # mm
_CAP_CENTRE_FROM_EDGE = (2.3, 4.0)  # along the plane's normal (up), along its front direction; mm
_CAP_INNER, _CAP_OUTER = 3.0, 6.0  # offsets of the shell's inner and outer surfaces from the skin, mm
_CAP_AZIMUTHS, _CAP_RINGS = 64, 14
_BRIM_LENGTH, _BRIM_HALF_ARC, _BRIM_THICKNESS, _BRIM_DROOP = 62.0, 78.0, 2.4, 0.12


@dataclass(frozen=True)
class _CapPlacement:
    """The crown's edge plane ``y = a + b z`` and the rays' origin ``centre`` ``(3,)`` mm, on the template."""

    a: float
    b: float
    centre: np.ndarray


def _cap_placement(skin_v: np.ndarray, skin_f: np.ndarray, eye_height: float) -> _CapPlacement:
    """:class:`_CapPlacement` measured on the skin (rules: the constants above)."""
    b = _CAP_SLOPE
    y = eye_height + _CAP_FRONT_ABOVE_EYES
    z = _first_hits(np.array([[0.0, y, 0.0]]), np.array([[0.0, 0.0, 1.0]]), skin_v, skin_f)[0]
    a = y - b * z
    axis, front, _ = _cap_frame(b)
    start = np.array([0.0, y, z]) - front  # 1 mm inside the forehead, then back along the plane
    back = start - _first_hits(start[None], -front[None], skin_v, skin_f)[0] * front
    if not (np.isfinite(z) and np.isfinite(back).all()):
        raise RuntimeError("cap: the edge plane's midline does not meet the skin")
    middle = 0.5 * (np.array([0.0, y, z]) + back)
    centre = middle + _CAP_CENTRE_FROM_EDGE[0] * axis + _CAP_CENTRE_FROM_EDGE[1] * front
    return _CapPlacement(a=float(a), b=b, centre=centre)


def _cap_frame(b: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edge plane's (slope ``b``) upward unit normal ``axis`` and two unit vectors spanning it (``front``:
    toward +Z)."""
    axis = np.array([0.0, 1.0, -b]) / math.hypot(1.0, b)
    front = np.array([0.0, b, 1.0]) / math.hypot(1.0, b)
    return axis, front, np.cross(axis, front)


def _scalp_points(theta: np.ndarray, phi: np.ndarray, place: _CapPlacement, skin_v, skin_f) -> np.ndarray:
    """Where rays from ``place.centre`` at polar angle ``theta`` (from the plane's normal) and azimuth
    ``phi`` (0: the front) first meet the skin, ``(N, 3)``."""
    axis, front, lateral = _cap_frame(place.b)
    d = np.cos(theta)[:, None] * axis + np.sin(theta)[:, None] * (
        np.cos(phi)[:, None] * front + np.sin(phi)[:, None] * lateral
    )
    origin = np.broadcast_to(place.centre, d.shape)
    t = _first_hits(origin, d, skin_v, skin_f)
    if not np.isfinite(t).all():
        raise RuntimeError("cap: a ray from the skull's centre missed the skin")
    return origin + t[:, None] * d


def _edge_angles(phi: np.ndarray, place: _CapPlacement, skin_v, skin_f) -> np.ndarray:
    """Per azimuth, the polar angle at which the skin point reaches the edge plane (bisection)."""
    a, b = place.a, place.b
    low, high = np.zeros_like(phi), np.full_like(phi, math.radians(150.0))
    for _ in range(30):
        mid = 0.5 * (low + high)
        p = _scalp_points(mid, phi, place, skin_v, skin_f)
        above = p[:, 1] - (a + b * p[:, 2]) > 0
        low, high = np.where(above, mid, low), np.where(above, high, mid)
    return 0.5 * (low + high)


def _grid_faces(rows: int, cols: int, offset: int = 0) -> np.ndarray:
    """Faces of a ``rows x cols`` vertex grid, periodic in the columns."""
    i, k = np.meshgrid(np.arange(rows - 1), np.arange(cols), indexing="ij")
    a, b = i * cols + k, i * cols + (k + 1) % cols
    c, d = (i + 1) * cols + (k + 1) % cols, (i + 1) * cols + k
    return offset + np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])


def _crown(place: _CapPlacement, skin_v, skin_f) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The crown shell (closed) and its outer edge ring ``(azimuths, 3)``."""
    phi = 2.0 * np.pi * np.arange(_CAP_AZIMUTHS) / _CAP_AZIMUTHS
    edge = _edge_angles(phi, place, skin_v, skin_f)
    s = np.arange(1, _CAP_RINGS + 1) / _CAP_RINGS
    theta = (s[:, None] * edge[None]).ravel()
    on_skin = np.concatenate(
        [
            _scalp_points(np.zeros(1), np.zeros(1), place, skin_v, skin_f),
            _scalp_points(theta, np.tile(phi, _CAP_RINGS), place, skin_v, skin_f),
        ]
    )
    normal = _skin_normals(on_skin, skin_v, skin_f)
    outer, inner = on_skin + _CAP_OUTER * normal, on_skin + _CAP_INNER * normal
    n = len(on_skin)  # 1 pole + rings x azimuths
    cols = _CAP_AZIMUTHS
    k = np.arange(cols)
    pole_fan = np.stack([np.zeros(cols, np.int64), 1 + (k + 1) % cols, 1 + k], -1)  # CCW seen from above
    grid = _grid_faces(_CAP_RINGS, cols, 1)[:, ::-1]
    outer_faces = np.concatenate([pole_fan, grid])
    inner_faces = outer_faces[:, ::-1] + n
    last = 1 + (_CAP_RINGS - 1) * cols
    band_o, band_i = last + k, n + last + k
    band = np.concatenate(
        [
            np.stack([band_o, band_i, band_i[(k + 1) % cols]], -1),
            np.stack([band_o, band_i[(k + 1) % cols], band_o[(k + 1) % cols]], -1),
        ]
    )
    vertices = np.concatenate([outer, inner])
    faces = np.concatenate([outer_faces, inner_faces, band])
    return vertices, faces, outer[last : last + cols]


def _brim(edge_ring: np.ndarray, b: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed slab in front of the crown (edge plane slope ``b``), from the front arc of its outer edge
    outward."""
    axis, front, lateral = _cap_frame(b)
    n_arc = 33
    phi = np.radians(np.linspace(-_BRIM_HALF_ARC, _BRIM_HALF_ARC, n_arc))
    ring_phi = 2.0 * np.pi * np.arange(len(edge_ring)) / len(edge_ring)
    closed = np.concatenate([edge_ring, edge_ring[:1]])
    angles = np.concatenate([ring_phi, [2.0 * np.pi]])
    root = np.stack(
        [np.interp(np.mod(phi, 2.0 * np.pi), angles, closed[:, c], period=2.0 * np.pi) for c in range(3)], 1
    )
    out = np.cos(phi)[:, None] * front + np.sin(phi)[:, None] * lateral
    out = out - _BRIM_DROOP * axis
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    length = 4.0 + _BRIM_LENGTH * np.cos(0.5 * np.pi * phi / math.radians(_BRIM_HALF_ARC)) ** 0.7
    s = np.linspace(-0.04, 1.0, 9)
    mid = root[None] + (s[:, None, None] * length[None, :, None]) * out[None]  # (rows, arc, 3)
    top = mid + 0.5 * _BRIM_THICKNESS * axis
    bottom = mid - 0.5 * _BRIM_THICKNESS * axis
    rows, cols = mid.shape[:2]
    vertices = np.concatenate([top.reshape(-1, 3), bottom.reshape(-1, 3)])
    idx_top = np.arange(rows * cols).reshape(rows, cols)
    idx_bot = idx_top + rows * cols

    def quads(g: np.ndarray) -> np.ndarray:  # g: (r, c) vertex ids; faces CCW when seen with ids increasing
        a, b, c, d = g[:-1, :-1], g[:-1, 1:], g[1:, 1:], g[1:, :-1]
        return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])

    faces = [quads(idx_top), quads(idx_bot)[:, ::-1]]
    for top_line, bot_line in (
        (idx_top[0], idx_bot[0]),
        (idx_top[-1], idx_bot[-1]),
        (idx_top[:, 0], idx_bot[:, 0]),
        (idx_top[:, -1], idx_bot[:, -1]),
    ):
        faces.append(quads(np.stack([top_line, bot_line])))
    faces = np.concatenate(faces)
    return vertices, _orient_outward(vertices, faces)


def cap_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The example cap on the template: ``vertices (N, 3)`` mm and ``faces (F, 3)`` (a closed crown shell 3-6
    mm off the scalp and a closed brim), mirror-symmetric, clear of the skin."""
    skin_v, skin_f = _skin()
    place = _cap_placement(skin_v, skin_f, float(_landmarks().eye[1]))
    crown_v, crown_f, edge_ring = _crown(place, skin_v, skin_f)
    crown_f = _orient_outward(crown_v, crown_f)
    vertices, faces = _combine([(crown_v, crown_f), _brim(edge_ring, place.b)])
    _check_clear("cap", vertices, skin_v, skin_f)
    return vertices, faces
