"""ASM's parameters: the channels of a bone's transform, :class:`AsmParameters` (every tunable float of a
batch of heads), which of them a variant frees (:class:`AsmVariant`), the eq.-19 regulariser's weights and
units, and one head's parameters as JSON (:func:`asm_params_to_dict`, :func:`asm_params_from_dict`). See
:mod:`rig.skinning.asm`.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Protocol

import numpy as np
import torch

from rig.errors import InputError, SetupError, ShapeError

__all__ = [
    "ASM_CHANNELS",
    "DEFAULT_COMPONENTS",
    "TAU_UNITS",
    "UV_UNIT",
    "AsmInitError",
    "AsmParameters",
    "AsmRegularizer",
    "AsmVariant",
    "asm_params_from_dict",
    "asm_params_to_dict",
]


#: Channels of one bone's transform ``tau`` in order (units: deg, mm, ``factor - 1``).
ASM_CHANNELS: tuple[str, ...] = (
    "rotate_x",
    "rotate_y",
    "rotate_z",
    "translate_x",
    "translate_y",
    "translate_z",
    "scale_x",
    "scale_y",
    "scale_z",
)
#: Gaussians per bone (``K``) unless a model says otherwise.
DEFAULT_COMPONENTS = 2
#: Units of ``tau``'s channels in the regulariser and the fits' steps (10 deg, 1 mm, 0.1 scale).
TAU_UNITS = (10.0, 10.0, 10.0, 1.0, 1.0, 1.0, 0.1, 0.1, 0.1)
#: Unit of the UV quantities (``zeta``, ``mu``) there: 0.01, about 5 mm on the face.
UV_UNIT = 0.01


class AsmInitError(SetupError):
    """The initial ASM parameters are missing, corrupt or for another template."""


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
        bones[name] = {
            "tau": {c: float(v) for c, v in zip(ASM_CHANNELS, q.tau[j])},
            "zeta": q.zeta[j].tolist(),
            "log_pi": q.log_pi[j].tolist(),
            "mu": q.mu[j].tolist(),
            "chol": q.chol[j].tolist(),
        }
    return {
        "components": p.components,
        "bones": bones,
        "units": {"tau": "rotate deg, translate mm, scale factor - 1", "zeta": "uv", "mu": "uv"},
    }


class _AsmModel(Protocol):
    """What :func:`asm_params_from_dict` reads of a model (:class:`rig.skinning.asm.AdaptiveSkinning`):
    its ``components``, ``rig`` (the joint names) and ``initial(batch)``."""

    components: int
    rig: object

    def initial(self, batch: int) -> AsmParameters: ...


def asm_params_from_dict(data: dict, model: _AsmModel) -> AsmParameters:
    """Inverse of :func:`asm_params_to_dict` for ``model`` (batch 1). Bones missing from the file keep
    their initial values.

    Raises:
        ValueError: another ``K``, an unknown bone or channel, values of the wrong length or not finite.
    """
    if not isinstance(data, dict) or not isinstance(data.get("bones"), dict):
        raise InputError("ASM parameters must be an object with a 'bones' object")
    if int(data.get("components", -1)) != model.components:
        raise InputError(
            f"ASM parameters have K = {data.get('components')} Gaussians per bone, the model {model.components}"
        )
    names = model.rig.asset.joint_names
    p = model.initial(1).map(lambda t: t.detach().clone())
    K = model.components
    for name, bone in data["bones"].items():
        if name not in names:
            raise InputError(f"unknown ASM bone {name!r}; bones are the rig's joints ({names[0]}, ...)")
        j = names.index(name)
        tau = bone.get("tau", {})
        unknown = [c for c in tau if c not in ASM_CHANNELS]
        if unknown:
            raise InputError(f"bone {name!r}: unknown channel(s) {unknown}; channels are {list(ASM_CHANNELS)}")
        for c, v in tau.items():
            p.tau[0, j, ASM_CHANNELS.index(c)] = float(v)
        for field, shape in (("zeta", (2,)), ("log_pi", (K,)), ("mu", (K, 2)), ("chol", (K, 3))):
            if field in bone:
                value = torch.as_tensor(np.asarray(bone[field], np.float64), dtype=p.tau.dtype)
                if tuple(value.shape) != shape:
                    raise InputError(f"bone {name!r}: {field} must have shape {shape}, got {tuple(value.shape)}")
                getattr(p, field)[0, j] = value
    for field, t in p.as_dict().items():
        if not torch.isfinite(t).all():
            raise InputError(f"ASM parameters: {field} has NaN or infinite values")
    return p
