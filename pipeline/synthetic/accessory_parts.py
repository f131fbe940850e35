"""The building blocks of jnr's example accessories (:mod:`pipeline.synthetic.accessories`): closed tubes swept
along paths with parallel-transport frames (:func:`tube_mesh`), joining, mirroring and orienting meshes, and
the template's outer skin as the parts are fitted to it (landmarks, ray hits, normals, pushing paths out to a
clearance, the final clearance check). The underscored helpers are shared by the glasses
(:mod:`pipeline.synthetic.accessories`) and the cap (:mod:`pipeline.synthetic.accessory_cap`) only.

Rig space: mm, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rig.accessory import outer_skin_faces, signed_distance
from rig.asset import load_asset
from rig.geometry import closest_surface_points, surface_values, vertex_normals

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


def _orient_outward(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces of a closed mesh made consistent and outward (trimesh's winding fix and volume sign)."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    trimesh.repair.fix_winding(mesh)
    if mesh.volume < 0:
        mesh.invert()
    return np.asarray(mesh.faces, np.int64)


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
