"""Expressive synthetic heads: identity heads plus ICT's 53 expression shapes (not the rig's basis).

The rig fits expressions with MakeHuman's 52 ARKit face units (:mod:`rig.expressions`). Evaluating
expression fitting on heads made from those same shapes would be an inverse crime, so the test expressions
here are sparse mixes of a basis made by other people for another topology: the 53 expression shapes of the
ICT Face Model (USC ICT, MIT licence; :mod:`rig.ict.data`), captured from light-stage scans of real
people's expressions and transferred onto the template's vertices by :func:`rig.ict.modes.expression_shapes`
(weight 1 = ICT's full expression). The rig keeps MakeHuman's ARKit shapes, so ICT's are the honest choice
for the expressive set (issue 25): same action names, independent data.

What is independent of the rig's basis
--------------------------------------
Every displacement comes from ICT's shapes; nothing of :func:`rig.expressions.build_expression_basis`
(ARKit units, jaw rotation, jaw weight, corrective) is used to make a head. Only the template's vertices,
mirror map and regions are shared (and the correspondence through which :mod:`rig.ict.transfer` carries
ICT's deltas onto them). The two bases overlap, though (both follow ARKit's action list):
:func:`span_residuals` measures, per shape or per head, the fraction of the offset that no combination of
the rig's 52 ARKit shapes explains. Per shape (teeth and tongue left out of the measure, see
:data:`SPAN_EXCLUDED_REGIONS`): median 54 %, least ``jawLeft``/``jawRight`` 34 %, most
``eyeLookOut_*`` 96 % (``eyeLookIn_*`` 96 %: ICT's gaze shapes move the lids and the skin around the eye,
the rig's gaze turns the eyeball); the brows 54-76 %, the eyes 56-96 %, the cheeks 43-63 %, the nose 44 %,
the mouth and jaw 34-65 %. The expressions of the held-out heads (``expressive_split("heldout", 0)``):
median 47 %, 34-96 %.

Features
--------
:data:`EXPRESSIVE_FEATURE_NAMES`: ICT's 53 names in ICT's order (``browDown_L``, ..., ``eyeBlink_L``,
``jawOpen``, ``mouthClose``, ``mouthSmile_R``, ``noseSneer_R``), every coefficient in ``[0, 1]``
(:data:`EXPRESSIVE_LIMITS`). ``_L`` (and ``jawLeft``, ``mouthLeft``) is the subject's left (+X), as in the
rig. Peaks at 1 (largest vertex displacement, :func:`expressive_peaks`): 2.5 mm (``eyeLookIn_*``,
``eyeLookOut_*``) to 42 mm (``jawOpen``: the chin drops 24 mm, the lower lip 34 mm); ``eyeBlink_*``
9.5 mm; brows 5.8-8.6 mm; the other mouth shapes 4-19 mm. ``mouthClose`` (42 mm) is ARKit's corrective for
``jawOpen``: alone it pushes the lower lip 35 mm up through the upper one, with ``jawOpen`` it closes the
lips over the dropped jaw; the sampler only uses it so (:data:`COMPANIONS`). A head's expression is
``vertices = neutral + expressive_offsets(c)``: template-space offsets added to the identity head (as ICT's
own model adds its expression deltas to any identity), linear in ``c``.

Mirror
------
ICT's shapes were captured on a real, slightly asymmetric face, and are kept as captured (no mirror
symmetrisation, unlike the rig's exactly symmetric basis): measured with ``mirror(f) = f[asset.mirror] *
(-1, 1, 1)``, each pair ``X_L`` vs ``mirror(X_R)`` (:data:`EXPRESSIVE_PAIRS`, with ``jawLeft``/``jawRight``
and ``mouthLeft``/``mouthRight``) differs by at most 0.60 mm (``eyeBlink``; median over pairs 0.14 mm),
at most 2.1 % of the shape's norm (``cheekSquint``); the 9 midline shapes differ from their own mirror
image by at most 0.22 mm (``jawOpen``), 2.6 % (``mouthShrugUpper``). The asymmetry is small but real
(part of the captured data, as a real face's is); averaging it away would only make the test expressions
more like the rig's symmetric basis. So mirrored coefficients give mirrored heads to within 0.6 mm, not
exactly, and a pair's two span residuals agree to 0.001.

Sampling
--------
:func:`sample_expression_coefficients`: per head 1 to 3 distinct drawn shapes, strengths uniform in
``[0.4, 1]``, the rest 0; then, within each facial area (:data:`EXPRESSIVE_GROUPS`: each eye, each brow,
the nose, the cheeks, the mouth with the jaw), strengths summing to more than 1 are scaled down to sum 1;
last, a drawn ``mouthClose`` adds its strength to ``jawOpen`` (so ``c[jawOpen] >= c[mouthClose]``; up to 4
non-zero coefficients). Flipped visible-skin triangles in 1,000 draws on the template: at most 15.7 mm²
(0.01 % of the 152,000 mm² of visible skin); without the area rule at most 21.9 mm², without the
``mouthClose`` rule up to 117 mm². :func:`expressive_split` draws head ``i`` from its own seed
(:func:`expressive_seeds`), independent of the identity seeds, and records seeds and coefficients.

Limits
------
- ICT's shapes fold the template's skin a little at full strength: 24 of the 53 turn some triangles of
  the visible skin (no vertex in :data:`rig.template.HIDDEN_REGIONS`) by more than 90 degrees:
  ``mouthClose`` alone 101 mm² (94 triangles; never drawn alone: with ``jawOpen`` 14.6 mm²), the others
  at most 15.2 mm² (``mouthShrugLower``), then ``mouthRollUpper`` 13.6, ``eyeBlink_*`` 10-11 (small
  triangles at the lid), ``mouthDimple_*`` 6.8, ``mouthRollLower`` 6.3, ``jawForward`` 3.8, ``jawLeft``/
  ``jawRight`` 3.0, ``jawOpen`` 2.6, and below 1 mm² for ten more, all but the lids in the mouth corners,
  where the template's lip rim meets ICT's lip contact line (13 shapes folded when the rim went to ICT's
  skin boundary inside the mouth). Sampled heads keep these folds (1,000 draws: at most 15.6 mm²). No
  sampled head is a broken mesh for scans or photos, but "no flipped triangle" does not hold.
- The closed lids are ICT's: ``eyeBlink_*`` moves the upper lid's skin up to 9.5 mm down over the eyeball
  (a ray along -Z through the eyeball's centre meets the eyeball at rest and the lid at weight 0.5); the
  template's rim loops (:attr:`rig.asset.RigAsset.eye_loops`, deeper in the lid) move by at most 4.8 mm.
- The shapes are ICT's mean-face deltas carried onto the template; added to another identity they move the
  same vertices by the same amounts (no adaptation to the identity's eye or mouth shape).
- The eyeballs never move (ICT's expressions barely move its eyeball centres); the gaze shapes
  ``eyeLook*`` move only the lids and the skin around the eye. Outside the face, :mod:`rig.ict.transfer`'s
  continuation moves the scalp and ears by at most 2.5 mm (``jawOpen``) and the eye pockets by at most
  3.9 mm; the jaw and mouth shapes move the neck (``jawOpen`` 29 mm) and, rigidly with the nearest skin,
  the teeth and tongue (up to 23 mm, ``jawOpen``).

Coordinates: millimetres, right-handed, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from pipeline.synthetic.population import SPLIT_SIZES, population_split
from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.errors import InputError, SetupError
from rig.expressions import EXPRESSION_NAMES, ExpressionModel
from rig.ict.modes import expression_shapes

__all__ = [
    "COMPANIONS",
    "EXPRESSION_BASIS",
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

EXPRESSION_BASIS = "ict"
"""The expression basis of every head: ICT's 53 expression shapes (:func:`rig.ict.modes.expression_shapes`)."""

EXPRESSIVE_FEATURE_NAMES: tuple[str, ...] = (
    "browDown_L",
    "browDown_R",
    "browInnerUp_L",
    "browInnerUp_R",
    "browOuterUp_L",
    "browOuterUp_R",
    "cheekPuff_L",
    "cheekPuff_R",
    "cheekSquint_L",
    "cheekSquint_R",
    "eyeBlink_L",
    "eyeBlink_R",
    "eyeLookDown_L",
    "eyeLookDown_R",
    "eyeLookIn_L",
    "eyeLookIn_R",
    "eyeLookOut_L",
    "eyeLookOut_R",
    "eyeLookUp_L",
    "eyeLookUp_R",
    "eyeSquint_L",
    "eyeSquint_R",
    "eyeWide_L",
    "eyeWide_R",
    "jawForward",
    "jawLeft",
    "jawOpen",
    "jawRight",
    "mouthClose",
    "mouthDimple_L",
    "mouthDimple_R",
    "mouthFrown_L",
    "mouthFrown_R",
    "mouthFunnel",
    "mouthLeft",
    "mouthLowerDown_L",
    "mouthLowerDown_R",
    "mouthPress_L",
    "mouthPress_R",
    "mouthPucker",
    "mouthRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthSmile_L",
    "mouthSmile_R",
    "mouthStretch_L",
    "mouthStretch_R",
    "mouthUpperUp_L",
    "mouthUpperUp_R",
    "noseSneer_L",
    "noseSneer_R",
)
"""ICT's 53 expression names (its spelling, its order: :attr:`rig.ict.data.IctModel.expression_names`): the
coefficient order."""

EXPRESSIVE_LIMITS: dict[str, tuple[float, float]] = {n: (0.0, 1.0) for n in EXPRESSIVE_FEATURE_NAMES}
"""Coefficient limits per feature: all ``[0, 1]``."""

COMPANIONS: dict[str, str] = {"mouthClose": "jawOpen"}
"""Correctives and the shape they correct: the sampler never draws ``mouthClose`` without as much
``jawOpen`` (module docstring, Sampling)."""

_SIDE_TWINS = {"jawLeft": "jawRight", "mouthLeft": "mouthRight"}


def _twin(name: str) -> str:
    if name.endswith("_L"):
        return name[:-2] + "_R"
    if name.endswith("_R"):
        return name[:-2] + "_L"
    for left, right in _SIDE_TWINS.items():
        if name == left:
            return right
        if name == right:
            return left
    return name


EXPRESSIVE_PAIRS: tuple[tuple[str, str], ...] = tuple(
    (n, _twin(n)) for n in EXPRESSIVE_FEATURE_NAMES if n.endswith("_L") or n in _SIDE_TWINS
)
"""The 22 ``(left, right)`` pairs (``X_L``/``X_R``, ``jawLeft``/``jawRight``, ``mouthLeft``/``mouthRight``;
``left`` = the subject's left, +X): mirror images of each other to within 0.6 mm, kept as captured (module
docstring, Mirror); the other 9 shapes are midline shapes."""


def _group(name: str) -> str:
    if name.startswith(("mouth", "jaw")):
        return "mouth"
    if name.startswith("nose"):
        return "nose"
    if name.startswith("cheek"):
        return "cheeks"
    side = name[-1]  # eye... and brow... end in _L / _R
    return ("eye_" if name.startswith("eye") else "brow_") + side


EXPRESSIVE_GROUPS: dict[str, str] = {n: _group(n) for n in EXPRESSIVE_FEATURE_NAMES}
"""Facial area of each shape: ``eye_L``, ``eye_R`` (blink, look, squint, wide), ``brow_L``, ``brow_R``,
``nose`` (sneer), ``cheeks`` (puff, squint), ``mouth`` (the mouth and jaw shapes): the sampler keeps the
drawn strengths of one area's active shapes summing to at most 1."""

SPAN_EXCLUDED_REGIONS: tuple[str, ...] = ("teeth", "tongue")
"""Regions :func:`span_residuals` leaves out: the mouth's rigid insides, which a scan or photo does not see
and which the two bases move differently (the rig's ``jawOpen`` carries them with the jaw, 31 mm; ICT's
data has no teeth or tongue, :mod:`rig.ict.transfer` moves them rigidly with the nearest skin, up to 23 mm).
Counted in, ``jawOpen`` would be 39 % outside the span instead of 36 %; the median over shapes stays
54 %."""

_INDEX = {n: i for i, n in enumerate(EXPRESSIVE_FEATURE_NAMES)}
_GROUP_INDEX = np.array(
    [sorted(set(EXPRESSIVE_GROUPS.values())).index(EXPRESSIVE_GROUPS[n]) for n in EXPRESSIVE_FEATURE_NAMES]
)
_COMPANION_INDEX = tuple((_INDEX[c], _INDEX[b]) for c, b in COMPANIONS.items())
_MIN_STRENGTH, _MAX_STRENGTH = 0.4, 1.0
_MAX_ACTIVE = 3


# ----------------------------------------------------------------------------------------------------
# The shapes
# ----------------------------------------------------------------------------------------------------


def expressive_units(asset: RigAsset | None = None) -> np.ndarray:
    """ICT's 53 expression shapes at weight 1 on the template's vertices: ``(53, V, 3)`` float64 mm,
    read-only, in :data:`EXPRESSIVE_FEATURE_NAMES` order; transferred once per asset
    (:func:`rig.ict.modes.expression_shapes`).

    Raises:
        rig.errors.SetupError: the ICT data is missing or its names are not :data:`EXPRESSIVE_FEATURE_NAMES`.
    """
    names, shapes = expression_shapes(load_asset() if asset is None else asset)
    if tuple(names) != EXPRESSIVE_FEATURE_NAMES:
        raise SetupError(
            f"ICT's expression shapes are {list(names)}; this code expects {list(EXPRESSIVE_FEATURE_NAMES)} "
            "(rig/assets/ict/ changed?)"
        )
    return shapes


def _check_coefficients(coefficients) -> tuple[np.ndarray, bool]:
    c = np.asarray(coefficients, dtype=float)
    single = c.ndim == 1
    c = c[None] if single else c
    n_feat = len(EXPRESSIVE_FEATURE_NAMES)
    if c.ndim != 2 or c.shape[1] != n_feat:
        raise InputError(
            f"expressive_offsets: coefficients must have shape (n, {n_feat}) or ({n_feat},), "
            f"got {np.shape(coefficients)}"
        )
    if not np.isfinite(c).all():
        raise InputError("expressive_offsets: coefficients must be finite")
    bad = (c < -1e-9) | (c > 1.0 + 1e-9)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise InputError(
            f"expressive_offsets: coefficient {EXPRESSIVE_FEATURE_NAMES[j]!r} = {c[i, j]} of head {i} "
            f"is outside its limits {EXPRESSIVE_LIMITS[EXPRESSIVE_FEATURE_NAMES[j]]}"
        )
    return c, single


def expressive_offsets(coefficients: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """Expression displacements on the template: ``einsum("nf,fvk->nvk", c, expressive_units(asset))``.

    Args:
        coefficients: ``(n, 53)`` or ``(53,)`` in :data:`EXPRESSIVE_FEATURE_NAMES` order, within ``[0, 1]``.
        asset: the template (default: :func:`rig.asset.load_asset`).

    Returns:
        ``(n, V, 3)`` or ``(V, 3)`` float64 offsets in mm (linear in the coefficients; 0 at 0).

    Raises:
        ValueError: wrong shape, non-finite values or coefficients outside ``[0, 1]``.

    Example:
        >>> c = np.zeros(len(EXPRESSIVE_FEATURE_NAMES)); c[EXPRESSIVE_FEATURE_NAMES.index("jawOpen")] = 0.5
        >>> expressive_offsets(c).shape
        (4874, 3)
    """
    c, single = _check_coefficients(coefficients)
    out = np.einsum("nf,fvk->nvk", c, expressive_units(asset))
    return out[0] if single else out


def expressive_peaks(asset: RigAsset | None = None) -> dict[str, float]:
    """Peak displacement (mm) of each shape alone at coefficient 1."""
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
        raise InputError(
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
    """:func:`span_residuals` of every shape at coefficient 1, by name (median 0.54, least ``jawLeft`` and
    ``jawRight`` 0.34, most ``eyeLookOut_*`` 0.96)."""
    res = span_residuals(expressive_units(asset), asset)
    return dict(zip(EXPRESSIVE_FEATURE_NAMES, (float(r) for r in res)))


# ----------------------------------------------------------------------------------------------------
# Sampling and splits
# ----------------------------------------------------------------------------------------------------


def sample_expression_coefficients(rng: np.random.Generator | int, n: int) -> np.ndarray:
    """Random sparse expressions (module docstring, Sampling).

    Per head: ``k = rng.integers(1, 4)`` distinct shapes ``rng.choice(53, k, replace=False)`` with strengths
    ``rng.uniform(0.4, 1, k)``; where one facial area's (:data:`EXPRESSIVE_GROUPS`) active strengths sum to
    more than 1 they are scaled to sum 1; then a drawn corrective (:data:`COMPANIONS`: ``mouthClose``) adds
    its strength to the shape it corrects (``jawOpen``, which stays <= 1: both are in the mouth's area);
    the other coefficients are 0.

    Args:
        rng: a ``np.random.Generator`` or an integer seed.
        n: number of heads, >= 0.

    Returns:
        ``(n, 53)`` float64 coefficients in ``[0, 1]``, ``c[jawOpen] >= c[mouthClose]``.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise InputError(f"sample_expression_coefficients: n must be a non-negative integer, got {n!r}")
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
        for corrective, base in _COMPANION_INDEX:
            c[i, base] = min(1.0, c[i, base] + c[i, corrective])  # <= 1 but for rounding
    return c


@dataclass(frozen=True)
class ExpressiveHeads:
    """Identity heads with expressions.

    Attributes:
        names: ``n`` head names (``heldout_000``, ... as in the identity split).
        identity_coefficients: ``(n, M)`` the identity split's coefficients (``Population.coefficients``).
        expression_coefficients: ``(n, 53)`` expression coefficients (:data:`EXPRESSIVE_FEATURE_NAMES`).
        neutral: ``(n, V, 3)`` float64 neutral identity heads, mm.
        vertices: ``(n, V, 3)`` float64 expressive heads, ``neutral + expressive_offsets(...)``, mm.
        seeds: ``(n,)`` int64 per-head expression seeds:
            ``sample_expression_coefficients(np.random.default_rng(seed), 1)`` gives the coefficients.
        feature_names: :data:`EXPRESSIVE_FEATURE_NAMES`.
        basis: :data:`EXPRESSION_BASIS`.
    """

    names: tuple[str, ...]
    identity_coefficients: np.ndarray
    expression_coefficients: np.ndarray
    neutral: np.ndarray
    vertices: np.ndarray
    seeds: np.ndarray
    feature_names: tuple[str, ...] = field(default=EXPRESSIVE_FEATURE_NAMES)
    basis: str = EXPRESSION_BASIS

    def __len__(self) -> int:
        return len(self.names)

    def span_residuals(self, asset: RigAsset | None = None) -> np.ndarray:
        """``(n,)``: :func:`span_residuals` of each head's expression (``vertices - neutral``)."""
        return span_residuals(self.vertices - self.neutral, asset)


def _check_split(name) -> str:
    if name not in SPLIT_SIZES:
        raise InputError(f"unknown split {name!r}; splits are {list(SPLIT_SIZES)}")
    return name


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
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
    a random sparse mix of ICT's expression shapes.

    Args:
        name: split name (``train``, ``val``, ``test``, ``heldout``, ``makehuman``).
        seed: base seed, >= 0.
        n: keep the first ``n`` heads (default: all), ``0 <= n <= split size``.
        asset: the template the shapes are transferred onto (default: :func:`rig.asset.load_asset`); the identity
            heads must share its vertices.

    Returns:
        :class:`ExpressiveHeads`; deterministic given ``(name, seed)``; head ``i`` does not depend on ``n``.
    """
    seeds = expressive_seeds(name, seed)
    if n is not None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 0 <= n <= len(seeds):
            raise InputError(f"expressive_split: n must be an integer in [0, {len(seeds)}], got {n!r}")
        seeds = seeds[: int(n)]
    asset = load_asset() if asset is None else asset
    population = population_split(name, seed, first=len(seeds))  # the same identities, only those needed
    k = len(seeds)
    neutral = np.asarray(population.vertices[:k], dtype=float)
    if neutral.shape[1:] != asset.vertices.shape:
        raise InputError(
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
