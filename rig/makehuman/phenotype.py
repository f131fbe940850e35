"""Phenotypes: MakeHuman's macro sliders (:class:`Phenotype`) and the mix of macro targets they make
(:func:`macro_target_weights`, :func:`phenotype_offsets`)."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

from rig.errors import InputError, SetupError
from rig.makehuman.base_mesh import data_dir
from rig.makehuman.head import head_mesh
from rig.makehuman.targets import target_on_head

RACES = ("african", "asian", "caucasian")


@dataclass(frozen=True)
class Phenotype:
    """MakeHuman's macro sliders, each in [0, 1], in MakeHuman's own scales (``macrodetails/macro.json``):
    gender 0 female .. 1 male; age 0 = 1 year, 0.1875 = 11, 0.5 = 25, 1 = 90 years (linear between);
    muscle, weight, height, proportions 0.5 = average; race weights (normalised to sum 1).

    The default is the adult average of issue 13: gender 0.5, age 40 years, average build and height,
    equal race weights.
    """

    gender: float = 0.5
    age: float = 0.5 + 0.5 * (40.0 - 25.0) / (90.0 - 25.0)
    muscle: float = 0.5
    weight: float = 0.5
    height: float = 0.5
    proportions: float = 0.5
    african: float = 1.0 / 3.0
    asian: float = 1.0 / 3.0
    caucasian: float = 1.0 / 3.0

    def __post_init__(self) -> None:
        for name in ("gender", "age", "muscle", "weight", "height", "proportions", *RACES):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0.0 <= value <= 1.0):
                raise InputError(f"Phenotype: {name} must be within [0, 1], got {value}")
        if sum(getattr(self, r) for r in RACES) <= 0:
            raise InputError("Phenotype: the race weights must not all be 0")

    @staticmethod
    def age_value(years: float) -> float:
        """MakeHuman's age slider for an age in years (1-90)."""
        anchors_years, anchors_value = (1.0, 11.0, 25.0, 90.0), (0.0, 0.1875, 0.5, 1.0)
        return float(np.interp(years, anchors_years, anchors_value))

    def category_weights(self) -> dict[str, dict[str, float]]:
        """Per macro variable, the weight of each of its target categories (each set sums to 1, the
        neutral middle of height and proportions being the empty category ``""``)."""

        def two_sided(v: float, low: str, mid: str, high: str) -> dict[str, float]:
            if v < 0.5:
                return {low: 1.0 - v / 0.5, mid: v / 0.5, high: 0.0}
            return {low: 0.0, mid: 1.0 - (v - 0.5) / 0.5, high: (v - 0.5) / 0.5}

        a = self.age
        if a < 0.1875:
            age = {"baby": 1.0 - a / 0.1875, "child": a / 0.1875, "young": 0.0, "old": 0.0}
        elif a < 0.5:
            age = {"baby": 0.0, "child": 1.0 - (a - 0.1875) / 0.3125, "young": (a - 0.1875) / 0.3125, "old": 0.0}
        else:
            age = {"baby": 0.0, "child": 0.0, "young": 1.0 - (a - 0.5) / 0.5, "old": (a - 0.5) / 0.5}
        total = sum(getattr(self, r) for r in RACES)
        return {
            "gender": {"female": 1.0 - self.gender, "male": self.gender},
            "age": age,
            "muscle": two_sided(self.muscle, "minmuscle", "averagemuscle", "maxmuscle"),
            "weight": two_sided(self.weight, "minweight", "averageweight", "maxweight"),
            "height": two_sided(self.height, "minheight", "", "maxheight"),
            "proportions": two_sided(self.proportions, "uncommonproportions", "", "idealproportions"),
            "race": {r: getattr(self, r) / total for r in RACES},
        }


def macro_target_weights(phenotype: Phenotype) -> dict[str, float]:
    """The macro targets (paths under ``targets/macrodetails/``) and their weights for ``phenotype``:
    products of category weights over MakeHuman's combinations (``universal-gender-age-muscle-weight``,
    ``race-gender-age``, ``height/gender-age-muscle-weight-height``,
    ``proportions/gender-age-muscle-weight-proportions``); zero weights and neutral categories left out."""
    w = phenotype.category_weights()
    out: dict[str, float] = {}

    def add(path: str, *parts: float) -> None:
        value = float(np.prod(parts))
        if value > 0:
            out[path] = out.get(path, 0.0) + value

    build = list(product(w["gender"].items(), w["age"].items(), w["muscle"].items(), w["weight"].items()))
    for (g, wg), (a, wa), (m, wm), (b, wb) in build:
        add(f"universal-{g}-{a}-{m}-{b}.target.gz", wg, wa, wm, wb)
        for h, wh in w["height"].items():
            if h:
                add(f"height/{g}-{a}-{m}-{b}-{h}.target.gz", wg, wa, wm, wb, wh)
        for p, wp in w["proportions"].items():
            if p and a not in ("baby",):
                add(f"proportions/{g}-{a}-{m}-{b}-{p}.target.gz", wg, wa, wm, wb, wp)
    for (r, wr), (g, wg), (a, wa) in product(w["race"].items(), w["gender"].items(), w["age"].items()):
        add(f"{r}-{g}-{a}.target.gz", wr, wg, wa)
    return out


def phenotype_offsets(phenotype: Phenotype | None = None) -> np.ndarray:
    """``(V, 3)`` float64 mm: the macro targets of ``phenotype`` (default: the adult average) summed on the
    head's vertices (:func:`head_mesh`); the phenotype's head is ``head_mesh().vertices + this``."""
    head = head_mesh()
    folder = data_dir() / "mpfb2" / "targets" / "macrodetails"
    total = np.zeros_like(head.vertices)
    for path, weight in macro_target_weights(phenotype or Phenotype()).items():
        if not (folder / path).is_file():
            raise SetupError(f"{folder / path}: a MakeHuman macro target is missing")
        total += weight * target_on_head(folder / path, head)
    return total


__all__ = ["RACES", "Phenotype", "macro_target_weights", "phenotype_offsets"]
