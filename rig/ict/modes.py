"""ICT's identity modes and expression shapes on the rig asset's vertices (:class:`rig.ict.transfer.Transfer`
built from the correspondence stored in the asset), computed once per asset.

Units: mm, the rig frame's orientation (deltas: no translation).
"""

from __future__ import annotations

import numpy as np

from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.ict.data import load_ict
from rig.ict.transfer import Transfer

__all__ = ["expression_shapes", "identity_modes", "transfer_of"]


@cached_per_asset
def transfer_of(asset: RigAsset) -> Transfer:
    """The transfer ICT -> ``asset``'s vertices (from the correspondence the asset stores)."""
    ict = load_ict()
    return Transfer(
        asset.faces,
        asset.regions,
        asset.vertices,
        tuple(asset.eye_loops),
        asset.ict_covered,
        asset.ict_triangle,
        asset.ict_barycentric,
        ict.triangles,
        len(ict.neutral),
    )


@cached_per_asset
def _identity(asset: RigAsset) -> np.ndarray:
    ict = load_ict()
    modes = transfer_of(asset).apply(ict.identity.astype(np.float64) @ asset.ict_rotation.T)
    modes.setflags(write=False)
    return modes


@cached_per_asset
def _expression(asset: RigAsset) -> np.ndarray:
    ict = load_ict()
    r = asset.ict_rotation
    shapes = transfer_of(asset).apply(ict.expression.astype(np.float64) @ r.T, ict.expression_eye_centres @ r.T)
    shapes.setflags(write=False)
    return shapes


def identity_modes(asset: RigAsset | None = None) -> np.ndarray:
    """``(100, V, 3)`` float64 read-only: ICT's identity modes on the asset's vertices, mm per unit
    coefficient (``c ~ N(0, 1)``)."""
    return _identity(load_asset() if asset is None else asset)


def expression_shapes(asset: RigAsset | None = None) -> tuple[tuple[str, ...], np.ndarray]:
    """ICT's 53 expression names and shapes ``(53, V, 3)`` float64 read-only on the asset's vertices, mm at
    weight 1 (eyeballs move with ICT's eyeball centres)."""
    return load_ict().expression_names, _expression(load_asset() if asset is None else asset)
