"""The sRGB transfer function (IEC 61966-2-1), in one place: photos are sRGB-encoded, the renderer and
the photometric loss work in linear RGB."""

from __future__ import annotations

import numpy as np

__all__ = ["linear_to_srgb", "srgb_to_linear"]


def srgb_to_linear(x) -> np.ndarray:
    """sRGB transfer function, inverse (IEC 61966-2-1): encoded ``(*)`` in [0, 1] -> linear ``(*)``.

    Inputs outside [0, 1] are clipped. Returns float64 (float32 for float32 input).

    Example:
        >>> round(float(srgb_to_linear(0.5)), 5)
        0.21404
    """
    x = np.clip(np.asarray(x, dtype=np.result_type(np.asarray(x).dtype, np.float32)), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(x.dtype)


def linear_to_srgb(x) -> np.ndarray:
    """sRGB transfer function (IEC 61966-2-1): linear ``(*)`` in [0, 1] -> encoded ``(*)`` in [0, 1].

    Inputs outside [0, 1] are clipped. Returns float64 (float32 for float32 input).

    Example:
        >>> round(float(linear_to_srgb(0.21404)), 4)
        0.5
    """
    x = np.clip(np.asarray(x, dtype=np.result_type(np.asarray(x).dtype, np.float32)), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1.0 / 2.4) - 0.055).astype(x.dtype)
