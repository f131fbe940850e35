"""Dynamic bone binding (ASM eq. 7-16): bones as UV points on the template's skin island, located in its
triangles and mapped to 3D (:func:`bone_positions_from_uv`), their 9-float transforms
(:func:`bone_local_transforms`), and the island itself with each bone's anchor vertex (:func:`uv_domain`).
See :mod:`rig.skinning.asm`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from rig.asset import RigAsset, cached_per_asset
from rig.errors import check_shape
from rig.joints import JOINT_MIRROR
from rig.lbs import euler_to_matrix
from rig.skinning.asm.parameters import AsmInitError

__all__ = [
    "SCALE_FLOOR",
    "STATIC_REGIONS",
    "UvDomain",
    "bone_local_transforms",
    "bone_positions_from_uv",
    "locate_uv",
    "mirror_uv",
    "uv_barycentric",
    "uv_domain",
    "uv_face_tree",
]


#: Smallest scale factor a bone may reach (``1 + s >= SCALE_FLOOR``), as the JNR channels.
SCALE_FLOOR = 0.5
#: Islands of MakeHuman's atlas that ASM's GMM does not cover (their vertices keep the painted weights).
STATIC_REGIONS: tuple[str, ...] = ("neck", "eyeballs", "mouth_interior", "teeth", "tongue", "eye_pockets")


def uv_barycentric(points: torch.Tensor, triangles: torch.Tensor) -> torch.Tensor:
    """Barycentric coordinates of 2D points in 2D triangles (ASM eq. 10); outside a triangle they
    extrapolate (some are negative).

    Args:
        points: ``(*, 2)``.
        triangles: ``(*, 3, 2)`` corners ``A, B, C``.

    Returns:
        ``(*, 3)`` ``(alpha, beta, gamma)``, summing to 1, with ``point = alpha A + beta B + gamma C``.
    """
    check_shape(points.shape[-1:] == (2,), "uv_barycentric", "points", "(*, 2)", tuple(points.shape))
    check_shape(triangles.shape[-2:] == (3, 2), "uv_barycentric", "triangles", "(*, 3, 2)", tuple(triangles.shape))
    A, B, C = triangles.unbind(-2)
    x, y = points[..., 0], points[..., 1]
    alpha = (-(x - B[..., 0]) * (C[..., 1] - B[..., 1]) + (y - B[..., 1]) * (C[..., 0] - B[..., 0])) / (
        -(A[..., 0] - B[..., 0]) * (C[..., 1] - B[..., 1]) + (A[..., 1] - B[..., 1]) * (C[..., 0] - B[..., 0])
    )
    beta = (-(x - C[..., 0]) * (A[..., 1] - C[..., 1]) + (y - C[..., 1]) * (A[..., 0] - C[..., 0])) / (
        -(B[..., 0] - C[..., 0]) * (A[..., 1] - C[..., 1]) + (B[..., 1] - C[..., 1]) * (A[..., 0] - C[..., 0])
    )
    return torch.stack([alpha, beta, 1.0 - alpha - beta], dim=-1)


def uv_face_tree(face_uv: torch.Tensor):
    """A KD-tree of the triangles' UV centroids for :func:`locate_uv` (build once per triangle set)."""
    return cKDTree(face_uv.detach().mean(1).cpu().numpy())


def locate_uv(points: torch.Tensor, face_uv: torch.Tensor, candidates: int = 16, tree=None) -> torch.Tensor:
    """The triangle that contains each UV point (ASM eq. 8), or the nearest one for points outside all.

    Only the ``candidates`` triangles with the nearest centroids (a KD-tree) are tested; a point inside
    none of them is tested against every triangle.

    Args:
        points: ``(N, 2)``.
        face_uv: ``(F, 3, 2)`` triangles.
        candidates: triangles tested per point first.
        tree: :func:`uv_face_tree` of ``face_uv`` (default: built here).

    Returns:
        ``(N,)`` int64 triangle index (the one whose smallest barycentric coordinate is largest).
    """
    check_shape(points.dim() == 2 and points.shape[1] == 2, "locate_uv", "points", "(N, 2)", tuple(points.shape))
    check_shape(
        face_uv.dim() == 3 and face_uv.shape[1:] == (3, 2), "locate_uv", "face_uv", "(F, 3, 2)", tuple(face_uv.shape)
    )
    with torch.no_grad():
        pts = points.detach().to(face_uv.dtype)
        k = min(candidates, face_uv.shape[0])
        _, cand = (tree or uv_face_tree(face_uv)).query(pts.cpu().numpy(), k=k)
        cand = torch.as_tensor(cand, device=points.device).view(len(pts), k)
        inside = uv_barycentric(pts[:, None, :], face_uv[cand]).min(-1).values  # (N, k)
        best = inside.argmax(-1)
        face = cand.gather(1, best[:, None])[:, 0]
        outside = inside.gather(1, best[:, None])[:, 0] < -1e-9
        if outside.any():
            bary = uv_barycentric(pts[outside][:, None, :], face_uv[None])  # (n, F, 3)
            face[outside] = bary.min(-1).values.argmax(-1)
        return face


def bone_positions_from_uv(
    zeta: torch.Tensor,
    face_uv: torch.Tensor,
    face_xyz: torch.Tensor,
    anchor_xyz: torch.Tensor,
    initial_positions: torch.Tensor,
    tree=None,
) -> torch.Tensor:
    """Dynamic bone binding (ASM eq. 11): ``psi_j = alpha v_A + beta v_B + gamma v_C - v_t + psi_j^0``.

    Args:
        zeta: ``(B, J, 2)`` bone UV positions.
        face_uv: ``(F, 3, 2)`` UV triangles the bones move on.
        face_xyz: ``(F, 3, 3)`` the same triangles' corners on the rest mesh, mm.
        anchor_xyz: ``(J, 3)`` anchor vertex ``v_t`` of each bone, mm.
        initial_positions: ``(J, 3)`` initial bone positions ``psi^0``, mm.
        tree: optional :func:`uv_face_tree` of ``face_uv``.

    Returns:
        ``(B, J, 3)`` bind positions, mm (``psi^0`` when ``zeta`` is the anchors' UV).
    """
    check_shape(
        zeta.dim() == 3 and zeta.shape[-1] == 2, "bone_positions_from_uv", "zeta", "(B, J, 2)", tuple(zeta.shape)
    )
    B, J = zeta.shape[:2]
    flat = zeta.reshape(B * J, 2)
    face = locate_uv(flat, face_uv, tree=tree)
    bary = uv_barycentric(flat, face_uv[face].to(zeta.dtype))  # (B*J, 3)
    surface = (bary.unsqueeze(-1) * face_xyz[face].to(zeta.dtype)).sum(-2).view(B, J, 3)
    return surface - anchor_xyz.to(zeta.dtype) + initial_positions.to(zeta.dtype)


def bone_local_transforms(tau: torch.Tensor) -> torch.Tensor:
    """Each bone's local transform ``M(tau) = T R S`` from its 9 floats.

    Args:
        tau: ``(B, J, 9)`` rotation xyz (deg; ``R = Rz Ry Rx``), translation xyz (mm), scale xyz
            (``factor - 1``, clamped so the factor stays >= :data:`SCALE_FLOOR`).

    Returns:
        ``(B, J, 4, 4)``.
    """
    check_shape(tau.dim() == 3 and tau.shape[-1] == 9, "bone_local_transforms", "tau", "(B, J, 9)", tuple(tau.shape))
    rotation = euler_to_matrix(tau[..., 0:3] * (math.pi / 180.0))
    scale = 1.0 + tau[..., 6:9].clamp(min=SCALE_FLOOR - 1.0)
    linear = rotation * scale.unsqueeze(-2)
    top = torch.cat([linear, tau[..., 3:6].unsqueeze(-1)], dim=-1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


@dataclass(frozen=True)
class UvDomain:
    """Where the GMM lives on the template (numpy; see the module docstring for the choices).

    Attributes:
        gmm_vertices: ``(N,)`` int64 vertices weighted by the GMM (the skin island).
        vertex_uv: ``(N, 2, 2)`` their UV copies (symmetrised); ``copy_mask``: ``(N, 2)`` bool (the second
            copy exists on the seam).
        faces: ``(F, 3)`` int64 skin-island faces (vertex indices); ``face_uv``: ``(F, 3, 2)``.
        anchors: ``(J,)`` int64 anchor vertex ``t`` of each joint; ``zeta0``: ``(J, 2)`` its UV.
        mirror_v: the island's mirror line ``v = mirror_v``.
    """

    gmm_vertices: np.ndarray
    vertex_uv: np.ndarray
    copy_mask: np.ndarray
    faces: np.ndarray
    face_uv: np.ndarray
    anchors: np.ndarray
    zeta0: np.ndarray
    mirror_v: float

    @property
    def seam_rows(self) -> np.ndarray:
        """``(S,)`` rows of :attr:`gmm_vertices` with a second UV copy."""
        return np.nonzero(self.copy_mask[:, 1])[0]

    @property
    def seam_uv(self) -> np.ndarray:
        """``(S, 2)`` the second copies."""
        return self.vertex_uv[self.seam_rows, 1]


def mirror_uv(uv: np.ndarray | torch.Tensor, mirror_v: float):
    """Reflect UV points in the island's mirror line ``v = mirror_v`` (x -> -x in rig space)."""
    out = uv.clone() if isinstance(uv, torch.Tensor) else np.array(uv, dtype=float, copy=True)
    out[..., 1] = 2.0 * mirror_v - out[..., 1]
    return out


@cached_per_asset
def uv_domain(asset: RigAsset) -> UvDomain:
    """The skin island, per-vertex UVs and bone anchors of ``asset`` (computed once per asset)."""
    static = asset.region_mask(*STATIC_REGIONS)
    # The skin island: the UV-connected component with the most faces whose corners are not all static.
    uv = asset.face_uvs
    keys: dict[tuple, int] = {}
    corner_key = np.array(
        [keys.setdefault((round(float(a), 7), round(float(b), 7)), len(keys)) for a, b in uv.reshape(-1, 2)]
    ).reshape(-1, 3)
    edges = np.concatenate([corner_key[:, [0, 1]], corner_key[:, [1, 2]], corner_key[:, [2, 0]]])
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(keys), len(keys)))
    _, label = connected_components(graph, directed=False)
    face_island = label[corner_key[:, 0]]
    skin_score = np.bincount(face_island, weights=(~static[asset.faces]).all(1).astype(float))
    island = int(skin_score.argmax())
    skin_faces = np.nonzero(face_island == island)[0]
    faces = asset.faces[skin_faces]
    face_uv = uv[skin_faces]
    copies: dict[int, list[tuple[float, float]]] = {}
    for f in range(len(faces)):
        for c in range(3):
            key = (round(float(face_uv[f, c, 0]), 7), round(float(face_uv[f, c, 1]), 7))
            lst = copies.setdefault(int(faces[f, c]), [])
            if key not in lst:
                lst.append(key)
    gmm_vertices = np.array(sorted(copies), dtype=np.int64)
    if max(len(c) for c in copies.values()) > 2:
        raise AsmInitError("uv_domain: a skin vertex has more than two UV copies")
    vertex_uv = np.zeros((len(gmm_vertices), 2, 2))
    copy_mask = np.zeros((len(gmm_vertices), 2), bool)
    for i, v in enumerate(gmm_vertices):
        for c, key in enumerate(copies[int(v)]):
            vertex_uv[i, c] = key
            copy_mask[i, c] = True
    # Mirror line and symmetrised UVs: a vertex's copies against its mirror partner's copies (matched
    # by reflection).
    row = {int(v): i for i, v in enumerate(gmm_vertices)}
    single = copy_mask.sum(1) == 1
    pairs = [
        (i, row[int(asset.mirror[v])])
        for i, v in enumerate(gmm_vertices)
        if single[i] and int(asset.mirror[v]) in row and single[row[int(asset.mirror[v])]]
    ]
    mirror_v = float(np.mean([0.5 * (vertex_uv[i, 0, 1] + vertex_uv[j, 0, 1]) for i, j in pairs]))
    sym = vertex_uv.copy()
    for i, v in enumerate(gmm_vertices):
        j = row.get(int(asset.mirror[v]))
        if j is None:
            continue
        for c in np.nonzero(copy_mask[i])[0]:
            reflected = mirror_uv(vertex_uv[j][copy_mask[j]], mirror_v)
            k = int(np.argmin(np.linalg.norm(reflected - vertex_uv[i, c], axis=1)))
            sym[i, c] = 0.5 * (vertex_uv[i, c] + reflected[k])
    vertex_uv = sym
    # Face UVs from the symmetrised vertex UVs (the copy nearest the original corner).
    new_face_uv = face_uv.copy()
    for f in range(len(faces)):
        for c in range(3):
            i = row[int(faces[f, c])]
            k = int(np.argmin(np.linalg.norm(vertex_uv[i] - face_uv[f, c], axis=1) + 1e9 * ~copy_mask[i]))
            new_face_uv[f, c] = vertex_uv[i, k]
    anchors = _anchor_vertices(asset, gmm_vertices[single], mirror_v)
    zeta0 = vertex_uv[[row[int(t)] for t in anchors], 0]
    return UvDomain(gmm_vertices, vertex_uv, copy_mask, faces, new_face_uv, anchors, zeta0, mirror_v)


def _anchor_vertices(asset: RigAsset, candidates: np.ndarray, mirror_v: float) -> np.ndarray:
    """ASM eq. 5's vertex ``t`` per joint: the nearest candidate vertex in 3D, symmetric across the midline."""
    xyz = asset.vertices[candidates]
    midline = candidates[np.abs(xyz[:, 0]) < 1e-6]
    anchors = np.zeros(len(asset.joint_names), np.int64)
    for j, p in enumerate(asset.joint_positions):
        if abs(p[0]) < 1e-6:
            pool = midline
        elif p[0] > 0:
            pool = candidates[asset.vertices[candidates, 0] > 0]
        else:
            continue
        anchors[j] = pool[np.argmin(np.linalg.norm(asset.vertices[pool] - p, axis=1))]
    for j, p in enumerate(asset.joint_positions):
        if p[0] < -1e-6:
            anchors[j] = asset.mirror[anchors[JOINT_MIRROR[j]]]
    return anchors
