"""Second-order spherical-harmonic lighting of a Lambertian face (Ramamoorthi & Hanrahan 2001), the
standard light model of face fitting: 9 coefficients per colour channel.

The irradiance on a surface of unit normal ``n`` under any distant light is, to within ~1 % on average,
``E(n) = sum_k L_k Y'_k(n)`` over the 9 real SH basis functions of bands 0-2, with the Lambertian kernel's
band factors folded into the basis (:func:`sh_basis`). A pixel of albedo ``a`` then reads
``a * E(n)`` (linear RGB). The coefficients ``L (9, 3)`` are found by linear least squares on the face
pixels (:func:`fit_sh`) and optimised with the rest in the photometric stages.

Normals are in the photo camera's frame (OpenCV: x right, y down, z forward); any fixed frame works, the
coefficients absorb it.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from rig.lbs import ShapeError

# Real SH constants (bands 0-2) times the clamped-cosine kernel's band factors (pi, 2pi/3, pi/4).
_C0 = math.pi * 0.282095
_C1 = 2.0 * math.pi / 3.0 * 0.488603
_C2 = math.pi / 4.0 * 1.092548
_C3 = math.pi / 4.0 * 0.315392
_C4 = math.pi / 4.0 * 0.546274

SH_COEFFICIENTS = 9


def sh_basis(normals):
    """``(..., 3)`` unit normals -> ``(..., 9)`` irradiance basis (torch or numpy, same kind and dtype).

    Order: 1, y, z, x, xy, yz, 3z^2 - 1, xz, x^2 - y^2 (bands 0, 1, 2)."""
    if normals.shape[-1] != 3:
        raise ShapeError(f"sh_basis: normals must have shape (..., 3), got {tuple(normals.shape)}")
    x, y, z = normals[..., 0], normals[..., 1], normals[..., 2]
    parts = [
        _C0 * (x * 0 + 1),
        _C1 * y,
        _C1 * z,
        _C1 * x,
        _C2 * x * y,
        _C2 * y * z,
        _C3 * (3 * z * z - 1),
        _C2 * x * z,
        _C4 * (x * x - y * y),
    ]
    if isinstance(normals, torch.Tensor):
        return torch.stack(parts, -1)
    return np.stack(parts, -1)


def fit_sh(albedo: np.ndarray, normals: np.ndarray, target: np.ndarray, ridge: float = 1e-3) -> np.ndarray:
    """Coefficients ``(9, 3)`` of ``target ~ albedo * (sh_basis(normals) @ L)`` per channel by ridge-regularised
    linear least squares (``ridge`` times the design's mean diagonal, so a narrow range of normals cannot
    blow up the higher bands).

    Args: albedo, target ``(N, 3)`` linear RGB; normals ``(N, 3)`` unit.
    """
    albedo, normals, target = (np.asarray(x, np.float64) for x in (albedo, normals, target))
    if not (albedo.shape == target.shape == normals.shape and albedo.ndim == 2 and albedo.shape[1] == 3):
        raise ShapeError(
            f"fit_sh: albedo, normals and target must all be (N, 3), got {albedo.shape}, "
            f"{normals.shape}, {target.shape}"
        )
    basis = sh_basis(normals)  # (N, 9)
    out = np.zeros((SH_COEFFICIENTS, 3))
    for c in range(3):
        design = albedo[:, c : c + 1] * basis
        gram = design.T @ design
        gram += ridge * np.trace(gram) / SH_COEFFICIENTS * np.eye(SH_COEFFICIENTS)
        out[:, c] = np.linalg.solve(gram, design.T @ target[:, c])
    return out
