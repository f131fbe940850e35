"""Sizes of the rig: what ``jnr rig info`` prints (and the demo's ``summary.json`` records)."""

from __future__ import annotations

from rig.asset import RigAsset, load_asset
from rig.expressions import EXPRESSION_NAMES
from rig.parameters import NUM_PARAMETERS, symmetric_groups
from rig.skinning.asm import uv_domain

#: The ``K`` (Gaussians per bone) whose ASM sizes ``jnr rig info`` prints.
ASM_REPORTED_K = (2, 3, 5)


def rig_info(asset: RigAsset | None = None) -> dict:
    """The sizes of the rig built on ``asset`` (default: the committed one).

    Returns:
        ``{"vertices", "faces", "joints", "free_parameters"`` (joint channels),
        ``"free_parameters_symmetric"`` (with left/right tied), ``"skinning_floats"`` (free skinning
        weights), ``"skinning_nonzeros"``, ``"max_influences"`` (joints per vertex), ``"model_floats"``
        (template coordinates + joint positions + skinning floats), ``"expressions"`` (52),
        ``"expression_names"`` (the ARKit names, in coefficient order), ``"regions"`` (names), ``"units"``
        (``"mm"``), ``"asset_version"``, then the ASM skinning model (:mod:`rig.skinning.asm`):
        ``"asm_parameters_per_bone"`` (``{"K=2": 23, ...}``, ASM Table 1's ``11 + 6K``),
        ``"asm_parameters"`` (the same times the 52 bones) and ``"asm_gmm_vertices"`` (vertices weighted by
        the GMM; the others keep the painted weights)``}``; ints except the lists, dicts and strings, in
        this order.

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
        "asm_parameters_per_bone": {f"K={k}": 11 + 6 * k for k in ASM_REPORTED_K},
        "asm_parameters": {f"K={k}": len(asset.joint_names) * (11 + 6 * k) for k in ASM_REPORTED_K},
        "asm_gmm_vertices": len(uv_domain(asset).gmm_vertices),
    }


__all__ = ["rig_info"]
