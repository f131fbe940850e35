"""The rig as a torch module: registers the asset's tensors and calls the pure functions of :mod:`rig.lbs`."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from rig.asset import RigAsset, load_asset
from rig.joints import CHANNEL_KINDS
from rig.lbs import (
    ShapeError,
    channels_to_trs,
    hierarchy_levels,
    joint_world_transforms,
    local_transforms,
    skin_vertices,
    skin_with_basis,
    skinning_basis,
)
from rig.losses import uniform_laplacian
from rig.parameters import CHANNELS, NUM_PARAMETERS


@dataclass(frozen=True)
class RigOutput:
    """Result of a rig evaluation.

    Attributes:
        vertices: ``(B, V, 3)`` posed vertices, mm.
        joint_world: ``(B, K, 4, 4)`` world frames of the joints.
        skinning: ``(B, K, 4, 4)`` skinning transforms (world frame times inverse bind pose).
    """

    vertices: torch.Tensor
    joint_world: torch.Tensor
    skinning: torch.Tensor

    @property
    def joints(self) -> torch.Tensor:
        """``(B, K, 3)`` joint positions, mm."""
        return self.joint_world[..., :3, 3]


class JointRig(nn.Module):
    """JNR's joint rig: ``theta (B, P) -> vertices (B, V, 3)``.

    Args:
        asset: the rig asset (default: the committed one).
        dtype: float32 or float64.

    Example:
        >>> rig = JointRig()
        >>> rig(torch.zeros(1, rig.num_parameters)).vertices.shape
        torch.Size([1, 4978, 3])
    """

    def __init__(self, asset: RigAsset | None = None, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        asset = asset or load_asset()
        self.asset = asset
        self.register_buffer("template", torch.as_tensor(asset.vertices, dtype=dtype))
        self.register_buffer("faces", torch.as_tensor(asset.faces, dtype=torch.long))
        self.register_buffer("bind_positions", torch.as_tensor(asset.joint_positions, dtype=dtype))
        self.register_buffer("parents", torch.as_tensor(asset.parents, dtype=torch.long))
        self.register_buffer("channel_joint", torch.tensor([c.joint for c in CHANNELS], dtype=torch.long))
        self.register_buffer(
            "channel_kind", torch.tensor([CHANNEL_KINDS.index(c.kind) for c in CHANNELS], dtype=torch.long)
        )
        self.register_buffer("weight_rows", torch.as_tensor(asset.weight_rows, dtype=torch.long))
        self.register_buffer("weight_cols", torch.as_tensor(asset.weight_cols, dtype=torch.long))
        self.register_buffer("weight_free_index", torch.as_tensor(asset.weight_free_index, dtype=torch.long))
        self.register_buffer("weights_free", torch.as_tensor(asset.weight_free, dtype=dtype))
        self.levels = hierarchy_levels(self.parents)
        self._basis_cache: tuple[tuple, torch.Tensor] | None = None
        self._laplacian: torch.Tensor | None = None

    @property
    def laplacian(self) -> torch.Tensor:
        """Sparse ``(V, V)`` uniform Laplacian of the template (for L_p), built on first use."""
        if self._laplacian is None:
            self._laplacian = uniform_laplacian(self.asset.faces, self.num_vertices).to(self.template.dtype)
        return self._laplacian

    @property
    def num_parameters(self) -> int:
        return NUM_PARAMETERS

    @property
    def num_vertices(self) -> int:
        return int(self.template.shape[0])

    @property
    def num_joints(self) -> int:
        return int(self.bind_positions.shape[0])

    @property
    def num_skinning_floats(self) -> int:
        return int(self.weights_free.shape[0])

    def dense_weights(self, free: torch.Tensor | None = None) -> torch.Tensor:
        """Free skinning floats ``(S,)`` (default: the rig's own) -> dense ``(V, K)`` weights."""
        if free is None:
            free = self.weights_free
        if free.shape != self.weights_free.shape:
            raise ShapeError(
                f"JointRig.dense_weights: free must have shape {tuple(self.weights_free.shape)}, "
                f"got {tuple(free.shape)}"
            )
        out = free.new_zeros(self.num_vertices, self.num_joints)
        return out.index_put((self.weight_rows, self.weight_cols), free[self.weight_free_index])

    def _default_basis(self) -> torch.Tensor:
        """Sparse-CSR skinning basis of the template and the rig's own weights, rebuilt when they change."""
        key = (self.weights_free._version, self.template._version, self.template.dtype, self.template.device)
        if self._basis_cache is None or self._basis_cache[0] != key:
            with torch.no_grad(), warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "sparse CSR support is in beta"
                basis = skinning_basis(self.template, self.dense_weights()).to_sparse_csr()
            self._basis_cache = (key, basis)
        return self._basis_cache[1]

    def channel_transforms(self, theta: torch.Tensor) -> torch.Tensor:
        """``theta (B, P)`` -> each joint's local channel transform ``tau`` (eq. 1), ``(B, K, 4, 4)``."""
        if theta.dim() != 2 or theta.shape[1] != NUM_PARAMETERS:
            raise ShapeError(f"JointRig: theta must have shape (B, {NUM_PARAMETERS}), got {tuple(theta.shape)}")
        rotation, translation, scale = channels_to_trs(theta, self.channel_joint, self.channel_kind, self.num_joints)
        return local_transforms(rotation, translation, scale)

    def joint_transforms(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``theta (B, P)`` -> ``(joint_world, skinning)``, each ``(B, K, 4, 4)``."""
        return joint_world_transforms(self.channel_transforms(theta), self.bind_positions, self.parents, self.levels)

    def forward(
        self,
        theta: torch.Tensor,
        weights: torch.Tensor | None = None,
        vertices: torch.Tensor | None = None,
        basis: torch.Tensor | None = None,
    ) -> RigOutput:
        """Pose the rig.

        Args:
            theta: ``(B, P)`` parameters (deg, mm, ``scale - 1``; see :mod:`rig.parameters`).
            weights: optional ``(V, K)`` or ``(B, V, K)`` skinning weights (default: the rig's).
            vertices: optional ``(V, 3)`` or ``(B, V, 3)`` rest vertices (default: the template), e.g.
                with expression offsets added.
            basis: optional precomputed :func:`rig.lbs.skinning_basis` of ``vertices`` and ``weights``
                (``(V, 4K)`` or ``(B, V, 4K)``), for loops where only ``theta`` changes.

        Returns:
            :class:`RigOutput` with ``vertices (B, V, 3)`` in mm.
        """
        world, skinning = self.joint_transforms(theta)
        if basis is not None:
            posed = skin_with_basis(basis, skinning)
        elif weights is None and vertices is None and not self.weights_free.requires_grad:
            # The common case (fitting joints): a cached sparse product, ~16 non-zeros per row.
            posed = skin_with_basis(self._default_basis(), skinning)
        else:
            w = self.dense_weights() if weights is None else weights
            v = self.template if vertices is None else vertices
            posed = skin_vertices(v, w, skinning)
        return RigOutput(posed, world, skinning)

    def mirror_vertices(self, vertices: torch.Tensor) -> torch.Tensor:
        """Reflect ``(..., V, 3)`` vertices in x = 0 and re-index them by the mirror map."""
        mirror = torch.as_tensor(np.asarray(self.asset.mirror), device=vertices.device)
        sign = vertices.new_tensor([-1.0, 1.0, 1.0])
        return vertices[..., mirror, :] * sign
