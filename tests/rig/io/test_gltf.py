"""Round trips of rig.io.gltf: skinned glTF through pygltflib."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import trimesh

from rig.io.gltf import export_skinned_gltf
from tests.rig.io.conftest import JOINT_NAMES, JOINT_POSITIONS, PARENTS
from tests.support.gltf_reader import read_skinned_gltf


def _hidden_files(directory: Path) -> list[str]:
    """Temporary files are hidden (``.name...``): none may be left behind."""
    return [p.name for p in directory.iterdir() if p.name.startswith(".")]


def _rotation(axis, angle):
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _affine(linear=None, translation=(0.0, 0.0, 0.0)):
    m = np.eye(4)
    m[:3, :3] = np.eye(3) if linear is None else linear
    m[:3, 3] = translation
    return m


def _pose(kind: str) -> np.ndarray:
    """(3, 4, 4) local pose transforms in mm: rigid + scale (TRS-decomposable) or sheared."""
    taus = np.stack(
        [
            _affine(_rotation([1, 0.2, 0], 0.3), (2.0, -1.0, 3.0)),
            _affine(_rotation([0, 1, 0.5], -0.5) @ np.diag([1.1, 0.9, 1.2]), (0.0, 4.0, -2.0)),
            _affine(_rotation([0.3, 0, 1], 0.8), (1.0, 1.0, 1.0)),
        ]
    )
    if kind == "sheared":
        shear = np.eye(3)
        shear[0, 1] = 0.4
        taus[1, :3, :3] = taus[1, :3, :3] @ shear
    return taus


# ----------------------------------------------------------------------------------------------
# glTF
# ----------------------------------------------------------------------------------------------


def _export_sphere_gltf(sphere, path, **kwargs):
    export_skinned_gltf(
        path,
        sphere["vertices"],
        sphere["faces"],
        joint_names=JOINT_NAMES,
        parents=PARENTS,
        joint_positions=JOINT_POSITIONS,
        weights=sphere["weights"],
        face_uvs=sphere["face_uvs"],
        vertex_colors=sphere["colors"],
        **kwargs,
    )


def _expected_posed(vertices, weights, taus):
    """LBS directly from our inputs, in mm: W_k = W_parent T(p_k - p_parent) tau_k, skin = W_k T(-p_k)."""
    world = []
    for k in range(len(PARENTS)):
        parent_pos = JOINT_POSITIONS[PARENTS[k]] if PARENTS[k] >= 0 else np.zeros(3)
        local = _affine(translation=JOINT_POSITIONS[k] - parent_pos) @ taus[k]
        world.append(local if PARENTS[k] < 0 else world[PARENTS[k]] @ local)
    skin = np.stack([w @ _affine(translation=-p) for w, p in zip(world, JOINT_POSITIONS)])
    homogeneous = np.column_stack([vertices, np.ones(len(vertices))])
    per_joint = np.einsum("kij,vj->vki", skin, homogeneous)[..., :3]
    return np.einsum("vk,vki->vi", weights, per_joint)


def _gltf_posed(path):
    """glTF-style skinning straight from the file with pygltflib, in metres, returned in mm."""
    gltf = pygltflib.GLTF2.load(str(path))
    if path.suffix == ".glb":
        blob = gltf.binary_blob()
    else:
        import base64

        blob = base64.b64decode(gltf.buffers[0].uri.split(",", 1)[1])

    def accessor(index):
        acc = gltf.accessors[index]
        view = gltf.bufferViews[acc.bufferView]
        dtype = {5126: "<f4", 5123: "<u2", 5125: "<u4"}[acc.componentType]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc.type]
        assert view.byteOffset % 4 == 0
        assert view.byteLength == acc.count * width * np.dtype(dtype).itemsize
        data = np.frombuffer(blob, dtype=dtype, count=acc.count * width, offset=view.byteOffset)
        return data.reshape(acc.count, width)

    def local(node):
        if node.matrix is not None:
            return np.asarray(node.matrix).reshape(4, 4).T
        m = np.eye(4)
        if node.rotation is not None:
            x, y, z, w = node.rotation
            m[:3, :3] = [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        if node.scale is not None:
            m[:3, :3] = m[:3, :3] @ np.diag(node.scale)
        if node.translation is not None:
            m[:3, 3] = node.translation
        return m

    parent_of = {c: i for i, n in enumerate(gltf.nodes) for c in n.children}

    def global_matrix(index):
        m = local(gltf.nodes[index])
        while index in parent_of:
            index = parent_of[index]
            m = local(gltf.nodes[index]) @ m
        return m

    mesh_node = next(n for n in gltf.nodes if n.mesh is not None)
    skin = gltf.skins[mesh_node.skin]
    ibm = accessor(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    joint_matrices = np.stack([global_matrix(j) @ b for j, b in zip(skin.joints, ibm)])
    attributes = gltf.meshes[mesh_node.mesh].primitives[0].attributes
    positions = accessor(attributes.POSITION).astype(np.float64)
    joints = accessor(attributes.JOINTS_0).astype(np.int64)
    weights = accessor(attributes.WEIGHTS_0).astype(np.float64)
    skin_matrices = np.einsum("vi,vijk->vjk", weights, joint_matrices[joints])
    homogeneous = np.column_stack([positions, np.ones(len(positions))])
    return np.einsum("vij,vj->vi", skin_matrices, homogeneous)[:, :3] * 1000.0, gltf


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_gltf_round_trip(sphere, tmp_path, suffix):
    v, f = sphere["vertices"], sphere["faces"]
    n = len(v)
    path = tmp_path / f"rig{suffix}"
    _export_sphere_gltf(sphere, path)
    assert _hidden_files(tmp_path) == []

    out = read_skinned_gltf(path)
    np.testing.assert_allclose(out["vertices"], v, rtol=0, atol=1e-4)
    np.testing.assert_array_equal(out["faces"], f)
    split = out["split_source"]
    assert len(split) > n and np.array_equal(split[:n], np.arange(n))
    assert out["joint_names"] == JOINT_NAMES
    np.testing.assert_array_equal(out["parents"], PARENTS)
    np.testing.assert_allclose(out["joint_positions"], JOINT_POSITIONS, rtol=0, atol=1e-4)

    dense = np.zeros_like(sphere["weights"])
    np.add.at(dense, (np.repeat(np.arange(n), 4), out["joints"].reshape(-1)), out["weights"].reshape(-1))
    np.testing.assert_allclose(dense, sphere["weights"], rtol=0, atol=1e-6)

    # UVs back in v-up convention, per face corner
    np.testing.assert_allclose(out["texcoords"][out["gltf_faces"]], sphere["face_uvs"], atol=1e-6)
    np.testing.assert_allclose(out["colors"][:n], sphere["colors"], atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(out["normals"], axis=1), 1.0, atol=1e-5)
    # normals point outwards on a sphere
    assert (np.sum(out["normals"][:n] * v, axis=1) > 0).all()

    _, gltf = _gltf_posed(path)
    assert gltf.asset.generator == "jnr"
    position = gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION]
    assert len(position.min) == 3 and len(position.max) == 3
    for view in gltf.bufferViews[:-1]:
        assert view.target in (pygltflib.ARRAY_BUFFER, pygltflib.ELEMENT_ARRAY_BUFFER)
    mesh_node = next(node for node in gltf.nodes if node.mesh is not None)
    assert mesh_node.extras["units"].startswith("metres")
    roots = [i for i, p in enumerate(PARENTS) if p < 0]
    assert set(gltf.scenes[gltf.scene].nodes) == {gltf.nodes.index(mesh_node), *roots}

    scene = trimesh.load(path, process=False)
    geometries = scene.geometry.values() if isinstance(scene, trimesh.Scene) else [scene]
    assert sum(len(g.vertices) for g in geometries) >= n


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_gltf_posed_skinning_matches_numpy(sphere, tmp_path, suffix):
    taus = _pose("rigid_scaled")
    path = tmp_path / f"posed{suffix}"
    _export_sphere_gltf(sphere, path, joint_transforms=taus)

    posed, gltf = _gltf_posed(path)
    expected = _expected_posed(sphere["vertices"], sphere["weights"], taus)
    out = read_skinned_gltf(path)
    assert np.abs(expected - sphere["vertices"]).max() > 10.0  # the pose really moves the mesh
    np.testing.assert_allclose(posed, expected[out["split_source"]], rtol=0, atol=1e-3)
    # the pose did not move the bind data
    np.testing.assert_allclose(out["joint_positions"], JOINT_POSITIONS, rtol=0, atol=1e-4)
    np.testing.assert_allclose(out["vertices"], sphere["vertices"], rtol=0, atol=1e-4)
    # joints stay posable: translation / rotation / scale, never a matrix
    assert all(node.matrix is None for node in gltf.nodes[:3])
    assert all(node.rotation is not None for node in gltf.nodes[:3])
    assert gltf.nodes[1].scale is not None and gltf.nodes[0].scale is None
    # node-local matrices read back in mm are T(p_k - p_parent) @ tau_k
    for k in range(3):
        parent = JOINT_POSITIONS[PARENTS[k]] if PARENTS[k] >= 0 else np.zeros(3)
        expected_local = _affine(translation=JOINT_POSITIONS[k] - parent) @ taus[k]
        np.testing.assert_allclose(out["local_matrices"][k], expected_local, atol=1e-9)


def test_gltf_float32_pose_is_accepted(sphere, tmp_path):
    taus = _pose("rigid_scaled").astype(np.float32)
    path = tmp_path / "posed32.glb"
    _export_sphere_gltf(sphere, path, joint_transforms=taus)
    posed, _ = _gltf_posed(path)
    expected = _expected_posed(sphere["vertices"], sphere["weights"], taus.astype(np.float64))
    out = read_skinned_gltf(path)
    np.testing.assert_allclose(posed, expected[out["split_source"]], rtol=0, atol=1e-3)


def test_gltf_sheared_pose_is_rejected(sphere, tmp_path):
    path = tmp_path / "sheared.glb"
    with pytest.raises(ValueError, match=r"joint_transforms\[1\] \(joint 'head'\) has a shear"):
        _export_sphere_gltf(sphere, path, joint_transforms=_pose("sheared"))
    assert list(tmp_path.iterdir()) == []


def test_gltf_bind_pose_uses_translations(sphere, tmp_path):
    path = tmp_path / "bind.gltf"
    _export_sphere_gltf(sphere, path)
    doc = json.loads(path.read_text())
    assert doc["buffers"][0]["uri"].startswith("data:application/octet-stream;base64,")
    for k, node in enumerate(doc["nodes"][:3]):
        parent = JOINT_POSITIONS[PARENTS[k]] if PARENTS[k] >= 0 else np.zeros(3)
        np.testing.assert_allclose(node["translation"], (JOINT_POSITIONS[k] - parent) * 1e-3)
        assert "matrix" not in node and "rotation" not in node
    assert doc["skins"][0]["joints"] == [0, 1, 2]
    assert doc["skins"][0]["skeleton"] == 0
    posed, _ = _gltf_posed(path)
    out = read_skinned_gltf(path)
    np.testing.assert_allclose(posed, sphere["vertices"][out["split_source"]], atol=1e-3)


def test_gltf_without_uvs_or_colors(sphere, tmp_path):
    path = tmp_path / "plain.glb"
    v, f = sphere["vertices"], sphere["faces"]
    export_skinned_gltf(
        path,
        v,
        f,
        joint_names=JOINT_NAMES,
        parents=PARENTS,
        joint_positions=JOINT_POSITIONS,
        weights=sphere["weights"],
    )
    out = read_skinned_gltf(path)
    assert len(out["split_source"]) == len(v)
    assert out["texcoords"] is None and out["colors"] is None
    np.testing.assert_array_equal(out["gltf_faces"], f)


def _png(image: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_gltf_base_color_texture_round_trip(sphere, tmp_path, suffix):
    """The PNG is stored as it is and is the material's baseColorTexture on TEXCOORD_0 = (u, 1 - v)."""
    image = np.zeros((8, 8, 3), np.uint8)
    image[:4] = (255, 0, 0)  # top half red: OBJ v > 0.5, glTF v < 0.5
    image[4:] = (0, 0, 255)
    png = _png(image)
    path = tmp_path / f"textured{suffix}"
    export_skinned_gltf(
        path,
        sphere["vertices"],
        sphere["faces"],
        joint_names=JOINT_NAMES,
        parents=PARENTS,
        joint_positions=JOINT_POSITIONS,
        weights=sphere["weights"],
        face_uvs=sphere["face_uvs"],
        base_color_texture=png,
    )
    out = read_skinned_gltf(path)
    assert out["base_color_texture"] == png and out["colors"] is None
    np.testing.assert_allclose(out["texcoords"][out["gltf_faces"]], sphere["face_uvs"], atol=1e-6)

    gltf = pygltflib.GLTF2.load(str(path))
    pbr = gltf.materials[gltf.meshes[0].primitives[0].material].pbrMetallicRoughness
    assert pbr.baseColorTexture.index == 0 and (pbr.baseColorTexture.texCoord or 0) == 0
    assert gltf.images[gltf.textures[0].source].mimeType == "image/png"
    raw_uv = _raw_accessor(gltf, path, gltf.meshes[0].primitives[0].attributes.TEXCOORD_0)
    np.testing.assert_allclose(raw_uv[:, 1], 1.0 - out["texcoords"][:, 1], atol=1e-6)  # glTF's v points down

    # a viewer's reading (trimesh): the same image, and a vertex high on the sphere (OBJ v near 1) is red
    scene = trimesh.load(path, process=False)
    mesh = next(iter(scene.geometry.values()))
    np.testing.assert_array_equal(np.asarray(mesh.visual.material.baseColorTexture.convert("RGB")), image)
    colours = mesh.visual.to_color().vertex_colors[:, :3]
    top, bottom = np.argmax(mesh.vertices[:, 1]), np.argmin(mesh.vertices[:, 1])
    assert tuple(colours[top]) == (255, 0, 0) and tuple(colours[bottom]) == (0, 0, 255)


def _raw_accessor(gltf, path, index):
    import base64

    blob = gltf.binary_blob() if path.suffix == ".glb" else base64.b64decode(gltf.buffers[0].uri.split(",", 1)[1])
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    return np.frombuffer(blob, "<f4", acc.count * 2, view.byteOffset).reshape(acc.count, 2)


def test_gltf_texture_is_checked(sphere, tmp_path):
    args = dict(joint_names=JOINT_NAMES, parents=PARENTS, joint_positions=JOINT_POSITIONS, weights=sphere["weights"])
    with pytest.raises(ValueError, match="bytes of a PNG"):
        export_skinned_gltf(
            tmp_path / "a.glb",
            sphere["vertices"],
            sphere["faces"],
            face_uvs=sphere["face_uvs"],
            base_color_texture=b"GIF89a",
            **args,
        )
    with pytest.raises(ValueError, match="needs face_uvs"):
        export_skinned_gltf(
            tmp_path / "a.glb",
            sphere["vertices"],
            sphere["faces"],
            base_color_texture=_png(np.zeros((2, 2, 3), np.uint8)),
            **args,
        )
    assert list(tmp_path.iterdir()) == []


def test_gltf_too_many_influences(sphere, tmp_path):
    v, f = sphere["vertices"], sphere["faces"]
    k = 6
    names = [f"j{i}" for i in range(k)]
    parents = np.arange(k) - 1
    positions = np.zeros((k, 3))
    path = tmp_path / "lossy.glb"
    uniform = np.full((len(v), k), 1.0 / k)
    with pytest.raises(ValueError, match="more than 4 influences"):
        export_skinned_gltf(path, v, f, joint_names=names, parents=parents, joint_positions=positions, weights=uniform)
    assert not path.exists()

    # a 5th influence below the tolerance is dropped and the rest renormalised
    almost = np.zeros((len(v), k))
    almost[:, :4] = (1.0 - 5e-4) / 4
    almost[:, 4] = 5e-4
    export_skinned_gltf(path, v, f, joint_names=names, parents=parents, joint_positions=positions, weights=almost)
    out = read_skinned_gltf(path)
    np.testing.assert_allclose(out["weights"], 0.25, atol=1e-6)
    assert set(np.unique(out["joints"])) == {0, 1, 2, 3}


# ----------------------------------------------------------------------------------------------
# errors and atomic writes
# ----------------------------------------------------------------------------------------------


def test_bad_format(sphere, tmp_path):
    with pytest.raises(ValueError, match="unsupported file format 'obj'"):
        _export_sphere_gltf(sphere, tmp_path / "a.obj")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"parents": np.array([-1, 0])}, r"parents must have shape \(K,\).*\(2,\)"),
        ({"parents": np.array([-1, 2, 1])}, r"parents must be -1 \(root\) or the index of an earlier"),
        ({"joint_positions": np.zeros((3, 2))}, r"joint_positions must have shape .*\(3, 2\)"),
        ({"weights": np.full((162, 4), 0.25)}, r"weights must have shape \(V, K\).*\(162, 4\)"),
        ({"weights": np.full((162, 3), 0.5)}, r"weights rows must sum to 1"),
        ({"joint_transforms": np.zeros((3, 3, 3))}, r"joint_transforms must have shape .*\(3, 3, 3\)"),
    ],
)
def test_bad_rig_shapes(sphere, tmp_path, kwargs, match):
    args = {
        "joint_names": JOINT_NAMES,
        "parents": PARENTS,
        "joint_positions": JOINT_POSITIONS,
        "weights": sphere["weights"],
    }
    args.update(kwargs)
    path = tmp_path / "bad.glb"
    with pytest.raises(ValueError, match=match):
        export_skinned_gltf(path, sphere["vertices"], sphere["faces"], **args)
    assert not path.exists()


def test_failed_write_leaves_nothing(sphere, tmp_path, monkeypatch):
    def broken_fsync(fd):
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError, match="disk full"):
        _export_sphere_gltf(sphere, tmp_path / "a.glb")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_gltf_morph_targets_round_trip_sparse(sphere, tmp_path, suffix):
    v = sphere["vertices"]
    rng = np.random.default_rng(3)
    targets = np.zeros((3, len(v), 3))
    targets[0, v[:, 0] > 0] = [1.0, 2.0, 3.0]  # half the vertices move
    targets[1, :5] = rng.normal(size=(5, 3))  # five move
    # target 2 moves nothing (glTF needs one stored element: an explicit zero)
    path = tmp_path / f"morph{suffix}"
    _export_sphere_gltf(sphere, path, morph_targets=targets, morph_names=["a", "b", "still"], morph_weights=[0.5, 0, 1])
    out = read_skinned_gltf(path)
    assert out["morph_names"] == ["a", "b", "still"]
    np.testing.assert_allclose(out["morph_targets"], targets, atol=1e-6)
    np.testing.assert_array_equal(out["morph_weights"], [0.5, 0.0, 1.0])
    gltf = pygltflib.GLTF2().load(str(path))
    primitive = gltf.meshes[0].primitives[0]
    accessors = [gltf.accessors[t["POSITION"] if isinstance(t, dict) else t.POSITION] for t in primitive.targets]
    assert [a.sparse.count for a in accessors] == [int((v[:, 0] > 0).sum()), 5, 1]  # only moved vertices stored
    assert all(a.min is not None and a.max is not None for a in accessors)  # POSITION needs min/max
    material = gltf.materials[primitive.material].pbrMetallicRoughness
    assert material.metallicFactor == 0.0  # not shown as metal (three.js's default is metallic)


def test_gltf_morph_targets_are_checked(sphere, tmp_path):
    v = sphere["vertices"]
    with pytest.raises(ValueError, match="morph_targets"):
        _export_sphere_gltf(
            sphere, tmp_path / "x.glb", morph_targets=np.zeros((2, len(v) + 1, 3)), morph_names=["a", "b"]
        )
    with pytest.raises(ValueError, match="unique names"):
        _export_sphere_gltf(sphere, tmp_path / "x.glb", morph_targets=np.zeros((2, len(v), 3)), morph_names=["a", "a"])
    with pytest.raises(ValueError, match="without morph_targets"):
        _export_sphere_gltf(sphere, tmp_path / "x.glb", morph_names=["a"])
    assert not (tmp_path / "x.glb").exists()


def _animated_local(channels, node_names, t_index, out):
    """Node-local matrices (mm) of the joints at keyframe ``t_index``: the file's static TRS overridden by
    the animation's channels, composed as glTF does (T @ R @ S)."""
    from scipy.spatial.transform import Rotation

    local = out["local_matrices"].copy()
    trs = {}
    for j, name in enumerate(node_names):
        m = local[j]
        scale = np.linalg.norm(m[:3, :3], axis=0)
        trs[name] = {
            "translation": m[:3, 3].copy(),
            "rotation": Rotation.from_matrix(m[:3, :3] / scale).as_quat(),
            "scale": scale,
        }
    for ch in channels:
        if ch["node"] in trs:
            trs[ch["node"]][ch["path"]] = ch["values"][t_index]
    result = []
    for name in node_names:
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat(trs[name]["rotation"]).as_matrix() * trs[name]["scale"][None, :]
        m[:3, 3] = trs[name]["translation"]
        result.append(m)
    return np.stack(result)


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_gltf_animation_and_attachment_round_trip(sphere, tmp_path, suffix):
    """Keyframed joint transforms and morph weights read back as channels whose keys pose the head and the
    attachment exactly as LBS with that keyframe's transforms; the attachment keeps its own weights,
    targets and colour and shares the skin."""
    from rig.io.gltf import GltfAnimation, GltfAttachment

    v = sphere["vertices"]
    targets = np.zeros((2, len(v), 3))
    targets[0, v[:, 1] > 0] = [0.0, 5.0, 0.0]
    targets[1, :7] = 1.0
    box = trimesh.creation.box(extents=(40.0, 20.0, 10.0))
    acc_v = np.asarray(box.vertices) + [0.0, 110.0, 0.0]
    acc_w = np.zeros((len(acc_v), 3))
    acc_w[:, 2] = 1.0  # rigid on "crown"
    acc_t = np.zeros((2, len(acc_v), 3))
    acc_t[0] = [0.0, 5.0, 0.0]
    rest = np.tile(np.eye(4), (3, 1, 1))
    third = np.stack(
        [_affine(_rotation([1, 1, 0], 0.4 * (k + 1)) @ np.diag([1.0, 1.1, 0.95]), (k, -2.0, 1.0)) for k in range(3)]
    )
    taus = np.stack([rest, _pose("rigid_scaled"), third])
    weights = np.array([[0.0, 0.0], [1.0, 0.25], [0.5, 1.0]])
    path = tmp_path / f"anim{suffix}"
    _export_sphere_gltf(
        sphere,
        path,
        morph_targets=targets,
        morph_names=["up", "few"],
        attachments=[GltfAttachment("hat", acc_v, np.asarray(box.faces), acc_w, acc_t, (0.1, 0.2, 0.3))],
        animation=GltfAnimation(np.array([0.0, 0.5, 1.0]), weights, taus, name="test"),
    )
    out = read_skinned_gltf(path)
    (hat,) = out["attachments"]
    assert hat["name"] == "hat"
    np.testing.assert_allclose(hat["vertices"], acc_v, atol=1e-4)
    np.testing.assert_array_equal(hat["faces"], box.faces)
    np.testing.assert_allclose(hat["morph_targets"], acc_t, atol=1e-6)
    np.testing.assert_allclose(hat["color"], [0.1, 0.2, 0.3, 1.0])
    assert np.all(hat["joints"][:, 0] == 2) and np.allclose(hat["weights"][:, 0], 1.0)

    (anim,) = out["animations"]
    assert anim["name"] == "test"
    weight_channels = [c for c in anim["channels"] if c["path"] == "weights"]
    assert sorted(c["node"] for c in weight_channels) == ["hat", "mesh"]
    for c in weight_channels:
        np.testing.assert_allclose(c["values"], weights, atol=1e-7)
        np.testing.assert_allclose(c["times"], [0.0, 0.5, 1.0])
    joint_channels = [c for c in anim["channels"] if c["path"] != "weights"]
    assert {c["path"] for c in joint_channels} == {"translation", "rotation", "scale"}
    assert all(c["interpolation"] == "LINEAR" and len(c["times"]) == 3 for c in anim["channels"])
    for t in range(3):
        local = _animated_local(joint_channels, JOINT_NAMES, t, out)
        for k in range(3):
            parent = JOINT_POSITIONS[PARENTS[k]] if PARENTS[k] >= 0 else np.zeros(3)
            np.testing.assert_allclose(
                local[k], _affine(translation=JOINT_POSITIONS[k] - parent) @ taus[t, k], atol=1e-4
            )


def test_gltf_animation_quaternions_take_the_short_way(sphere, tmp_path):
    """Rotations of 170 deg then -170 deg about one axis are 20 deg apart: consecutive keys are stored in one
    hemisphere so a viewer's linear interpolation turns 20 deg, not 340."""
    from rig.io.gltf import GltfAnimation

    taus = np.tile(np.eye(4), (2, 3, 1, 1))
    taus[0, 1, :3, :3] = _rotation([0, 1, 0], np.radians(170.0))
    taus[1, 1, :3, :3] = _rotation([0, 1, 0], np.radians(-170.0))
    path = tmp_path / "turn.glb"
    _export_sphere_gltf(sphere, path, animation=GltfAnimation(np.array([0.0, 1.0]), None, taus))
    (anim,) = read_skinned_gltf(path)["animations"]
    (rot,) = [c for c in anim["channels"] if c["path"] == "rotation"]
    assert rot["node"] == "head"
    assert float(np.dot(rot["values"][0], rot["values"][1])) > 0.98  # cos(10 deg)


def test_gltf_animation_is_checked(sphere, tmp_path):
    from rig.io.gltf import GltfAnimation

    with pytest.raises(ValueError, match="strictly increasing"):
        _export_sphere_gltf(
            sphere,
            tmp_path / "x.glb",
            animation=GltfAnimation(np.array([0.0, 0.0]), None, np.tile(np.eye(4), (2, 3, 1, 1))),
        )
    with pytest.raises(ValueError, match="morph_weights"):
        _export_sphere_gltf(sphere, tmp_path / "x.glb", animation=GltfAnimation(np.array([0.0]), np.zeros((1, 2))))
    with pytest.raises(ValueError, match="animates nothing"):
        _export_sphere_gltf(
            sphere,
            tmp_path / "x.glb",
            animation=GltfAnimation(np.array([0.0, 1.0]), None, np.tile(np.eye(4), (2, 3, 1, 1))),
        )
    assert not (tmp_path / "x.glb").exists()
