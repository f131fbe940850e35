"""Lighting model for faces in photos: ambient + one directional light, both RGB and differentiable.

Why this model: a face photo is mostly lit by one dominant source plus diffuse fill; ambient +
directional captures that with 6 (+2 direction) numbers, is cheap on a CPU (one shadow ray per
sample, no environment sampling; a constant environment emitter with indirect silhouettes is far
slower, see ``docs/render.md``), and its gradients are low-variance. Second-order spherical harmonics would
model soft multi-source light better but need an environment emitter, i.e. far more samples.

Shading of a Lambertian point with albedo ``a`` (linear RGB), unit normal ``n``:
``radiance = a * ambient + a / pi * irradiance * max(0, n . (-direction)) * visible``.
The ambient term is rendered as emission of the mesh itself (``a * ambient``), so it carries exact
silhouette gradients and no occlusion.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from render.errors import RenderArgumentError


@dataclass(frozen=True)
class Lighting:
    """Ambient + directional light.

    Attributes:
        ambient: ``(3,)`` linear RGB, radiance factor: a surface of albedo ``a`` emits ``a * ambient``.
        irradiance: ``(3,)`` linear RGB irradiance of the directional light on a surface facing it.
        direction: ``(3,)`` direction the light *travels* (world/rig space, +Y up, +Z out of the face);
            e.g. ``(0, 0, -1)`` lights the face head-on. Not differentiable (set per scene or per call).
    """

    ambient: torch.Tensor
    irradiance: torch.Tensor
    direction: torch.Tensor

    @staticmethod
    def default(dtype: torch.dtype = torch.float32) -> Lighting:
        """A frontal key light from upper right and a soft fill, for a face looking along +Z."""
        return Lighting(
            ambient=torch.tensor([0.35, 0.35, 0.35], dtype=dtype),
            irradiance=torch.tensor([2.0, 2.0, 2.0], dtype=dtype),
            direction=torch.tensor([-0.3, -0.4, -1.0], dtype=dtype),
        )


def check_lighting(light: Lighting) -> None:
    """Raise ValueError unless ``light``'s fields are ``(3,)`` tensors with a non-zero direction."""
    for name in ("ambient", "irradiance", "direction"):
        value = getattr(light, name)
        if not isinstance(value, torch.Tensor) or tuple(value.shape) != (3,):
            shape = tuple(value.shape) if hasattr(value, "shape") else type(value).__name__
            raise RenderArgumentError(f"Lighting: expected {name} a (3,) torch tensor, got {shape}")
    if float(light.direction.detach().norm()) == 0.0:
        raise RenderArgumentError("Lighting: direction must be non-zero")


def shade_lambert(albedo: torch.Tensor, normals: torch.Tensor, light: Lighting) -> torch.Tensor:
    """Reference shading (no shadows), for tests: ``(..., 3)`` albedo and unit normals -> ``(..., 3)`` radiance."""
    d = -light.direction / light.direction.norm()
    cos = (normals * d).sum(-1, keepdim=True).clamp_min(0.0)
    return albedo * light.ambient + albedo / torch.pi * light.irradiance * cos
