"""The Adaptive Skinning Model as a head model (:mod:`rig.head_model`'s ``asm``; :mod:`rig.skinning.asm`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
import torch

from rig.asset import RigAsset, load_asset
from rig.expressions import EXPRESSION_NAMES, ExpressionModel, coefficients_from_dict
from rig.head_params import (
    HeadModelError,
    HeadParams,
    HeadPose,
    ParameterGroup,
    expression_group,
    require_entries,
    vector_of,
)
from rig.model import JointRig
from rig.skinning.asm import (
    DEFAULT_COMPONENTS,
    AdaptiveSkinning,
    AsmParameters,
    asm_params_from_dict,
    asm_params_to_dict,
)

__all__ = ["AsmHead"]


class AsmHead:
    """The Adaptive Skinning Model (ASM, ICCV 2023; :mod:`rig.skinning.asm`) on the rig's template: 9-DoF
    bones with dynamic binding and Gaussian-mixture weights in UV space, plus the 52 ARKit shapes. Its
    weights and bind positions change per head, so it is not :attr:`posable` by the rig's joints.

    Args:
        asset: the rig asset. components: Gaussians per bone.
    """

    kind: ClassVar[str] = "asm"
    posable: ClassVar[bool] = False
    entries: ClassVar[tuple[str, ...]] = ("asm", "expressions")
    """The keys of a ``params.json`` this model reads (:meth:`to_dict`)."""

    def __init__(self, asset: RigAsset | None = None, *, components: int | None = None, rig=None) -> None:
        if rig is None or rig.template.dtype != torch.float64:
            rig = JointRig(rig.asset if rig is not None else asset or load_asset(), dtype=torch.float64)
        self.rig = rig
        self.asset = rig.asset
        self.model = AdaptiveSkinning(rig, components=components or DEFAULT_COMPONENTS)
        self._expressions = ExpressionModel(self.asset, dtype=torch.float64)

    def groups(self) -> tuple[ParameterGroup, ...]:
        p = self.model.initial(1)
        names, low, high = [], [], []
        for field, tensor in p.as_dict().items():
            n = tensor[0].numel()
            names += [f"{field}[{i}]" for i in range(n)]
            low.append(np.full(n, -np.inf))
            high.append(np.full(n, np.inf))
        group = ParameterGroup("asm", tuple(names), np.concatenate(low), np.concatenate(high), "ASM units")
        return (group, expression_group())

    def initial(self) -> HeadParams:
        p = self.model.initial(1)
        values = {k: v.detach().numpy() for k, v in p.as_dict().items()}
        return HeadParams(self.kind, {"asm": values, "expressions": np.zeros(len(EXPRESSION_NAMES))})

    def _parameters(self, params: HeadParams):
        return AsmParameters(**{k: torch.as_tensor(np.asarray(v, np.float64)) for k, v in params["asm"].items()})

    def vertices(self, values: Mapping, vertex_ids: torch.Tensor | None = None) -> torch.Tensor:
        """The differentiable, batched forward: ``values`` ``{"asm": AsmParameters of batch B, "expressions":
        (B, E)}`` -> ``(B, U, 3)`` posed vertices, mm, float64 (``U``: ``vertex_ids`` or every vertex;
        gradients flow to every ASM parameter and coefficient)."""
        rest = self._expressions.vertices(values["expressions"].to(torch.float64))
        posed = self.model(values["asm"], vertices=rest).vertices
        return posed if vertex_ids is None else posed[:, vertex_ids]

    def forward(self, params: HeadParams) -> HeadPose:
        self._check(params)
        c = torch.as_tensor(vector_of(params["expressions"], len(EXPRESSION_NAMES), "expressions"))
        with torch.no_grad():
            posed = self.vertices({"asm": self._parameters(params), "expressions": c[None]})[0].numpy()
            rest = self._expressions.vertices(c[None])[0]
        return HeadPose(posed, rest.numpy(), None, None, c.numpy())

    def to_dict(self, params: HeadParams) -> dict:
        self._check(params)
        return {
            "asm": asm_params_to_dict(self._parameters(params), self.asset.joint_names),
            "expressions": {n: float(c) for n, c in zip(EXPRESSION_NAMES, params["expressions"])},
        }

    def from_dict(self, data: Mapping) -> HeadParams:
        require_entries(data, ("asm", "expressions"))
        try:
            p = asm_params_from_dict(data["asm"], self.model)
        except ValueError as exc:
            raise HeadModelError(str(exc)) from None
        c = coefficients_from_dict(data["expressions"], dtype=torch.float64).numpy()
        return HeadParams(self.kind, {"asm": {k: v.detach().numpy() for k, v in p.as_dict().items()}, "expressions": c})

    @staticmethod
    def options_from_params(params: HeadParams) -> dict:
        return {"components": int(np.asarray(params["asm"]["log_pi"]).shape[-1])}

    @staticmethod
    def options_from_dict(data: Mapping) -> dict:
        block = data.get("asm")
        components = block.get("components", DEFAULT_COMPONENTS) if isinstance(block, Mapping) else None
        return {"components": int(components)} if isinstance(components, int | float) else {}

    def _check(self, params: HeadParams) -> None:
        if params.kind != self.kind:
            raise HeadModelError(f"{self.kind} head model given {params.kind} parameters")
