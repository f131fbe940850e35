"""A random photo background: a smooth colour gradient with multi-scale texture and soft blobs
(:func:`synthetic_background`)."""

from __future__ import annotations

import colorsys

import numpy as np

from pipeline.colour import srgb_to_linear
from pipeline.synthetic.photos.settings import _as_generator
from rig.errors import InputError


def _value_noise(rng: np.random.Generator, width: int, height: int, cells: int) -> np.ndarray:
    """``(H, W)`` smooth noise: a ``cells x cells`` grid of N(0, 1) values, bicubically upsampled."""
    import cv2

    grid = rng.normal(0.0, 1.0, size=(cells + 1, cells + 1)).astype(np.float32)
    return cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC).astype(np.float64)


def synthetic_background(rng: np.random.Generator | int, width: int, height: int) -> np.ndarray:
    """A random photo background: a smooth colour gradient with multi-scale texture and soft blobs.

    Args:
        rng: ``np.random.Generator`` or integer seed.
        width, height: image size, pixels.

    Returns:
        ``(H, W, 3)`` float32 linear RGB in [0, 1], deterministic given the generator's state.

    Raises:
        ValueError: non-positive size.

    Example:
        >>> synthetic_background(0, 64, 48).shape
        (48, 64, 3)
    """
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise InputError(f"synthetic_background: {name} must be an integer >= 1, got {value!r}")
    rng = _as_generator(rng, "synthetic_background")
    width, height = int(width), int(height)
    hue, saturation, value = rng.uniform(0.0, 1.0), rng.uniform(0.05, 0.45), rng.uniform(0.3, 0.85)
    base = srgb_to_linear(np.array(colorsys.hsv_to_rgb(hue, saturation, value)))
    corners = base[None] * np.exp(rng.normal(0.0, 0.3, size=(4, 3)))  # top-left, top-right, bottom-left, bottom-right
    y = np.linspace(0.0, 1.0, height)[:, None, None]
    x = np.linspace(0.0, 1.0, width)[None, :, None]
    image = (1 - y) * ((1 - x) * corners[0] + x * corners[1]) + y * ((1 - x) * corners[2] + x * corners[3])

    texture = np.zeros((height, width))
    for octave, cells in enumerate((3, 7, 15, 31)):
        texture += 0.35 * 0.55**octave * _value_noise(rng, width, height, cells)
    colour_texture = 0.08 * np.stack([_value_noise(rng, width, height, 5) for _ in range(3)], axis=-1)
    image = image * np.exp(texture[..., None] + colour_texture)

    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    size = float(max(width, height))
    for _ in range(int(rng.integers(2, 6))):  # soft out-of-focus objects
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        radius = rng.uniform(0.05, 0.25) * size
        blob_colour = srgb_to_linear(rng.uniform(0.1, 0.9, size=3))
        weight = rng.uniform(0.3, 0.8) * np.exp(-0.5 * ((xx - cx) ** 2 + (yy - cy) ** 2) / radius**2)
        image = image + weight[..., None] * (blob_colour - image)
    return np.clip(image, 0.0, 1.0).astype(np.float32)


__all__ = ["synthetic_background"]
