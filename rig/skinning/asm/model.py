"""The ASM head model, :class:`AdaptiveSkinning`: :class:`AsmParameters` -> posed vertices (ASM eq. 3),
with GMM weights on the skin island, the painted weights elsewhere, and the eq.-19 regulariser. See
:mod:`rig.skinning.asm`.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
from torch import nn

from rig.errors import InputError, ShapeError
from rig.lbs import hierarchy_levels, joint_world_transforms, skin_vertices_blended
from rig.model import JointRig, RigOutput
from rig.skinning.asm.binding import bone_local_transforms, bone_positions_from_uv, uv_domain, uv_face_tree
from rig.skinning.asm.gmm import gmm_skinning_weights, sigma_from_cholesky
from rig.skinning.asm.initial import load_initial_gmm
from rig.skinning.asm.parameters import (
    DEFAULT_COMPONENTS,
    TAU_UNITS,
    UV_UNIT,
    AsmParameters,
    AsmRegularizer,
    AsmVariant,
)

__all__ = ["LOG_PI_RANGE", "SIGMA_RANGE", "AdaptiveSkinning"]

#: Smallest and largest Gaussian axis (Cholesky diagonal) the model evaluates, UV units (0.1-250 mm).
SIGMA_RANGE = (2e-4, 0.5)
#: Range of ``log pi`` the model evaluates.
LOG_PI_RANGE = (-60.0, 20.0)


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
            raise InputError(f"AdaptiveSkinning: components must be a positive int, got {components!r}")
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

    def num_floats(self, variant: AsmVariant | None = None) -> dict[str, int]:
        """Model size in floats: the fixed part (template, initial binding, painted weights of the static
        islands, initial GMM) and the per-head tunable part of ``variant`` (default ``AsmVariant()``: all)."""
        variant = AsmVariant() if variant is None else variant
        J, K = self.num_bones, self.components
        per_head = {"tau": 9 * J, "zeta": 2 * J, "log_pi": K * J, "mu": 2 * K * J, "chol": 3 * K * J}
        static_rows = self.rig.num_vertices - len(self.domain.gmm_vertices)
        painted_static = int((self.painted[~self._gmm_row_mask()] > 0).sum())
        fixed = (
            3 * self.rig.num_vertices + 3 * J + (6 * K * J if variant.gmm_weights else int((self.painted > 0).sum()))
        )
        if variant.gmm_weights:
            fixed += painted_static
        return {
            "fixed": int(fixed),
            "per_head": int(sum(per_head[n] for n in variant.free())),
            "static_vertices": int(static_rows),
        }

    def _gmm_row_mask(self) -> torch.Tensor:
        mask = torch.zeros(self.rig.num_vertices, dtype=torch.bool)
        mask[self.gmm_vertices] = True
        return mask

    # parameters --------------------------------------------------------------------------------------
    def initial(self, batch: int = 1) -> AsmParameters:
        """The initial binding and GMM fits, zero transforms, for ``batch`` heads (new tensors)."""
        if not isinstance(batch, int) or batch < 1:
            raise InputError(f"AdaptiveSkinning.initial: batch must be a positive int, got {batch!r}")
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
        chol = torch.cat(
            [
                p.chol[..., :2].clamp(math.log(SIGMA_RANGE[0]), math.log(SIGMA_RANGE[1])),
                p.chol[..., 2:].clamp(-SIGMA_RANGE[1], SIGMA_RANGE[1]),
            ],
            dim=-1,
        )
        return gmm_skinning_weights(
            self.vertex_uv.to(p.mu.dtype),
            p.log_pi.clamp(*LOG_PI_RANGE),
            centres,
            sigma_from_cholesky(chol),
            self.seam_rows,
            self.seam_uv,
        )

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
        return bone_positions_from_uv(
            p.zeta, self.face_uv, self.face_xyz, self.anchor_xyz, self.rig.bind_positions, self.face_tree
        )

    def forward(
        self,
        p: AsmParameters,
        vertices: torch.Tensor | None = None,
        *,
        dynamic_binding: bool = True,
        gmm_weights: bool = True,
    ):
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

    def regularizer(self, p: AsmParameters, weights: AsmRegularizer | None = None) -> torch.Tensor:
        """ASM eq. 19 per head, ``(B,)`` (units: :class:`AsmRegularizer`; default weights: ASM's)."""
        weights = AsmRegularizer() if weights is None else weights
        self._check(p)
        units = p.tau.new_tensor(TAU_UNITS)
        terms = (
            weights.tau * ((p.tau / units) ** 2).sum((1, 2))
            + weights.zeta * (((p.zeta - self.zeta0) / UV_UNIT) ** 2).sum((1, 2))
            + weights.pi * ((p.log_pi - self.log_pi0) ** 2).sum((1, 2))
            + weights.mu * (((p.mu - self.mu0) / UV_UNIT) ** 2).sum((1, 2, 3))
            + weights.sigma * ((p.chol - self.chol0) ** 2).sum((1, 2, 3))
        )
        return terms
