"""Expressive synthetic heads: identity heads plus expressions that are NOT the model's blendshapes.

:mod:`pipeline.synthetic.population` makes neutral identity heads and :mod:`rig.expressions` sculpts the 24
blendshapes the rig fits with. Evaluating expression fitting on heads made from those same 24
shapes would be an inverse crime, so this module builds an independent set of expression
deformation fields by a different construction:

- falloffs are windowed Gaussians ``exp(-t^2 / 2)`` (cut off smoothly, C-infinity, between 2.5 and
  3.2 standard deviations) and C-infinity transitions ``psi(t) / (psi(t) + psi(1 - t))`` with
  ``psi(t) = exp(-1/t)``, instead of the model's compact bumps and quintic ramps;
- centres, radii and directions are chosen independently of the model (a smile that also bulges
  the cheek, an asymmetric corner pull, a lip funnel, a nose wrinkle, ...);
- ``jaw_drop`` is the exact rotation by ``c * 22`` degrees about the X axis through
  :data:`JAW_HINGE` ``(0, -28, -5)`` mm (the model: 18 degrees about ``(0, -20, 5)``) plus a
  forward-and-down condylar glide ``c *`` :data:`JAW_GLIDE_MM`, with its own weight field;
- ``eye_close_*`` blends the rims towards each other along straight lines, meeting at
  :data:`LID_MEET_FRACTION` of the way down (the model rotates the upper lid about the eyeball
  centre onto the still lower lid) and pushes whatever would dip into the eyeball back out radially
  to :data:`LID_CLEARANCE_MM` from the eyeball centre (so it is nonlinear in its coefficient).

Only geometric helpers are shared with the rig (the mouth slit and eye rims, region masks, the
smoothed normal field, the harmonic extension over the mouth interior); no field of
:func:`rig.expressions.build_expression_basis` is used.

Features
--------
:data:`EXPRESSIVE_FEATURE_NAMES` (fixed order), limits ``[0, 1]`` except ``cheek_puff``
(``[-1, 1]``; negative sucks the cheeks in). Peak = largest vertex displacement at coefficient 1:

=====================  =======  ==========================================================
name                   peak mm  what coefficient 1 does
=====================  =======  ==========================================================
jaw_drop               ~44      jaw rotated 22 deg down about the hinge and glided (chin ~44 mm)
smile_bulge_l/r        9        mouth corner up, back and out; the cheek above bulges out
eye_close_l/r          ~7       rims blended onto each other, meeting 65 % of the way down
brow_lift_l/r          7        brow and forehead lifted smoothly along the surface
lip_pucker             8        lips forward, towards the midline and the slit; perioral skin follows
lip_funnel             6        lips forward and rolled open (upper up, lower down)
cheek_puff             7        cheeks out along the normals
nose_wrinkle           3.5      nose sides and alae up, slightly in
corner_pull_l/r        6        one mouth corner out, down and back (asymmetric)
=====================  =======  ==========================================================

Topology: fields are smooth functions of 3D position except across the mouth slit and the eye
openings, where a field may differ on the two sides only with a factor that vanishes at the slit's
corners (so the lips and lids move independently, the skin stays continuous). The eyeballs never
move; the mouth interior follows the lip rim (harmonic extension); nothing but ``jaw_drop`` moves
the ears, scalp or neck (< 0.05 mm), and ``jaw_drop`` leaves the ears and scalp still too.
``*_r`` fields are the exact mirror images of the ``*_l`` ones; the others are mirror-symmetric.

Expressions are added to an identity head as template-space offsets (like the rig's blendshapes):
``vertices = neutral + expressive_offsets(c)``.

Coordinates: millimetres, right-handed, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from pipeline.synthetic.population import (
    SPLIT_SIZES,
    check_seed,
    check_split,
    population_split,
)
from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.expressions import harmonic_extension, left_eye_geometry, mouth_geometry
from rig.fields import smoothed_normals

__all__ = [
    "EXPRESSIVE_FEATURE_NAMES",
    "EXPRESSIVE_LIMITS",
    "JAW_DROP_DEG",
    "JAW_GLIDE_MM",
    "JAW_HINGE",
    "LID_CLEARANCE_MM",
    "LID_MEET_FRACTION",
    "ExpressiveHeads",
    "expressive_offsets",
    "expressive_peaks",
    "expressive_seeds",
    "expressive_split",
    "sample_expression_coefficients",
]

EXPRESSIVE_FEATURE_NAMES: tuple[str, ...] = (
    "jaw_drop", "smile_bulge_l", "smile_bulge_r", "eye_close_l", "eye_close_r", "brow_lift_l",
    "brow_lift_r", "lip_pucker", "lip_funnel", "cheek_puff", "nose_wrinkle", "corner_pull_l",
    "corner_pull_r",
)
"""The expressive feature names, in coefficient order."""

EXPRESSIVE_LIMITS: dict[str, tuple[float, float]] = {
    n: ((-1.0, 1.0) if n == "cheek_puff" else (0.0, 1.0)) for n in EXPRESSIVE_FEATURE_NAMES}
"""Coefficient limits per feature."""

JAW_HINGE = (0.0, -28.0, -5.0)
"""Hinge point of ``jaw_drop`` (mm); the axis is along +X."""
JAW_DROP_DEG = 22.0
"""Rotation of ``jaw_drop`` at coefficient 1, degrees."""
JAW_GLIDE_MM = (0.0, -3.0, 5.0)
"""Condylar glide of ``jaw_drop`` at coefficient 1 (mm, forward and down), scaled by ``c`` and the weight."""
LID_MEET_FRACTION = 0.65
"""``eye_close_*``: the rims meet this fraction of the way from the upper rim to the lower rim."""
LID_CLEARANCE_MM = 12.4
"""``eye_close_*`` keeps the closing lid at least this far from the eyeball centre (eyeball radius 12)."""

_INDEX = {n: i for i, n in enumerate(EXPRESSIVE_FEATURE_NAMES)}
_NONLINEAR = ("jaw_drop", "eye_close_l", "eye_close_r")
_MIRROR_X = np.array([-1.0, 1.0, 1.0])
_PEAKS = {"smile_bulge_l": 9.0, "brow_lift_l": 7.0, "lip_pucker": 8.0, "lip_funnel": 6.0, "cheek_puff": 7.0,
          "nose_wrinkle": 3.5, "corner_pull_l": 6.0}


# ----------------------------------------------------------------------------------------------------
# Falloffs (different from pipeline.synthetic.population's bumps and quintic ramps)
# ----------------------------------------------------------------------------------------------------

def _cinf_step(x: np.ndarray, e0: float, e1: float) -> np.ndarray:
    """C-infinity transition: 0 for ``x <= e0``, 1 for ``x >= e1`` (``e1 < e0`` ramps the other way)."""
    t = np.clip((np.asarray(x, float) - e0) / (e1 - e0), 0.0, 1.0)
    with np.errstate(divide="ignore", over="ignore"):
        a = np.where(t > 0.0, np.exp(-1.0 / np.maximum(t, 1e-300)), 0.0)
        b = np.where(t < 1.0, np.exp(-1.0 / np.maximum(1.0 - t, 1e-300)), 0.0)
    return a / (a + b)


def _gauss(p: np.ndarray, center, sigmas) -> np.ndarray:
    """Windowed anisotropic Gaussian of ``(V, 3)`` mm positions, ``(V,)``: exactly 0 beyond 3.2 sigma."""
    t = np.sqrt((((p - np.asarray(center, float)) / np.asarray(sigmas, float)) ** 2).sum(axis=-1))
    return np.exp(-0.5 * t * t) * (1.0 - _cinf_step(t, 2.5, 3.2))


def _dir(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _along_surface(normals: np.ndarray, direction) -> np.ndarray:
    """Unit ``direction`` with its component along the (smoothed) normals removed, ``(V, 3)``."""
    d = _dir(direction)
    n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-9)
    t = d - (n @ d)[:, None] * n
    return t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-9)


def _peak(field: np.ndarray, peak: float) -> np.ndarray:
    return field * (peak / np.linalg.norm(field, axis=1).max())


def _mirrored(asset: RigAsset, field: np.ndarray) -> np.ndarray:
    return field[asset.mirror] * _MIRROR_X


def _lip_gate(x: np.ndarray, x_corner: float) -> np.ndarray:
    """``(1 - (x / x_c)^2)^2`` inside the mouth corners, 0 beyond: where the two lips may differ."""
    u = np.clip(np.abs(x) / x_corner, 0.0, 1.0)
    return (1.0 - u * u) ** 2


# ----------------------------------------------------------------------------------------------------
# The fields
# ----------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Fields:
    linear: np.ndarray  # (F, V, 3) mm at coefficient 1 (zero rows for the nonlinear features)
    jaw_weight: np.ndarray  # (V,)
    lid_weight: np.ndarray  # (V,) left upper lid
    lid_delta: np.ndarray  # (V, 3) left rim-to-rim blend at full weight, mm
    eye_center: np.ndarray  # (3,) left eyeball centre


def _jaw_weight(asset: RigAsset) -> np.ndarray:
    v = asset.vertices
    x, y, z = v.T
    mouth = mouth_geometry(asset)
    dy = y - mouth.slit(x)
    a = 1.0 - _cinf_step(dy, -34.0, 20.0)  # 1 well below the mouth line, 0 well above
    g = np.exp(-0.5 * (x / (0.45 * mouth.x_corner)) ** 2) * (1.0 - _cinf_step(np.abs(x), 0.55 * mouth.x_corner,
                                                                                mouth.x_corner))
    w = np.where(dy < 0.0, a + g * (1.0 - a), a * (1.0 - g))  # lower - upper = g: 0 at the corners
    w = w * _cinf_step(z, -35.0, 10.0)  # not the back of the neck
    w = w * (1.0 - _cinf_step(-y, 92.0, 135.0) * (1.0 - _cinf_step(z, 35.0, 80.0)))  # throat fades
    w = np.where(asset.region_mask("eyeballs", "ears", "scalp"), 0.0, w)
    w = harmonic_extension(asset, w, asset.region_mask("mouth_interior"))
    return 0.5 * (w + w[asset.mirror])


def _lid_blend(asset: RigAsset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left eye closure at full coefficient: weight ``(V,)`` and rim-to-rim vector field ``(V, 3)``.

    The rims meet at :data:`LID_MEET_FRACTION` of the way down: upper-lid points move by
    ``w * f * d(x)``, lower-lid points by ``-w * (1 - f) * d(x)``, where ``d(x)`` is the (spline
    interpolated) vector from the upper to the lower rim of the column at ``x``, zero at the corners.
    The returned field already carries the side's factor (``f`` or ``-(1 - f)``).
    """
    v = asset.vertices
    eye = left_eye_geometry(asset)
    x, y, z = v.T
    xs = np.concatenate([[eye.x_inner], v[eye.upper, 0], [eye.x_outer]])
    d = np.concatenate([np.zeros((1, 3)), v[eye.lower] - v[eye.upper], np.zeros((1, 3))])
    spline = CubicSpline(xs, d, axis=0, bc_type="clamped")
    inside = (x > eye.x_inner) & (x < eye.x_outer)
    delta = np.where(inside[:, None], spline(np.clip(x, eye.x_inner, eye.x_outer)), 0.0)
    y_up = eye.rim_height(v, eye.upper, x)
    y_lo = eye.rim_height(v, eye.lower, x)
    upper_side = y >= 0.5 * (y_up + y_lo)
    above = y - y_up
    below = y_lo - y
    w_up = np.where(above <= 0.0, 1.0, np.exp(-0.5 * (above / 6.0) ** 2) * (1.0 - _cinf_step(above, 14.0, 19.0)))
    w_lo = np.where(below <= 0.0, 1.0, np.exp(-0.5 * (below / 3.5) ** 2) * (1.0 - _cinf_step(below, 8.0, 11.0)))
    w = np.where(upper_side, w_up, w_lo) * _cinf_step(z, 40.0, 55.0)
    w = np.where(asset.region_mask("eyeballs"), 0.0, w)
    factor = np.where(upper_side, LID_MEET_FRACTION, -(1.0 - LID_MEET_FRACTION))
    return w, delta * factor[:, None], eye.center


def _build(asset: RigAsset) -> _Fields:
    v = asset.vertices
    x, y, z = v.T
    normals = smoothed_normals(asset, radius=14.0)
    normals_u = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-9)
    mouth = mouth_geometry(asset)
    ys = mouth.slit(x)
    corner = np.array([mouth.x_corner, mouth.y_corner, 80.0])
    gate = _lip_gate(x, mouth.x_corner)
    fields: dict[str, np.ndarray] = {}

    # Smile: corner up, back and out, plus a cheek bulge along the normals.
    s = _gauss(v, corner + (3.0, 3.0, -3.0), (10.0, 9.0, 11.0))[:, None] * _dir((0.3, 0.85, -0.45))
    bulge = _gauss(v, (38.0, -46.0, 68.0), (11.0, 9.0, 10.0))[:, None] * (normals_u + (0.0, 0.35, 0.0))
    fields["smile_bulge_l"] = s + 0.55 * bulge

    # Brow: a broad, smooth lift of brow and lower forehead along the surface (no wrinkles).
    lift = (_gauss(v, (30.0, 36.0, 80.0), (16.0, 15.0, 22.0)) * _cinf_step(y, 9.0, 22.0) * _cinf_step(z, 30.0, 50.0)
            * (1.0 - _cinf_step(y, 55.0, 70.0)))
    fields["brow_lift_l"] = lift[:, None] * _along_surface(normals, (0.0, 1.0, 0.0))

    # Lips: pucker (forward, in, towards the slit) and funnel (forward, rolled open).
    lips = _gauss(v, (0.0, -71.0, 86.0), (13.0, 8.0, 9.0))
    toward_slit = -np.tanh((y - ys) / 4.0)
    pucker = np.stack([-0.8 * np.tanh(x / 8.0), 0.6 * toward_slit, np.ones_like(x)], axis=1)
    perioral = _gauss(v, (0.0, -74.0, 80.0), (24.0, 20.0, 16.0))  # the skin around the lips follows
    fields["lip_pucker"] = lips[:, None] * pucker + 0.45 * perioral[:, None] * _dir((0.0, 0.1, 1.0))
    funnel_lips = _gauss(v, (0.0, -71.0, 84.0), (15.0, 10.0, 9.0))
    roll = np.tanh((y - ys) / 2.5) * gate  # differs across the slit only between the corners
    funnel = np.stack([np.zeros_like(x), 0.8 * roll, 0.6 + 0.3 * np.abs(roll)], axis=1)
    fields["lip_funnel"] = funnel_lips[:, None] * funnel

    # Cheeks out along the normals.
    cheek = _gauss(v, (42.0, -57.0, 58.0), (13.0, 13.0, 12.0))[:, None] * normals_u
    fields["cheek_puff"] = cheek + _mirrored(asset, cheek)

    # Nose wrinkle: nose sides and alae up and a little towards the midline.
    side = _gauss(v, (9.0, -22.0, 96.0), (7.0, 10.0, 9.0))[:, None] * _dir((-0.3, 1.0, -0.15))
    ala = _gauss(v, (15.0, -43.0, 90.0), (6.0, 6.0, 7.0))[:, None] * _dir((0.1, 1.0, 0.2))
    nose = side + 0.8 * ala
    fields["nose_wrinkle"] = nose + _mirrored(asset, nose)

    # Asymmetric corner pull: out, down and back.
    pull = _gauss(v, corner + (1.0, -2.0, -2.0), (9.0, 9.0, 10.0))
    fields["corner_pull_l"] = pull[:, None] * _dir((0.8, -0.45, -0.4))

    eyeballs = asset.region_mask("eyeballs")
    interior = asset.region_mask("mouth_interior")
    linear = np.zeros((len(EXPRESSIVE_FEATURE_NAMES), len(v), 3))
    for name, f in fields.items():
        f = np.where(eyeballs[:, None], 0.0, f)
        f = harmonic_extension(asset, f, interior)
        if not name.endswith("_l"):
            f = 0.5 * (f + _mirrored(asset, f))
        f = _peak(f, _PEAKS[name])
        linear[_INDEX[name]] = f
        if name.endswith("_l"):
            linear[_INDEX[name[:-2] + "_r"]] = _mirrored(asset, f)
    lid_w, lid_d, center = _lid_blend(asset)
    return _Fields(linear, _jaw_weight(asset), lid_w, lid_d, np.asarray(center, float))


_fields = cached_per_asset(_build)
"""The fields of an asset, built once."""


def _jaw_offsets(asset: RigAsset, weight: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``(n, V, 3)``: ``w(p) [(R_x(c * 22 deg) - I)(p - hinge) + c * glide]``, exact rotation (front goes
    down) plus the forward-and-down glide of the mandible."""
    q = asset.vertices - np.asarray(JAW_HINGE)
    ang = np.radians(JAW_DROP_DEG) * c[:, None]  # (n, 1)
    cos, sin = np.cos(ang), np.sin(ang)
    qy, qz = q[None, :, 1], q[None, :, 2]
    d = np.stack([np.zeros_like(cos * qy), cos * qy - sin * qz - qy, sin * qy + cos * qz - qz], axis=-1)
    d = d + c[:, None, None] * np.asarray(JAW_GLIDE_MM)
    return weight[None, :, None] * d


def _lid_offsets(asset: RigAsset, f: _Fields, c: np.ndarray) -> np.ndarray:
    """Left eye closure ``(n, V, 3)``: straight blend, then pushed out of the eyeball radially."""
    moving = f.lid_weight > 0.0
    q = asset.vertices[moving] - f.eye_center
    blend = c[:, None, None] * (f.lid_weight[moving, None] * f.lid_delta[moving])[None]
    qn = q[None] + blend
    r = np.linalg.norm(qn, axis=-1, keepdims=True)
    push = np.maximum(LID_CLEARANCE_MM - r, 0.0) * (qn[..., 2:3] > 0.0)
    out = np.zeros((len(c), len(asset.vertices), 3))
    out[:, moving] = blend + push * qn / np.maximum(r, 1e-9)
    return out


def _check_coefficients(coefficients) -> tuple[np.ndarray, bool]:
    c = np.asarray(coefficients, dtype=float)
    single = c.ndim == 1
    c = c[None] if single else c
    n_feat = len(EXPRESSIVE_FEATURE_NAMES)
    if c.ndim != 2 or c.shape[1] != n_feat:
        raise ValueError(f"expressive_offsets: coefficients must have shape (n, {n_feat}) or ({n_feat},), "
                         f"got {np.shape(coefficients)}")
    if not np.isfinite(c).all():
        raise ValueError("expressive_offsets: coefficients must be finite")
    low = np.array([EXPRESSIVE_LIMITS[n][0] for n in EXPRESSIVE_FEATURE_NAMES])
    high = np.array([EXPRESSIVE_LIMITS[n][1] for n in EXPRESSIVE_FEATURE_NAMES])
    bad = (c < low - 1e-9) | (c > high + 1e-9)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise ValueError(f"expressive_offsets: coefficient {EXPRESSIVE_FEATURE_NAMES[j]!r} = {c[i, j]} of head {i} "
                         f"is outside its limits {EXPRESSIVE_LIMITS[EXPRESSIVE_FEATURE_NAMES[j]]}")
    return c, single


def expressive_offsets(coefficients: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """Expression displacements on the template.

    Args:
        coefficients: ``(n, F)`` or ``(F,)`` in :data:`EXPRESSIVE_FEATURE_NAMES` order, within
            :data:`EXPRESSIVE_LIMITS` (``F = 13``).
        asset: the template (default: :func:`rig.asset.load_asset`).

    Returns:
        ``(n, V, 3)`` or ``(V, 3)`` float64 offsets in mm. Linear in the coefficients except
        ``jaw_drop`` (exact rotation) and ``eye_close_*`` (blend plus radial push off the eyeball).

    Raises:
        ValueError: wrong shape, non-finite values or coefficients outside the limits.

    Example:
        >>> c = np.zeros(len(EXPRESSIVE_FEATURE_NAMES)); c[0] = 0.5      # jaw half open
        >>> expressive_offsets(c).shape
        (4978, 3)
    """
    c, single = _check_coefficients(coefficients)
    asset = load_asset() if asset is None else asset
    f = _fields(asset)
    out = np.einsum("nf,fvk->nvk", c, f.linear)
    out += _jaw_offsets(asset, f.jaw_weight, c[:, _INDEX["jaw_drop"]])
    out += _lid_offsets(asset, f, c[:, _INDEX["eye_close_l"]])
    right = _lid_offsets(asset, f, c[:, _INDEX["eye_close_r"]])
    out += right[:, asset.mirror] * _MIRROR_X
    return out[0] if single else out


def expressive_peaks(asset: RigAsset | None = None) -> dict[str, float]:
    """Peak displacement (mm) of each feature alone at its upper limit."""
    offsets = expressive_offsets(np.eye(len(EXPRESSIVE_FEATURE_NAMES)), asset)
    return {n: float(np.linalg.norm(o, axis=1).max()) for n, o in zip(EXPRESSIVE_FEATURE_NAMES, offsets)}


# ----------------------------------------------------------------------------------------------------
# Sampling and splits
# ----------------------------------------------------------------------------------------------------

def sample_expression_coefficients(rng: np.random.Generator | int, n: int) -> np.ndarray:
    """Random expressions: each head gets 1 to 3 distinct active features, amplitudes in
    ``[0.4, 1]`` (``cheek_puff``: random sign), the rest 0.

    Args:
        rng: a ``np.random.Generator`` or an integer seed.
        n: number of heads, >= 0.

    Returns:
        ``(n, F)`` float64 coefficients.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"sample_expression_coefficients: n must be a non-negative integer, got {n!r}")
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    n_feat = len(EXPRESSIVE_FEATURE_NAMES)
    c = np.zeros((int(n), n_feat))
    for i in range(int(n)):
        k = int(rng.integers(1, 4))
        active = rng.choice(n_feat, size=k, replace=False)
        amp = rng.uniform(0.4, 1.0, size=k)
        sign = np.where(rng.random(k) < 0.3, -1.0, 1.0)
        for j, a, s in zip(active, amp, sign):
            c[i, j] = a * (s if EXPRESSIVE_LIMITS[EXPRESSIVE_FEATURE_NAMES[j]][0] < 0 else 1.0)
    return c


@dataclass(frozen=True)
class ExpressiveHeads:
    """Identity heads with expressions.

    Attributes:
        names: ``n`` head names (``heldout_000``, ... as in the identity split).
        identity_coefficients: ``(n, M)`` identity coefficients (:data:`pipeline.synthetic.population.FEATURE_NAMES`).
        expression_coefficients: ``(n, F)`` expression coefficients (:data:`EXPRESSIVE_FEATURE_NAMES`).
        neutral: ``(n, V, 3)`` float64 neutral identity heads, mm.
        vertices: ``(n, V, 3)`` float64 expressive heads, ``neutral + expressive_offsets(...)``, mm.
        seeds: ``(n,)`` int64 per-head expression seeds:
            ``sample_expression_coefficients(np.random.default_rng(seed), 1)`` gives the coefficients.
    """

    names: tuple[str, ...]
    identity_coefficients: np.ndarray
    expression_coefficients: np.ndarray
    neutral: np.ndarray
    vertices: np.ndarray
    seeds: np.ndarray

    def __len__(self) -> int:
        return len(self.names)


def expressive_seeds(name: str = "heldout", seed: int = 0) -> np.ndarray:
    """Per-head expression seeds ``(n,)`` int64 from ``SeedSequence([seed, crc32("expressive-" + name)])``:
    a stream independent of the identity seeds."""
    name, seed = check_split(name), check_seed(seed)
    ss = np.random.SeedSequence([seed, zlib.crc32(("expressive-" + name).encode("utf-8"))])
    return ss.generate_state(SPLIT_SIZES[name], dtype=np.uint32).astype(np.int64)


def expressive_split(name: str = "heldout", seed: int = 0, n: int | None = None,
                     asset: RigAsset | None = None) -> ExpressiveHeads:
    """The identities of ``pipeline.synthetic.population.population_split(name, seed)`` (the first ``n``), each with
    a random expression.

    Args:
        name: split name (``train``, ``val``, ``test``, ``heldout``).
        seed: base seed, >= 0.
        n: keep the first ``n`` heads (default: all), ``0 <= n <= split size``.
        asset: the template (default: :func:`rig.asset.load_asset`).

    Returns:
        :class:`ExpressiveHeads`; deterministic given ``(name, seed)``; head ``i`` does not depend on ``n``.
    """
    seeds = expressive_seeds(name, seed)
    if n is not None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 0 <= n <= len(seeds):
            raise ValueError(f"expressive_split: n must be an integer in [0, {len(seeds)}], got {n!r}")
        seeds = seeds[: int(n)]
    asset = load_asset() if asset is None else asset
    population = population_split(name, seed, asset)
    k = len(seeds)
    coefficients = np.zeros((k, len(EXPRESSIVE_FEATURE_NAMES)))
    for i, s in enumerate(seeds):
        coefficients[i] = sample_expression_coefficients(np.random.default_rng(int(s)), 1)[0]
    neutral = population.vertices[:k]
    vertices = neutral + expressive_offsets(coefficients, asset) if k else neutral.copy()
    return ExpressiveHeads(names=population.names[:k], identity_coefficients=population.coefficients[:k],
                           expression_coefficients=coefficients, neutral=neutral, vertices=vertices, seeds=seeds)
