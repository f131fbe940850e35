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
    "MAKEHUMAN_SPLIT_SIZES",
    "SHIFTED_SPLITS",
    "SPLIT_SIZES",
    "Population",
    "check_split",
    "makehuman_split",
    "population_split",
    "similarity_normalised",
    "split_seeds",
]


SPLIT_SIZES: dict[str, int] = {"train": 85, "val": 2, "test": 7, "heldout": 100, "makehuman": 100}
"""The splits: ``train``, ``val``, ``test`` and the shifted ``heldout`` are ICT identities
(:mod:`pipeline.synthetic.population.ict`); ``makehuman`` is the out-of-distribution split, MakeHuman heads
drawn as the MakeHuman population's shifted held-out set (:func:`makehuman_split`)."""
SHIFTED_SPLITS: tuple[str, ...] = ("heldout", "makehuman")
"""Splits drawn from a shifted distribution (ICT: :data:`~pipeline.synthetic.population.ict.SHIFTED_MODE_SD`;
MakeHuman: the ``asym`` and ``head_shape`` features, module docstring of :mod:`pipeline.synthetic.population`)."""
MAKEHUMAN_SPLIT_SIZES: dict[str, int] = {"train": 85, "val": 2, "test": 7, "heldout": 100}
"""The MakeHuman population's own splits (:func:`makehuman_split`)."""


@dataclass(frozen=True)
class Population:
    """A split of synthetic identity heads.

    Attributes:
        split: split name (:data:`SPLIT_SIZES`).
        names: ``n`` head names (``train_000``, ...).
        coefficients: ``(n, M)`` float64: ICT identity coefficients (``M = 100``) or MakeHuman feature
            (slider) values.
        vertices: ``(n, V, 3)`` float64 vertices, mm, in the template's vertex order.
        feature_names: the ``M`` feature names, in coefficient order.
        seeds: ``(n,)`` int64 per-head seeds: ``ict_coefficients(seed, shifted)`` (ICT) or
            ``sample_head(seed, shifted)`` (MakeHuman) gives the head's coefficients (``shifted`` for the
            :data:`SHIFTED_SPLITS`).
        phenotypes: ``(n, P)`` float64 MakeHuman phenotypes, columns ``phenotype_names`` (``P = 0`` for ICT).
        phenotype_names: :data:`PHENOTYPE_NAMES` (empty for ICT).
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
        raise InputError(f"unknown split {name!r}; splits are {list(SPLIT_SIZES)}")
    return name


def split_seeds(name: str, seed: int = 0, stream: str = "ict") -> np.ndarray:
    """Per-head integer seeds of a split, ``(n,)`` int64, from ``SeedSequence([seed, crc32(name)])`` for the
    MakeHuman splits (``stream="makehuman"``, as before issue 25) and ``SeedSequence([seed, crc32("ict-" +
    name)])`` for the ICT splits (their own streams)."""
    seed = check_seed(seed)
    sizes = MAKEHUMAN_SPLIT_SIZES if stream == "makehuman" else SPLIT_SIZES
    if name not in sizes:
        raise InputError(f"unknown split {name!r}; splits are {list(sizes)}")
    key = name if stream == "makehuman" else f"ict-{name}"
    ss = np.random.SeedSequence([seed, zlib.crc32(key.encode("utf-8"))])
    return ss.generate_state(sizes[name], dtype=np.uint32).astype(np.int64)


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


def _first(seeds: np.ndarray, first) -> np.ndarray:
    if first is not None:
        if isinstance(first, bool) or not isinstance(first, (int, np.integer)) or first < 0:
            raise InputError(f"population_split: first must be an integer >= 0, got {first!r}")
        seeds = seeds[:first]
    return seeds


def population_split(name: str, seed: int = 0, asset: RigAsset | None = None, first: int | None = None) -> Population:
    """One split of synthetic heads (:data:`SPLIT_SIZES`): ``train`` (85), ``val`` (2), ``test`` (7) and
    ``heldout`` (100, shifted) are ICT identities (:mod:`pipeline.synthetic.population.ict`); ``makehuman``
    (100) is the out-of-distribution split of MakeHuman heads (:func:`makehuman_split` of its shifted
    ``heldout`` distribution).

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
    from pipeline.synthetic.population.ict import MODE_NAMES, ict_coefficients, ict_heads

    check_split(name)
    if name == "makehuman":
        seeds = _first(split_seeds(name, seed), first)
        return _makehuman(name, seeds, True, asset)
    seeds = _first(split_seeds(name, seed), first)
    shifted = name in SHIFTED_SPLITS
    asset = load_asset() if asset is None else asset
    coefficients = np.array([ict_coefficients(int(s), shifted, asset) for s in seeds]).reshape(
        len(seeds), len(MODE_NAMES)
    )
    return Population(
        split=name,
        names=tuple(f"{name}_{i:03d}" for i in range(len(seeds))),
        coefficients=coefficients,
        vertices=ict_heads(coefficients, asset).reshape(len(seeds), len(asset.vertices), 3),
        feature_names=MODE_NAMES,
        seeds=seeds,
        phenotypes=np.zeros((len(seeds), 0)),
        phenotype_names=(),
    )


def makehuman_split(name: str, seed: int = 0, asset: RigAsset | None = None, first: int | None = None) -> Population:
    """One split of the MakeHuman population (:data:`MAKEHUMAN_SPLIT_SIZES`; module docstring of
    :mod:`pipeline.synthetic.population`): MakeHuman's artist-made targets on MakeHuman's average head.
    Arguments as :func:`population_split`."""
    seeds = _first(split_seeds(name, seed, stream="makehuman"), first)
    return _makehuman(name, seeds, name in SHIFTED_SPLITS, asset)


def _makehuman(name: str, seeds: np.ndarray, shifted: bool, asset: RigAsset | None) -> Population:
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
