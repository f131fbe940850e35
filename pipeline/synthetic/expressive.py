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

The names, the shapes and the span measure are in :mod:`pipeline.synthetic.expressive_shapes` (re-exported
here); this module samples the expressions and makes the expressive splits.

Coordinates: millimetres, right-handed, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from pipeline.synthetic.expressive_shapes import (
    COMPANIONS,
    EXPRESSION_BASIS,
    EXPRESSIVE_FEATURE_NAMES,
    EXPRESSIVE_GROUPS,
    EXPRESSIVE_LIMITS,
    EXPRESSIVE_PAIRS,
    SPAN_EXCLUDED_REGIONS,
    expressive_offsets,
    expressive_peaks,
    expressive_units,
    span_residuals,
    unit_span_residuals,
)
from pipeline.synthetic.population import SPLIT_SIZES, population_split
from rig.asset import RigAsset, load_asset
from rig.errors import InputError

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

_INDEX = {n: i for i, n in enumerate(EXPRESSIVE_FEATURE_NAMES)}
_GROUP_INDEX = np.array(
    [sorted(set(EXPRESSIVE_GROUPS.values())).index(EXPRESSIVE_GROUPS[n]) for n in EXPRESSIVE_FEATURE_NAMES]
)
_COMPANION_INDEX = tuple((_INDEX[c], _INDEX[b]) for c, b in COMPANIONS.items())
_MIN_STRENGTH, _MAX_STRENGTH = 0.4, 1.0
_MAX_ACTIVE = 3


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
