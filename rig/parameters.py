"""Named rig parameters: the flat parameter vector, its limits and mirroring (the JSON file: :mod:`rig.io.params`).

The flat vector ``theta`` of shape ``(B, P)`` holds one entry per channel in :data:`CHANNELS` order:
rotations in degrees, translations in millimetres and scales as ``factor - 1``, so ``theta = 0`` is the
rest pose. Names are ``"<joint>.<channel>"`` (``nose_tip.translate_y``). In JSON and in
:func:`params_to_dict` scales are written as factors (1 = rest).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from rig.errors import InputError, is_number
from rig.joints import JOINT_INDEX, JOINT_MIRROR, JOINTS, mirror_joint_name


class ParameterError(InputError):
    """An unknown parameter name or a value outside the parameter's limits."""


@dataclass(frozen=True)
class Channel:
    """One free variable of the rig.

    Attributes:
        name: ``"<joint>.<channel>"``.
        joint: index of the joint in :data:`rig.joints.JOINTS`.
        kind: ``rotate_x`` ... ``scale`` (see :mod:`rig.joints`).
        low, high: limits in the channel's unit (deg, mm, or scale factor).
    """

    name: str
    joint: int
    kind: str
    low: float
    high: float

    @property
    def is_scale(self) -> bool:
        return self.kind.startswith("scale")

    @property
    def unit(self) -> str:
        return "deg" if self.kind.startswith("rotate") else "mm" if self.kind.startswith("translate") else "factor"

    def to_theta(self, value: float) -> float:
        """Channel value (deg, mm, factor) -> entry of the flat vector."""
        return value - 1.0 if self.is_scale else value

    def from_theta(self, theta: float) -> float:
        return theta + 1.0 if self.is_scale else theta


CHANNELS: tuple[Channel, ...] = tuple(
    Channel(f"{j.name}.{kind}", i, kind, lo, hi) for i, j in enumerate(JOINTS) for kind, (lo, hi) in j.channels.items()
)
CHANNEL_INDEX: dict[str, int] = {c.name: i for i, c in enumerate(CHANNELS)}
NUM_PARAMETERS = len(CHANNELS)

_MIRROR_SIGN = {"rotate_y": -1.0, "rotate_z": -1.0, "translate_x": -1.0}


def _mirror_tables() -> tuple[list[int], list[float]]:
    index, sign = [], []
    for c in CHANNELS:
        other = f"{mirror_joint_name(JOINTS[c.joint].name)}.{c.kind}"
        index.append(CHANNEL_INDEX[other])
        sign.append(_MIRROR_SIGN.get(c.kind, 1.0))
    return index, sign


MIRROR_INDEX, MIRROR_SIGN = _mirror_tables()


def symmetric_groups() -> list[list[int]]:
    """Channel indices that a symmetric fit ties together: each left/right pair, and each midline channel alone."""
    seen: set[int] = set()
    groups = []
    for i, j in enumerate(MIRROR_INDEX):
        if i in seen:
            continue
        groups.append(sorted({i, j}))
        seen.update((i, j))
    return groups


def theta_limits(dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Lower and upper limits of the flat vector, each of shape ``(P,)`` (scales as ``factor - 1``)."""
    low = torch.tensor([c.to_theta(c.low) for c in CHANNELS], dtype=dtype)
    high = torch.tensor([c.to_theta(c.high) for c in CHANNELS], dtype=dtype)
    return low, high


def mirror_theta(theta: torch.Tensor) -> torch.Tensor:
    """The parameters of the mirror-image head (x -> -x).

    Args:
        theta: ``(..., P)`` flat parameters.

    Returns:
        ``(..., P)``: left and right channels swapped; ``rotate_y``, ``rotate_z`` and ``translate_x``
        negated (a reflection in the YZ plane flips those).
    """
    sign = torch.tensor(MIRROR_SIGN, dtype=theta.dtype, device=theta.device)
    return theta[..., MIRROR_INDEX] * sign


LIMIT_TOLERANCE = 1e-6
"""Values this far outside a limit (relative to the channel's range) are taken as the limit."""


def params_to_theta(
    values: dict[str, float], *, clamp: bool = False, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """Named channel values -> flat vector ``(P,)``; channels not named stay at rest.

    Args:
        values: ``{"nose_tip.translate_y": 2.0, "neck.scale": 1.1, ...}`` in deg, mm or factor.
        clamp: clamp out-of-limit values to the limits with a warning instead of raising.

    Raises:
        ParameterError: an unknown name, a value that is not a number (a boolean, a string), a non-finite
            value, or (without ``clamp``) a value outside limits.
    """
    if not isinstance(values, Mapping):
        raise ParameterError(
            f"rig parameters must be an object of names to values, got {type(values).__name__} "
            '(e.g. {"nose_tip.translate_y": 2.0})'
        )
    theta = torch.zeros(NUM_PARAMETERS, dtype=dtype)
    for name, value in values.items():
        if not isinstance(name, str) or name not in CHANNEL_INDEX:
            name = str(name)
            close = [c for c in CHANNEL_INDEX if c.split(".")[0] == name.split(".")[0]]
            hint = f"; {name.split('.')[0]} has {', '.join(close)}" if close else ""
            raise ParameterError(f"unknown rig parameter {name!r}{hint}")
        if not is_number(value):  # true and "1.0" are refused, not read as numbers
            raise ParameterError(f"rig parameter {name!r} must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ParameterError(f"rig parameter {name!r} must be finite, got {value}")
        c = CHANNELS[CHANNEL_INDEX[name]]
        tol = LIMIT_TOLERANCE * max(1.0, c.high - c.low)  # float32 rounding of a fitted value at its limit
        if c.low - tol <= value <= c.high + tol:
            value = min(max(value, c.low), c.high)
        if not c.low <= value <= c.high:
            if not clamp:
                raise ParameterError(
                    f"rig parameter {name!r} = {value} {c.unit} is outside its limits [{c.low}, {c.high}]"
                )
            clamped = min(max(value, c.low), c.high)
            warnings.warn(f"rig parameter {name!r} = {value} {c.unit} clamped to {clamped}", stacklevel=2)
            value = clamped
        theta[CHANNEL_INDEX[name]] = c.to_theta(value)
    return theta


def theta_to_params(theta: torch.Tensor, *, include_rest: bool = True) -> dict[str, float]:
    """Flat vector ``(P,)`` -> ``{name: value}`` in deg, mm or factor."""
    if theta.shape != (NUM_PARAMETERS,):
        raise ParameterError(f"theta_to_params: expected shape ({NUM_PARAMETERS},), got {tuple(theta.shape)}")
    out = {}
    for c, t in zip(CHANNELS, theta.detach().cpu().double().tolist()):
        if include_rest or t != 0.0:
            out[c.name] = c.from_theta(t)
    return out


def random_theta(
    generator: torch.Generator, batch: int = 1, *, spread: float = 0.5, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """Random parameters inside the limits, ``(batch, P)``: each channel uniform in ``spread`` x its range around
    rest."""
    low, high = theta_limits(dtype)
    u = torch.rand(batch, NUM_PARAMETERS, generator=generator, dtype=dtype)
    return spread * (low + u * (high - low))


__all__ = [
    "CHANNELS",
    "CHANNEL_INDEX",
    "JOINT_INDEX",
    "JOINT_MIRROR",
    "NUM_PARAMETERS",
    "Channel",
    "ParameterError",
    "mirror_theta",
    "params_to_theta",
    "random_theta",
    "symmetric_groups",
    "theta_limits",
    "theta_to_params",
]
