"""Initial ("hand-painted") skinning weights, made the way DCC tools make them, and their sparse,
symmetric layout.

Each joint paints a seed area of the template (a region, or a ball around an anatomical anchor) with
full weight and fades out with geodesic distance over the mesh (``(1 - (d/R)^2)^3`` for ``d < R``). The
joints are applied from the root down the hierarchy, each taking its share from what the vertex had
(later, more specific joints win, as when an artist paints a child bone over its parent). Geodesic
distance is the shortest path along mesh edges, so weights do not leak across the mouth slit or the
eye openings. Then each vertex keeps its 4 largest weights (mirror pairs kept or dropped together on
the midline), small ones are pruned, rows are renormalised to sum to 1 and made exactly symmetric.

The free floats of a weight matrix are its non-zeros up to mirror symmetry: entry ``(v, k)`` and
``(mirror(v), mirror(k))`` share one float (:class:`SkinningLayout`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

from rig.geometry import mesh_edges
from rig.joints import (
    JOINT_INDEX,
    JOINT_MIRROR,
    JOINT_NAMES,
    JOINTS,
    PARENTS,
    mirror_joint_name,
)
from rig.template import REGION_NAMES, TemplateMesh

MAX_INFLUENCES = 4
PRUNE_BELOW = 0.01
# Every falloff radius below is widened by this factor: blends over several rings of vertices.
FALLOFF_SCALE = 3.0


@dataclass(frozen=True)
class Influence:
    """Where a joint paints: seed vertices and a geodesic falloff radius (mm).

    Seeds are the vertices in ``regions`` (on the joint's side for left/right joints) that satisfy
    ``box`` (``(axis, low, high)`` bounds on x, y, z in mm, x as |x|), plus geodesic balls of radius
    ``ball`` around the surface points nearest to ``anchors``. Given for midline and left joints;
    right joints use the mirror image.
    """

    regions: tuple[str, ...] = ()
    box: tuple[tuple[int, float, float], ...] = ()
    anchors: tuple[tuple[float, float, float], ...] = ()
    ball: float = 0.0
    radius: float = 10.0
    priority: int = 0  # painted after every joint of lower priority (else root first, by depth)


_X, _Y, _Z = 0, 1, 2
_FACE = (
    "forehead",
    "brows",
    "eyelids",
    "nose",
    "cheeks",
    "lips",
    "chin",
    "jaw",
    "eyeballs",
    "mouth_interior",
    "teeth",
    "tongue",
    "eye_pockets",
)
# Anchors and boxes in mm on the MakeHuman template (rig.template; landmarks listed in rig.joints): the
# mouth slit at y = -62, the eyelid rims between y = -0.3 and 7.8, menton y = -104, neck cut y = -166.
INFLUENCES: dict[str, Influence] = {
    "root": Influence(regions=("neck",), box=((_Y, -1e9, -150.0),), radius=20.0),
    "neck": Influence(regions=("neck",), box=((_Y, -150.0, 1e9),), radius=25.0),
    "skull_root": Influence(regions=("scalp", "ears") + _FACE, radius=30.0),
    "cranium": Influence(regions=("scalp", "forehead"), box=((_Y, 25.0, 1e9),), radius=30.0),
    "crown": Influence(regions=("scalp",), box=((_Y, 85.0, 1e9),), radius=30.0),
    "skull_center": Influence(anchors=((0.0, 5.0, 78.0),), ball=30.0, radius=20.0),
    "brow_center": Influence(anchors=((0.0, 23.0, 84.0),), ball=12.0, radius=20.0),
    "left_orbital": Influence(anchors=((30.0, 6.0, 66.0),), ball=22.0, radius=15.0),
    "left_brow_outer": Influence(anchors=((45.0, 25.0, 68.0),), ball=8.0, radius=16.0),
    "left_eye_socket": Influence(regions=("eyelids", "eyeballs", "eye_pockets"), radius=8.0),
    "left_upper_eyelid": Influence(regions=("eyelids",), box=((_Y, 4.0, 1e9),), radius=5.0),
    "left_lower_eyelid": Influence(regions=("eyelids",), box=((_Y, -1e9, 1.5),), radius=5.0),
    "left_cheek_bone": Influence(anchors=((46.0, -12.0, 62.0),), ball=9.0, radius=18.0),
    "nose_root_a": Influence(anchors=((0.0, 12.0, 81.0),), ball=9.0, radius=14.0),
    "nose_root_b": Influence(anchors=((0.0, 4.0, 82.5),), ball=6.0, radius=10.0),
    "nose_bridge": Influence(anchors=((0.0, -6.0, 86.0),), ball=6.0, radius=10.0),
    "nose_ridge_a": Influence(anchors=((0.0, -15.0, 91.0),), ball=6.0, radius=10.0),
    "nose_ridge_b": Influence(anchors=((0.0, -25.0, 96.0),), ball=6.0, radius=10.0),
    "ears": Influence(regions=("ears",), radius=14.0),
    "left_ear_position": Influence(regions=("ears",), radius=10.0),
    "left_ear_rotate_scale": Influence(regions=("ears",), radius=4.0),
    "lower_face_root": Influence(
        regions=("cheeks", "jaw", "chin", "lips", "mouth_interior"), box=((_Y, -1e9, -30.0),), radius=20.0
    ),
    "jaw_root": Influence(regions=("jaw", "chin", "cheeks"), box=((_Y, -1e9, -50.0),), radius=20.0),
    "maxilla": Influence(anchors=((0.0, -50.0, 86.0),), ball=20.0, radius=16.0),
    "nose_base_position": Influence(anchors=((0.0, -43.0, 90.0),), ball=10.0, radius=10.0),
    "nose_base_rotate": Influence(anchors=((0.0, -45.0, 91.0),), ball=7.0, radius=8.0),
    "nose_tip": Influence(anchors=((0.0, -31.0, 99.5),), ball=7.0, radius=9.0, priority=1),
    "nose_nostril": Influence(anchors=((9.0, -42.0, 90.0), (-9.0, -42.0, 90.0)), ball=6.0, radius=7.0),
    "mouth_center_top": Influence(regions=("lips", "mouth_interior"), box=((_Y, -62.0, 1e9),), radius=12.0),
    "mouth_left_corner": Influence(anchors=((22.5, -62.8, 73.5),), ball=5.0, radius=8.0, priority=1),
    "jaw_front": Influence(regions=("chin", "lips", "mouth_interior"), box=((_Y, -1e9, -63.0),), radius=18.0),
    "chin": Influence(regions=("chin",), box=((_Y, -1e9, -86.0),), radius=14.0),
    "top_lip": Influence(regions=("lips",), box=((_Y, -62.0, -50.0),), radius=5.0),
    "mouth_center_bottom": Influence(regions=("lips", "mouth_interior"), box=((_Y, -1e9, -63.0),), radius=10.0),
    "bottom_lip": Influence(regions=("lips",), box=((_Y, -76.0, -63.0),), radius=5.0),
    "left_cheek": Influence(anchors=((40.0, -36.0, 68.0),), ball=14.0, radius=20.0),
    "left_chin": Influence(anchors=((15.0, -98.0, 72.0),), ball=6.0, radius=12.0),
    "left_jaw_root": Influence(anchors=((50.0, -75.0, 18.0),), ball=12.0, radius=20.0),
    "left_crown_outer": Influence(anchors=((45.0, 92.0, -20.0),), ball=12.0, radius=30.0),
}
"""Where each joint paints (midline and left joints; right joints mirror their left twin)."""
RIGID_PIECES: dict[str, str] = {
    "left_eyeball": "left_eye_socket",
    "upper_teeth": "maxilla",
    "lower_teeth": "jaw_front",
    "tongue": "jaw_front",
}
"""Separate pieces of the head follow one joint rigidly (the right eyeball: ``right_eye_socket``)."""


def _mirror_influence(inf: Influence) -> Influence:
    return Influence(
        regions=inf.regions,
        box=inf.box,
        anchors=tuple((-x, y, z) for x, y, z in inf.anchors),
        ball=inf.ball,
        radius=inf.radius,
        priority=inf.priority,
    )


def influence_of(joint: str) -> Influence:
    """The painting spec of a joint (right joints mirror their left twin)."""
    if joint in INFLUENCES:
        return INFLUENCES[joint]
    twin = JOINT_NAMES[JOINT_MIRROR[JOINT_INDEX[joint]]]
    return _mirror_influence(INFLUENCES[twin])


def edge_graph(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Sparse ``(V, V)`` matrix of mesh edge lengths in mm (symmetric)."""
    e = mesh_edges(faces)
    length = np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1)
    n = len(vertices)
    g = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(n, n))
    return (g + g.T).tocsr()


def _seeds(inf: Influence, joint: str, mesh: TemplateMesh, graph: sp.csr_matrix) -> np.ndarray:
    v = mesh.vertices
    side = np.sign(JOINTS[JOINT_INDEX[joint]].position[0])
    seeds = np.zeros(len(v), bool)
    if inf.regions:
        ids = [REGION_NAMES.index(r) for r in inf.regions]
        mask = np.isin(mesh.regions, ids)
        if side != 0:
            mask &= np.sign(v[:, 0]) == side
        coords = np.abs(v) * np.array([1.0, 0.0, 0.0]) + v * np.array([0.0, 1.0, 1.0])
        for axis, lo, hi in inf.box:
            mask &= (coords[:, axis] >= lo) & (coords[:, axis] <= hi)
        seeds |= mask
    if inf.anchors:
        nearest = [int(np.argmin(np.linalg.norm(v - np.asarray(a), axis=1))) for a in inf.anchors]
        d = dijkstra(graph, indices=nearest, min_only=True, limit=inf.ball + 1e-9)
        seeds |= d <= inf.ball
    if not seeds.any():
        raise RuntimeError(f"joint {joint} paints no vertex")
    return seeds


def paint_weights(mesh: TemplateMesh) -> np.ndarray:
    """Dense initial weights ``(V, K)`` before sparsification (rows sum to 1)."""
    graph = edge_graph(mesh.vertices, mesh.faces)
    V, K = len(mesh.vertices), len(JOINTS)
    depth = [0] * K
    for k, p in enumerate(PARENTS):
        depth[k] = 0 if p < 0 else depth[p] + 1
    order = sorted(range(K), key=lambda k: (influence_of(JOINT_NAMES[k]).priority if k else -1, depth[k], k))
    w = np.zeros((V, K))
    w[:, order[0]] = 1.0
    for k in order[1:]:
        inf = influence_of(JOINT_NAMES[k])
        seeds = _seeds(inf, JOINT_NAMES[k], mesh, graph)
        radius = inf.radius * FALLOFF_SCALE
        d = dijkstra(graph, indices=np.flatnonzero(seeds), min_only=True, limit=radius)
        t = np.clip(d / radius, 0.0, 1.0)
        a = np.where(np.isfinite(d), (1.0 - t**2) ** 3, 0.0)
        w *= (1.0 - a)[:, None]
        w[:, k] += a
    return w


def symmetrise_weights(w: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """Average ``w`` with its mirror image: ``w'[v, k] = (w[v, k] + w[mirror(v), mirror(k)]) / 2``."""
    return 0.5 * (w + w[mirror][:, list(JOINT_MIRROR)])


def sparsify_weights(
    w: np.ndarray, mirror: np.ndarray, max_influences: int = MAX_INFLUENCES, prune_below: float = PRUNE_BELOW
) -> np.ndarray:
    """Keep each vertex's largest weights (at most ``max_influences``), prune small ones, renormalise.

    On midline vertices a joint and its mirror twin are kept or dropped together so that the result
    stays symmetric. ``w`` must already be symmetric.
    """
    out = np.zeros_like(w)
    midline = mirror == np.arange(len(w))
    jm = np.asarray(JOINT_MIRROR)
    for v in range(len(w)):
        row = w[v]
        kept: list[int] = []
        for k in np.argsort(-row, kind="stable"):
            if row[k] < prune_below or len(kept) >= max_influences:
                break
            if k in kept:
                continue
            group = [int(k)] if not midline[v] or jm[k] == k else [int(k), int(jm[k])]
            if len(kept) + len(group) > max_influences:
                continue
            kept.extend(group)
        out[v, kept] = row[kept]
    out /= out.sum(axis=1, keepdims=True)
    return out


@dataclass(frozen=True)
class SkinningLayout:
    """Sparse symmetric storage of a ``(V, K)`` skinning weight matrix.

    Attributes:
        rows, cols: ``(N,)`` int64 positions of the non-zeros.
        free_index: ``(N,)`` int64 index of each non-zero's free float; mirror-image entries share one.
        num_free: number of free floats ``S``.
        shape: ``(V, K)``.
    """

    rows: np.ndarray
    cols: np.ndarray
    free_index: np.ndarray
    num_free: int
    shape: tuple[int, int]

    @staticmethod
    def from_weights(w: np.ndarray, mirror: np.ndarray) -> SkinningLayout:
        rows, cols = np.nonzero(w)
        jm = np.asarray(JOINT_MIRROR)
        key = rows * w.shape[1] + cols
        mirror_key = mirror[rows] * w.shape[1] + jm[cols]
        rep = np.minimum(key, mirror_key)
        unique, free_index = np.unique(rep, return_inverse=True)
        return SkinningLayout(
            rows.astype(np.int64),
            cols.astype(np.int64),
            free_index.astype(np.int64),
            len(unique),
            (int(w.shape[0]), int(w.shape[1])),
        )

    def free_values(self, w: np.ndarray) -> np.ndarray:
        """The free floats of a (symmetric) weight matrix in this layout, ``(S,)``."""
        values = np.zeros(self.num_free)
        values[self.free_index] = w[self.rows, self.cols]
        return values

    def dense(self, free: np.ndarray) -> np.ndarray:
        """``(S,)`` free floats -> dense ``(V, K)`` weights (numpy)."""
        out = np.zeros(self.shape)
        out[self.rows, self.cols] = free[self.free_index]
        return out


def rigid_pieces(mesh: TemplateMesh) -> dict[str, np.ndarray]:
    """``{piece: (V,) bool}`` of the separate pieces that move rigidly (:data:`RIGID_PIECES`): each eyeball,
    the upper and the lower teeth strip (the connected component of the teeth region above / below), the
    tongue."""
    name = REGION_NAMES.index
    v = mesh.vertices
    eyeballs = mesh.regions == name("eyeballs")
    teeth = mesh.regions == name("teeth")
    graph = sp.coo_matrix(
        (np.ones(3 * len(mesh.faces)), (mesh.faces.ravel(), np.roll(mesh.faces, 1, 1).ravel())), shape=(len(v), len(v))
    )
    _, component = connected_components(graph, directed=False)
    strips = np.unique(component[teeth])
    if len(strips) != 2:
        raise RuntimeError(f"the template's teeth are {len(strips)} pieces, expected an upper and a lower strip")
    upper = max(strips, key=lambda c: v[component == c, 1].mean())
    return {
        "left_eyeball": eyeballs & (v[:, 0] > 0),
        "right_eyeball": eyeballs & (v[:, 0] < 0),
        "upper_teeth": teeth & (component == upper),
        "lower_teeth": teeth & (component != upper),
        "tongue": mesh.regions == name("tongue"),
    }


def initial_weights(mesh: TemplateMesh) -> np.ndarray:
    """The rig's initial weights: painted, the separate pieces bound rigidly (:func:`rigid_pieces`),
    symmetrised, sparsified, ``(V, K)`` with rows summing to 1."""
    w = paint_weights(mesh)
    for piece, mask in rigid_pieces(mesh).items():
        joint = RIGID_PIECES.get(piece) or mirror_joint_name(RIGID_PIECES[piece.replace("right_", "left_")])
        w[mask] = 0.0
        w[mask, JOINT_INDEX[joint]] = 1.0
    w = symmetrise_weights(w, mesh.mirror)
    w = sparsify_weights(w, mesh.mirror)
    return symmetrise_weights(w, mesh.mirror)
