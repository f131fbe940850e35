"""The phenotype part of a synthetic head: MakeHuman's macro targets at a phenotype, relative to the
template's adult average (:func:`phenotype_displacements`), and the phenotypes a population draws
(:func:`sample_phenotypes`). See :mod:`pipeline.synthetic.population`; millimetres.
"""

from __future__ import annotations

from functools import cache
from itertools import product

import numpy as np

from pipeline.synthetic.population.features import _check_rows, _check_template, _mirror, _target
from rig.asset import RigAsset, load_asset
from rig.errors import InputError
from rig.makehuman.head import head_mesh
from rig.makehuman.phenotype import RACES, Phenotype, macro_target_weights

__all__ = [
    "AGE_YEARS",
    "BUILD_RANGE",
    "BUILD_SD",
    "HEIGHT_RANGE",
    "HEIGHT_SD",
    "PHENOTYPE_NAMES",
    "default_phenotype",
    "phenotype_displacements",
    "phenotype_of",
    "sample_phenotypes",
]


PHENOTYPE_NAMES: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions", *RACES)
"""The phenotype columns (:attr:`Population.phenotypes`), :class:`rig.makehuman.phenotype.Phenotype`'s fields."""
AGE_YEARS = (18.0, 80.0)
"""Ages are uniform in this range (years)."""
BUILD_SD, BUILD_RANGE = 0.1, (0.3, 0.7)
"""Muscle and weight: ``N(0.5, BUILD_SD)`` clipped to ``BUILD_RANGE``."""
HEIGHT_SD, HEIGHT_RANGE = 0.1, (0.25, 0.75)
"""Height: ``N(0.5, HEIGHT_SD)`` clipped to ``HEIGHT_RANGE``."""


def _check_count(n) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise InputError(f"n must be a non-negative integer, got {n!r}")
    return int(n)


def _generator(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, bool) or not isinstance(rng, (int, np.integer)):
        raise InputError(f"rng must be a numpy Generator or an integer seed, got {type(rng).__name__}")
    return np.random.default_rng(int(rng))


def _check_phenotypes(phenotypes) -> np.ndarray:
    return _check_rows(phenotypes, len(PHENOTYPE_NAMES), "phenotypes", f"columns {PHENOTYPE_NAMES}")


def phenotype_of(row) -> Phenotype:
    """A :class:`rig.makehuman.phenotype.Phenotype` from a ``(P,)`` row in :data:`PHENOTYPE_NAMES` order."""
    return Phenotype(**{n: float(v) for n, v in zip(PHENOTYPE_NAMES, np.asarray(row, float))})


def default_phenotype() -> np.ndarray:
    """``(P,)``: the template's adult average (:class:`rig.makehuman.phenotype.Phenotype`'s defaults)."""
    p = Phenotype()
    return np.array([getattr(p, n) for n in PHENOTYPE_NAMES])


def _macro(path: str) -> np.ndarray:
    return _target(f"macrodetails/{path}")


@cache
def _preload_macro() -> int:
    """Parse every macro target a phenotype of :func:`sample_phenotypes` can reach (once per process; any
    other is parsed when first needed). Returns their number."""
    paths: set[str] = set()
    for age, muscle, weight, height in product(
        (Phenotype.age_value(AGE_YEARS[0]), 0.75), (0.4, 0.6), (0.4, 0.6), (0.4, 0.6)
    ):
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


def _clipped_normal(
    rng: np.random.Generator, mean: float, sd: float, bounds: tuple[float, float], n: int
) -> np.ndarray:
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
