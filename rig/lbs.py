"""Pure tensor functions of the joint rig: local transforms, the kinematic chain (JNR eq. 1) and linear
blend skinning (JNR eq. 2).

Conventions: column vectors, 4x4 homogeneous matrices, millimetres, rig space (right-handed, +Y up,
+Z out of the face). Every function works for float32 and float64 and any batch size ``B``.
"""

from __future__ import annotations

import math

import torch

from rig.errors import ShapeError, check_shape
from rig.joints import CHANNEL_KINDS, ROTATE, SCALE_AXES, TRANSLATE, UNIFORM_SCALE


def euler_to_matrix(angles: torch.Tensor) -> torch.Tensor:
    """Rotation matrices from Euler angles in radians, ``R = Rz(c) @ Ry(b) @ Rx(a)``.

    Args:
        angles: ``(*, 3)`` angles ``(a, b, c)`` about x, y, z in radians.

    Returns:
        ``(*, 3, 3)`` rotation matrices (act on column vectors; x rotation applied first).

    Example:
        >>> euler_to_matrix(torch.tensor([0.0, 0.0, math.pi / 2])) @ torch.tensor([1.0, 0.0, 0.0])
        tensor([-4.3711e-08,  1.0000e+00,  0.0000e+00])
    """
    check_shape(angles.shape[-1:] == (3,), "euler_to_matrix", "angles", "(*, 3)", tuple(angles.shape))
    ca, cb, cc = torch.cos(angles).unbind(-1)
    sa, sb, sc = torch.sin(angles).unbind(-1)
    rows = (
        cb * cc,
        sa * sb * cc - ca * sc,
        ca * sb * cc + sa * sc,
        cb * sc,
        sa * sb * sc + ca * cc,
        ca * sb * sc - sa * cc,
        -sb,
        sa * cb,
        ca * cb,
    )
    return torch.stack(rows, dim=-1).reshape(angles.shape[:-1] + (3, 3))


def channels_to_trs(
    theta: torch.Tensor, channel_joint: torch.Tensor, channel_kind: torch.Tensor, num_joints: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Scatter the flat parameter vector into per-joint rotation, translation and scale.

    Args:
        theta: ``(B, P)`` flat parameters (deg, mm, ``scale - 1``).
        channel_joint: ``(P,)`` int64 joint index of each channel.
        channel_kind: ``(P,)`` int64 index into :data:`rig.joints.CHANNEL_KINDS` of each channel.
        num_joints: ``K``.

    Returns:
        ``(rotation_rad (B, K, 3), translation_mm (B, K, 3), scale (B, K, 3))``; joints without a channel
        get zero rotation/translation and unit scale.
    """
    check_shape(
        theta.dim() == 2 and theta.shape[1] == channel_joint.shape[0],
        "channels_to_trs",
        "theta",
        f"(B, {channel_joint.shape[0]})",
        tuple(theta.shape),
    )
    batch = theta.shape[0]
    # One (B, K, 10) table: rotate xyz, translate xyz, scale xyz offsets, uniform scale offset.
    table = theta.new_zeros(batch, num_joints * len(CHANNEL_KINDS))
    table = table.index_add(1, channel_joint * len(CHANNEL_KINDS) + channel_kind, theta)
    table = table.view(batch, num_joints, len(CHANNEL_KINDS))
    rotation = table[..., 0:3] * (math.pi / 180.0)
    translation = table[..., 3:6]
    scale = 1.0 + table[..., 6:9] + table[..., 9:10]
    return rotation, translation, scale


def local_transforms(rotation: torch.Tensor, translation: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Each joint's channel transform ``tau = T @ R @ S`` about the joint's own origin.

    Args:
        rotation: ``(B, K, 3)`` Euler angles in radians.
        translation: ``(B, K, 3)`` in mm.
        scale: ``(B, K, 3)`` factors.

    Returns:
        ``(B, K, 4, 4)``.
    """
    check_shape(
        rotation.shape == translation.shape == scale.shape and rotation.shape[-1] == 3,
        "local_transforms",
        "rotation/translation/scale",
        "(B, K, 3) each",
        (tuple(rotation.shape), tuple(translation.shape), tuple(scale.shape)),
    )
    linear = euler_to_matrix(rotation) * scale.unsqueeze(-2)
    top = torch.cat([linear, translation.unsqueeze(-1)], dim=-1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


def joint_world_transforms(
    tau: torch.Tensor, bind_positions: torch.Tensor, parents: torch.Tensor, levels: list[torch.Tensor] | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Compose the joint transforms down the hierarchy (JNR eq. 1).

    Bind poses are translations ``B_k = T(p_k)`` (joint frames aligned with rig axes). With
    ``L_k = T(p_k - p_parent) @ tau_k`` the world frame is ``G_k = G_parent @ L_k`` and the skinning
    transform is ``A_k = G_k @ B_k^-1`` (identity when every ``tau_k`` is). With per-head bind positions
    ``(B, K, 3)`` this is ASM's dynamic bone binding (its eq. 13-16 with the rotation and scale of the
    initial binding, the identity here).

    Args:
        tau: ``(B, K, 4, 4)`` local channel transforms.
        bind_positions: ``(K, 3)`` joint positions in mm, or ``(B, K, 3)`` one set per head.
        parents: ``(K,)`` int64 parent index, -1 for the root; parents come before children.
        levels: optional joint indices grouped by depth (from :func:`hierarchy_levels`); each level is
            composed in one batched matmul.

    Returns:
        ``(world (B, K, 4, 4), skinning (B, K, 4, 4))``.
    """
    K = bind_positions.shape[-2]
    check_shape(
        tau.dim() == 4 and tau.shape[1:] == (K, 4, 4),
        "joint_world_transforms",
        "tau",
        f"(B, {K}, 4, 4)",
        tuple(tau.shape),
    )
    check_shape(
        bind_positions.shape[-1] == 3
        and (bind_positions.dim() == 2 or (bind_positions.dim() == 3 and bind_positions.shape[0] == tau.shape[0])),
        "joint_world_transforms",
        "bind_positions",
        f"({K}, 3) or ({tau.shape[0]}, {K}, 3)",
        tuple(bind_positions.shape),
    )
    check_shape(parents.shape == (K,), "joint_world_transforms", "parents", f"({K},)", tuple(parents.shape))
    if levels is None:
        levels = hierarchy_levels(parents)
    bind = bind_positions.to(tau.dtype)
    has_parent = (parents >= 0).unsqueeze(-1)
    parent_pos = torch.where(has_parent, bind[..., parents.clamp(min=0), :], torch.zeros_like(bind))
    offset = bind - parent_pos
    local = tau.clone()
    local[..., :3, 3] = local[..., :3, 3] + offset
    world = torch.empty_like(local)
    world[:, levels[0]] = local[:, levels[0]]
    for level in levels[1:]:
        world[:, level] = world[:, parents[level]] @ local[:, level]
    skinning = world.clone()
    # A = G @ T(-p): the translation column gains -R' p.
    skinning[..., :3, 3] = world[..., :3, 3] - (world[..., :3, :3] @ bind.unsqueeze(-1)).squeeze(-1)
    return world, skinning


def hierarchy_levels(parents: torch.Tensor) -> list[torch.Tensor]:
    """Joint indices grouped by depth in the tree: ``levels[0]`` are roots, ``levels[d]`` have parents in ``d-1``."""
    depth: list[int] = []
    for p in parents.tolist():
        depth.append(0 if p < 0 else depth[p] + 1)
    return [
        torch.tensor([i for i, d in enumerate(depth) if d == level], dtype=torch.long)
        for level in range(max(depth) + 1)
    ]


def skinning_basis(vertices: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Per-vertex weighted homogeneous coordinates ``X[v, 4k + c] = w_vk * [v_v, 1]_c``.

    LBS is then one matrix product with the stacked skinning transforms (:func:`skin_with_basis`);
    the basis depends only on the rest vertices and weights, so a rig can build it once.

    Args:
        vertices: ``(V, 3)`` or ``(B, V, 3)`` rest vertices, mm.
        weights: ``(V, K)`` or ``(B, V, K)``.

    Returns:
        ``(V, 4K)`` or ``(B, V, 4K)``.
    """
    check_shape(
        vertices.shape[-1] == 3 and vertices.dim() in (2, 3),
        "skinning_basis",
        "vertices",
        "(V, 3) or (B, V, 3)",
        tuple(vertices.shape),
    )
    check_shape(
        weights.dim() in (2, 3) and weights.shape[-2] == vertices.shape[-2],
        "skinning_basis",
        "weights",
        f"(V, K) or (B, V, K) with V = {vertices.shape[-2]}",
        tuple(weights.shape),
    )
    homogeneous = torch.cat([vertices, torch.ones_like(vertices[..., :1])], dim=-1)
    basis = weights.unsqueeze(-1) * homogeneous.unsqueeze(-2)
    return basis.flatten(-2)


def skin_with_basis(basis: torch.Tensor, skinning: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning from a :func:`skinning_basis`: ``v'_v = sum_k w_vk A_k [v_v, 1]``.

    Args:
        basis: ``(V, 4K)`` dense or sparse-CSR, or ``(B, V, 4K)`` dense.
        skinning: ``(B, K, 4, 4)`` skinning transforms.

    Returns:
        ``(B, V, 3)`` posed vertices, mm.
    """
    check_shape(
        skinning.dim() == 4 and skinning.shape[-2:] == (4, 4),
        "skin_with_basis",
        "skinning",
        "(B, K, 4, 4)",
        tuple(skinning.shape),
    )
    batch, K = skinning.shape[:2]
    check_shape(
        basis.shape[-1] == 4 * K, "skin_with_basis", "basis", f"(V, {4 * K}) or (B, V, {4 * K})", tuple(basis.shape)
    )
    if basis.dim() == 3:
        # (B, V, 4K) @ (B, 4K, 3)
        return torch.bmm(basis, skinning[:, :, :3, :].permute(0, 1, 3, 2).reshape(batch, 4 * K, 3))
    # One GEMM for the whole batch: (V, 4K) @ (4K, B*3).
    stacked = skinning[:, :, :3, :].permute(1, 3, 0, 2).reshape(4 * K, batch * 3)
    return (basis @ stacked).view(-1, batch, 3).transpose(0, 1)


def skin_vertices(vertices: torch.Tensor, weights: torch.Tensor, skinning: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning (JNR eq. 2): ``v'_i = sum_k w_ik A_k v_i``.

    Args:
        vertices: ``(V, 3)`` or ``(B, V, 3)`` rest vertices in mm.
        weights: ``(V, K)`` or ``(B, V, K)`` skinning weights (rows sum to 1).
        skinning: ``(B, K, 4, 4)`` skinning transforms ``A_k`` from :func:`joint_world_transforms`.

    Returns:
        ``(B, V, 3)`` posed vertices in mm.
    """
    check_shape(
        skinning.dim() == 4 and skinning.shape[-2:] == (4, 4),
        "skin_vertices",
        "skinning",
        "(B, K, 4, 4)",
        tuple(skinning.shape),
    )
    batch, K = skinning.shape[:2]
    check_shape(
        weights.shape[-1] == K and weights.dim() in (2, 3),
        "skin_vertices",
        "weights",
        f"(V, {K}) or (B, V, {K})",
        tuple(weights.shape),
    )
    basis = skinning_basis(vertices, weights)
    if basis.dim() == 3 and basis.shape[0] != batch:
        basis = basis.expand(batch, -1, -1)
    return skin_with_basis(basis, skinning)


__all__ = [
    "ROTATE",
    "SCALE_AXES",
    "TRANSLATE",
    "UNIFORM_SCALE",
    "ShapeError",
    "channels_to_trs",
    "euler_to_matrix",
    "hierarchy_levels",
    "joint_world_transforms",
    "local_transforms",
    "skin_vertices",
    "skin_with_basis",
    "skinning_basis",
]


def skin_vertices_shared_weights(vertices: torch.Tensor, weights: torch.Tensor, skinning: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning of a few vertices with one set of weights for a large batch of poses.

    The per-vertex blended transforms ``M_v = sum_k w_vk A_k`` are one matrix product
    ``(V, K) @ (K, B * 12)``, then ``v' = M_v [v, 1]``: for ``B`` in the hundreds and ``V`` in the hundreds
    this is several times faster than :func:`skin_vertices`, which builds a ``(B, V, 4K)`` basis.

    Args:
        vertices: ``(V, 3)`` or ``(B, V, 3)`` rest vertices, mm.
        weights: ``(V, K)`` skinning weights, shared by the batch.
        skinning: ``(B, K, 4, 4)`` skinning transforms.

    Returns:
        ``(B, V, 3)`` posed vertices, mm (equal to :func:`skin_vertices`).
    """
    check_shape(
        skinning.dim() == 4 and skinning.shape[-2:] == (4, 4),
        "skin_vertices_shared_weights",
        "skinning",
        "(B, K, 4, 4)",
        tuple(skinning.shape),
    )
    batch, K = skinning.shape[:2]
    check_shape(
        weights.dim() == 2 and weights.shape[1] == K,
        "skin_vertices_shared_weights",
        "weights",
        f"(V, {K})",
        tuple(weights.shape),
    )
    check_shape(
        vertices.shape[-1] == 3 and vertices.shape[-2] == weights.shape[0] and vertices.dim() in (2, 3),
        "skin_vertices_shared_weights",
        "vertices",
        f"(V, 3) or (B, V, 3) with V = {weights.shape[0]}",
        tuple(vertices.shape),
    )
    top = skinning[:, :, :3, :].permute(1, 0, 2, 3).reshape(K, batch * 12)
    blended = (weights.to(top.dtype) @ top).view(-1, batch, 3, 4).transpose(0, 1)  # (B, V, 3, 4)
    return (blended[..., :3] @ vertices.unsqueeze(-1)).squeeze(-1) + blended[..., 3]


def skin_vertices_blended(vertices: torch.Tensor, weights: torch.Tensor, skinning: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning with per-head dense weights, by blending the transforms first:
    ``M_v = sum_k w_vk A_k`` (one ``(V, K) @ (K, 12)`` product per head), then ``v' = M_v [v, 1]``.

    Equal to :func:`skin_vertices`; cheaper when every head has its own dense weights (ASM's GMM
    weights), since no ``(B, V, 4K)`` basis is built.

    Args:
        vertices: ``(V, 3)`` or ``(B, V, 3)`` rest vertices, mm.
        weights: ``(B, V, K)`` skinning weights.
        skinning: ``(B, K, 4, 4)`` skinning transforms.

    Returns:
        ``(B, V, 3)`` posed vertices, mm.
    """
    check_shape(
        skinning.dim() == 4 and skinning.shape[-2:] == (4, 4),
        "skin_vertices_blended",
        "skinning",
        "(B, K, 4, 4)",
        tuple(skinning.shape),
    )
    batch, K = skinning.shape[:2]
    check_shape(
        weights.dim() == 3 and weights.shape[0] == batch and weights.shape[2] == K,
        "skin_vertices_blended",
        "weights",
        f"({batch}, V, {K})",
        tuple(weights.shape),
    )
    check_shape(
        vertices.shape[-1] == 3 and vertices.shape[-2] == weights.shape[1] and vertices.dim() in (2, 3),
        "skin_vertices_blended",
        "vertices",
        f"(V, 3) or (B, V, 3) with V = {weights.shape[1]}",
        tuple(vertices.shape),
    )
    blended = (weights.to(skinning.dtype) @ skinning[:, :, :3, :].reshape(batch, K, 12)).view(batch, -1, 3, 4)
    return (blended[..., :3] @ vertices.unsqueeze(-1)).squeeze(-1) + blended[..., 3]
