"""ASM, the Adaptive Skinning Model (Yang et al., ICCV 2023), on the rig's template and 52 joints.

ASM makes every part of a skinning model a fitting variable, so that a head can be registered without
any training data:

- **GMM skinning weights** (ASM eq. 4-6): bone ``j``'s weight field is a ``K``-component 2D Gaussian
  mixture in the template's UV space, ``W_j(u) = sum_k pi_jk N(u | zeta_j + mu_jk, Sigma_jk)``, and a
  vertex's weights are the fields normalised across bones, ``w_vj = W_j(u_v) / sum_i W_i(u_v)``
  (:func:`gmm_skinning_weights`, computed in log space so that vertices far from every Gaussian stay
  finite).
- **Dynamic bone binding** (ASM eq. 7-16, Appendix B): bone ``j``'s bind position is a UV point
  ``zeta_j`` mapped to 3D by barycentric interpolation on the template,
  ``psi_j = alpha v_A + beta v_B + gamma v_C - v_t + psi_j^0`` (:func:`bone_positions_from_uv`), where
  ``t`` is the anchor vertex whose UV is the initial ``zeta_j``. The bind poses are recomputed from
  ``psi`` with the rotation and scale of the initial binding (the identity for this rig), which is
  :func:`rig.lbs.joint_world_transforms` with per-head bind positions.
- **Bone transforms** ``tau_j`` (9 floats: rotation xyz in degrees, translation xyz in mm, scale xyz as
  ``factor - 1``), composed down the joint hierarchy as in JNR.

Per bone that is ``2 + K + 2K + 3K + 9 = 11 + 6K`` floats (ASM Table 1); with the rig's 52 joints and
``K = 2``, 1196.

Our choices where ASM is silent or differs (each is tested):

- **pi**: ASM writes ``sum_k pi_k = 1`` but counts ``K`` floats per bone, and the normalisation across
  bones makes a bone's total mass matter. We keep ``K`` free positive amplitudes, stored as
  ``log_pi``.
- **Sigma**: stored as 3 Cholesky floats ``(log l11, log l22, l21)``, ``Sigma = L L^T``, so it is
  symmetric positive definite for any value (:func:`sigma_from_cholesky`).
- **UV domain.** MakeHuman's atlas has 12 UV islands. The GMM covers the skin island (scalp, face,
  ears, the top of the neck: 3185 vertices). Vertices only on the other islands (the rest of the neck,
  the eye pockets, eyeballs, mouth bag, teeth and tongue: 1689 vertices, which ASM's BFM mesh does not
  have) keep the rig's painted initial weights. The island's 18 **seam** vertices (the back of the
  scalp, where the island is cut) have two UV copies: their mixture value is the mean of the values at
  both copies, so the weights are continuous across the seam and mirror-symmetric. The island is
  mirror-symmetric about the line ``v = c`` (``c`` = 0.4832); per-vertex UVs are symmetrised about it
  (a change of at most 4e-4) so that symmetric GMM parameters give exactly symmetric weights.
- **zeta outside the island**: it is located in the nearest skin triangle and the barycentric
  coordinates extrapolate linearly, so the bone keeps moving smoothly (the regulariser keeps it near).
- **Anchor vertex t** (ASM eq. 5): the skin-island vertex nearest to the bone's initial position in
  3D (ASM projects along z then takes the nearest vertex; many of our joints are inside the head),
  chosen among vertices with one UV; joints on the midline take a midline vertex and right joints
  the mirror of their left partner's, so the binding is symmetric.

Frames and units as the rest of :mod:`rig`: millimetres, rig space (+Y up, +Z out of the face, +X the
subject's left), column vectors.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch
from torch import nn

from rig.asset import ASSET_DIR, RigAsset, cached_per_asset, read_npz, write_npz_atomic
from rig.errors import SetupError, ShapeError, check_shape
from rig.joints import JOINT_MIRROR
from rig.lbs import euler_to_matrix, hierarchy_levels, joint_world_transforms, skin_vertices_blended
from rig.model import JointRig, RigOutput
from rig.optim import Progress
from rig.template import TEMPLATE_VERSION

#: Channels of one bone's transform ``tau`` in order (units: deg, mm, ``factor - 1``).
ASM_CHANNELS: tuple[str, ...] = ("rotate_x", "rotate_y", "rotate_z", "translate_x", "translate_y", "translate_z",
                                 "scale_x", "scale_y", "scale_z")
#: Islands of MakeHuman's atlas that ASM's GMM does not cover (their vertices keep the painted weights).
STATIC_REGIONS: tuple[str, ...] = ("neck", "eyeballs", "mouth_interior", "teeth", "tongue", "eye_pockets")
#: Components of the committed initial GMM fits.
INIT_COMPONENTS: tuple[int, ...] = (2, 3, 5)
DEFAULT_COMPONENTS = 2
#: Smallest scale factor a bone may reach (``1 + s >= SCALE_FLOOR``), as the JNR channels.
SCALE_FLOOR = 0.5
LOG_PI_EMPTY = -30.0
#: Smallest and largest Gaussian axis (Cholesky diagonal) the model evaluates, UV units (0.1-250 mm).
SIGMA_RANGE = (2e-4, 0.5)
#: Range of ``log pi`` the model evaluates.
LOG_PI_RANGE = (-60.0, 20.0)


def default_init_path() -> Path:
    """The committed initial GMM parameters (``rig/assets/jnr_asm_init_v<template version>.npz``)."""
    return ASSET_DIR / f"jnr_asm_init_v{TEMPLATE_VERSION}.npz"


class AsmInitError(SetupError):
    """The initial ASM parameters are missing, corrupt or for another template."""


# --------------------------------------------------------------------------------------------------------
# Pure tensor functions
# --------------------------------------------------------------------------------------------------------

def sigma_from_cholesky(chol: torch.Tensor) -> torch.Tensor:
    """Covariances from Cholesky floats: ``L = [[exp(a), 0], [c, exp(b)]]``, ``Sigma = L L^T``.

    Args:
        chol: ``(*, 3)`` floats ``(a, b, c)`` (UV units for ``exp(a)``, ``exp(b)``, ``c``).

    Returns:
        ``(*, 2, 2)`` symmetric positive-definite matrices, UV units squared.

    Example:
        >>> sigma_from_cholesky(torch.tensor([0.0, 0.0, 0.0]))
        tensor([[1., 0.],
                [0., 1.]])
    """
    check_shape(chol.shape[-1:] == (3,), "sigma_from_cholesky", "chol", "(*, 3)", tuple(chol.shape))
    l11, l22, l21 = chol[..., 0].exp(), chol[..., 1].exp(), chol[..., 2]
    s00 = l11 * l11
    s01 = l11 * l21
    s11 = l21 * l21 + l22 * l22
    return torch.stack([s00, s01, s01, s11], dim=-1).reshape(chol.shape[:-1] + (2, 2))


def cholesky_from_sigma(sigma: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`sigma_from_cholesky`: ``(*, 2, 2)`` SPD matrices -> ``(*, 3)`` floats."""
    check_shape(sigma.shape[-2:] == (2, 2), "cholesky_from_sigma", "sigma", "(*, 2, 2)", tuple(sigma.shape))
    L = torch.linalg.cholesky(sigma)
    return torch.stack([L[..., 0, 0].log(), L[..., 1, 1].log(), L[..., 1, 0]], dim=-1)


def gmm_log_density(uv: torch.Tensor, log_pi: torch.Tensor, centres: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Log of each bone's mixture ``log W_j(u) = log sum_k pi_jk N(u | c_jk, Sigma_jk)`` (ASM eq. 4).

    The exponent of every Gaussian is a quadratic in ``(u, v)``, so all of them come from one matrix
    product of the points' monomials ``(u^2, v^2, uv, u, v, 1)`` with per-component coefficients
    (computed in float64; the result has ``log_pi``'s dtype).

    Args:
        uv: ``(N, 2)`` UV points.
        log_pi: ``(B, J, K)`` log amplitudes.
        centres: ``(B, J, K, 2)`` component centres (``zeta_j + mu_jk``), UV.
        sigma: ``(B, J, K, 2, 2)`` covariances (symmetric positive definite; the symmetric part is used).

    Returns:
        ``(B, N, J)`` log mixture values.
    """
    check_shape(uv.dim() == 2 and uv.shape[1] == 2, "gmm_log_density", "uv", "(N, 2)", tuple(uv.shape))
    check_shape(log_pi.dim() == 3, "gmm_log_density", "log_pi", "(B, J, K)", tuple(log_pi.shape))
    check_shape(centres.shape == log_pi.shape + (2,), "gmm_log_density", "centres", f"{tuple(log_pi.shape) + (2,)}",
                tuple(centres.shape))
    check_shape(sigma.shape == log_pi.shape + (2, 2), "gmm_log_density", "sigma", f"{tuple(log_pi.shape) + (2, 2)}",
                tuple(sigma.shape))
    B, J, K = log_pi.shape
    out_dtype = log_pi.dtype
    # float64 throughout: the expanded quadratic cancels (p x^2 - 2 p x c + p c^2 with p = 1 / sigma^2 up to
    # 1e7), which float32 cannot resolve for sharp Gaussians; the products are small, float64 costs little.
    uv, log_pi, centres, sigma = uv.double(), log_pi.double(), centres.double(), sigma.double()
    origin = uv.detach().mean(0)
    x, y = (uv - origin).unbind(-1)
    cx, cy = (centres - origin).unbind(-1)
    a, d = sigma[..., 0, 0], sigma[..., 1, 1]
    b = 0.5 * (sigma[..., 0, 1] + sigma[..., 1, 0])
    det = a * d - b * b
    p, q, r = d / det, -b / det, a / det                                  # Sigma^-1 = [[p, q], [q, r]]
    const = (log_pi - math.log(2.0 * math.pi) - 0.5 * det.log()
             - 0.5 * (p * cx * cx + 2.0 * q * cx * cy + r * cy * cy))
    coeffs = torch.stack([-0.5 * p, -0.5 * r, -q, p * cx + q * cy, q * cx + r * cy, const], dim=-1)  # (B, J, K, 6)
    monomials = torch.stack([x * x, y * y, x * y, x, y, torch.ones_like(x)], dim=-1)                  # (N, 6)
    # (K, 6, B*J): one GEMM per component, then a log-sum-exp across the K slices (elementwise, fast).
    per_k = coeffs.permute(2, 3, 0, 1).reshape(K, 6, B * J)
    exponent = monomials.unsqueeze(0) @ per_k                                                          # (K, N, B*J)
    if K == 1:
        out = exponent[0]
    else:
        peak = exponent.detach().amax(0)
        out = peak + (exponent - peak).exp().sum(0).log()
    return out.view(-1, B, J).transpose(0, 1).to(out_dtype)


def gmm_skinning_weights(vertex_uv: torch.Tensor, log_pi: torch.Tensor, centres: torch.Tensor, sigma: torch.Tensor,
                         seam_rows: torch.Tensor | None = None, seam_uv: torch.Tensor | None = None) -> torch.Tensor:
    """GMM skinning weights normalised across bones (ASM eq. 6), ``w_vj = W_j(u_v) / sum_i W_i(u_v)``.

    A vertex on a UV seam has a second UV copy; its mixture value is the mean of the values at both.

    Args:
        vertex_uv: ``(N, 2)`` the (first) UV of each vertex.
        log_pi, centres, sigma: as :func:`gmm_log_density`.
        seam_rows: optional ``(S,)`` int64 rows of ``vertex_uv`` that have a second copy,
            ``seam_uv``: ``(S, 2)`` those copies.

    Returns:
        ``(B, N, J)`` weights: non-negative, each row sums to 1.
    """
    check_shape(vertex_uv.dim() == 2 and vertex_uv.shape[-1] == 2, "gmm_skinning_weights", "vertex_uv", "(N, 2)",
                tuple(vertex_uv.shape))
    N = vertex_uv.shape[0]
    if seam_rows is not None and len(seam_rows):
        check_shape(seam_uv is not None and seam_uv.shape == (len(seam_rows), 2), "gmm_skinning_weights", "seam_uv",
                    f"({len(seam_rows)}, 2)", None if seam_uv is None else tuple(seam_uv.shape))
        log_w = gmm_log_density(torch.cat([vertex_uv, seam_uv.to(vertex_uv.dtype)]), log_pi, centres, sigma)
        first, second = log_w[:, :N], log_w[:, N:]
        mean = torch.logaddexp(first[:, seam_rows], second) - math.log(2.0)
        log_w = first.index_copy(1, seam_rows, mean)
    else:
        log_w = gmm_log_density(vertex_uv, log_pi, centres, sigma)
    return torch.softmax(log_w, dim=-1)


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
    alpha = ((-(x - B[..., 0]) * (C[..., 1] - B[..., 1]) + (y - B[..., 1]) * (C[..., 0] - B[..., 0]))
             / (-(A[..., 0] - B[..., 0]) * (C[..., 1] - B[..., 1]) + (A[..., 1] - B[..., 1]) * (C[..., 0] - B[..., 0])))
    beta = ((-(x - C[..., 0]) * (A[..., 1] - C[..., 1]) + (y - C[..., 1]) * (A[..., 0] - C[..., 0]))
            / (-(B[..., 0] - C[..., 0]) * (A[..., 1] - C[..., 1]) + (B[..., 1] - C[..., 1]) * (A[..., 0] - C[..., 0])))
    return torch.stack([alpha, beta, 1.0 - alpha - beta], dim=-1)


def uv_face_tree(face_uv: torch.Tensor):
    """A KD-tree of the triangles' UV centroids for :func:`locate_uv` (build once per triangle set)."""
    from scipy.spatial import cKDTree

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
    check_shape(face_uv.dim() == 3 and face_uv.shape[1:] == (3, 2), "locate_uv", "face_uv", "(F, 3, 2)",
                tuple(face_uv.shape))
    with torch.no_grad():
        pts = points.detach().to(face_uv.dtype)
        k = min(candidates, face_uv.shape[0])
        _, cand = (tree or uv_face_tree(face_uv)).query(pts.cpu().numpy(), k=k)
        cand = torch.as_tensor(cand, device=points.device).view(len(pts), k)
        inside = uv_barycentric(pts[:, None, :], face_uv[cand]).min(-1).values      # (N, k)
        best = inside.argmax(-1)
        face = cand.gather(1, best[:, None])[:, 0]
        outside = inside.gather(1, best[:, None])[:, 0] < -1e-9
        if outside.any():
            bary = uv_barycentric(pts[outside][:, None, :], face_uv[None])              # (n, F, 3)
            face[outside] = bary.min(-1).values.argmax(-1)
        return face


def bone_positions_from_uv(zeta: torch.Tensor, face_uv: torch.Tensor, face_xyz: torch.Tensor,
                           anchor_xyz: torch.Tensor, initial_positions: torch.Tensor, tree=None) -> torch.Tensor:
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
    check_shape(zeta.dim() == 3 and zeta.shape[-1] == 2, "bone_positions_from_uv", "zeta", "(B, J, 2)",
                tuple(zeta.shape))
    B, J = zeta.shape[:2]
    flat = zeta.reshape(B * J, 2)
    face = locate_uv(flat, face_uv, tree=tree)
    bary = uv_barycentric(flat, face_uv[face].to(zeta.dtype))               # (B*J, 3)
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


# --------------------------------------------------------------------------------------------------------
# The UV domain of the template
# --------------------------------------------------------------------------------------------------------

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
    corner_key = np.array([keys.setdefault((round(float(a), 7), round(float(b), 7)), len(keys))
                           for a, b in uv.reshape(-1, 2)]).reshape(-1, 3)
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

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
    pairs = [(i, row[int(asset.mirror[v])]) for i, v in enumerate(gmm_vertices)
             if single[i] and int(asset.mirror[v]) in row and single[row[int(asset.mirror[v])]]]
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


# --------------------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class AsmParameters:
    """Every tunable float of ASM for a batch of ``B`` heads (``J`` bones, ``K`` components).

    Attributes:
        tau: ``(B, J, 9)`` bone transforms (:data:`ASM_CHANNELS`: deg, mm, ``factor - 1``).
        zeta: ``(B, J, 2)`` bone positions in UV space.
        log_pi: ``(B, J, K)`` log mixture amplitudes.
        mu: ``(B, J, K, 2)`` component offsets from ``zeta``, UV.
        chol: ``(B, J, K, 3)`` Cholesky floats of the covariances (:func:`sigma_from_cholesky`).
    """

    tau: torch.Tensor
    zeta: torch.Tensor
    log_pi: torch.Tensor
    mu: torch.Tensor
    chol: torch.Tensor

    @staticmethod
    def names() -> tuple[str, ...]:
        return tuple(f.name for f in fields(AsmParameters))

    def as_dict(self) -> dict[str, torch.Tensor]:
        return {n: getattr(self, n) for n in self.names()}

    def map(self, fn) -> AsmParameters:
        """A new set with ``fn`` applied to every tensor (``p.map(torch.Tensor.detach)``)."""
        return AsmParameters(**{n: fn(t) for n, t in self.as_dict().items()})

    def select(self, index) -> AsmParameters:
        """Heads ``index`` (an int keeps a batch of 1)."""
        if isinstance(index, int):
            index = slice(index, index + 1)
        return self.map(lambda t: t[index])

    @property
    def batch(self) -> int:
        return int(self.tau.shape[0])

    @property
    def components(self) -> int:
        return int(self.log_pi.shape[-1])


@dataclass(frozen=True)
class AsmVariant:
    """Which parts of ASM are tunable (ASM's ablation, Table 7).

    Attributes:
        dynamic_binding: ``zeta`` moves the bind positions (and the GMM centres).
        gmm_weights: GMM skinning weights with tunable ``pi, mu, Sigma`` (else the rig's painted
            weights, fixed).
    """

    dynamic_binding: bool = True
    gmm_weights: bool = True

    @property
    def name(self) -> str:
        if self.dynamic_binding and self.gmm_weights:
            return "asm"
        if self.gmm_weights:
            return "asm_gmm"
        return "asm_dynamic_binding" if self.dynamic_binding else "asm_static"

    def free(self) -> tuple[str, ...]:
        """Names of the :class:`AsmParameters` fields that this variant optimises."""
        names = ["tau"]
        if self.dynamic_binding:
            names.append("zeta")
        if self.gmm_weights:
            names += ["log_pi", "mu", "chol"]
        return tuple(names)


@dataclass(frozen=True)
class AsmRegularizer:
    """ASM eq. 19: ``l1 |tau|^2 + l2 |zeta - zeta'|^2 + l3 |pi - pi'|^2 + l4 |mu - mu'|^2 + l5 |Sigma - Sigma'|^2``.

    ``tau`` is measured in units of :data:`TAU_UNITS` (10 deg, 1 mm, 0.1 scale), UV quantities in units
    of :data:`UV_UNIT` (0.01, about 5 mm on the face), ``pi`` as ``log pi`` and ``Sigma`` as its Cholesky
    floats. Defaults are ASM's (1, 0.1, 0.1, 0.1, 0.1). Each term is a sum over bones, mean over nothing.
    """

    tau: float = 1.0
    zeta: float = 0.1
    pi: float = 0.1
    mu: float = 0.1
    sigma: float = 0.1


TAU_UNITS = (10.0, 10.0, 10.0, 1.0, 1.0, 1.0, 0.1, 0.1, 0.1)
UV_UNIT = 0.01


# --------------------------------------------------------------------------------------------------------
# The model
# --------------------------------------------------------------------------------------------------------

class AdaptiveSkinning(nn.Module):
    """ASM on the rig's template and joints: :class:`AsmParameters` -> posed vertices.

    Args:
        rig: the :class:`rig.model.JointRig` whose template, hierarchy and painted weights it uses
            (default: a new float32 rig).
        components: ``K``, Gaussians per bone (the committed initial fits have ``K`` in
            :data:`INIT_COMPONENTS`; other values start from a fit made on the spot, a few seconds).
        init_path: initial GMM parameters (default: :func:`default_init_path`).

    Example:
        >>> model = AdaptiveSkinning(components=2)
        >>> p = model.initial(1)
        >>> model(p).vertices.shape
        torch.Size([1, 4874, 3])
    """

    def __init__(self, rig=None, components: int = DEFAULT_COMPONENTS, init_path: str | Path | None = None) -> None:
        super().__init__()
        if rig is None:
            rig = JointRig()
        if not isinstance(components, int) or components < 1:
            raise ValueError(f"AdaptiveSkinning: components must be a positive int, got {components!r}")
        self.rig = rig
        self.components = components
        asset = rig.asset
        domain = uv_domain(asset)
        self.domain = domain
        dtype = rig.template.dtype
        self.register_buffer("gmm_vertices", torch.as_tensor(domain.gmm_vertices))
        self.register_buffer("vertex_uv", torch.as_tensor(domain.vertex_uv[:, 0], dtype=dtype))
        self.register_buffer("seam_rows", torch.as_tensor(domain.seam_rows))
        self.register_buffer("seam_uv", torch.as_tensor(domain.seam_uv, dtype=dtype))
        self.register_buffer("face_uv", torch.as_tensor(domain.face_uv, dtype=dtype))
        self.face_tree = uv_face_tree(self.face_uv)  # locate_uv's, built once
        self.register_buffer("face_xyz", torch.as_tensor(asset.vertices[domain.faces], dtype=dtype))
        self.register_buffer("anchor_xyz", torch.as_tensor(asset.vertices[domain.anchors], dtype=dtype))
        self.register_buffer("painted", rig.dense_weights().detach().clone())
        self.levels = hierarchy_levels(rig.parents)
        init = load_initial_gmm(components, init_path)
        self.register_buffer("zeta0", torch.as_tensor(domain.zeta0, dtype=dtype))
        self.register_buffer("log_pi0", torch.as_tensor(init["log_pi"], dtype=dtype))
        self.register_buffer("mu0", torch.as_tensor(init["mu"], dtype=dtype))
        self.register_buffer("chol0", torch.as_tensor(init["chol"], dtype=dtype))

    # sizes -------------------------------------------------------------------------------------------
    @property
    def num_bones(self) -> int:
        return int(self.zeta0.shape[0])

    @property
    def parameters_per_bone(self) -> int:
        """ASM Table 1: ``2 (zeta) + K (pi) + 2K (mu) + 3K (Sigma) + 9 (tau) = 11 + 6K``."""
        return 11 + 6 * self.components

    @property
    def num_parameters(self) -> int:
        return self.num_bones * self.parameters_per_bone

    def num_floats(self, variant: AsmVariant = AsmVariant()) -> dict[str, int]:
        """Model size in floats: the fixed part (template, initial binding, painted weights of the static
        islands, initial GMM) and the per-head tunable part of ``variant``."""
        J, K = self.num_bones, self.components
        per_head = {"tau": 9 * J, "zeta": 2 * J, "log_pi": K * J, "mu": 2 * K * J, "chol": 3 * K * J}
        static_rows = self.rig.num_vertices - len(self.domain.gmm_vertices)
        painted_static = int((self.painted[~self._gmm_row_mask()] > 0).sum())
        fixed = 3 * self.rig.num_vertices + 3 * J + (6 * K * J if variant.gmm_weights else
                                                     int((self.painted > 0).sum()))
        if variant.gmm_weights:
            fixed += painted_static
        return {"fixed": int(fixed), "per_head": int(sum(per_head[n] for n in variant.free())),
                "static_vertices": int(static_rows)}

    def _gmm_row_mask(self) -> torch.Tensor:
        mask = torch.zeros(self.rig.num_vertices, dtype=torch.bool)
        mask[self.gmm_vertices] = True
        return mask

    # parameters --------------------------------------------------------------------------------------
    def initial(self, batch: int = 1) -> AsmParameters:
        """The initial binding and GMM fits, zero transforms, for ``batch`` heads (new tensors)."""
        if not isinstance(batch, int) or batch < 1:
            raise ValueError(f"AdaptiveSkinning.initial: batch must be a positive int, got {batch!r}")
        J, K = self.num_bones, self.components
        return AsmParameters(
            tau=self.zeta0.new_zeros(batch, J, 9),
            zeta=self.zeta0.expand(batch, J, 2).clone(),
            log_pi=self.log_pi0.expand(batch, J, K).clone(),
            mu=self.mu0.expand(batch, J, K, 2).clone(),
            chol=self.chol0.expand(batch, J, K, 3).clone(),
        )

    def _check(self, p: AsmParameters) -> None:
        B, J, K = p.batch, self.num_bones, self.components
        want = {"tau": (B, J, 9), "zeta": (B, J, 2), "log_pi": (B, J, K), "mu": (B, J, K, 2), "chol": (B, J, K, 3)}
        for name, shape in want.items():
            got = tuple(getattr(p, name).shape)
            if got != shape:
                raise ShapeError(f"AdaptiveSkinning: AsmParameters.{name} must have shape {shape}, got {got}")

    # evaluation --------------------------------------------------------------------------------------
    def gmm_weights(self, p: AsmParameters) -> torch.Tensor:
        """``(B, N, J)`` GMM weights of the skin-island vertices (:attr:`gmm_vertices`).

        A Gaussian's axes are kept within :data:`SIGMA_RANGE` (UV units) and ``log pi`` within
        :data:`LOG_PI_RANGE`, so that no optimiser step can make a covariance singular.
        """
        self._check(p)
        centres = p.zeta.unsqueeze(-2) + p.mu
        chol = torch.cat([p.chol[..., :2].clamp(math.log(SIGMA_RANGE[0]), math.log(SIGMA_RANGE[1])),
                          p.chol[..., 2:].clamp(-SIGMA_RANGE[1], SIGMA_RANGE[1])], dim=-1)
        return gmm_skinning_weights(self.vertex_uv.to(p.mu.dtype), p.log_pi.clamp(*LOG_PI_RANGE), centres,
                                    sigma_from_cholesky(chol), self.seam_rows, self.seam_uv)

    def weights(self, p: AsmParameters, gmm: bool = True) -> torch.Tensor:
        """``(B, V, J)`` skinning weights of every vertex: the GMM's on the skin island, the painted
        initial weights elsewhere (all painted with ``gmm=False``)."""
        painted = self.painted.to(p.tau.dtype).expand(p.batch, -1, -1)
        if not gmm:
            return painted
        return painted.index_copy(1, self.gmm_vertices, self.gmm_weights(p))

    def bone_positions(self, p: AsmParameters, dynamic: bool = True) -> torch.Tensor:
        """``(B, J, 3)`` bind positions, mm (the initial binding with ``dynamic=False``)."""
        self._check(p)
        if not dynamic:
            return self.rig.bind_positions.to(p.tau.dtype).expand(p.batch, -1, -1)
        return bone_positions_from_uv(p.zeta, self.face_uv, self.face_xyz, self.anchor_xyz, self.rig.bind_positions,
                                      self.face_tree)

    def forward(self, p: AsmParameters, vertices: torch.Tensor | None = None, *, dynamic_binding: bool = True,
                gmm_weights: bool = True):
        """Pose the head (ASM eq. 3).

        Args:
            p: the parameters of ``B`` heads.
            vertices: optional ``(V, 3)`` or ``(B, V, 3)`` rest vertices, mm (default: the template; e.g.
                with expression offsets added).
            dynamic_binding: bind positions from ``zeta`` (else the initial binding).
            gmm_weights: GMM weights on the skin island (else the painted weights everywhere).

        Returns:
            :class:`rig.model.RigOutput` with ``vertices (B, V, 3)`` in mm.
        """
        self._check(p)
        bind = self.bone_positions(p, dynamic_binding)
        world, skinning = joint_world_transforms(bone_local_transforms(p.tau), bind, self.rig.parents, self.levels)
        rest = self.rig.template if vertices is None else vertices
        posed = skin_vertices_blended(rest.to(p.tau.dtype), self.weights(p, gmm_weights), skinning)
        return RigOutput(posed, world, skinning)

    def regularizer(self, p: AsmParameters, weights: AsmRegularizer = AsmRegularizer()) -> torch.Tensor:
        """ASM eq. 19 per head, ``(B,)`` (units: :class:`AsmRegularizer`)."""
        self._check(p)
        units = p.tau.new_tensor(TAU_UNITS)
        terms = (weights.tau * ((p.tau / units) ** 2).sum((1, 2))
                 + weights.zeta * (((p.zeta - self.zeta0) / UV_UNIT) ** 2).sum((1, 2))
                 + weights.pi * ((p.log_pi - self.log_pi0) ** 2).sum((1, 2))
                 + weights.mu * (((p.mu - self.mu0) / UV_UNIT) ** 2).sum((1, 2, 3))
                 + weights.sigma * ((p.chol - self.chol0) ** 2).sum((1, 2, 3)))
        return terms


# --------------------------------------------------------------------------------------------------------
# Fitting the initial GMM to the painted weights
# --------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class GmmInitFit:
    """Result of :func:`fit_initial_gmm`: parameters ``(J, K, ...)`` and how well they reproduce the
    painted weights on the skin island (``rms``, ``max_abs``: weight units; ``seconds``)."""

    log_pi: np.ndarray
    mu: np.ndarray
    chol: np.ndarray
    rms: float
    max_abs: float
    seconds: float


def _moment_init(uv: np.ndarray, w: np.ndarray, zeta: np.ndarray, K: int, rng: np.random.Generator):
    """Starting mixtures of every bone from its painted weights ``w (N, J)`` at ``uv (N, 2)``: weighted
    k-means in UV, then each cluster's weighted moments; bones without skin weight get ``LOG_PI_EMPTY``."""
    J = w.shape[1]
    log_pi = np.full((J, K), LOG_PI_EMPTY)
    mu = np.zeros((J, K, 2))
    chol = np.zeros((J, K, 3))
    chol[..., 0] = chol[..., 1] = math.log(0.02)
    for j in range(J):
        mass = w[:, j]
        if mass.sum() < 1e-6:
            continue
        idx = np.nonzero(mass > 1e-4)[0]
        pts, m = uv[idx], mass[idx]
        centres = pts[rng.choice(len(pts), size=min(K, len(pts)), replace=False, p=m / m.sum())]
        if len(centres) < K:
            centres = np.concatenate([centres, np.repeat(centres[:1], K - len(centres), 0)])
        for _ in range(20):
            assign = np.argmin(((pts[:, None] - centres[None]) ** 2).sum(-1), axis=1)
            for k in range(K):
                sel = assign == k
                if m[sel].sum() > 0:
                    centres[k] = (pts[sel] * m[sel, None]).sum(0) / m[sel].sum()
        for k in range(K):
            sel = assign == k
            mk = m[sel]
            if mk.sum() <= 0:
                continue
            d = pts[sel] - centres[k]
            cov = (d[:, :, None] * d[:, None, :] * mk[:, None, None]).sum(0) / mk.sum() + np.eye(2) * 1e-5
            L = np.linalg.cholesky(cov)
            chol[j, k] = (math.log(L[0, 0]), math.log(L[1, 1]), L[1, 0])
            mu[j, k] = centres[k] - zeta[j]
            log_pi[j, k] = math.log(mk.sum() / len(uv) * 0.05 + 1e-12)
    return log_pi, mu, chol


def fit_initial_gmm(model_or_rig=None, components: int = DEFAULT_COMPONENTS, *, iterations: int = 1500,
                    lr: float = 0.03, seed: int = 0, ce_weight: float = 0.0,
                    progress: Progress | None = None) -> GmmInitFit:
    """Fit the GMM of every bone to the rig's painted initial weights on the skin island (ASM fits
    Blender's automatic weights): least squares on the normalised weights (eq. 6), Adam from a weighted
    k-means start, ``zeta`` at the anchors.

    Args:
        model_or_rig: a :class:`rig.model.JointRig` (default: a new one).
        components: ``K``.
        iterations, lr: Adam on ``(log_pi, mu / 0.01, chol)``.
        ce_weight: weight of a cross-entropy term (painted weights against GMM weights) added to the
            squared error.
        seed: for the k-means start.
        progress: ``progress("gmm", i, iterations)``.

    Returns:
        :class:`GmmInitFit` (float64 arrays).
    """
    t0 = time.perf_counter()
    rig = model_or_rig if model_or_rig is not None else JointRig()
    domain = uv_domain(rig.asset)
    painted = rig.dense_weights().detach().double()[torch.as_tensor(domain.gmm_vertices)]
    rng = np.random.default_rng(seed)
    log_pi0, mu0, chol0 = _moment_init(domain.vertex_uv[:, 0], painted.numpy(), domain.zeta0, components, rng)
    uv = torch.as_tensor(domain.vertex_uv[:, 0])
    seam_rows, seam_uv = torch.as_tensor(domain.seam_rows), torch.as_tensor(domain.seam_uv)
    zeta = torch.as_tensor(domain.zeta0)[None]
    log_pi = torch.tensor(log_pi0)[None].requires_grad_(True)
    mu_n = torch.tensor(mu0 / UV_UNIT)[None].requires_grad_(True)
    chol = torch.tensor(chol0)[None].requires_grad_(True)
    opt = torch.optim.Adam([log_pi, mu_n, chol], lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, iterations, eta_min=lr * 0.02)
    target = painted[None]
    for it in range(iterations):
        w = gmm_skinning_weights(uv, log_pi, zeta.unsqueeze(-2) + mu_n * UV_UNIT, sigma_from_cholesky(chol),
                                 seam_rows, seam_uv)
        loss = ((w - target) ** 2).sum(-1).mean()
        if ce_weight:
            # cross-entropy: a vertex whose painted bone gets almost no GMM weight costs a lot
            loss = loss + ce_weight * -(target * (w + 1e-6).log()).sum(-1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if progress is not None:
            progress("gmm", it + 1, iterations)
    with torch.no_grad():
        w = gmm_skinning_weights(uv, log_pi, zeta.unsqueeze(-2) + mu_n * UV_UNIT, sigma_from_cholesky(chol),
                                 seam_rows, seam_uv)
        err = (w - target)[0]
    return GmmInitFit(log_pi.detach()[0].numpy(), (mu_n.detach()[0] * UV_UNIT).numpy(), chol.detach()[0].numpy(),
                      float(err.pow(2).mean().sqrt()), float(err.abs().max()), time.perf_counter() - t0)


def symmetrize_gmm(log_pi: np.ndarray, mu: np.ndarray, chol: np.ndarray):
    """Make a fitted GMM exactly mirror-symmetric: each right bone becomes the reflection of its left
    partner (``mu_v -> -mu_v``, ``Sigma_uv -> -Sigma_uv``); midline bones are left as fitted."""
    log_pi, mu, chol = log_pi.copy(), mu.copy(), chol.copy()
    from rig.asset import load_asset

    positions = load_asset().joint_positions
    for j, partner in enumerate(JOINT_MIRROR):
        if positions[j, 0] < -1e-6:
            log_pi[j] = log_pi[partner]
            mu[j] = mu[partner] * np.array([1.0, -1.0])
            chol[j] = chol[partner] * np.array([1.0, 1.0, -1.0])
    return log_pi, mu, chol


def build_initial_gmm(components: tuple[int, ...] = INIT_COMPONENTS, *, iterations: int = 3000,
                      ce_weight: float = 0.05, progress: Progress | None = None) -> dict[str, np.ndarray]:
    """The arrays of the initial-GMM asset: ``k{K}_log_pi (J, K)``, ``k{K}_mu (J, K, 2)``,
    ``k{K}_chol (J, K, 3)``, ``k{K}_report (rms, max_abs, seconds)`` for each ``K``, plus ``version``.

    The loss is the squared weight error plus ``ce_weight`` times the cross-entropy of the painted weights
    against the GMM's (0.05: on K = 2, 600 steps, it lowered the RMS error from 0.021 to 0.017)."""
    rig = JointRig(dtype=torch.float64)
    arrays: dict[str, np.ndarray] = {"version": np.array(TEMPLATE_VERSION)}
    for K in components:
        fit = fit_initial_gmm(rig, K, iterations=iterations, ce_weight=ce_weight, progress=progress)
        log_pi, mu, chol = symmetrize_gmm(fit.log_pi, fit.mu, fit.chol)
        arrays[f"k{K}_log_pi"], arrays[f"k{K}_mu"], arrays[f"k{K}_chol"] = log_pi, mu, chol
        w = _weights_of(rig, log_pi, mu, chol)
        painted = rig.dense_weights().detach()[torch.as_tensor(uv_domain(rig.asset).gmm_vertices)]
        err = w - painted
        arrays[f"k{K}_report"] = np.array([float(err.pow(2).mean().sqrt()), float(err.abs().max()), fit.seconds])
    return arrays


def _weights_of(rig, log_pi, mu, chol) -> torch.Tensor:
    domain = uv_domain(rig.asset)
    zeta = torch.as_tensor(domain.zeta0)[None]
    with torch.no_grad():
        return gmm_skinning_weights(torch.as_tensor(domain.vertex_uv[:, 0]), torch.as_tensor(log_pi)[None],
                                    zeta.unsqueeze(-2) + torch.as_tensor(mu)[None],
                                    sigma_from_cholesky(torch.as_tensor(chol)[None]),
                                    torch.as_tensor(domain.seam_rows), torch.as_tensor(domain.seam_uv))[0]


def save_initial_gmm(path: str | Path | None = None, **kwargs) -> dict[str, np.ndarray]:
    """Fit (:func:`build_initial_gmm`) and write the initial-GMM asset atomically; returns the arrays."""
    arrays = build_initial_gmm(**kwargs)
    write_npz_atomic(path or default_init_path(), arrays)
    load_initial_gmm.cache_clear()
    return arrays


def _load_init_file(path: str) -> dict[str, np.ndarray]:
    p = Path(path)
    arrays = read_npz(p, AsmInitError, "initial ASM parameters", "make them with `jnr train --asm-init`")
    if int(arrays.get("version", -1)) != TEMPLATE_VERSION:
        raise AsmInitError(f"initial ASM parameters {p} are for template version {arrays.get('version')}; this code "
                           f"expects {TEMPLATE_VERSION} (remake them with `jnr train --asm-init`)")
    return arrays



@functools.lru_cache(maxsize=16)
def _initial_gmm_cached(components: int, path: str) -> dict[str, np.ndarray]:
    arrays = _load_init_file(path)
    key = f"k{components}_log_pi"
    if key in arrays:
        return {"log_pi": arrays[key], "mu": arrays[f"k{components}_mu"], "chol": arrays[f"k{components}_chol"]}
    fit = fit_initial_gmm(None, components)
    log_pi, mu, chol = symmetrize_gmm(fit.log_pi, fit.mu, fit.chol)
    return {"log_pi": log_pi, "mu": mu, "chol": chol}


def load_initial_gmm(components: int = DEFAULT_COMPONENTS, path: str | Path | None = None) -> dict[str, np.ndarray]:
    """Initial ``log_pi (J, K)``, ``mu (J, K, 2)``, ``chol (J, K, 3)`` for ``K = components`` (from the
    asset file; a ``K`` it lacks is fitted on the spot and cached for the process)."""
    return _initial_gmm_cached(int(components), str(path or default_init_path()))


load_initial_gmm.cache_clear = _initial_gmm_cached.cache_clear  # type: ignore[attr-defined]


# --------------------------------------------------------------------------------------------------------
# Registration to meshes in the template's topology
# --------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class AsmFit:
    """Result of :func:`fit_asm`.

    Attributes:
        params: the fitted :class:`AsmParameters`.
        vertices: ``(B, V, 3)`` fitted vertices, mm.
        rmse: ``(B,)`` vertex RMSE against the targets, mm.
        losses: ``(T,)`` mean loss per iteration.
        seconds: wall time of the fit.
    """

    params: AsmParameters
    vertices: torch.Tensor
    rmse: torch.Tensor
    losses: torch.Tensor
    seconds: float


#: Adam step scale per parameter (its unit): tau as :data:`TAU_UNITS`, UV in :data:`UV_UNIT`.
def _units(p: AsmParameters) -> dict[str, torch.Tensor | float]:
    return {"tau": p.tau.new_tensor(TAU_UNITS), "zeta": UV_UNIT, "log_pi": 1.0, "mu": UV_UNIT, "chol": 1.0}


def fit_asm(model: AdaptiveSkinning, targets: torch.Tensor, *, variant: AsmVariant = AsmVariant(),
            init: AsmParameters | None = None, iterations: int = 400, lr: float = 0.02,
            regularizer: AsmRegularizer = AsmRegularizer(tau=1e-4, zeta=1e-3, pi=1e-3, mu=1e-3, sigma=1e-3),
            vertex_mask: torch.Tensor | None = None, progress: Progress | None = None) -> AsmFit:
    """Register ASM to meshes with known correspondence (point-to-point, ASM Appendix C's setting with
    known correspondence): Adam on the free parameters of ``variant`` in normalised units, cosine
    learning-rate decay, plus the eq.-19 regulariser.

    Args:
        model: the model.
        targets: ``(B, V, 3)`` meshes in the template's topology, mm.
        variant: which parts are tunable.
        init: starting parameters (default: :meth:`AdaptiveSkinning.initial`).
        iterations, lr: Adam steps and step size (in the units of :func:`_units`).
        regularizer: eq.-19 weights; the loss is the mean squared vertex distance (mm^2) + the regulariser
            divided by the number of vertices.
        vertex_mask: optional ``(V,)`` bool, the vertices that count (default: all).
        progress: ``progress("asm", i, iterations)``.

    Returns:
        :class:`AsmFit`.
    """
    V = model.rig.num_vertices
    if targets.dim() != 3 or targets.shape[1:] != (V, 3):
        raise ShapeError(f"fit_asm: targets must have shape (B, {V}, 3), got {tuple(targets.shape)}")
    if not torch.isfinite(targets).all():
        raise ValueError("fit_asm: targets contain NaN or infinite values")
    t0 = time.perf_counter()
    dtype = model.rig.template.dtype
    targets = targets.to(dtype)
    B = targets.shape[0]
    start = (init or model.initial(B)).map(lambda t: t.detach().to(dtype))
    if start.batch != B:
        raise ShapeError(f"fit_asm: init has {start.batch} heads, targets {B}")
    units = _units(start)
    free = variant.free()
    scaled = {n: (getattr(start, n) / units[n]).clone().requires_grad_(True) for n in free}
    opt = torch.optim.Adam(list(scaled.values()), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(iterations, 1), eta_min=lr * 0.02)
    mask = None if vertex_mask is None else vertex_mask.to(targets.device)
    count = V if mask is None else int(mask.sum())

    def current() -> AsmParameters:
        values = start.as_dict()
        values.update({n: scaled[n] * units[n] for n in free})
        return AsmParameters(**values)

    losses = []
    for it in range(iterations):
        p = current()
        pred = model(p, dynamic_binding=variant.dynamic_binding, gmm_weights=variant.gmm_weights).vertices
        sq = ((pred - targets) ** 2).sum(-1)
        data = (sq if mask is None else sq[:, mask]).mean(-1)
        loss = (data + model.regularizer(p, regularizer) / count).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(loss.item())
        if progress is not None:
            progress("asm", it + 1, iterations)
    with torch.no_grad():
        p = current().map(torch.Tensor.detach)
        pred = model(p, dynamic_binding=variant.dynamic_binding, gmm_weights=variant.gmm_weights).vertices
        rmse = ((pred - targets) ** 2).sum(-1).mean(-1).sqrt()
    return AsmFit(p, pred, rmse, torch.tensor(losses), time.perf_counter() - t0)


__all__ = [
    "ASM_CHANNELS",
    "AdaptiveSkinning",
    "AsmFit",
    "AsmInitError",
    "AsmParameters",
    "AsmRegularizer",
    "AsmVariant",
    "GmmInitFit",
    "UvDomain",
    "bone_local_transforms",
    "bone_positions_from_uv",
    "build_initial_gmm",
    "cholesky_from_sigma",
    "default_init_path",
    "fit_asm",
    "fit_initial_gmm",
    "gmm_log_density",
    "gmm_skinning_weights",
    "load_initial_gmm",
    "locate_uv",
    "mirror_uv",
    "save_initial_gmm",
    "sigma_from_cholesky",
    "symmetrize_gmm",
    "uv_barycentric",
    "uv_domain",
    "uv_face_tree",
]


# --------------------------------------------------------------------------------------------------------
# Named parameter files
# --------------------------------------------------------------------------------------------------------

def asm_params_to_dict(p: AsmParameters, joint_names: tuple[str, ...]) -> dict:
    """One head's parameters as JSON-ready nested lists, by bone name: ``{"components": K, "bones":
    {name: {"tau": {channel: value}, "zeta": [u, v], "log_pi": [K], "mu": [[du, dv] x K],
    "chol": [[log l11, log l22, l21] x K]}}}`` (channels :data:`ASM_CHANNELS`)."""
    if p.batch != 1:
        raise ShapeError(f"asm_params_to_dict: one head expected, got a batch of {p.batch}")
    if len(joint_names) != p.tau.shape[1]:
        raise ShapeError(f"asm_params_to_dict: {len(joint_names)} names for {p.tau.shape[1]} bones")
    q = p.map(lambda t: t.detach().double().cpu()[0])
    bones = {}
    for j, name in enumerate(joint_names):
        bones[name] = {"tau": {c: float(v) for c, v in zip(ASM_CHANNELS, q.tau[j])},
                       "zeta": q.zeta[j].tolist(), "log_pi": q.log_pi[j].tolist(), "mu": q.mu[j].tolist(),
                       "chol": q.chol[j].tolist()}
    return {"components": p.components, "bones": bones,
            "units": {"tau": "rotate deg, translate mm, scale factor - 1", "zeta": "uv", "mu": "uv"}}


def asm_params_from_dict(data: dict, model: AdaptiveSkinning) -> AsmParameters:
    """Inverse of :func:`asm_params_to_dict` for ``model`` (batch 1). Bones missing from the file keep
    their initial values.

    Raises:
        ValueError: another ``K``, an unknown bone or channel, values of the wrong length or not finite.
    """
    if not isinstance(data, dict) or not isinstance(data.get("bones"), dict):
        raise ValueError("ASM parameters must be an object with a 'bones' object")
    if int(data.get("components", -1)) != model.components:
        raise ValueError(f"ASM parameters have K = {data.get('components')} Gaussians per bone, the model "
                         f"{model.components}")
    names = model.rig.asset.joint_names
    p = model.initial(1).map(lambda t: t.detach().clone())
    K = model.components
    for name, bone in data["bones"].items():
        if name not in names:
            raise ValueError(f"unknown ASM bone {name!r}; bones are the rig's joints ({names[0]}, ...)")
        j = names.index(name)
        tau = bone.get("tau", {})
        unknown = [c for c in tau if c not in ASM_CHANNELS]
        if unknown:
            raise ValueError(f"bone {name!r}: unknown channel(s) {unknown}; channels are {list(ASM_CHANNELS)}")
        for c, v in tau.items():
            p.tau[0, j, ASM_CHANNELS.index(c)] = float(v)
        for field, shape in (("zeta", (2,)), ("log_pi", (K,)), ("mu", (K, 2)), ("chol", (K, 3))):
            if field in bone:
                value = torch.as_tensor(np.asarray(bone[field], np.float64), dtype=p.tau.dtype)
                if tuple(value.shape) != shape:
                    raise ValueError(f"bone {name!r}: {field} must have shape {shape}, got {tuple(value.shape)}")
                getattr(p, field)[0, j] = value
    for field, t in p.as_dict().items():
        if not torch.isfinite(t).all():
            raise ValueError(f"ASM parameters: {field} has NaN or infinite values")
    return p


__all__ += ["asm_params_from_dict", "asm_params_to_dict"]
