"""Synthetic identity heads: a seeded population in the template's topology.

JNR fits its rig to 3D scans of real people (94 identities: 85 train, 2 validation, 7 test) and
evaluates on a held-out set of 100. We have no scans, so this module makes them: every head is the
template plus a sum of smooth, anatomically local displacement fields, with random coefficients.
The heads keep the template's vertex order, so correspondence is known.

Features
--------
Each feature (:data:`FEATURES`) is a displacement field on the template, ``(V, 3)`` mm per unit of
its coefficient, and has a plausible coefficient range:

- ``mm`` features are normalised so that a coefficient of 1 moves the most-displaced vertex by 1 mm
  (the coefficient is the feature's peak displacement);
- ``deg`` features are rotations of a region about a local axis, in degrees, linearised (small
  angle): the field is ``w(p) * axis x (p - pivot)`` per degree, with ``w`` fading from 1 to 0.
  At the largest angles in range (12 deg) the linearisation stretches the rotated part by < 2.5 %.

Every field is the restriction to the vertices of a smooth function of 3D position (Euclidean, not
geodesic, falloffs: compact bumps ``(1 - t^2)^3`` and quintic ramps; directions along fixed axes,
radial from a local centre, or along a kernel-smoothed normal field). Because the fields live in the
ambient space, vertices that are close in space move alike: the lips on both sides of the mouth slit,
the eyelids and the eyeballs behind them, the mouth interior and the lips, the ears and the skull
behind them. Within the ranges below the summed field varies slowly enough that sampled heads keep
every face's orientation and nearby surfaces apart (the tests check 40 heads: no flipped face, and no
two vertices within 8 mm of each other come closer than a third of their distance), so there are no
self-intersections for typical samples.

Symmetry: the anatomical features are mirror-symmetric (``f[mirror] * [-1, 1, 1] == f``). Paired
features (one anchor per side: ``nose_width``, ``ear_angle``, ...) also get an antisymmetric partner
``asym_<name>``, so that the left side (+X) is deformed with coefficient ``c + a`` and the right side
with ``c - a``. A few global antisymmetric modes (nose deviation, jaw shift, face roll and yaw) and
a set of small antisymmetric bumps at fixed anchors (``asym_bump_*``; random coefficients, so a
random smooth asymmetric field) add the mild asymmetry of real faces.

A head with coefficients ``c`` (``(M,)``, in :attr:`FeatureBasis.names` order) is
``template + einsum("m,mvk->vk", c, fields)``: linear, hence smooth, in ``c``.

Splits
------
:func:`population_split` makes the JNR splits (``train`` 85, ``val`` 2, ``test`` 7, ``heldout`` 100)
from a base seed. Each split draws from its own stream, seeded by ``SeedSequence([seed,
crc32(split)])``, and each head from its own integer seed derived from that stream (recorded in the
manifest: ``sample_coefficients(np.random.default_rng(head_seed), 1)`` reproduces the head).
:func:`write_population` writes meshes and a ``manifest.json``; :func:`read_population` reads them back.

Expressions (extension point)
-----------------------------
All heads here are neutral: :attr:`Population.expression` and the manifest's ``"expression"`` say
``"neutral"``. Expressive heads are a separate layer applied on top of an identity head (e.g. posing
the fitted rig, or expression displacement fields added after :func:`synthesize_heads`); they should
add their own coefficients next to the identity ones and a value other than ``"neutral"`` there,
without changing the identity coefficients, seeds or files described here.

Coordinates: millimetres, right-handed, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import json
import os
import zlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.special import ndtr, ndtri

from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.fields import bump, capsule_bump, ramp, smoothed_normals, unit
from rig.io.atomic import staged_folder
from rig.optim import Progress

GENERATOR_VERSION = 1
SPLIT_SIZES: dict[str, int] = {"train": 85, "val": 2, "test": 7, "heldout": 100}
FILE_FORMATS = ("ply", "obj")
MANIFEST_NAME = "manifest.json"
COORDINATES = {
    "units": "mm",
    "handedness": "right",
    "up": "+Y",
    "front": "+Z (out of the face)",
    "left": "+X (the subject's left)",
}

_MIRROR_X = np.array([-1.0, 1.0, 1.0])


@dataclass(frozen=True)
class _Context:
    p: np.ndarray  # (V, 3) template vertices, mm
    normals: np.ndarray  # (V, 3) smoothed normal field


# ----------------------------------------------------------------------------------------------------
# Feature fields. Paired features are modelled on the subject's left (+X) and mirrored; midline and
# global ones are symmetrised (or antisymmetrised) afterwards through the vertex mirror map.
# ----------------------------------------------------------------------------------------------------

def _rotation_field(p: np.ndarray, weight: np.ndarray, pivot, axis) -> np.ndarray:
    """Linearised rotation per radian about ``axis`` through ``pivot``, faded by ``weight``."""
    return weight[:, None] * np.cross(unit(axis), p - np.asarray(pivot, float))


def _nose_length(c: _Context) -> np.ndarray:
    return bump(c.p, (0, -40, 104), (20, 24, 24))[:, None] * unit((0, -0.2, 1))


def _nose_width(c: _Context) -> np.ndarray:
    return bump(c.p, (14, -42, 92), (13, 16, 16))[:, None] * np.array([1.0, 0, 0])


def _nose_hump(c: _Context) -> np.ndarray:
    return bump(c.p, (0, -8, 96), (12, 14, 14))[:, None] * unit((0, 0.4, 0.92))


def _nostril_flare(c: _Context) -> np.ndarray:
    center = np.array([8.0, -49.0, 97.0])
    return bump(c.p, center, (14, 12, 14))[:, None] * (c.p - center) * np.array([1.0, 0.3, 1.0])


def _lip_volume_upper(c: _Context) -> np.ndarray:
    return bump(c.p, (0, -69, 88), (28, 10, 16))[:, None] * c.normals


def _lip_volume_lower(c: _Context) -> np.ndarray:
    return bump(c.p, (0, -81, 86), (28, 10, 16))[:, None] * c.normals


def _mouth_width(c: _Context) -> np.ndarray:
    return bump(c.p, (23, -75, 78), (12, 12, 14))[:, None] * unit((1, 0, -0.5))


def _cheek_fullness(c: _Context) -> np.ndarray:
    return bump(c.p, (46, -40, 64), (24, 26, 24))[:, None] * c.normals


def _cheekbone(c: _Context) -> np.ndarray:
    return bump(c.p, (50, -14, 62), (18, 14, 18))[:, None] * c.normals


def _brow_ridge(c: _Context) -> np.ndarray:
    return capsule_bump(c.p, (8, 28, 82), (50, 24, 66), 16.0)[:, None] * c.normals


def _chin_projection(c: _Context) -> np.ndarray:
    return bump(c.p, (0, -102, 80), (30, 20, 24))[:, None] * unit((0, -0.25, 1))


def _chin_width(c: _Context) -> np.ndarray:
    return bump(c.p, (17, -102, 74), (16, 16, 18))[:, None] * np.array([1.0, 0, 0])


def _jaw_angle_width(c: _Context) -> np.ndarray:
    return bump(c.p, (54, -78, 12), (22, 28, 28))[:, None] * np.array([1.0, 0, 0])


def _forehead_slope(c: _Context) -> np.ndarray:
    # Positive: the forehead slopes back (rotation about -X through a pivot behind the brows).
    return _rotation_field(c.p, bump(c.p, (0, 62, 70), (80, 48, 48)), (0, 28, 70), (-1, 0, 0))


# The ear (left): the template's ear disc (tilted back 12 degrees) reaches from y ~ -41 to +25 and
# z ~ -40 to +12 mm and stands off the side of the skull, whose x there is about that of the cranium
# ellipsoid (65 mm at the ear's middle, 75 mm just above it), and no less than ~64 mm lower down.
_EAR_CENTER = np.array([77.0, -10.0, -12.0])


def _ear_frame(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ear's in-plane coordinates (mm): along its (tilted) long axis, and front-back."""
    q = p - np.array([70.0, -12.0, -10.0])
    cs, sn = np.cos(np.radians(12)), np.sin(np.radians(12))
    return cs * q[:, 1] + sn * q[:, 2], -sn * q[:, 1] + cs * q[:, 2] + 2.0


def _ear_weight(p: np.ndarray) -> np.ndarray:
    """1 on the left ear where it stands off the skull, 0 on the skull and away from the ear (smooth)."""
    y, z = p[:, 1], p[:, 2]
    cranium = 75.0 * np.sqrt(np.clip(1.0 - ((y - 32.0) / 90.0) ** 2 - ((z + 14.0) / 99.0) ** 2, 0.0, None))
    base = 0.5 * (cranium + 64.0 + np.sqrt((cranium - 64.0) ** 2 + 4.0))  # smooth max(cranium, 64)
    ly, lz = _ear_frame(p)
    rho = np.sqrt((ly / 34.0) ** 2 + (lz / 21.0) ** 2)
    return ramp(p[:, 0] - base, 0.0, 9.0) * (1.0 - ramp(rho, 1.0, 1.5))


def _ear_size(c: _Context) -> np.ndarray:
    # Scaled in the ear's (sagittal) plane about its centre: no push into or away from the skull.
    return _ear_weight(c.p)[:, None] * (c.p - _EAR_CENTER) * np.array([0.0, 1.0, 1.0])


def _ear_angle(c: _Context) -> np.ndarray:
    # Positive: the back of the ear swings out from the skull about a vertical axis at the ear's front root.
    return _rotation_field(c.p, _ear_weight(c.p), (68, -12, 4), (0, -1, 0))


def _ear_shape(c: _Context) -> np.ndarray:
    # Positive: a cupped ear, the rim (helix) bulging outwards from the skull more than the concha.
    ly, lz = _ear_frame(c.p)
    return (_ear_weight(c.p) * ((ly / 31.0) ** 2 + (lz / 17.0) ** 2))[:, None] * np.array([1.0, 0, 0])


def _eye_size(c: _Context) -> np.ndarray:
    center = np.array([33.0, 5.0, 66.0])
    return bump(c.p, center, (22, 18, 26))[:, None] * (c.p - center) * np.array([1.0, 1.0, 0.0])


def _eye_spacing(c: _Context) -> np.ndarray:
    return bump(c.p, (33, 5, 64), (26, 20, 28))[:, None] * np.array([1.0, 0, 0])


def _skull_width(c: _Context) -> np.ndarray:
    return bump(c.p, (72, 35, -15), (45, 60, 70))[:, None] * np.array([1.0, 0, 0])


def _occiput_projection(c: _Context) -> np.ndarray:
    return bump(c.p, (0, 25, -110), (70, 70, 45))[:, None] * unit((0, 0.1, -1))


def _face_length(c: _Context) -> np.ndarray:
    # Positive: a longer mid-face; everything below the eyes moves down, fading in under the nose, out
    # towards the back of the jaw, the ears and down the neck.
    x, y, z = c.p.T
    w = ramp(y, 8.0, -55.0) * ramp(z, -30.0, 30.0) * (1.0 - ramp(y, -120.0, -165.0)) * \
        (1.0 - ramp(x * x, 45.0 ** 2, 70.0 ** 2))
    return w[:, None] * np.array([0.0, -1.0, 0.0])


def _nose_deviation(c: _Context) -> np.ndarray:
    return bump(c.p, (0, -30, 100), (22, 30, 30))[:, None] * np.array([1.0, 0, 0])


def _jaw_shift(c: _Context) -> np.ndarray:
    x, y, z = c.p.T
    w = ramp(y, -50.0, -95.0) * ramp(z, -20.0, 40.0) * (1.0 - ramp(y, -125.0, -170.0))
    return w[:, None] * np.array([1.0, 0, 0])


def _face_mask(p: np.ndarray) -> np.ndarray:
    return bump(p, (0, -20, 50), (100, 110, 80))


def _face_roll(c: _Context) -> np.ndarray:
    return (_face_mask(c.p) * c.p[:, 0] / 60.0)[:, None] * np.array([0.0, 1.0, 0.0])


def _face_yaw(c: _Context) -> np.ndarray:
    return (_face_mask(c.p) * c.p[:, 0] / 60.0)[:, None] * np.array([0.0, 0.0, 1.0])


def _normal_bump(center, radius: float) -> Callable[[_Context], np.ndarray]:
    def field(c: _Context) -> np.ndarray:
        return bump(c.p, center, (radius, radius, radius))[:, None] * c.normals
    return field


# Anchors (left side) of the small random asymmetric bumps: (name, centre mm, radius mm).
_ASYM_BUMPS = (
    ("temple", (58, 40, 40), 26.0),
    ("forehead", (30, 55, 80), 28.0),
    ("brow", (35, 24, 80), 18.0),
    ("lower_orbit", (38, -10, 70), 16.0),
    ("cheek", (42, -32, 72), 22.0),
    ("jaw", (50, -85, 30), 24.0),
    ("parietal", (55, 70, -40), 35.0),
    ("upper_lip", (14, -64, 88), 14.0),
)


@dataclass(frozen=True)
class Feature:
    """One named displacement feature.

    Attributes:
        name: feature name (``nose_length``, ``asym_ear_angle``, ...).
        unit: ``"mm"`` (coefficient = peak displacement) or ``"deg"`` (linearised rotation angle).
        low, high: plausible coefficient range, in ``unit``; 0 (the template) is always inside.
        sd: standard deviation of the (truncated, zero-mean) normal the coefficient is drawn from.
        p_active: probability that a sampled coefficient is non-zero (sparser features < 1).
        symmetry: ``"symmetric"`` (mirror-symmetric field) or ``"antisymmetric"``.
        description: what a positive coefficient does.
    """

    name: str
    unit: str
    low: float
    high: float
    sd: float
    p_active: float
    symmetry: str
    description: str


# (name, builder, kind, unit, low, high, sd, p_active, what a positive coefficient does)
# kind: "midline" (symmetrised), "paired" (left field + mirror; gets an asym_ partner), "asym" (global,
# antisymmetrised). sd None = half the larger bound.
_SPECS: tuple = (
    ("nose_length", _nose_length, "midline", "mm", -4.0, 4.0, None, 1.0, "nose tip and base forward"),
    ("nose_width", _nose_width, "paired", "mm", -3.0, 3.0, None, 1.0, "alae outwards"),
    ("nose_hump", _nose_hump, "midline", "mm", -2.5, 3.5, None, 0.7, "bump on the nasal bridge"),
    ("nostril_flare", _nostril_flare, "paired", "mm", -1.0, 1.5, None, 1.0, "nostrils and alar base larger"),
    ("lip_volume_upper", _lip_volume_upper, "midline", "mm", -2.5, 3.0, None, 1.0, "fuller upper lip"),
    ("lip_volume_lower", _lip_volume_lower, "midline", "mm", -2.5, 3.0, None, 1.0, "fuller lower lip"),
    ("mouth_width", _mouth_width, "paired", "mm", -3.0, 3.0, None, 1.0, "mouth corners outwards"),
    ("cheek_fullness", _cheek_fullness, "paired", "mm", -4.0, 4.0, None, 1.0, "fuller cheeks"),
    ("cheekbone", _cheekbone, "paired", "mm", -3.0, 3.0, None, 1.0, "more prominent cheekbones"),
    ("brow_ridge", _brow_ridge, "paired", "mm", -3.0, 3.0, None, 1.0, "more prominent brow ridge"),
    ("chin_projection", _chin_projection, "midline", "mm", -5.0, 5.0, None, 1.0, "chin forward"),
    ("chin_width", _chin_width, "paired", "mm", -3.0, 3.0, None, 1.0, "wider chin"),
    ("jaw_angle_width", _jaw_angle_width, "paired", "mm", -5.0, 5.0, None, 1.0, "jaw angles (gonion) outwards"),
    ("forehead_slope", _forehead_slope, "midline", "deg", -6.0, 6.0, None, 1.0, "forehead slopes back"),
    ("ear_size", _ear_size, "paired", "mm", -3.0, 3.0, None, 1.0, "larger ears"),
    ("ear_angle", _ear_angle, "paired", "deg", -4.0, 12.0, 5.0, 1.0, "ears stand out from the skull"),
    ("ear_shape", _ear_shape, "paired", "mm", -2.0, 2.0, None, 0.7, "ear rim (helix) bulges outwards"),
    ("eye_size", _eye_size, "paired", "mm", -1.5, 1.5, None, 1.0, "larger eye openings"),
    ("eye_spacing", _eye_spacing, "paired", "mm", -2.5, 2.5, None, 1.0, "eyes further apart"),
    ("skull_width", _skull_width, "paired", "mm", -6.0, 6.0, None, 1.0, "wider parietal region"),
    ("occiput_projection", _occiput_projection, "midline", "mm", -6.0, 6.0, None, 1.0, "back of the head further back"),
    ("face_length", _face_length, "midline", "mm", -5.0, 5.0, None, 1.0, "longer mid-face (lower face down)"),
    ("asym_nose_deviation", _nose_deviation, "asym", "mm", -2.0, 2.0, 0.8, 1.0, "nose towards the subject's left"),
    ("asym_jaw_shift", _jaw_shift, "asym", "mm", -2.0, 2.0, 0.8, 1.0, "chin and jaw towards the subject's left"),
    ("asym_face_roll", _face_roll, "asym", "mm", -2.0, 2.0, 0.8, 1.0, "left side of the face up, right down"),
    ("asym_face_yaw", _face_yaw, "asym", "mm", -2.0, 2.0, 0.8, 1.0, "left side of the face forward, right back"),
) + tuple(
    (f"asym_bump_{name}", _normal_bump(center, radius), "asym", "mm", -1.5, 1.5, 0.7, 0.5,
     f"left {name.replace('_', ' ')} out, right in")
    for name, center, radius in _ASYM_BUMPS
)
# The antisymmetric partner of a paired feature spans this fraction of its range (mild asymmetry).
_PAIRED_ASYM_FRACTION = 0.25


def _feature_table() -> tuple[tuple[Feature, Callable[[_Context], np.ndarray], str], ...]:
    """All features in basis order: symmetric ones, paired partners, then the global asymmetric modes."""
    main, partners, asym = [], [], []
    for name, builder, kind, unit_name, low, high, sd, p_active, desc in _SPECS:
        sd = 0.5 * max(abs(low), abs(high)) if sd is None else sd
        if kind == "asym":
            asym.append((Feature(name, unit_name, low, high, sd, p_active, "antisymmetric", desc), builder, kind))
            continue
        main.append((Feature(name, unit_name, low, high, sd, p_active, "symmetric", desc), builder, kind))
        if kind == "paired":
            span = _PAIRED_ASYM_FRACTION * max(abs(low), abs(high))
            partners.append((Feature(f"asym_{name}", unit_name, -span, span, 0.5 * span, 1.0, "antisymmetric",
                                     f"left side gets {name} + a, right side {name} - a"), builder, "paired_asym"))
    return tuple(main + partners + asym)


_TABLE = _feature_table()
FEATURES: tuple[Feature, ...] = tuple(f for f, _, _ in _TABLE)
FEATURE_NAMES: tuple[str, ...] = tuple(f.name for f in FEATURES)


# ----------------------------------------------------------------------------------------------------
# The basis
# ----------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FeatureBasis:
    """Unit displacement fields of all features on one template.

    Attributes:
        names: ``M`` feature names (:data:`FEATURE_NAMES`).
        features: the ``M`` :class:`Feature` specs (unit, range, symmetry).
        fields: ``(M, V, 3)`` float64, mm per unit coefficient (per mm of peak displacement, or per
            degree for ``deg`` features).
        template: ``(V, 3)`` float64 template vertices, mm.
    """

    names: tuple[str, ...]
    features: tuple[Feature, ...]
    fields: np.ndarray
    template: np.ndarray

    def displacements(self, coefficients: np.ndarray) -> np.ndarray:
        """``(n, M)`` (or ``(M,)``) coefficients -> ``(n, V, 3)`` (or ``(V, 3)``) displacements, mm."""
        c = _check_coefficients(coefficients, len(self.names))
        out = np.einsum("nm,mvk->nvk", c, self.fields)
        return out[0] if np.ndim(coefficients) == 1 else out


def _mirror(field: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """The mirror image (in x = 0) of a per-vertex vector field."""
    return field[mirror] * _MIRROR_X


def build_basis(asset: RigAsset) -> FeatureBasis:
    """Compute every feature's unit field on ``asset``'s template (no caching; see :func:`feature_basis`)."""
    ctx = _Context(p=np.asarray(asset.vertices, float), normals=smoothed_normals(asset))
    m = asset.mirror
    fields = np.zeros((len(_TABLE), len(ctx.p), 3))
    paired_scale: dict[str, float] = {}
    for i, (feature, builder, kind) in enumerate(_TABLE):
        g = builder(ctx)
        if kind == "midline":
            f = 0.5 * (g + _mirror(g, m))
        elif kind == "paired":
            f = g + _mirror(g, m)
        elif kind == "paired_asym":
            f = g - _mirror(g, m)
        else:
            f = 0.5 * (g - _mirror(g, m))
        if feature.unit == "deg":
            scale = np.pi / 180.0  # builders give rotation fields per radian
        elif kind == "paired_asym":
            scale = paired_scale[feature.name[len("asym_"):]]  # c + a on the left, c - a on the right
        else:
            scale = 1.0 / np.linalg.norm(f, axis=1).max()
        paired_scale[feature.name] = scale
        fields[i] = f * scale
    fields.setflags(write=False)
    template = np.array(asset.vertices, float)
    template.setflags(write=False)
    return FeatureBasis(names=FEATURE_NAMES, features=FEATURES, fields=fields, template=template)


_cached_basis = cached_per_asset(build_basis)


def feature_basis(asset: RigAsset | None = None) -> FeatureBasis:
    """The feature basis of ``asset`` (default: :func:`rig.asset.load_asset`), computed once per asset."""
    return _cached_basis(load_asset() if asset is None else asset)


# ----------------------------------------------------------------------------------------------------
# Sampling and synthesis
# ----------------------------------------------------------------------------------------------------

def _check_coefficients(coefficients, m: int) -> np.ndarray:
    c = np.asarray(coefficients, dtype=float)
    if c.ndim == 1:
        c = c[None]
    if c.ndim != 2 or c.shape[1] != m:
        raise ValueError(f"coefficients must have shape (n, {m}) or ({m},) (one per feature in "
                         f"FEATURE_NAMES order); got {np.shape(coefficients)}")
    if not np.isfinite(c).all():
        raise ValueError("coefficients must be finite")
    return c


def sample_coefficients(rng: np.random.Generator | int, n: int) -> np.ndarray:
    """Random feature coefficients for ``n`` heads.

    Each coefficient is drawn from a zero-mean normal with the feature's ``sd``, truncated to its
    ``[low, high]`` range, and kept with probability ``p_active`` (else 0).

    Parameters
    ----------
    rng : numpy.random.Generator or int
        The random generator (or a seed for ``np.random.default_rng``).
    n : int
        Number of heads, >= 0.

    Returns
    -------
    numpy.ndarray
        ``(n, M)`` float64 coefficients in :data:`FEATURE_NAMES` order (mm or degrees).
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n!r}")
    if not isinstance(rng, np.random.Generator):
        if isinstance(rng, bool) or not isinstance(rng, (int, np.integer)):
            raise ValueError(f"rng must be a numpy Generator or an integer seed, got {type(rng).__name__}")
        rng = np.random.default_rng(rng)
    low = np.array([f.low for f in FEATURES])
    high = np.array([f.high for f in FEATURES])
    sd = np.array([f.sd for f in FEATURES])
    p_active = np.array([f.p_active for f in FEATURES])
    u = rng.uniform(size=(int(n), len(FEATURES)))
    keep = rng.uniform(size=(int(n), len(FEATURES))) < p_active
    a, b = ndtr(low / sd), ndtr(high / sd)
    c = np.clip(sd * ndtri(a + u * (b - a)), low, high)  # inverse-CDF truncated normal
    return np.where(keep, c, 0.0)


def synthesize_heads(coefficients: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """Identity heads for the given coefficients.

    Parameters
    ----------
    coefficients : array_like
        ``(n, M)`` (or ``(M,)``) feature coefficients in :data:`FEATURE_NAMES` order (mm or degrees).
    asset : RigAsset, optional
        The template (default: :func:`rig.asset.load_asset`).

    Returns
    -------
    numpy.ndarray
        ``(n, V, 3)`` float64 vertices in mm (``(V, 3)`` for a 1-D input), in the template's vertex order.
    """
    basis = feature_basis(asset)
    c = _check_coefficients(coefficients, len(basis.names))
    heads = basis.template + np.einsum("nm,mvk->nvk", c, basis.fields)
    return heads[0] if np.ndim(coefficients) == 1 else heads


# ----------------------------------------------------------------------------------------------------
# Splits
# ----------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Population:
    """A split of synthetic identity heads.

    Attributes:
        split: split name (``train``, ``val``, ``test``, ``heldout``).
        names: ``n`` head names (``train_000``, ...).
        coefficients: ``(n, M)`` float64 feature coefficients (mm or degrees).
        vertices: ``(n, V, 3)`` float64 vertices, mm, in the template's vertex order.
        feature_names: the ``M`` feature names, in coefficient order.
        seeds: ``(n,)`` int64 per-head seeds: ``sample_coefficients(np.random.default_rng(seed), 1)``
            gives the head's coefficients.
        expression: ``"neutral"`` (expressive heads are a later extension).
    """

    split: str
    names: tuple[str, ...]
    coefficients: np.ndarray
    vertices: np.ndarray
    feature_names: tuple[str, ...]
    seeds: np.ndarray
    expression: str = "neutral"

    def __len__(self) -> int:
        return len(self.names)


def check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def check_split(name) -> str:
    if name not in SPLIT_SIZES:
        raise ValueError(f"unknown split {name!r}; splits are {list(SPLIT_SIZES)}")
    return name


def split_seeds(name: str, seed: int = 0) -> np.ndarray:
    """Per-head integer seeds of a split, ``(n,)`` int64, from ``SeedSequence([seed, crc32(name)])``."""
    name, seed = check_split(name), check_seed(seed)
    ss = np.random.SeedSequence([seed, zlib.crc32(name.encode("utf-8"))])
    return ss.generate_state(SPLIT_SIZES[name], dtype=np.uint32).astype(np.int64)


def population_split(name: str, seed: int = 0, asset: RigAsset | None = None) -> Population:
    """One JNR split of synthetic heads: ``train`` (85), ``val`` (2), ``test`` (7) or ``heldout`` (100).

    Deterministic given ``seed``; each split (and each head) has its own random stream, so the splits
    are independent (the held-out set shares nothing with the training data).

    Parameters
    ----------
    name : str
        Split name.
    seed : int
        Base seed, >= 0.
    asset : RigAsset, optional
        The template (default: :func:`rig.asset.load_asset`).

    Returns
    -------
    Population
    """
    seeds = split_seeds(name, seed)
    coefficients = np.zeros((len(seeds), len(FEATURES)))
    for i, s in enumerate(seeds):
        coefficients[i] = sample_coefficients(np.random.default_rng(int(s)), 1)[0]
    vertices = synthesize_heads(coefficients, asset)
    return Population(split=name, names=tuple(f"{name}_{i:03d}" for i in range(len(seeds))),
                      coefficients=coefficients, vertices=vertices, feature_names=FEATURE_NAMES, seeds=seeds)


# ----------------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------------

def _mesh_bytes(vertices: np.ndarray, faces: np.ndarray, file_format: str) -> bytes:
    import trimesh

    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    if file_format == "ply":
        return trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=False)
    text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_color=False,
                                           include_texture=False, digits=8)
    return text.encode("utf-8")


def _check_splits(splits) -> tuple[str, ...]:
    if isinstance(splits, str):
        splits = (splits,)
    splits = tuple(splits)
    if not splits:
        raise ValueError("splits must name at least one split")
    for s in splits:
        check_split(s)
    if len(set(splits)) != len(splits):
        raise ValueError(f"splits contains duplicates: {list(splits)}")
    return splits


PROGRESS_STAGE = "synthesising heads"
"""The stage name :func:`write_population` reports progress under."""


def write_population(out_dir: str | os.PathLike, seed: int = 0,
                     splits: Iterable[str] = ("train", "val", "test", "heldout"), file_format: str = "ply",
                     overwrite: bool = False, progress: Progress | None = None,
                     asset: RigAsset | None = None) -> Path:
    """Write synthetic heads as meshes plus a ``manifest.json``.

    Heads go to ``out_dir/<split>/<name>.<ext>`` (written through trimesh with ``process=False``, so the
    template's vertex order and faces are kept; PLY stores float32 coordinates, < 1e-5 mm error, OBJ 8
    decimals). ``manifest.json`` lists every head (split, name, file relative to ``out_dir``, seed,
    coefficients by feature name, vertex count, expression) and the generator version, units, coordinate
    conventions and feature specs. Everything is written into a temporary sibling directory that is
    moved into place in one step at the end (:func:`rig.io.atomic.staged_folder`), so a failure or a
    signal leaves nothing half-written and an existing ``out_dir`` as it was.

    Parameters
    ----------
    out_dir : path
        Output directory.
    seed : int
        Base seed (see :func:`population_split`).
    splits : iterable of str
        Splits to write.
    file_format : {"ply", "obj"}
        Mesh format.
    overwrite : bool
        Replace a non-empty ``out_dir``; otherwise it raises :class:`FileExistsError`.
    progress : callable, optional
        :data:`rig.optim.Progress`, called as ``progress("synthesising heads", done, total)`` after each head
        is written (and once with ``done = 0``).
    asset : RigAsset, optional
        The template (default: :func:`rig.asset.load_asset`).

    Returns
    -------
    pathlib.Path
        Path of the written ``manifest.json``.
    """
    out_dir = Path(out_dir)
    seed = check_seed(seed)
    splits = _check_splits(splits)
    if file_format not in FILE_FORMATS:
        raise ValueError(f"file_format must be one of {FILE_FORMATS}, got {file_format!r}")
    if progress is not None and not callable(progress):
        raise ValueError("progress must be callable as progress(stage, done, total)")
    if out_dir.exists() and not out_dir.is_dir():
        raise FileExistsError(f"{out_dir} exists and is not a directory")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not overwrite:
        raise FileExistsError(f"{out_dir} exists and is not empty; use --force (overwrite=True) to replace it")

    asset = load_asset() if asset is None else asset
    populations = [population_split(s, seed, asset) for s in splits]
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    replace = overwrite or out_dir.is_dir()  # an empty folder is replaced without overwrite too
    with staged_folder(out_dir, replace=replace, check_replace=None if overwrite else _still_empty) as tmp:
        heads = _write_heads(tmp, populations, asset.faces, file_format, progress)
        manifest = _manifest(seed, file_format, asset, populations, heads)
        (tmp / MANIFEST_NAME).write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    return out_dir / MANIFEST_NAME


def _still_empty(out_dir: Path) -> None:
    """Without ``overwrite`` only an empty folder is replaced (checked again just before the move)."""
    if out_dir.is_dir() and any(out_dir.iterdir()):
        raise FileExistsError(f"{out_dir} exists and is not empty; use --force (overwrite=True) to replace it")


def _write_heads(folder: Path, populations: list[Population], faces: np.ndarray, file_format: str,
                 progress: Progress | None) -> list[dict]:
    """Write every head's mesh below ``folder``; returns the manifest's rows."""
    total = sum(len(p) for p in populations)
    heads = []
    done = 0
    if progress is not None:
        progress(PROGRESS_STAGE, 0, total)
    for pop in populations:
        (folder / pop.split).mkdir()
        for i, name in enumerate(pop.names):
            rel = f"{pop.split}/{name}.{file_format}"
            (folder / rel).write_bytes(_mesh_bytes(pop.vertices[i], faces, file_format))
            heads.append({
                "split": pop.split, "name": name, "file": rel, "seed": int(pop.seeds[i]),
                "vertex_count": int(pop.vertices.shape[1]), "expression": pop.expression,
                "coefficients": {f: float(v) for f, v in zip(pop.feature_names, pop.coefficients[i])},
            })
            done += 1
            if progress is not None:
                progress(PROGRESS_STAGE, done, total)
    return heads


def _manifest(seed: int, file_format: str, asset: RigAsset, populations: list[Population], heads: list[dict]) -> dict:
    """The ``manifest.json`` content (see :func:`write_population`)."""
    return {
        "generator": "pipeline.synthetic.population",
        "generator_version": GENERATOR_VERSION,
        "template_version": int(asset.version),
        "units": "mm",
        "coordinates": COORDINATES,
        "base_seed": seed,
        "seed_derivation": "split: SeedSequence([base_seed, crc32(split)]).generate_state(n, uint32); "
                           "head: sample_coefficients(numpy.random.default_rng(seed), 1)",
        "file_format": file_format,
        "vertex_count": len(asset.vertices),
        "face_count": len(asset.faces),
        "split_sizes": {p.split: len(p) for p in populations},
        "feature_names": list(FEATURE_NAMES),
        "features": [{"name": f.name, "unit": f.unit, "low": f.low, "high": f.high, "sd": f.sd,
                      "p_active": f.p_active, "symmetry": f.symmetry, "description": f.description}
                     for f in FEATURES],
        "heads": heads,
    }


def read_population(manifest_path: str | os.PathLike) -> dict[str, Population]:
    """Load heads written by :func:`write_population`.

    Parameters
    ----------
    manifest_path : path
        The ``manifest.json`` (or the directory holding it).

    Returns
    -------
    dict[str, Population]
        One :class:`Population` per split in the manifest, in file order; vertices ``(n, V, 3)`` float64
        mm read from the mesh files, coefficients ``(n, M)`` from the manifest.
    """
    import trimesh

    path = Path(manifest_path)
    if path.is_dir():
        path = path / MANIFEST_NAME
    if not path.is_file():
        raise FileNotFoundError(f"population manifest not found: {path}")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
        feature_names = tuple(manifest["feature_names"])
        heads = manifest["heads"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{path} is not a population manifest: {exc}") from None
    grouped: dict[str, list[dict]] = {}
    for head in heads:
        grouped.setdefault(head["split"], []).append(head)
    out = {}
    for split, rows in grouped.items():
        vertices = []
        for row in rows:
            mesh = trimesh.load(path.parent / row["file"], process=False, force="mesh")
            v = np.asarray(mesh.vertices, dtype=np.float64)
            if len(v) != row["vertex_count"]:
                raise ValueError(f"{row['file']} has {len(v)} vertices, the manifest says {row['vertex_count']}")
            vertices.append(v)
        missing = [f for f in feature_names if any(f not in r["coefficients"] for r in rows)]
        if missing:
            raise ValueError(f"{path}: heads of split {split!r} lack coefficients {missing[:5]}")
        out[split] = Population(
            split=split, names=tuple(r["name"] for r in rows),
            coefficients=np.array([[r["coefficients"][f] for f in feature_names] for r in rows], float),
            vertices=np.stack(vertices), feature_names=feature_names,
            seeds=np.array([r["seed"] for r in rows], np.int64),
            expression=rows[0].get("expression", "neutral"),
        )
    return out
