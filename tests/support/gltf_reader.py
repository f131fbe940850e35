"""Reading a skinned glTF 2.0 file back into numpy arrays, for the tests: :func:`read_skinned_gltf` undoes
what :func:`rig.io.gltf.export_skinned_gltf` does (metres back to millimetres, the UV-seam split back to
the source vertices, column-major matrices back to numpy's). jnr itself never reads glTF.
"""

from __future__ import annotations

import base64
import os
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib

from rig.io.gltf.encoding import COMPONENT_DTYPES, EXTRAS_SOURCE_COUNT, EXTRAS_SPLIT_SOURCE, MM_TO_M, compose_trs

__all__ = ["read_skinned_gltf"]

TYPE_SHAPES = {
    "SCALAR": (),
    "VEC2": (2,),
    "VEC3": (3,),
    "VEC4": (4,),
    "MAT2": (2, 2),
    "MAT3": (3, 3),
    "MAT4": (4, 4),
}
"""Shape of one element of each glTF accessor type."""


def _buffer_bytes(gltf: pygltflib.GLTF2, index: int, directory: Path, cache: dict) -> bytes:
    if index in cache:
        return cache[index]
    buffer = gltf.buffers[index]
    if buffer.uri is None:
        data = gltf.binary_blob()
        if data is None:
            raise ValueError(f"read_skinned_gltf: buffer {index} has no uri and the file no BIN chunk")
    elif buffer.uri.startswith("data:"):
        data = base64.b64decode(buffer.uri.split(",", 1)[1])
    else:
        data = (directory / buffer.uri).read_bytes()
    cache[index] = bytes(data)
    return cache[index]


def _view_array(
    gltf: pygltflib.GLTF2,
    view_index: int,
    offset: int | None,
    count: int,
    dtype: np.dtype,
    n_components: int,
    directory: Path,
    cache: dict,
) -> np.ndarray:
    """``count`` tightly packed elements of ``n_components`` from a buffer view (sparse indices / values)."""
    view = gltf.bufferViews[view_index]
    data = _buffer_bytes(gltf, view.buffer, directory, cache)
    start = (view.byteOffset or 0) + (offset or 0)
    return np.frombuffer(data, dtype=dtype, count=count * n_components, offset=start).reshape(count, n_components)


def _read_accessor(gltf: pygltflib.GLTF2, index: int, directory: Path, cache: dict) -> np.ndarray:
    accessor = gltf.accessors[index]
    dtype = COMPONENT_DTYPES[accessor.componentType]
    shape = TYPE_SHAPES[accessor.type]
    n_components = int(np.prod(shape)) if shape else 1
    if accessor.bufferView is None:
        out = np.zeros((accessor.count, *shape), dtype=dtype)
    else:
        view = gltf.bufferViews[accessor.bufferView]
        data = _buffer_bytes(gltf, view.buffer, directory, cache)
        start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
        element_size = dtype.itemsize * n_components
        stride = view.byteStride or element_size
        if stride == element_size:
            flat = np.frombuffer(data, dtype=dtype, count=accessor.count * n_components, offset=start)
            out = flat.reshape(accessor.count, *shape).copy()
        else:
            rows = [
                np.frombuffer(data, dtype=dtype, count=n_components, offset=start + i * stride)
                for i in range(accessor.count)
            ]
            out = np.asarray(rows).reshape(accessor.count, *shape)
    if accessor.sparse is not None:
        out = out.copy()
        sparse = accessor.sparse
        ids = _view_array(
            gltf,
            sparse.indices.bufferView,
            sparse.indices.byteOffset,
            sparse.count,  # (n, 1)
            COMPONENT_DTYPES[sparse.indices.componentType],
            1,
            directory,
            cache,
        )[:, 0].astype(np.int64)
        values = _view_array(
            gltf,
            sparse.values.bufferView,
            sparse.values.byteOffset,
            sparse.count,
            dtype,
            n_components,
            directory,
            cache,
        )
        out.reshape(accessor.count, -1)[ids] = values.reshape(sparse.count, -1)
    if accessor.normalized and dtype.kind in "iu":
        out = out.astype(np.float64) / np.iinfo(dtype).max
        if dtype.kind == "i":
            out = np.maximum(out, -1.0)
    if accessor.type.startswith("MAT"):
        out = np.swapaxes(out, -1, -2)  # column-major storage to row-major numpy matrices
    return out


def read_skinned_gltf(path: str | os.PathLike) -> dict[str, Any]:
    """Read a skinned glTF 2.0 file (as written by :func:`rig.io.gltf.export_skinned_gltf`) into numpy arrays.

    Uses the first node that has both a mesh and a skin, and that mesh's first primitive. Files
    from other tools are read too, as long as they have one triangle primitive with ``POSITION``,
    ``JOINTS_0``, ``WEIGHTS_0`` and indices (then every glTF vertex is its own source vertex).

    Parameters
    ----------
    path : str or os.PathLike
        A ``.glb`` or ``.gltf`` file (embedded or external buffers).

    Returns
    -------
    dict
        ``vertices`` : (V, 3) float64
            Bind-pose positions in millimetres of the ``V`` source vertices (glTF vertices before
            the UV-seam duplicates).
        ``faces`` : (F, 3) int64
            Triangles into ``vertices`` (seam duplicates mapped back to their source).
        ``split_source`` : (N,) int64
            Source vertex of every glTF vertex (``N >= V``, ``split_source[:V] == arange(V)``).
        ``gltf_faces`` : (F, 3) int64
            Triangles into the ``N`` glTF vertices.
        ``joint_names`` : list of K str
        ``parents`` : (K,) int64
            Parent joint, ``-1`` for a root (a joint whose parent node is not a joint of the skin).
        ``joint_positions`` : (K, 3) float64
            World bind positions in millimetres, from the inverse bind matrices.
        ``joints`` : (V, 4) int64 and ``weights`` : (V, 4) float64
            ``JOINTS_0`` / ``WEIGHTS_0`` of the source vertices.
        ``local_matrices`` : (K, 4, 4) float64
            Node-local joint matrices (relative to the parent node), translations in millimetres.
        ``inverse_bind_matrices`` : (K, 4, 4) float64
            Translations in millimetres.
        ``normals`` : (N, 3) float64 or None
        ``texcoords`` : (N, 2) float64 or None
            ``TEXCOORD_0`` converted back to v-up, i.e. ``(u, 1 - v_gltf)``.
        ``colors`` : (N, 3) float64 or None
            ``COLOR_0`` RGB.
        ``base_color_texture`` : bytes or None
            The encoded image (e.g. PNG) of the primitive's material's ``baseColorTexture``, as stored.
        ``extras`` : dict
            The mesh node's ``extras``.
        ``morph_targets`` : (M, V, 3) float64, ``morph_names`` : list of M str, ``morph_weights`` : (M,)
            Morph-target offsets in millimetres (source vertices), their names (the mesh's
            ``extras.targetNames``) and the mesh's default weights.
        ``attachments`` : list of dict
            Every other node with a mesh and the same skin (:class:`rig.io.gltf.GltfAttachment`), in node order:
            ``name``, ``vertices`` (N, 3) mm, ``faces`` (F, 3), ``joints`` / ``weights`` (N, 4),
            ``morph_targets`` (M, N, 3) mm (``(0, N, 3)`` without targets), ``color`` (4,) base colour factor.
        ``animations`` : list of dict
            Each animation's ``name`` and ``channels``: a list of dict with ``node`` (the target node's
            name), ``path`` (``translation``, ``rotation``, ``scale`` or ``weights``), ``interpolation``,
            ``times`` (T,) seconds and ``values`` (T, n): translations in millimetres, rotations as xyzw
            quaternions, weights ``(T, M)``.
    """
    func = "read_skinned_gltf"
    path = Path(path)
    gltf = _load(func, path)
    directory = path.parent
    cache: dict = {}

    mesh_node = next((n for n in gltf.nodes if n.mesh is not None and n.skin is not None), None)
    if mesh_node is None:
        raise ValueError(f"{func}: {str(path)!r} has no node with both a mesh and a skin")
    primitive = gltf.meshes[mesh_node.mesh].primitives[0]
    if primitive.mode not in (None, pygltflib.TRIANGLES):
        raise ValueError(f"{func}: only triangle primitives are supported, got mode {primitive.mode}")
    attrs = primitive.attributes

    def attribute(name: str) -> np.ndarray | None:
        index = getattr(attrs, name, None)
        return None if index is None else _read_accessor(gltf, index, directory, cache)

    positions = attribute("POSITION").astype(np.float64) / MM_TO_M
    n_gltf = positions.shape[0]
    if primitive.indices is None:
        gltf_faces = np.arange(n_gltf, dtype=np.int64).reshape(-1, 3)
    else:
        gltf_faces = _read_accessor(gltf, primitive.indices, directory, cache).astype(np.int64).reshape(-1, 3)

    extras = dict(mesh_node.extras or {})
    n_source = int(extras.get(EXTRAS_SOURCE_COUNT, n_gltf))
    duplicates = np.asarray(extras.get(EXTRAS_SPLIT_SOURCE, []), dtype=np.int64)
    split_source = np.concatenate([np.arange(n_source, dtype=np.int64), duplicates])
    if split_source.shape[0] != n_gltf:
        raise ValueError(
            f"{func}: mesh node extras describe {split_source.shape[0]} vertices, the primitive has {n_gltf}"
        )

    joints = attribute("JOINTS_0")
    weights = attribute("WEIGHTS_0")
    if joints is None or weights is None:
        raise ValueError(f"{func}: the skinned primitive lacks JOINTS_0 or WEIGHTS_0")
    texcoords = attribute("TEXCOORD_0")
    if texcoords is not None:
        texcoords = np.column_stack([texcoords[:, 0], 1.0 - texcoords[:, 1].astype(np.float64)])
    colors = attribute("COLOR_0")
    normals = attribute("NORMAL")
    mesh = gltf.meshes[mesh_node.mesh]
    targets = [
        _read_accessor(gltf, t["POSITION"] if isinstance(t, dict) else t.POSITION, directory, cache).astype(np.float64)
        / MM_TO_M
        for t in (primitive.targets or [])
    ]
    target_names = list((mesh.extras or {}).get("targetNames", []))

    return {
        "vertices": positions[:n_source],
        "faces": split_source[gltf_faces],
        "split_source": split_source,
        "gltf_faces": gltf_faces,
        **_skeleton(gltf, gltf.skins[mesh_node.skin], directory, cache),
        "joints": joints[:n_source].astype(np.int64),
        "weights": weights[:n_source].astype(np.float64),
        "normals": None if normals is None else normals.astype(np.float64),
        "texcoords": None if texcoords is None else texcoords.astype(np.float64),
        "colors": None if colors is None else colors[:, :3].astype(np.float64),
        "base_color_texture": _base_color_image(gltf, primitive, directory, cache),
        "extras": extras,
        "morph_targets": np.stack(targets)[:, :n_source] if targets else np.zeros((0, n_source, 3)),
        "morph_names": target_names,
        "morph_weights": np.asarray(mesh.weights or [0.0] * len(targets), dtype=np.float64),
        "attachments": [
            _attachment(gltf, node, directory, cache)
            for node in gltf.nodes
            if node is not mesh_node and node.mesh is not None and node.skin == mesh_node.skin
        ],
        "animations": [_animation(gltf, a, directory, cache) for a in (gltf.animations or [])],
    }


def _attachment(gltf: pygltflib.GLTF2, node: pygltflib.Node, directory: Path, cache: dict) -> dict[str, Any]:
    """A further skinned mesh node's arrays (see :func:`read_skinned_gltf`, ``attachments``)."""
    primitive = gltf.meshes[node.mesh].primitives[0]
    attrs = primitive.attributes
    vertices = _read_accessor(gltf, attrs.POSITION, directory, cache).astype(np.float64) / MM_TO_M
    faces = _read_accessor(gltf, primitive.indices, directory, cache).astype(np.int64).reshape(-1, 3)
    targets = [
        _read_accessor(gltf, t["POSITION"] if isinstance(t, dict) else t.POSITION, directory, cache).astype(np.float64)
        / MM_TO_M
        for t in (primitive.targets or [])
    ]
    pbr = None if primitive.material is None else gltf.materials[primitive.material].pbrMetallicRoughness
    return {
        "name": node.name,
        "vertices": vertices,
        "faces": faces,
        "joints": _read_accessor(gltf, attrs.JOINTS_0, directory, cache).astype(np.int64),
        "weights": _read_accessor(gltf, attrs.WEIGHTS_0, directory, cache).astype(np.float64),
        "morph_targets": np.stack(targets) if targets else np.zeros((0, len(vertices), 3)),
        "color": np.asarray(pbr.baseColorFactor if pbr is not None else [1.0, 1.0, 1.0, 1.0], dtype=np.float64),
    }


def _animation(gltf: pygltflib.GLTF2, animation: pygltflib.Animation, directory: Path, cache: dict) -> dict[str, Any]:
    """One animation's channels (see :func:`read_skinned_gltf`, ``animations``)."""
    channels = []
    for ch in animation.channels:
        sampler = animation.samplers[ch.sampler]
        times = _read_accessor(gltf, sampler.input, directory, cache).astype(np.float64).reshape(-1)
        values = _read_accessor(gltf, sampler.output, directory, cache).astype(np.float64)
        values = values.reshape(len(times), -1)
        if ch.target.path == "translation":
            values = values / MM_TO_M
        channels.append(
            {
                "node": gltf.nodes[ch.target.node].name,
                "path": ch.target.path,
                "interpolation": sampler.interpolation or "LINEAR",
                "times": times,
                "values": values,
            }
        )
    return {"name": animation.name, "channels": channels}


def _base_color_image(
    gltf: pygltflib.GLTF2, primitive: pygltflib.Primitive, directory: Path, cache: dict
) -> bytes | None:
    """The encoded image of the primitive's ``baseColorTexture`` (buffer view, data URI or file), or None."""
    if primitive.material is None:
        return None
    pbr = gltf.materials[primitive.material].pbrMetallicRoughness
    info = None if pbr is None else pbr.baseColorTexture
    if info is None:
        return None
    image = gltf.images[gltf.textures[info.index].source]
    if image.bufferView is not None:
        view = gltf.bufferViews[image.bufferView]
        data = _buffer_bytes(gltf, view.buffer, directory, cache)
        start = view.byteOffset or 0
        return bytes(data[start : start + view.byteLength])
    if image.uri.startswith("data:"):
        return base64.b64decode(image.uri.split(",", 1)[1])
    return (directory / image.uri).read_bytes()


def _load(func: str, path: Path) -> pygltflib.GLTF2:
    """A ``.glb`` (by its magic bytes) or ``.gltf`` file as a ``pygltflib.GLTF2``."""
    raw = path.read_bytes()
    try:
        if raw[:4] == b"glTF":
            gltf = pygltflib.GLTF2.load_from_bytes(raw)
        else:
            gltf = pygltflib.GLTF2.from_json(raw.decode("utf-8"))
    except Exception as exc:
        raise ValueError(f"{func}: could not read {str(path)!r} as glTF: {exc}") from exc
    if gltf is None:
        raise ValueError(f"{func}: could not read {str(path)!r} as glTF")
    return gltf


def _skeleton(gltf: pygltflib.GLTF2, skin: pygltflib.Skin, directory: Path, cache: dict) -> dict[str, Any]:
    """The skin's joints: ``joint_names``, ``parents``, ``joint_positions``, ``local_matrices`` and
    ``inverse_bind_matrices`` (see :func:`read_skinned_gltf`; millimetres)."""
    joint_nodes = list(skin.joints)
    k = len(joint_nodes)
    node_to_joint = {node: j for j, node in enumerate(joint_nodes)}
    parent_node = {child: i for i, n in enumerate(gltf.nodes) for child in (n.children or [])}
    parents = np.array([node_to_joint.get(parent_node.get(node, -1), -1) for node in joint_nodes], dtype=np.int64)
    names = [gltf.nodes[node].name or f"joint_{j}" for j, node in enumerate(joint_nodes)]
    if skin.inverseBindMatrices is None:
        inverse_bind = np.tile(np.eye(4), (k, 1, 1))
    else:
        inverse_bind = _read_accessor(gltf, skin.inverseBindMatrices, directory, cache).astype(np.float64)
    world_bind = np.linalg.inv(inverse_bind)
    joint_positions = world_bind[:, :3, 3] / MM_TO_M

    local = np.stack([_node_local_matrix(gltf.nodes[node]) for node in joint_nodes])
    local[:, :3, 3] /= MM_TO_M
    inverse_bind_mm = inverse_bind.copy()
    inverse_bind_mm[:, :3, 3] /= MM_TO_M
    return {
        "joint_names": names,
        "parents": parents,
        "joint_positions": joint_positions,
        "local_matrices": local,
        "inverse_bind_matrices": inverse_bind_mm,
    }


def _node_local_matrix(node: pygltflib.Node) -> np.ndarray:
    """Local 4x4 matrix of a glTF node (its ``matrix`` or its T @ R @ S), glTF units."""
    if node.matrix is not None:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T  # column-major storage
    return compose_trs(node.translation, node.rotation, node.scale)
