"""``render.png`` and ``overlay.png`` of a photo fit: the fitted head rendered at the photo's size with its
albedo and light (:func:`render_fit`), and blended over the photo with the input and fitted landmarks
(:func:`overlay_image`)."""

from __future__ import annotations

import numpy as np
import torch

from pipeline.colour import linear_to_srgb
from pipeline.photo.fit import PhotoFit
from render.lighting import Lighting
from render.renderer import DifferentiableRenderer
from rig.asset import RigAsset, load_asset
from rig.errors import InputError

INPUT_COLOUR = (40, 220, 60)
FIT_COLOUR = (235, 40, 40)


def render_fit(
    fit: PhotoFit,
    *,
    spp: int = 16,
    seed: int = 0,
    asset: RigAsset | None = None,
    mask_regions: tuple[str, ...] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The fitted head rendered at the photo's size with its albedo and light.

    Args:
        asset: the rig asset of the fit, for its faces (default: the committed one).
        mask_regions: region names (:data:`rig.template.REGION_NAMES`): the mask then covers only the
            pixels whose visible triangle belongs to one of them (e.g. :data:`rig.template.FACE_REGIONS`);
            None: every pixel the head covers.

    Returns:
        ``(image (H, W, 3) float32 linear RGB, mask (H, W) float32)``: the mask is 1 where the ray through
        the pixel centre hits the head (in ``mask_regions``), else 0.

    Raises:
        ValueError: an unknown region name.
    """
    asset = asset or load_asset()
    region_ids = None
    if mask_regions is not None:
        unknown = [r for r in mask_regions if r not in asset.region_names]
        if unknown:
            raise InputError(f"render_fit: unknown mask_regions {unknown}; the regions are {list(asset.region_names)}")
        region_ids = [asset.region_names.index(r) for r in mask_regions]
    v = torch.as_tensor(fit.rig_vertices, dtype=torch.float32)
    albedo = torch.as_tensor(fit.appearance.albedo, dtype=torch.float32)
    light = Lighting(
        torch.as_tensor(fit.appearance.ambient, dtype=torch.float32),
        torch.as_tensor(fit.appearance.irradiance, dtype=torch.float32),
        torch.as_tensor(fit.appearance.light_rig, dtype=torch.float32),
    )
    renderer = DifferentiableRenderer(
        v,
        asset.faces,
        albedo,
        fit.camera,
        light,
        spp=spp,
        seed=seed,
        regions=None if region_ids is None else asset.regions,
    )
    with torch.no_grad():
        out = renderer.render(v, albedo, light, seed=seed, aovs=region_ids is not None)
    if region_ids is None:
        return out.image.numpy(), out.mask.numpy()
    return out.image.numpy(), np.isin(out.region_ids.numpy(), region_ids).astype(np.float32)


def overlay_image(
    photo: np.ndarray,
    render: np.ndarray,
    mask: np.ndarray,
    landmarks_in: np.ndarray,
    landmarks_fit: np.ndarray,
    alpha: float = 0.6,
) -> np.ndarray:
    """``(H, W, 3)`` uint8: the render (linear RGB) blended over the photo (uint8 sRGB) by ``alpha * mask``
    (``mask`` ``(H, W)`` in [0, 1]; where it is 0 the photo is unchanged), with the input landmarks as
    green dots and the fitted ones as red crosses."""
    import cv2

    rendered = (linear_to_srgb(render) * 255.0).astype(np.float32)
    a = (alpha * np.clip(mask, 0, 1))[..., None]
    out = np.ascontiguousarray(np.clip(photo.astype(np.float32) * (1 - a) + rendered * a, 0, 255).astype(np.uint8))
    radius = max(1, round(max(photo.shape[:2]) / 300))
    for x, y in np.asarray(landmarks_in, float):
        cv2.circle(out, (round(x), round(y)), radius + 1, INPUT_COLOUR, -1, lineType=cv2.LINE_AA)
    for x, y in np.asarray(landmarks_fit, float):
        p = (round(x), round(y))
        cv2.drawMarker(out, p, FIT_COLOUR, cv2.MARKER_CROSS, 3 * radius + 2, max(1, radius // 2 + 1), cv2.LINE_AA)
    return out
