"""Sizes of the rig: what ``jnr rig info`` prints (and the demo's ``summary.json`` records)."""

from __future__ import annotations

from rig.asset import RigAsset, load_asset
from rig.expressions import EXPRESSION_NAMES
from rig.parameters import NUM_PARAMETERS, symmetric_groups


def rig_info(asset: RigAsset | None = None) -> dict:
    """The sizes of the rig built on ``asset`` (default: the committed one).

    Returns:
        ``{"vertices", "faces", "joints", "free_parameters"`` (joint channels),
        ``"free_parameters_symmetric"`` (with left/right tied), ``"skinning_floats"`` (free skinning
        weights), ``"skinning_nonzeros"``, ``"max_influences"`` (joints per vertex), ``"model_floats"``
        (template coordinates + joint positions + skinning floats), ``"expressions"`` (52),
        ``"expression_names"`` (the ARKit names, in coefficient order), ``"regions"`` (names), ``"units"``
        (``"mm"``), ``"asset_version"}``; ints except the lists and the strings, in this order.

    Example:
        >>> rig_info()["joints"]
        52
    """
    asset = asset or load_asset()
    skinning = len(asset.weight_free)
    return {
        "vertices": len(asset.vertices),
        "faces": len(asset.faces),
        "joints": len(asset.joint_names),
        "free_parameters": NUM_PARAMETERS,
        "free_parameters_symmetric": len(symmetric_groups()),
        "skinning_floats": int(skinning),
        "skinning_nonzeros": len(asset.weight_rows),
        "max_influences": int(max(1, (asset.weights > 0).sum(1).max())),
        "model_floats": int(asset.vertices.size + asset.joint_positions.size + skinning),
        "expressions": len(EXPRESSION_NAMES),
        "expression_names": list(EXPRESSION_NAMES),
        "regions": list(asset.region_names),
        "units": "mm",
        "asset_version": asset.version,
    }


__all__ = ["rig_info"]
