"""The skinned glTF of a head: the one writer of ``mesh.glb`` and every other skinned file jnr makes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pipeline.head.curves import HEAD_JOINT
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES, ExpressionModel, morph_targets
from rig.io.gltf import export_skinned_gltf
from rig.joints import JOINT_INDEX


def write_skinned_head(
    path: str | Path,
    asset,
    weights: np.ndarray,
    tau: np.ndarray,
    coefficients: np.ndarray | None = None,
    vertex_colors: np.ndarray | None = None,
    base_color_texture: bytes | None = None,
    attachments=(),
    animation=None,
    bind: str = "posed",
    expression: str = "baked",
) -> None:
    """The skinned glTF of a head: the posed head as the bind mesh (``bind``), the 52 ARKit shapes as morph
    targets named by ARKit (:func:`rig.expressions.morph_targets`) with ``coefficients (E,)`` as their weights
    (zeros when None), ``weights (V, J)``, the joint channel transforms ``tau (J, 4, 4)`` as the joints' pose,
    ``vertex_colors (V, 3)`` linear RGB in [0, 1] (glTF's ``COLOR_0`` is linear) and ``base_color_texture``
    the bytes of a PNG in the asset's UVs as the material's base colour (glTF multiplies it with
    ``COLOR_0``, so a textured head takes no vertex colours: ValueError); ``attachments``
    (:class:`rig.io.gltf.GltfAttachment`: accessories skinned to the same joints, their morph targets under the
    52 ARKit names) and ``animation`` (:class:`rig.io.gltf.GltfAnimation`) as
    :func:`rig.io.gltf.export_skinned_gltf`.

    ``bind="posed"`` (the default): the file's bind mesh is the head as ``tau`` and ``coefficients`` pose it
    (the fitted or edited head, its expression baked in; the morph weights then 0 and the coefficients in
    ``extras.bakedMorphWeights``; with an ``animation`` only the joints' pose is baked), so that readers that
    do not skin (trimesh, Open3D, MeshLab) load the same head as skinning viewers show; ``"rest"``: the
    template as the bind mesh (the file jnr wrote before issue 27). ``expression="keys"`` (with ``bind="posed"``):
    the posed head without its expression as the bind mesh and ``coefficients`` as the morph targets' default
    weights, so that animation tools (Blender's shape keys, Unity's blend shapes, three.js's influences) show the
    expression at the fitted values and typing ``params.json``'s values gives the same head (issue 38: with the
    expression baked they read 0, and typing the values doubled it); readers that do not apply morph weights then
    see the neutral face."""
    if expression not in ("baked", "keys"):
        raise InputError(f"write_skinned_head: expression must be 'baked' or 'keys', got {expression!r}")
    if base_color_texture is not None and vertex_colors is not None:
        raise InputError("write_skinned_head: a textured head takes no vertex colours (glTF would multiply them)")
    rest = asset.vertices
    bake = expression == "baked"
    if bake and bind == "posed" and animation is None and coefficients is not None and np.any(coefficients):
        # the expression baked into the bind mesh exactly (jawOpen turns the jaw; the morph targets are its chord)
        with torch.no_grad():
            c = torch.as_tensor(np.asarray(coefficients, np.float64))[None]
            rest = ExpressionModel(asset, dtype=torch.float64).vertices(c)[0].numpy()
    export_skinned_gltf(
        path,
        rest,
        asset.faces,
        joint_names=list(asset.joint_names),
        parents=asset.parents,
        joint_positions=asset.joint_positions,
        weights=weights,
        face_uvs=asset.face_uvs,
        vertex_colors=vertex_colors,
        joint_transforms=tau,
        morph_targets=morph_targets(asset),
        morph_names=EXPRESSION_NAMES,
        morph_weights=coefficients,
        base_color_texture=base_color_texture,
        attachments=attachments,
        animation=animation,
        bind=bind,
        bake_morphs=bake,
    )


def write_static_head(
    path: str | Path,
    asset,
    vertices: np.ndarray,
    base_color_texture: bytes | None = None,
    *,
    coefficients: np.ndarray | None = None,
    animation=None,
) -> None:
    """The glTF of a head that the joints do not pose (a head model that is not posable,
    :attr:`rig.head_model.HeadModel.posable`): ``vertices (V, 3)`` (rig space, mm; written in metres) with the
    asset's faces and UVs, ``base_color_texture`` (PNG bytes in the asset's UVs) as its base colour, skinned to
    one joint ``head`` at the rig's :data:`~pipeline.head.curves.HEAD_JOINT` with weight 1 (a mesh every glTF reader
    loads as it is, turned as a whole by an ``animation``). With ``coefficients (E,)`` or an ``animation``
    (:class:`rig.io.gltf.GltfAnimation`: the morph weights and the joint's transforms ``(T, 1, 4, 4)``), the 52
    ARKit shapes as morph targets (their offsets on the template, added to the head; ``coefficients`` their
    default weights)."""
    n = len(asset.vertices)
    morphs = coefficients is not None or animation is not None
    export_skinned_gltf(
        path,
        np.asarray(vertices, np.float64),
        asset.faces,
        joint_names=["head"],
        parents=np.array([-1]),
        joint_positions=np.asarray(asset.joint_positions, np.float64)[JOINT_INDEX[HEAD_JOINT]][None],
        weights=np.ones((n, 1)),
        face_uvs=asset.face_uvs,
        base_color_texture=base_color_texture,
        morph_targets=morph_targets(asset) if morphs else None,
        morph_names=EXPRESSION_NAMES if morphs else None,
        morph_weights=coefficients,
        animation=animation,
        bake_morphs=False,
    )
