"""MakeHuman's shape targets: reading a ``.target`` file and its offsets on the head's vertices."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from rig.errors import SetupError
from rig.makehuman.base_mesh import MAKEHUMAN_TO_MM
from rig.makehuman.head import HeadMesh


def read_target(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A MakeHuman shape target (``.target`` or gzip ``.target.gz``: sparse lines ``vertex dx dy dz`` in
    decimetres, on the base mesh).

    Returns:
        ``(vertices (K,) int64, offsets (K, 3) float64 mm)``.
    """
    path = Path(path)
    raw = gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes()
    rows = [line.split() for line in raw.decode().splitlines() if line.strip() and not line.startswith("#")]
    if any(len(r) != 4 for r in rows):
        raise SetupError(f"{path}: not a MakeHuman target (lines 'vertex dx dy dz')")
    data = np.asarray(rows, np.float64).reshape(-1, 4)  # an empty target is the base shape itself
    return data[:, 0].astype(np.int64), data[:, 1:] * MAKEHUMAN_TO_MM


def target_on_head(path: str | Path, head: HeadMesh) -> np.ndarray:
    """``(V, 3)`` mm: a base-mesh target's offsets on the head's vertices (zero elsewhere)."""
    ids, offsets = read_target(path)
    dense = np.zeros((int(max(ids.max(initial=0) + 1, head.source.max() + 1)), 3))
    dense[ids] = offsets
    return dense[head.source]


__all__ = ["read_target", "target_on_head"]
