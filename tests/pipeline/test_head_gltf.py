"""The head's skinned glTF: 52 joints, the 52 ARKit shapes as named morph targets, and the file reproduces
jnr's posed, expressive head (morph targets, then skinning, as glTF viewers do)."""

import numpy as np
import torch

from pipeline.head.skinned import write_skinned_head
from rig.expressions import (
    EXPRESSION_NAMES,
    JAW_INDEX,
    ExpressionModel,
    coefficients_from_dict,
    jaw_chord_error_mm,
)
from rig.model import JointRig
from rig.parameters import params_to_theta
from tests.support.gltf_reader import read_skinned_gltf


def _skin(out, joint_world):
    """Linear blend skinning of the file's bind mesh + weighted morph targets, numpy, mm."""
    rest = out["vertices"] + np.einsum("m,mvk->vk", out["morph_weights"], out["morph_targets"])
    skin = joint_world @ out["inverse_bind_matrices"]  # (K, 4, 4)
    m = np.einsum("vi,vijk->vjk", out["weights"], skin[out["joints"]])
    return np.einsum("vij,vj->vi", m, np.column_stack([rest, np.ones(len(rest))]))[:, :3]


def _world(out):
    world = np.zeros_like(out["local_matrices"])
    for k, p in enumerate(out["parents"]):
        world[k] = out["local_matrices"][k] if p < 0 else world[p] @ out["local_matrices"][k]
    return world


def test_head_gltf_has_52_joints_and_arkit_morph_targets_and_poses_like_jnr(asset, tmp_path):
    rig = JointRig(asset, dtype=torch.float64)
    theta = params_to_theta(
        {"nose_tip.translate_y": 4.0, "left_cheek.scale": 1.3, "jaw_front.scale": 1.2}, dtype=torch.float64
    )
    c = coefficients_from_dict({"mouthSmileLeft": 0.8, "eyeBlinkRight": 1.0, "jawOpen": 1.0}, dtype=torch.float64)
    with torch.no_grad():
        tau = rig.channel_transforms(theta[None])[0].numpy()
        expected = (
            rig(theta[None], vertices=ExpressionModel(asset, torch.float64).vertices(c[None])).vertices[0].numpy()
        )
    path = tmp_path / "head.glb"
    write_skinned_head(path, asset, asset.weights, tau, c.numpy())
    out = read_skinned_gltf(path)
    assert len(out["joint_names"]) == 52 and out["joint_names"] == list(asset.joint_names)
    assert out["morph_names"] == list(EXPRESSION_NAMES) and len(out["morph_names"]) == 52
    # the posed, expressive head is the bind mesh (the expression baked in, the weights 0 and recorded)
    np.testing.assert_allclose(out["morph_weights"], 0.0)
    np.testing.assert_allclose(out["extras"]["bakedMorphWeights"], c.numpy())
    assert out["extras"]["bind"] == "posed"
    np.testing.assert_allclose(_skin(out, _world(out)), expected, atol=1e-3)  # jawOpen at 1: exact
    np.testing.assert_allclose(out["vertices"], expected, atol=1e-3)  # what a reader that does not skin sees
    # a morph weight still moves the head as jnr's expression does, on top of the baked one
    smile = EXPRESSION_NAMES.index("mouthSmileRight")
    more = c.clone()
    more[smile] = 0.7
    with torch.no_grad():
        moved = (
            rig(theta[None], vertices=ExpressionModel(asset, torch.float64).vertices(more[None])).vertices[0].numpy()
        )
    out["morph_weights"] = np.zeros(len(EXPRESSION_NAMES))
    out["morph_weights"][smile] = 0.7
    np.testing.assert_allclose(_skin(out, _world(out)), moved, atol=1e-3)


def test_rest_bind_keeps_the_template(asset, tmp_path):
    """``bind="rest"``: the template is the bind mesh and the default weights are the coefficients."""
    tau = np.tile(np.eye(4), (len(asset.joint_names), 1, 1))
    tau[5, :3, 3] = (1.0, 2.0, 3.0)
    c = np.zeros(len(EXPRESSION_NAMES))
    c[3] = 0.5
    write_skinned_head(tmp_path / "rest.glb", asset, asset.weights, tau, c, bind="rest")
    out = read_skinned_gltf(tmp_path / "rest.glb")
    np.testing.assert_allclose(out["vertices"], asset.vertices, atol=1e-4)
    np.testing.assert_allclose(out["morph_weights"], c)


def test_trimesh_loads_the_posed_head(asset, tmp_path):
    """A reader that does not skin (trimesh) gets the posed head, not the template."""
    import trimesh

    rig = JointRig(asset, dtype=torch.float64)
    theta = params_to_theta({"nose_tip.translate_z": 5.0, "chin.scale": 1.2}, dtype=torch.float64)
    with torch.no_grad():
        tau = rig.channel_transforms(theta[None])[0].numpy()
        expected = rig(theta[None]).vertices[0].numpy()
    write_skinned_head(tmp_path / "head.glb", asset, asset.weights, tau)
    scene = trimesh.load(tmp_path / "head.glb", process=False)
    mesh = scene.to_geometry() if isinstance(scene, trimesh.Scene) else scene
    loaded = np.asarray(mesh.vertices) * 1000.0  # metres -> mm
    # the UV seams split vertices: compare each loaded vertex with its nearest expected one
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(expected).query(loaded)
    assert distance.max() < 0.1, distance.max()
    assert cKDTree(loaded).query(expected)[0].max() < 0.1
    assert cKDTree(asset.vertices).query(loaded)[0].max() > 1.0  # not the template


def test_jaw_chord_error_is_small():
    """glTF morph targets are linear: jawOpen between 0 and 1 is the chord of jnr's rotation."""
    assert 0.0 < jaw_chord_error_mm(coefficient=0.5) < 3.0
    assert jaw_chord_error_mm(coefficient=1.0) < 1e-9 and JAW_INDEX == EXPRESSION_NAMES.index("jawOpen")


def test_keys_layout_puts_the_expression_on_the_shape_keys(asset, tmp_path):
    """Issue 38: in mesh.glb the expression is baked into the mesh, so Blender showed every shape key at 0 and
    typing params.json's values doubled the expression. ``expression="keys"``: the posed neutral head is the
    bind mesh, the coefficients are the default weights, and skinning bind + weights gives jnr's head."""
    rig = JointRig(asset, dtype=torch.float64)
    theta = params_to_theta({"nose_tip.translate_y": 4.0, "left_cheek.scale": 1.3}, dtype=torch.float64)
    c = coefficients_from_dict({"mouthSmileLeft": 0.8, "eyeBlinkRight": 1.0, "browInnerUp": 0.4}, dtype=torch.float64)
    with torch.no_grad():
        tau = rig.channel_transforms(theta[None])[0].numpy()
        expected = (
            rig(theta[None], vertices=ExpressionModel(asset, torch.float64).vertices(c[None])).vertices[0].numpy()
        )
        neutral = rig(theta[None]).vertices[0].numpy()
    write_skinned_head(tmp_path / "keys.glb", asset, asset.weights, tau, c.numpy(), expression="keys")
    out = read_skinned_gltf(tmp_path / "keys.glb")
    np.testing.assert_allclose(out["morph_weights"], c.numpy(), atol=1e-6)  # the keys at the fitted values
    assert "bakedMorphWeights" not in (out["extras"] or {})
    np.testing.assert_allclose(out["vertices"], neutral, atol=1e-3)  # the bind mesh: the identity, no expression
    np.testing.assert_allclose(_skin(out, _world(out)), expected, atol=1e-3)  # as a skinning viewer shows it
