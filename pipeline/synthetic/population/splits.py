"""The JNR splits of synthetic heads (:func:`population_split`: train, val, test and the shifted held-out
set), each head from its own seed, and the similarity normalisation the known-correspondence fits take
(:func:`similarity_normalised`). See :mod:`pipeline.synthetic.population`.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from pipeline.synthetic.population.features import _feature_names
from pipeline.synthetic.population.heads import _draw_head, check_seed
from pipeline.synthetic.population.phenotypes import PHENOTYPE_NAMES
from rig.asset import RigAsset, load_asset
from rig.errors import InputError
from rig.geometry import Similarity

__all__ = [
    "SHIFTED_SPLITS",
    "SPLIT_SIZES",
    "Population",
    "check_split",
    "population_split",
    "similarity_normalised",
    "split_seeds",
]


SPLIT_SIZES: dict[str, int] = {"train": 85, "val": 2, "test": 7, "heldout": 100}
SHIFTED_SPLITS: tuple[str, ...] = ("heldout",)
"""Splits whose heads also use the ``asym`` and ``head_shape`` features (module docstring)."""


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
    vertices = np.asarray(vertices, np.float64)
    template = np.asarray(template, np.float64)
    return np.stack([Similarity.fit(v, template, with_scale=True).apply(v) for v in vertices])


def population_split(name: str, seed: int = 0, asset: RigAsset | None = None, first: int | None = None) -> Population:
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
    return Population(
        split=name,
        names=tuple(f"{name}_{i:03d}" for i in range(len(seeds))),
        coefficients=coefficients,
        vertices=vertices,
        feature_names=_feature_names(),
        seeds=seeds,
        phenotypes=phenotypes,
    )
