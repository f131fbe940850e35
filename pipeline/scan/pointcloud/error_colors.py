"""Colours for per-point errors (:func:`error_colors`), for the error map of a fit (``cloud_error.ply``)."""

from __future__ import annotations

import math

import numpy as np

from rig.errors import InputError

NAN_GREY = (128, 128, 128)

# Blue → light blue → pale yellow → orange → red (ColorBrewer RdYlBu, reversed): even lightness steps
# towards the middle, readable by the colour-blind, and no matplotlib needed.
_ERROR_STOPS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
_ERROR_COLOURS = np.array(
    [[44, 123, 182], [171, 217, 233], [255, 255, 191], [253, 174, 97], [215, 25, 28]], dtype=np.float64
)


def error_colors(distances_mm: np.ndarray, vmax_mm: float | None = None) -> np.ndarray:
    """Colours for per-point errors: blue (0) → yellow → red (``>= vmax_mm``), grey for NaN.

    Args:
        distances_mm: ``(N,)`` distances in mm (negative values are shown as 0).
        vmax_mm: distance shown as full red; default the 95th percentile of the finite distances
            (at least 1e-6).

    Returns:
        ``(N, 3)`` uint8 RGB colours.

    Example:
        >>> error_colors(np.array([0.0, 1.0, np.nan]), vmax_mm=1.0)
        array([[ 44, 123, 182],
               [215,  25,  28],
               [128, 128, 128]], dtype=uint8)
    """
    distances = np.asarray(distances_mm, dtype=np.float64)
    if distances.ndim != 1:
        raise InputError(f"error_colors: distances_mm must have shape (N,), got {distances.shape}")
    finite = distances[np.isfinite(distances)]
    if vmax_mm is None:
        vmax_mm = max(float(np.percentile(finite, 95.0)) if finite.size else 0.0, 1e-6)
    elif not (math.isfinite(vmax_mm) and vmax_mm > 0):
        raise InputError(f"error_colors: vmax_mm must be a positive number, got {vmax_mm}")
    t = np.clip(np.nan_to_num(distances, nan=0.0) / vmax_mm, 0.0, 1.0)
    rgb = np.stack([np.interp(t, _ERROR_STOPS, _ERROR_COLOURS[:, c]) for c in range(3)], axis=1)
    rgb = np.rint(rgb).astype(np.uint8)
    rgb[np.isnan(distances)] = NAN_GREY
    return rgb


__all__ = ["NAN_GREY", "error_colors"]
