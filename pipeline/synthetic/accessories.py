"""The two example accessories jnr ships, generated from the template by code: glasses and a cap.

Both are closed triangle meshes in rig space (mm, +Y up, +Z out of the face, +X the subject's left),
placed on the template in its bind pose, mirror-symmetric (to 0.01 mm), and clear of the outer skin
(:data:`rig.accessory.OUTER_SKIN_REGIONS`) by at least :data:`MIN_CLEARANCE_MM` at every vertex:

* **glasses** (:func:`glasses_mesh`): two rounded rims (superellipses) in front of the eyes with a
  pantoscopic tilt and a wrap, a bridge over the nose, and temples that run back along the side of the
  head above the ears and drop behind them; every part a closed tube (capped at open ends) swept along
  its path with parallel-transport frames (:func:`tube_mesh`). Rims, bridge and temple paths are fitted
  to the skin by ray casting and closest points (the rims moved forward until they clear the brows and
  the nose; the temples hug the skull at a fixed gap).
* **cap** (:func:`cap_mesh`): a crown shell over the scalp (inner surface 3 mm, outer 6 mm off the skin
  along its normals, joined at the edge), bounded by a plane tilted from the forehead (front edge
  50 mm above the eyes' level) to the occiput, and a brim in front.

``python -m pipeline.synthetic.accessories [--out FOLDER]`` regenerates the committed OBJ files in
``pipeline/assets/accessories/`` (:func:`write_example_accessories`); a test checks that the regenerated
meshes equal them.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.accessory import outer_skin_faces, signed_distance
from rig.asset import load_asset
from rig.geometry import closest_surface_points, surface_values, vertex_normals
from rig.io.atomic import write_bytes_atomic
from rig.io.mesh import RIG_SPACE_COMMENT

__all__ = [
    "ACCESSORY_DIGITS",
    "EXAMPLES",
    "MIN_CLEARANCE_MM",
    "cap_mesh",
    "glasses_mesh",
    "obj_text",
    "tube_mesh",
    "write_example_accessories",
]

ACCESSORY_DIGITS = 4
"""Decimal places of the committed OBJ files (0.1 micrometre)."""
MIN_CLEARANCE_MM = 0.5
"""Every vertex of a generated accessory lies at least this far outside the template's outer skin."""
_TUBE_SIDES = 8


# ----------------------------------------------------------------------------------------------------
# Meshes from paths
# ----------------------------------------------------------------------------------------------------


def _transport_frames(path: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents ``(M, 3)`` and parallel-transported normals ``(M, 3)`` along a polyline; for a
    closed loop the twist left at the end is spread evenly along it, so the frames close."""
    if closed:
        tangent = np.roll(path, -1, 0) - np.roll(path, 1, 0)
    else:
        tangent = np.gradient(path, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    seed = np.eye(3)[np.argmin(np.abs(tangent[0]))]
    normal = np.zeros_like(path)
    normal[0] = np.cross(tangent[0], seed)
    normal[0] /= np.linalg.norm(normal[0])
    for i in range(1, len(path)):
        n = normal[i - 1] - tangent[i] * (normal[i - 1] @ tangent[i])
        normal[i] = n / np.linalg.norm(n)
    if closed:
        n_end = normal[-1] - tangent[0] * (normal[-1] @ tangent[0])
        n_end /= np.linalg.norm(n_end)
        twist = math.atan2(np.cross(n_end, normal[0]) @ tangent[0], n_end @ normal[0])
        for i in range(len(path)):
            a = twist * (i + 1) / len(path)
            b = np.cross(tangent[i], normal[i])
            normal[i] = math.cos(a) * normal[i] + math.sin(a) * b
    return tangent, normal


def tube_mesh(
    path: np.ndarray, radius: float, *, closed: bool = False, sides: int = _TUBE_SIDES
) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube of circular cross-section swept along a polyline.

    Args:
        path: ``(M, 3)`` centre line, mm; radius: mm.
        closed: the path is a loop (a torus-like tube); otherwise both ends are capped with a fan around
            an end vertex, so the mesh is closed either way.
        sides: vertices per cross-section.

    Returns:
        ``vertices (M * sides [+ 2], 3)`` mm and ``faces (F, 3)``, outward-facing (CCW seen from outside).
    """
    path = np.asarray(path, float)
    tangent, normal = _transport_frames(path, closed)
    binormal = np.cross(tangent, normal)
    angle = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.cos(angle)[None, :, None] * normal[:, None] + np.sin(angle)[None, :, None] * binormal[:, None]
    vertices = (path[:, None] + radius * ring).reshape(-1, 3)
    m = len(path)
    i, k = np.meshgrid(np.arange(m if closed else m - 1), np.arange(sides), indexing="ij")
    a, b = i * sides + k, i * sides + (k + 1) % sides
    c, d = ((i + 1) % m) * sides + (k + 1) % sides, ((i + 1) % m) * sides + k
    faces = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    if not closed:
        start, end = len(vertices), len(vertices) + 1
        vertices = np.concatenate([vertices, path[:1], path[-1:]])
        ks = np.arange(sides)
        first = np.stack([np.full(sides, start), (ks + 1) % sides, ks], -1)
        last = np.stack([np.full(sides, end), (m - 1) * sides + ks, (m - 1) * sides + (ks + 1) % sides], -1)
        faces = np.concatenate([faces, first, last])
    return vertices, _orient_outward(vertices, faces)


def _combine(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    vertices, faces, offset = [], [], 0
    for v, f in parts:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def _mirror(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mirror image in x = 0, faces reversed so that they still face outward."""
    return vertices * np.array([-1.0, 1.0, 1.0]), faces[:, ::-1].copy()


# ----------------------------------------------------------------------------------------------------
# The skin: rays, clearance
# ----------------------------------------------------------------------------------------------------


def _skin():
    asset = load_asset()
    return asset.vertices, outer_skin_faces(asset)


@dataclass(frozen=True)
class _Landmarks:
    """Where the accessories are placed, measured on the template (mm, rig space): ``eye`` the left eyeball's
    centre (the mean of its vertices), ``ear_top`` / ``ear_back`` the left ear's highest ``y`` and rearmost
    ``z``."""

    eye: np.ndarray
    ear_top: float
    ear_back: float


def _landmarks(vertices: np.ndarray | None = None) -> _Landmarks:
    """:class:`_Landmarks` of the template (``vertices``: another shape on its topology, for comparisons)."""
    asset = load_asset()
    v = asset.vertices if vertices is None else np.asarray(vertices, float)
    left = v[:, 0] > 0
    eye = v[asset.region_mask("eyeballs") & left].mean(0)
    ear = v[asset.region_mask("ears") & left]
    return _Landmarks(eye=eye, ear_top=float(ear[:, 1].max()), ear_back=float(ear[:, 2].min()))


def _first_hits(
    origins: np.ndarray, directions: np.ndarray, vertices: np.ndarray, faces: np.ndarray, chunk: int = 32
) -> np.ndarray:
    """Distance along each ray to its first triangle (Moller-Trumbore), ``inf`` where none is hit."""
    tri = vertices[faces]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = np.full(len(origins), np.inf)
    for s in range(0, len(origins), chunk):
        o, d = origins[s : s + chunk, None], directions[s : s + chunk, None]
        p = np.cross(d, e2[None])
        det = (e1[None] * p).sum(-1)
        ok = np.abs(det) > 1e-12
        inv = 1.0 / np.where(ok, det, 1.0)
        t_vec = o - a[None]
        u = (t_vec * p).sum(-1) * inv
        q = np.cross(t_vec, e1[None])
        v = (d * q).sum(-1) * inv
        t = (e2[None] * q).sum(-1) * inv
        # A small tolerance on the barycentrics: a ray in the mirror plane through a midline edge must not
        # pass between its two triangles by rounding.
        hit = ok & (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9) & (t > 1e-9)
        out[s : s + chunk] = np.where(hit, t, np.inf).min(1)
    return out


def _skin_normals(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit outward skin normals at the closest skin points of ``points``."""
    anchors = closest_surface_points(points, vertices, faces)
    n = surface_values(vertex_normals(vertices, faces), faces, anchors)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _push_out(
    path: np.ndarray, clearance: float, vertices: np.ndarray, faces: np.ndarray, iterations: int = 8
) -> np.ndarray:
    """Move path points that are closer than ``clearance`` to the skin outward along its normal."""
    path = path.copy()
    for _ in range(iterations):
        sd = signed_distance(path, vertices, faces)
        short = sd < clearance
        if not short.any():
            break
        path[short] += (clearance - sd[short] + 0.05)[:, None] * _skin_normals(path[short], vertices, faces)
    return path


def _smooth_path(path: np.ndarray, iterations: int) -> np.ndarray:
    """Neighbour averaging of an open polyline's interior points (the ends stay)."""
    path = path.copy()
    for _ in range(iterations):
        path[1:-1] = 0.5 * path[1:-1] + 0.25 * (path[:-2] + path[2:])
    return path


def _resample(path: np.ndarray, spacing: float) -> np.ndarray:
    """A polyline resampled at (about) equal arc-length ``spacing``, mm."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(2, int(round(s[-1] / spacing)) + 1)
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, path[:, c]) for c in range(3)], 1)


def _check_clear(name: str, vertices: np.ndarray, skin_v: np.ndarray, skin_f: np.ndarray) -> None:
    low = float(signed_distance(vertices, skin_v, skin_f).min())
    if low < MIN_CLEARANCE_MM:
        raise RuntimeError(f"{name}: a vertex lies {low:.2f} mm from the skin (< {MIN_CLEARANCE_MM} mm)")


# ----------------------------------------------------------------------------------------------------
# Glasses
# ----------------------------------------------------------------------------------------------------

_RIM_FROM_EYE = (4.2, -2.0)  # the left rim's centre (x, y) from the left eyeball's centre: outward, down, mm
_RIM_START_DEPTH = 22.0  # the rims' first depth in front of the eyeballs' centres (then moved forward), mm
_RIM_AXES = (21.0, 15.0)  # half width, half height, mm
_RIM_EXPONENT = 2.6  # superellipse exponent (2: an ellipse; larger: squarer)
_RIM_SAMPLES = 48
_RIM_RADIUS, _BRIDGE_RADIUS, _TEMPLE_RADIUS = 1.6, 1.4, 1.3
_GAP_MM = 1.5  # skin to tube surface where a part hugs the head
_TILT, _WRAP = 0.15, 0.12  # dz/dy (pantoscopic tilt: the bottom nearer the cheeks), dz/d|x| (face form)


# The temple's centre line in the (z, y) plane, as offsets from the left ear's back (z) and top (y), mm: forward
# of the ear, 3-4 mm above it, then down 6-14 mm behind it (on the MakeHuman head, ear back z = -40.5 and top
# y = 25.4, these were the knots (45, 22), (20, 28.5), (-10, 29.5), (-38, 28.5), (-47, 20), (-52, 6), (-54, -4)).
_TEMPLE_FROM_EAR = ((85.5, -3.4), (60.5, 3.1), (30.5, 4.1), (2.5, 3.1), (-6.5, -5.4), (-11.5, -19.4), (-13.5, -29.4))


def _rim_path(centre: tuple[float, float], z0: float) -> np.ndarray:
    """The left rim's centre line ``(M, 3)``: a superellipse around ``centre`` (x, y) in a tilted, wrapped
    plane at depth ``z0``."""
    t = 2.0 * np.pi * np.arange(_RIM_SAMPLES) / _RIM_SAMPLES
    e = 2.0 / _RIM_EXPONENT
    x = centre[0] + _RIM_AXES[0] * np.sign(np.cos(t)) * np.abs(np.cos(t)) ** e
    y = centre[1] + _RIM_AXES[1] * np.sign(np.sin(t)) * np.abs(np.sin(t)) ** e
    z = z0 + _TILT * (y - centre[1]) - _WRAP * (x - (centre[0] - _RIM_AXES[0]))
    return np.stack([x, y, z], 1)


def _rim_at(path: np.ndarray, angle_deg: float) -> np.ndarray:
    """The rim's centre-line point nearest the direction ``angle_deg`` (0: outward +X, 90: up)."""
    centre = path.mean(0)
    a = np.arctan2(path[:, 1] - centre[1], path[:, 0] - centre[0])
    return path[np.argmin(np.abs(np.angle(np.exp(1j * (a - math.radians(angle_deg))))))]


def glasses_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The example glasses on the template: ``vertices (N, 3)`` mm and ``faces (F, 3)`` (closed tubes:
    two rims, a bridge, two temples), mirror-symmetric, clear of the skin."""
    skin_v, skin_f = _skin()
    marks = _landmarks()
    centre = (marks.eye[0] + _RIM_FROM_EYE[0], marks.eye[1] + _RIM_FROM_EYE[1])
    # Rims: forward until every centre-line point clears the skin by radius + gap.
    z0 = marks.eye[2] + _RIM_START_DEPTH
    for _ in range(20):
        low = float(signed_distance(_rim_path(centre, z0), skin_v, skin_f).min())
        if low >= _RIM_RADIUS + _GAP_MM:
            break
        z0 += _RIM_RADIUS + _GAP_MM - low + 0.1
    rim = _rim_path(centre, z0)
    # Bridge: from the left rim's upper inner side over the nose to its mirror image, a gap above the skin.
    start = _rim_at(rim, 150.0)
    mid_y = start[1] + 1.0
    mid_z = skin_v[:, 2][(np.abs(skin_v[:, 0]) < 3) & (np.abs(skin_v[:, 1] - mid_y) < 3)].max()
    end = start * np.array([-1.0, 1.0, 1.0])
    control = np.array([0.0, mid_y + 2.0, mid_z + _BRIDGE_RADIUS + _GAP_MM])
    t = np.linspace(0.0, 1.0, 25)[:, None]
    bridge = (1 - t) ** 2 * start + 2 * t * (1 - t) * control + t**2 * end
    bridge = _push_out(bridge, _BRIDGE_RADIUS + _GAP_MM, skin_v, skin_f)
    bridge = _smooth_path(bridge, 4)
    bridge = 0.5 * (bridge + bridge[::-1] * np.array([-1.0, 1.0, 1.0]))  # exactly symmetric
    # Temple: from the hinge on the rim's outer side back along the head above the ear, then down behind it.
    hinge = _rim_at(rim, 20.0) + np.array([_RIM_RADIUS, 0.0, -_RIM_RADIUS])
    ear = np.array([marks.ear_back, marks.ear_top])
    knots_zy = np.concatenate([[[hinge[2], hinge[1]]], ear + np.array(_TEMPLE_FROM_EAR)])
    z = np.linspace(knots_zy[0, 0], knots_zy[-1, 0], 80)
    y = np.interp(-z, -knots_zy[:, 0], knots_zy[:, 1])
    origins = np.stack([np.zeros_like(z), y, z], 1)
    side = _first_hits(origins, np.tile([1.0, 0.0, 0.0], (len(z), 1)), skin_v, skin_f)
    x = np.maximum(side + _TEMPLE_RADIUS + _GAP_MM, hinge[0])
    temple = np.concatenate([hinge[None], np.stack([x, y, z], 1)[1:]])
    temple = _smooth_path(_resample(temple, 2.5), 6)
    temple = _push_out(temple, _TEMPLE_RADIUS + _GAP_MM, skin_v, skin_f)
    temple = _smooth_path(temple, 2)
    left = _combine([tube_mesh(rim, _RIM_RADIUS, closed=True), tube_mesh(temple, _TEMPLE_RADIUS)])
    vertices, faces = _combine([left, _mirror(*left), tube_mesh(bridge, _BRIDGE_RADIUS)])
    _check_clear("glasses", vertices, skin_v, skin_f)
    return vertices, faces


# ----------------------------------------------------------------------------------------------------
# Cap
# ----------------------------------------------------------------------------------------------------

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


def _orient_outward(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces of a closed mesh made consistent and outward (trimesh's winding fix and volume sign)."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    trimesh.repair.fix_winding(mesh)
    if mesh.volume < 0:
        mesh.invert()
    return np.asarray(mesh.faces, np.int64)


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


# ----------------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------------

EXAMPLES = {"glasses": glasses_mesh, "cap": cap_mesh}
"""The shipped example accessories by name, and the functions that make them."""


def obj_text(vertices: np.ndarray, faces: np.ndarray, header: list[str] | tuple[str, ...] = (), digits: int = 6) -> str:
    """Wavefront OBJ text of a triangle mesh: ``# header`` lines, ``v x y z`` (fixed-point, ``digits``
    decimals; ``-0`` written as ``0``), ``f a b c`` (1-based)."""
    v = np.round(np.asarray(vertices, float), digits) + 0.0  # + 0.0: no "-0.0000"
    fmt = f"{{:.{digits}f}}"
    lines = [f"# {h}" for h in header]
    lines += ["v " + " ".join(fmt.format(c) for c in row) for row in v]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces)]
    return "\n".join(lines) + "\n"


def example_obj_text(name: str) -> str:
    """The OBJ text of a shipped example (``glasses`` or ``cap``), as committed."""
    vertices, faces = EXAMPLES[name]()
    header = [
        f"jnr: {RIG_SPACE_COMMENT}",
        f"jnr example accessory {name!r} on the jnr template, made by pipeline/synthetic/accessories.py",
        f"{len(vertices)} vertices, {len(faces)} triangles; closed parts, faces outward",
    ]
    return obj_text(vertices, faces, header, ACCESSORY_DIGITS)


def write_example_accessories(folder: str | Path) -> list[Path]:
    """Write ``glasses.obj`` and ``cap.obj`` into ``folder`` (created if missing), each atomically."""
    folder = Path(folder)
    paths = []
    for name in EXAMPLES:
        path = folder / f"{name}.obj"
        write_bytes_atomic(path, example_obj_text(name).encode(), make_parents=True)
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> None:
    """``python -m pipeline.synthetic.accessories [--out FOLDER]``: regenerate the shipped examples."""
    parser = argparse.ArgumentParser(description="Regenerate jnr's example accessories (glasses, cap).")
    parser.add_argument(
        "--out",
        default=str(Path(__file__).resolve().parents[1] / "assets" / "accessories"),
        help="folder (default: pipeline/assets/accessories)",
    )
    args = parser.parse_args(argv)
    for path in write_example_accessories(args.out):
        print(path)


if __name__ == "__main__":
    main()
