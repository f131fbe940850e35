"""The types every head model shares (:mod:`rig.head_model`): its parameter groups, its parameters, the head it
makes and its error; in a module of their own so a model's file (:mod:`rig.asm_head`) imports them without the
registry, which imports the models."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES, expression_limits

__all__ = [
    "HeadModelError",
    "HeadParams",
    "HeadPose",
    "ParameterGroup",
    "expression_group",
    "require_entries",
    "vector_of",
]


class HeadModelError(InputError):
    """An unknown head model, or parameters that do not belong to the model (exit status 2 on the CLI)."""


@dataclass(frozen=True)
class ParameterGroup:
    """A named group of a model's parameters.

    Attributes:
        name: the group (``joints``, ``latent``, ``expressions``, ``asm``).
        names: ``(n,)`` the name of each float (``nose_tip.translate_y``, ``jawOpen``, ``z_0``).
        low, high: ``(n,)`` float64 limits (``-inf`` / ``inf`` where there is none).
        units: what the values are in.
    """

    name: str
    names: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray
    units: str

    @property
    def size(self) -> int:
        return len(self.names)


@dataclass(frozen=True)
class HeadParams:
    """One head's parameters.

    Attributes:
        kind: the model they belong to.
        values: each group's float64 array by group name (``joints (P,)``, ``latent (50,)``,
            ``expressions (E,)``; ASM: ``asm``, a dict of its :class:`rig.skinning.asm.AsmParameters`
            fields as arrays of batch 1, and ``expressions``).
    """

    kind: str
    values: Mapping[str, Any]

    def __getitem__(self, group: str):
        return self.values[group]

    def replace(self, **groups) -> HeadParams:
        """A copy with some groups replaced."""
        return HeadParams(self.kind, {**self.values, **groups})


@dataclass(frozen=True, eq=False)
class HeadPose:
    """A head made by :meth:`HeadModel.forward` (float64, rig space, mm).

    Attributes:
        vertices: ``(V, 3)`` the posed head.
        rest: ``(V, 3)`` the template with the expressions applied (the bind shape the joints skin).
        weights: ``(V, J)`` skinning weights, or None for a model a skinned glTF cannot carry.
        joint_transforms: ``(J, 4, 4)`` each joint's channel transform (the glTF joints' pose), or None.
        expressions: ``(E,)`` the ARKit coefficients (:data:`rig.expressions.EXPRESSION_NAMES`).
    """

    vertices: np.ndarray
    rest: np.ndarray
    weights: np.ndarray | None
    joint_transforms: np.ndarray | None
    expressions: np.ndarray


def expression_group() -> ParameterGroup:
    """The 52 ARKit expression coefficients as a group, with their limits."""
    low, high = (t.numpy() for t in expression_limits(torch.float64))
    return ParameterGroup("expressions", tuple(EXPRESSION_NAMES), low, high, "ARKit coefficient")


def vector_of(values, size: int, what: str) -> np.ndarray:
    """``(size,)`` float64 of ``values``; HeadModelError naming ``what`` for another shape."""
    v = np.asarray(values, np.float64)
    if v.shape != (size,):
        raise HeadModelError(f"{what} must have {size} values, got shape {v.shape}")
    return v


def require_entries(data: Mapping, keys: tuple[str, ...]) -> None:
    """HeadModelError naming the ``keys`` a parameter file's ``data`` lacks."""
    missing = [k for k in keys if k not in data]
    if missing:
        raise HeadModelError(f"parameter file lacks {missing}")
