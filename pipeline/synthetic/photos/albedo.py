"""A random, plausible per-vertex albedo: skin tone, smooth variation, regional tints, hair, eyes, mouth
(:func:`synthesize_albedo`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.colour import srgb_to_linear
from pipeline.synthetic.photos.settings import PhotoSettings, _as_generator
from rig.asset import RigAsset, cached_per_asset, load_asset

SKIN_TONES_SRGB: tuple[tuple[int, int, int], ...] = (
    (236, 198, 172),  # very light
    (224, 174, 140),  # light
    (198, 140, 104),  # medium
    (164, 108, 74),  # tan / olive-brown
    (118, 76, 52),  # dark
    (78, 52, 38),  # very dark
)
"""Skin albedos from very light to very dark, 8-bit sRGB (typical diffuse skin colours of photos); a
tone parameter ``t`` in [0, 1] interpolates them piecewise linearly in linear RGB."""

HAIR_COLOURS_SRGB: tuple[tuple[int, int, int], ...] = (
    (28, 24, 22),  # black
    (58, 40, 30),  # dark brown
    (98, 68, 44),  # brown
    (176, 146, 100),  # blond
    (136, 66, 38),  # red
    (150, 146, 140),  # grey
)
"""Hair colours, 8-bit sRGB (scalp and, darkened, eyebrows)."""

IRIS_COLOURS_SRGB: tuple[tuple[int, int, int], ...] = (
    (62, 38, 24),  # dark brown
    (96, 62, 36),  # brown
    (110, 96, 58),  # hazel
    (70, 100, 130),  # blue
    (80, 104, 74),  # green
    (100, 106, 112),  # grey
)
"""Iris colours, 8-bit sRGB."""

_SCLERA_SRGB = (222, 212, 200)
_TEETH_SRGB = (226, 216, 192)
_TONGUE_SRGB = (176, 84, 86)
_MOUTH_INTERIOR_LINEAR = np.array([0.10, 0.025, 0.025])
_IRIS_RADIUS_MM = 5.5


def _palette(colours_srgb) -> np.ndarray:
    return srgb_to_linear(np.asarray(colours_srgb, np.float64) / 255.0)


def _skin_tone(t: float) -> np.ndarray:
    """``(3,)`` linear RGB skin albedo for a tone ``t`` in [0, 1] (0 very light, 1 very dark)."""
    tones = _palette(SKIN_TONES_SRGB)
    pos = float(np.clip(t, 0.0, 1.0)) * (len(tones) - 1)
    k = min(int(pos), len(tones) - 2)
    return tones[k] + (pos - k) * (tones[k + 1] - tones[k])


@cached_per_asset
def _neighbour_average(asset: RigAsset):
    """Sparse ``(V, V)`` row-stochastic matrix: the mean over each vertex and its mesh neighbours."""
    from scipy import sparse

    f = np.asarray(asset.faces, np.int64)
    n = len(asset.vertices)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0], np.arange(n)])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2], np.arange(n)])
    adjacency = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()
    adjacency.data[:] = 1.0  # duplicate edges (shared by two faces) count once
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    return sparse.diags(1.0 / degree) @ adjacency


def _smooth(field: np.ndarray, asset: RigAsset, iterations: int) -> np.ndarray:
    average = _neighbour_average(asset)
    for _ in range(iterations):
        field = average @ field
    return field


def _mirror_blend(field: np.ndarray, mirror: np.ndarray, asymmetry: float) -> np.ndarray:
    """The field's mirror-symmetric part plus ``asymmetry`` times its antisymmetric part."""
    symmetric = 0.5 * (field + field[mirror])
    return symmetric + asymmetry * (field - symmetric)


def synthesize_albedo(
    rng: np.random.Generator | int, asset: RigAsset | None = None, *, settings: PhotoSettings = PhotoSettings()
) -> np.ndarray:
    """A random, plausible per-vertex albedo for the rig's template topology.

    A skin tone from very light to very dark (:data:`SKIN_TONES_SRGB`), smooth low-frequency
    variation (Gaussian bumps over the template's vertex positions, almost left/right symmetric) and a
    faint per-vertex texture; redder, darker lips; eyebrows mixing skin and hair colour; a pinker nose,
    ears and cheeks, darker eyelids; hair colour on the scalp (or skin, for a bald head); eyes with a
    sclera and an iris colour; a dark mouth interior. Region boundaries are blended over a few mesh
    rings.

    Args:
        rng: ``np.random.Generator`` or integer seed; all randomness comes from it.
        asset: the rig template (regions, mirror map, faces); default :func:`rig.asset.load_asset`.
        settings: the albedo fields of :class:`PhotoSettings` are used.

    Returns:
        ``(V, 3)`` float64 linear RGB in [0, 1], deterministic given the generator's state.

    Example:
        >>> albedo = synthesize_albedo(0)
        >>> albedo.shape, bool(albedo.min() >= 0.0 and albedo.max() <= 1.0)
        ((4978, 3), True)
    """
    rng = _as_generator(rng, "synthesize_albedo")
    asset = load_asset() if asset is None else asset
    d = _draw(rng, settings, np.asarray(asset.vertices, np.float64))
    colour, lum = _skin(asset, d, settings)
    colour = _regional_tints(colour, lum, asset, d)
    colour = _eyes_and_mouth(colour, asset, d, rng)
    return np.clip(colour, 0.0, 1.0)


@dataclass(frozen=True)
class _AlbedoDraws:
    """The random draws of :func:`synthesize_albedo` before the teeth and tongue (colours linear RGB)."""

    tone: float
    redness: float
    yellowness: float
    bump_centres: np.ndarray  # (B, 3) mm
    bump_radii: np.ndarray  # (B,) mm
    bump_lum: np.ndarray  # (B,)
    bump_red: np.ndarray  # (B,)
    fine: np.ndarray  # (V,)
    hair: np.ndarray  # (3,)
    bald: bool
    brow_mix: float
    lip_red: float
    lip_dark: float
    blush: float
    iris: np.ndarray  # (3,)
    sclera: np.ndarray  # (3,)
    mouth: np.ndarray  # (3,)


def _draw(rng: np.random.Generator, s: PhotoSettings, v: np.ndarray) -> _AlbedoDraws:
    """Draws in a fixed order (the stream does not depend on the asset's regions)."""
    n = len(v)
    tone = float(rng.uniform(*s.skin_tone_range))
    redness, yellowness = rng.uniform(-0.05, 0.05, size=2)
    bump_centres = v[rng.integers(n, size=s.albedo_bumps)]
    bump_radii = rng.uniform(15.0, 45.0, size=s.albedo_bumps)
    bump_lum = rng.normal(0.0, s.albedo_variation, size=s.albedo_bumps)
    bump_red = rng.normal(0.0, 0.5 * s.albedo_variation, size=s.albedo_bumps)
    fine = rng.normal(0.0, 1.0, size=n)
    hair = _palette(HAIR_COLOURS_SRGB)[rng.integers(len(HAIR_COLOURS_SRGB))] * rng.uniform(0.85, 1.15, size=3)
    bald = bool(rng.random() < s.bald_probability)
    brow_mix = float(rng.uniform(0.45, 0.75))
    lip_red = float(rng.uniform(0.5, 0.7))
    lip_dark = float(rng.uniform(0.75, 0.95))
    blush = float(rng.uniform(0.0, 1.0))
    iris = _palette(IRIS_COLOURS_SRGB)[rng.integers(len(IRIS_COLOURS_SRGB))] * rng.uniform(0.8, 1.2)
    sclera = _palette([_SCLERA_SRGB])[0] * rng.uniform(0.85, 1.0)
    mouth = _MOUTH_INTERIOR_LINEAR * rng.uniform(0.7, 1.3)
    return _AlbedoDraws(
        tone=tone,
        redness=redness,
        yellowness=yellowness,
        bump_centres=bump_centres,
        bump_radii=bump_radii,
        bump_lum=bump_lum,
        bump_red=bump_red,
        fine=fine,
        hair=hair,
        bald=bald,
        brow_mix=brow_mix,
        lip_red=lip_red,
        lip_dark=lip_dark,
        blush=blush,
        iris=iris,
        sclera=sclera,
        mouth=mouth,
    )


def _region(asset: RigAsset, *names: str) -> np.ndarray:
    """``(V,)`` float64 1 on the vertices of the asset's regions among ``names`` (0 where it has none)."""
    present = [name for name in names if name in asset.region_names]
    return asset.region_mask(*present).astype(np.float64) if present else np.zeros(len(asset.vertices))


def _skin(asset: RigAsset, d: _AlbedoDraws, s: PhotoSettings) -> tuple[np.ndarray, np.ndarray]:
    """``(V, 3)`` the skin colour and ``(V,)`` its log-luminance field: the tone with smooth log-luminance
    and redness fields, mostly mirror-symmetric, and a faint, asymmetric texture."""
    v = np.asarray(asset.vertices, np.float64)
    n = len(v)
    mirror = np.asarray(asset.mirror, np.int64)
    skin = _skin_tone(d.tone) * np.array([1.0 + d.redness, 1.0 + d.yellowness, 1.0 - d.yellowness])
    d2 = ((v[:, None, :] - d.bump_centres[None]) ** 2).sum(-1)
    gauss = np.exp(-0.5 * d2 / d.bump_radii[None] ** 2)
    lum = _mirror_blend(gauss @ d.bump_lum, mirror, s.albedo_asymmetry)
    red = _mirror_blend(gauss @ d.bump_red, mirror, s.albedo_asymmetry)
    lum = lum + 0.25 * s.albedo_variation * _smooth(d.fine, asset, 1)  # faint, asymmetric skin texture
    colour = skin[None] * np.exp(lum)[:, None] * np.stack([1.0 + red, np.ones(n), 1.0 - red], axis=1)
    return colour, lum


def _tint(weight: np.ndarray, factor) -> np.ndarray:
    return 1.0 + weight[:, None] * (np.asarray(factor, np.float64)[None] - 1.0)


def _regional_tints(colour: np.ndarray, lum: np.ndarray, asset: RigAsset, d: _AlbedoDraws) -> np.ndarray:
    """Cheeks, nose, ears, eyelids and neck tinted, lips, brows and the scalp's hair blended in, each over a
    few rings of neighbours."""
    blush = d.blush
    colour = colour * _tint(
        _smooth(_region(asset, "cheeks"), asset, 2), (1.0 + 0.06 * blush, 1.0 - 0.03 * blush, 1.0 - 0.03 * blush)
    )
    colour = colour * _tint(_smooth(_region(asset, "nose"), asset, 2), (1.04, 0.97, 0.97))
    colour = colour * _tint(_smooth(_region(asset, "ears"), asset, 2), (0.97, 0.88, 0.88))
    colour = colour * _tint(_smooth(_region(asset, "eyelids"), asset, 2), (0.90, 0.84, 0.86))
    colour = colour * _tint(_smooth(_region(asset, "neck"), asset, 3), (0.96, 0.96, 0.98))
    lips = _smooth(_region(asset, "lips"), asset, 1)[:, None]
    lip_colour = colour * d.lip_dark * np.array([1.0, d.lip_red, d.lip_red + 0.05])
    colour = colour + lips * (lip_colour - colour)
    brows = _smooth(_region(asset, "brows"), asset, 1)[:, None]
    # eyebrows are darker than the skin around them, whatever the hair colour (grey, blond)
    brow_colour = (1.0 - d.brow_mix) * colour + d.brow_mix * np.minimum(0.7 * d.hair[None], 0.5 * colour)
    colour = colour + brows * (brow_colour - colour)
    if not d.bald:
        scalp = _smooth(_region(asset, "scalp"), asset, 3)[:, None]
        hair_colour = d.hair[None] * np.exp(0.5 * lum)[:, None]
        colour = colour + scalp * (hair_colour - colour)
    return colour


def _eyes_and_mouth(colour: np.ndarray, asset: RigAsset, d: _AlbedoDraws, rng: np.random.Generator) -> np.ndarray:
    """Sclera and a soft iris disc on the eyeballs, the dark mouth and eye pockets, the teeth and the tongue
    (their shades drawn last); no blending (separate surfaces). Changes ``colour`` in place."""
    v = np.asarray(asset.vertices, np.float64)
    eyes = _region(asset, "eyeballs") > 0
    colour[eyes] = d.sclera
    for side in (1.0, -1.0):
        ids = np.flatnonzero(eyes & (np.sign(v[:, 0]) == side))
        if len(ids):
            front = v[ids[np.argmax(v[ids, 2])]]
            # a soft-edged disc: the eyeball's vertices are a few mm apart, a hard edge would look jagged
            r = np.linalg.norm(v[ids, :2] - front[None, :2], axis=1)
            weight = np.clip((_IRIS_RADIUS_MM + 1.5 - r) / 3.0, 0.0, 1.0)[:, None]
            colour[ids] = d.sclera + weight * (d.iris - d.sclera)
    colour[_region(asset, "mouth_interior") > 0] = d.mouth
    colour[_region(asset, "eye_pockets") > 0] = 0.5 * d.mouth  # hidden behind the eyeballs; dark where it shows
    colour[_region(asset, "teeth") > 0] = _palette([_TEETH_SRGB])[0] * rng.uniform(0.85, 1.0)
    colour[_region(asset, "tongue") > 0] = _palette([_TONGUE_SRGB])[0] * rng.uniform(0.8, 1.1)
    return colour


__all__ = ["HAIR_COLOURS_SRGB", "IRIS_COLOURS_SRGB", "SKIN_TONES_SRGB", "synthesize_albedo"]
