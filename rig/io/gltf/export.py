"""Writing the skinned head as glTF 2.0: :func:`export_skinned_gltf`, with :class:`GltfAttachment` meshes
skinned to the same joints. See :mod:`rig.io.gltf`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pygltflib

from rig.errors import InputError
from rig.geometry import vertex_normals
from rig.io.atomic import write_bytes_atomic
from rig.io.gltf.animation import GltfAnimation, _add_animation
from rig.io.gltf.encoding import (
    _ARRAY_BUFFER,
    _ELEMENT_ARRAY_BUFFER,
    _FLOAT,
    _UNSIGNED_INT,
    _UNSIGNED_SHORT,
    EXTRAS_SOURCE_COUNT,
    EXTRAS_SPLIT_SOURCE,
    GLTF_UNITS_NOTE,
    MM_TO_M,
    _BufferBuilder,
    _document_bytes,
    _translation,
    is_png,
)
from rig.io.gltf.skin import _check_morphs, _check_rig, _joint_nodes, _scale_affine_to_metres, _top_influences
from rig.io.mesh import check_mesh_arrays, resolve_format, split_uv_seams

__all__ = ["BIND_MODES", "GltfAttachment", "export_skinned_gltf", "posed_bind", "rebind"]


@dataclass(frozen=True)
class GltfAttachment:
    """A further mesh skinned to the head's joints (an accessory), written as its own mesh node and material.

    Attributes:
        name: the node, mesh and material name (unique, not a joint name).
        vertices: ``(N, 3)`` bind-pose positions, millimetres (the head's rig space).
        faces: ``(F, 3)`` triangles into ``vertices``.
        weights: ``(N, K)`` skinning weights on the head's ``K`` joints (non-negative, rows sum to 1;
            at most 4 influences kept, as for the head).
        morph_targets: ``(M, N, 3)`` offsets in millimetres under the head's ``M`` morph-target names, so
            that one set of weights moves both; None: the attachment has no targets.
        color: linear RGB base colour in [0, 1] of its (non-metallic) material; None: light grey.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    morph_targets: np.ndarray | None = None
    color: tuple[float, float, float] | None = None


def _unit_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """:func:`rig.geometry.vertex_normals` ``(V, 3)``, with ``(0, 0, 1)`` where a vertex has none (glTF
    requires unit normals)."""
    normals = vertex_normals(vertices, faces)
    normals[np.linalg.norm(normals, axis=1) < 0.5] = (0.0, 0.0, 1.0)
    return normals


def export_skinned_gltf(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    joint_names: Sequence[str],
    parents: np.ndarray,
    joint_positions: np.ndarray,
    weights: np.ndarray,
    face_uvs: np.ndarray | None = None,
    vertex_colors: np.ndarray | None = None,
    joint_transforms: np.ndarray | None = None,
    morph_targets: np.ndarray | None = None,
    morph_names: Sequence[str] | None = None,
    morph_weights: np.ndarray | None = None,
    base_color_texture: bytes | None = None,
    attachments: Sequence[GltfAttachment] = (),
    animation: GltfAnimation | None = None,
    bind: str = "rest",
    bake_morphs: bool = True,
) -> None:
    """Write a skinned mesh with its joint hierarchy as glTF 2.0 (``.glb`` or ``.gltf``).

    The file holds one node per joint (nodes ``0 .. K-1``, in joint order, named by
    ``joint_names``, nested by ``parents``), one mesh node (node ``K``) with the mesh and the skin,
    and a scene with the mesh node and the root joint node(s). Lengths are converted from
    millimetres to metres; the axes are unchanged (glTF, like rig space, is right-handed, +Y up,
    +Z forward).

    Parameters
    ----------
    path : str or os.PathLike
        Destination; the suffix picks the container: ``.glb`` (binary) or ``.gltf`` (JSON with the
        buffer embedded as a base64 data URI). Written atomically.
    vertices : (V, 3) float
        Bind-pose vertex positions in millimetres.
    faces : (F, 3) int
        Triangles into ``vertices``.
    joint_names : sequence of K str
        Unique joint (node) names.
    parents : (K,) int
        Parent joint of each joint, ``-1`` for a root; parents come before their children.
    joint_positions : (K, 3) float
        Bind-pose joint positions in millimetres. Joint frames are axis-aligned in the bind pose,
        so the world bind matrix of joint ``k`` is the translation ``T(p_k)`` and its inverse bind
        matrix is ``T(-p_k)`` (stored in metres).
    weights : (V, K) float
        Dense skinning weights, non-negative, rows summing to 1. The 4 largest per vertex are kept
        (``JOINTS_0`` / ``WEIGHTS_0``) and renormalised.
    face_uvs : (F, 3, 2) float, optional
        Texture coordinates per face corner (v up). Stored as ``TEXCOORD_0`` = ``(u, 1 - v)``
        (glTF's v points down) on split vertices (see the module docstring).
    vertex_colors : (V, 3) float in [0, 1] or uint8, optional
        Stored unchanged as float ``COLOR_0`` (glTF reads it as linear RGB).
    joint_transforms : (K, 4, 4) float, optional
        Local pose transform ``tau_k`` of each joint relative to its bind pose (column vectors,
        translations in millimetres). Joint ``k``'s node then has the local matrix
        ``T(p_k - p_parent) @ tau_k`` (``p_parent = 0`` for a root), stored as node
        ``translation`` / ``rotation`` / ``scale`` so that the joints stay posable in DCC tools.
        glTF requires node transforms to decompose this way, so each ``tau_k`` must be
        ``T @ R @ S`` with a rotation ``R`` and positive axis scales ``S`` (as the rig's channel
        transforms are); a shear or reflection raises ValueError. The mesh is still stored in
        the bind pose; a glTF viewer shows it posed. None means identity (bind pose).
    morph_targets : (M, V, 3) float, optional
        Morph targets (blend shapes): per-vertex offsets in millimetres, stored as ``POSITION``
        targets in metres, applied before skinning as glTF specifies. Needs ``morph_names``
        (``M`` unique names, written to the mesh's ``extras.targetNames``, which Blender, three.js
        and Babylon read as the shape-key names) and takes ``morph_weights`` ``(M,)`` as the mesh's
        default weights (zeros when omitted).
    base_color_texture : bytes, optional
        A PNG file's bytes, stored as it is (``image/png``) and used as the material's
        ``baseColorTexture`` (``texCoord`` 0: needs ``face_uvs``; the image's top row is ``v = 1`` in
        ``face_uvs``, i.e. ``TEXCOORD_0`` ``v = 0``; linear filtering with mipmaps, clamped at the edges). glTF
        multiplies the texture with ``COLOR_0``: pass no ``vertex_colors`` to show the texture as it is.
    attachments : sequence of GltfAttachment, optional
        Further meshes skinned to the same joints (nodes ``K + 1 ...``, in order), each with its own
        non-metallic material; their morph targets (if any) take the head's target names.
    animation : GltfAnimation, optional
        Keyframed morph weights and joint transforms, stored as one animation (``LINEAR`` samplers;
        rotations as unit quaternions with consecutive keys in the same hemisphere). The node TRS and mesh
        weights stay those of ``joint_transforms`` / ``morph_weights`` (what a viewer shows without
        playing the animation).
    bind : {"rest", "posed"}
        ``"rest"`` (default): the mesh (and attachments) stored at ``vertices``, the inverse bind matrices
        ``T(-p_k)``; a reader that does not skin sees the rest mesh. ``"posed"``: the file's bind pose is
        the posed head (needs ``joint_transforms``), so that every reader sees the same mesh: ``POSITION``
        is ``vertices`` skinned by ``joint_transforms`` (each vertex ``sum_k w_k A_k v`` with the full
        weights, :func:`posed_bind`, :func:`rebind`), the morph targets are carried into that pose (the
        blended linear part applied to each offset), the inverse bind matrices are the inverses of the
        joints' posed world frames ``G_k``, and the mesh weights are 0, ``morph_weights`` being recorded in
        the mesh's ``extras.bakedMorphWeights``: the caller passes ``vertices`` with that expression
        applied (its exact shape, not the linear targets'), and a morph weight then adds to it. Attachments
        get their targets times ``morph_weights`` added before the pose. With an ``animation`` nothing is
        baked (the weights stay the default and absolute; ``vertices`` is then the neutral rest mesh), nor with
        ``bake_morphs=False`` (the posed neutral mesh as the bind, ``morph_weights`` as the mesh's default
        weights: animation tools show the expression on the shape keys, at the values given).
        The joint nodes keep ``joint_transforms``,
        so the file shows the posed head at rest and each joint still poses it (a re-bound skin: further
        poses blend slightly differently from jnr's own skinning).

    Raises
    ------
    ValueError
        Unsupported suffix; an argument with the wrong shape, dtype or range; weight rows not
        summing to 1; a vertex whose weights beyond its 4 largest sum to more than
        ``MAX_DROPPED_WEIGHT`` (1e-3); or a joint transform that is not translation @ rotation
        @ positive scale.

    Notes
    -----
    Mesh attributes: ``POSITION`` (float32, with min/max), ``NORMAL`` (area-weighted, unit; computed
    before the seam split, so seams stay smooth), ``TEXCOORD_0``, ``COLOR_0``, ``JOINTS_0``
    (unsigned short), ``WEIGHTS_0`` (float), indices unsigned int. The mesh node's ``extras``
    record the units, ``V`` and the source vertex of each seam duplicate, with which a reader undoes the
    split (:data:`EXTRAS_SOURCE_COUNT`, :data:`EXTRAS_SPLIT_SOURCE`).
    """
    func = "export_skinned_gltf"
    path = Path(path)
    fmt = resolve_format(func, path, None, ("glb", "gltf"))
    v, f, uv, colors = check_mesh_arrays(func, vertices, faces, face_uvs, vertex_colors)
    n_vertices = v.shape[0]
    names, par, pos, w, taus = _check_rig(
        func, n_vertices, joint_names, parents, joint_positions, weights, joint_transforms
    )
    k = len(names)
    if k > np.iinfo(np.uint16).max + 1:
        raise InputError(f"{func}: at most 65536 joints fit JOINTS_0 (unsigned short), got {k}")

    joints4, weights4 = _top_influences(func, w)
    targets, target_names, target_weights = _check_morphs(func, n_vertices, morph_targets, morph_names, morph_weights)
    if bind not in BIND_MODES:
        raise InputError(f"{func}: bind must be one of {list(BIND_MODES)}, got {bind!r}")
    inverse_bind = np.stack([_translation(-p * MM_TO_M) for p in pos])
    mesh_extras: dict = {}
    if bind == "posed":
        if taus is None:
            raise InputError(f"{func}: bind='posed' needs joint_transforms")
        world, skinning = posed_bind(pos, par, taus)
        inverse_bind = np.linalg.inv(_scale_affine_to_metres(world))
        bake = bake_morphs and animation is None and len(target_weights) > 0
        baked = np.asarray(target_weights, np.float64) if bake else None
        v, targets = rebind(w, skinning, v, targets)  # the caller's vertices hold the expression (docstring)
        if bake:
            mesh_extras["bakedMorphWeights"] = [float(x) for x in target_weights]
            target_weights = [0.0] * len(target_weights)
        attachments = [_rebind_attachment(func, a, skinning, target_names, baked, len(names)) for a in attachments]
    normals = _unit_normals(v, f)
    if base_color_texture is not None:
        if not is_png(base_color_texture):
            raise InputError(f"{func}: base_color_texture must be the bytes of a PNG file")
        if uv is None:
            raise InputError(f"{func}: base_color_texture needs face_uvs (TEXCOORD_0)")

    if uv is not None:
        f, uvs, source = split_uv_seams(f, uv, n_vertices)
    else:
        uvs, source = None, np.arange(n_vertices)

    builder = _BufferBuilder()
    attributes, indices = _add_mesh_arrays(builder, v, f, source, normals, uvs, colors, joints4, weights4)
    morphs = [
        pygltflib.Attributes(POSITION=builder.add_sparse(t[source] * MM_TO_M, name=f"target_{name}"))
        for t, name in zip(targets, target_names)
    ]
    # glTF matrices are column-major: store the transpose of each row-major numpy matrix
    ibm_accessor = builder.add(
        np.transpose(inverse_bind, (0, 2, 1)).reshape(k, 16), _FLOAT, "MAT4", name="inverseBindMatrices"
    )
    joint_nodes, roots = _joint_nodes(func, names, par, pos, taus)
    mesh_node = pygltflib.Node(
        name="mesh",
        mesh=0,
        skin=0,
        extras={
            "units": GLTF_UNITS_NOTE,
            EXTRAS_SOURCE_COUNT: int(n_vertices),
            EXTRAS_SPLIT_SOURCE: [int(s) for s in source[n_vertices:]],
            "bind": bind,
            **mesh_extras,
        },
    )
    morph = (morphs, target_names, target_weights)
    extra = [_add_attachment(func, builder, a, names, target_names, target_weights) for a in attachments]
    if len({m.name for m, _, _ in extra} | {"mesh"}) != len(extra) + 1:
        raise InputError(f"{func}: attachment names must be unique and not 'mesh'")
    texture_view = None if base_color_texture is None else builder._view(bytes(base_color_texture))
    gltf = _encode(
        builder, joint_nodes, roots, mesh_node, attributes, indices, ibm_accessor, morph, texture_view, extra
    )
    if animation is not None:
        _add_animation(
            func,
            gltf,
            builder,
            animation,
            names,
            par,
            pos,
            len(target_names),
            [k] + [k + 1 + i for i, (_, _, has_targets) in enumerate(extra) if has_targets],
        )
    write_bytes_atomic(path, _document_bytes(fmt, gltf, builder))


BIND_MODES = ("rest", "posed")
"""``export_skinned_gltf(bind=...)``: the mesh stored at rest (inverse bind matrices ``T(-p_k)``) or as posed."""


def posed_bind(
    joint_positions: np.ndarray, parents: np.ndarray, joint_transforms: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(world (K, 4, 4), skinning (K, 4, 4))``, millimetres: each joint's world frame ``G_k = G_parent @
    T(p_k - p_parent) @ tau_k`` and its skinning transform ``A_k = G_k @ T(-p_k)`` (JNR eq. 1, as
    :func:`rig.lbs.joint_world_transforms`, in numpy float64)."""
    k = len(parents)
    world = np.empty((k, 4, 4))
    for j in range(k):
        local = np.array(joint_transforms[j], dtype=np.float64)
        parent = int(parents[j])
        local[:3, 3] += joint_positions[j] - (joint_positions[parent] if parent >= 0 else 0.0)
        world[j] = local if parent < 0 else world[parent] @ local
    skinning = world.copy()
    skinning[:, :3, 3] -= np.einsum("kij,kj->ki", world[:, :3, :3], joint_positions)
    return world, skinning


def rebind(
    weights: np.ndarray,
    skinning: np.ndarray,
    vertices: np.ndarray,
    targets: np.ndarray | None,
    baked: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Rest vertices ``(N, 3)`` and morph targets ``(M, N, 3)`` (mm) carried into the pose of ``skinning``
    ``(K, 4, 4)`` with ``weights (N, K)``: ``sum_k w_k A_k (v + sum_m baked_m d_m)`` (``baked (M,)``, None:
    no morph baked in) and each offset through the blended linear part (exact: skinning is linear in the
    rest position)."""
    blended = np.einsum("nk,kij->nij", weights, skinning)  # (N, 4, 4)
    rest = vertices if baked is None or targets is None else vertices + np.einsum("m,mnj->nj", baked, targets)
    posed = np.einsum("nij,nj->ni", blended[:, :3, :3], rest) + blended[:, :3, 3]
    moved = None if targets is None else np.einsum("nij,mnj->mni", blended[:, :3, :3], targets)
    return posed, moved


def _rebind_attachment(
    func: str, attachment, skinning: np.ndarray, target_names, baked: np.ndarray | None, n_joints: int
):
    """An attachment carried into the posed bind as the head is (``export_skinned_gltf(bind='posed')``)."""
    if not isinstance(attachment, GltfAttachment):
        return attachment  # refused with its message by _add_attachment
    weights = np.asarray(attachment.weights, np.float64)
    if weights.ndim != 2 or weights.shape[1] != n_joints:
        return attachment  # refused with its message by _add_attachment
    targets = None if attachment.morph_targets is None else np.asarray(attachment.morph_targets, np.float64)
    if targets is not None and (targets.ndim != 3 or targets.shape[0] != len(target_names)):
        return attachment
    v, t = rebind(weights, skinning, np.asarray(attachment.vertices, np.float64), targets, baked)
    return replace(attachment, vertices=v, morph_targets=t)


def _add_attachment(
    func: str,
    builder: _BufferBuilder,
    attachment: GltfAttachment,
    joint_names: list[str],
    target_names: list[str],
    target_weights: list[float],
) -> tuple[pygltflib.Mesh, pygltflib.Material, bool]:
    """An attachment's arrays in the buffer: ``(mesh, material, has morph targets)``."""
    if not isinstance(attachment, GltfAttachment):
        raise InputError(f"{func}: attachments must be GltfAttachment, got {type(attachment).__name__}")
    name = str(attachment.name)
    if not name or name in joint_names:
        raise InputError(f"{func}: attachment name {name!r} must be non-empty and not a joint name")
    v, f, _, _ = check_mesh_arrays(f"{func}: attachment {name!r}", attachment.vertices, attachment.faces, None, None)
    _, _, _, w, _ = _check_rig(
        f"{func}: attachment {name!r}",
        v.shape[0],
        joint_names,
        np.arange(len(joint_names)) - 1,
        np.zeros((len(joint_names), 3)),
        attachment.weights,
        None,
    )
    joints4, weights4 = _top_influences(f"{func}: attachment {name!r}", w)
    source = np.arange(v.shape[0])
    attributes, indices = _add_mesh_arrays(builder, v, f, source, _unit_normals(v, f), None, None, joints4, weights4)
    targets = []
    if attachment.morph_targets is not None:
        t, _, _ = _check_morphs(
            f"{func}: attachment {name!r}", v.shape[0], attachment.morph_targets, target_names, None
        )
        targets = [
            pygltflib.Attributes(POSITION=builder.add_sparse(x * MM_TO_M, name=f"{name}_target_{n}"))
            for x, n in zip(t, target_names)
        ]
    color = (0.8, 0.8, 0.8) if attachment.color is None else tuple(float(c) for c in attachment.color)
    if len(color) != 3 or not all(0.0 <= c <= 1.0 for c in color):
        raise InputError(f"{func}: attachment {name!r} color must be 3 linear RGB values in [0, 1], got {color}")
    mesh = pygltflib.Mesh(
        name=name,
        primitives=[
            pygltflib.Primitive(attributes=attributes, indices=indices, mode=pygltflib.TRIANGLES, targets=targets)
        ],
        weights=list(target_weights) if targets else None,
        extras={"targetNames": list(target_names)} if targets else {},
    )
    material = pygltflib.Material(
        name=name,
        doubleSided=True,
        pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
            baseColorFactor=[*color, 1.0], metallicFactor=0.0, roughnessFactor=0.5
        ),
    )
    return mesh, material, bool(targets)


def _add_mesh_arrays(builder: _BufferBuilder, v, f, source, normals, uvs, colors, joints4, weights4):
    """The mesh primitive's accessors, in file order: ``(pygltflib.Attributes, indices accessor)``."""
    attributes = pygltflib.Attributes()
    attributes.POSITION = builder.add(
        v[source] * MM_TO_M, _FLOAT, "VEC3", target=_ARRAY_BUFFER, min_max=True, name="POSITION"
    )
    attributes.NORMAL = builder.add(normals[source], _FLOAT, "VEC3", target=_ARRAY_BUFFER, name="NORMAL")
    if uvs is not None:
        gltf_uv = np.column_stack([uvs[:, 0], 1.0 - uvs[:, 1]])
        attributes.TEXCOORD_0 = builder.add(gltf_uv, _FLOAT, "VEC2", target=_ARRAY_BUFFER, name="TEXCOORD_0")
    if colors is not None:
        attributes.COLOR_0 = builder.add(colors[source], _FLOAT, "VEC3", target=_ARRAY_BUFFER, name="COLOR_0")
    attributes.JOINTS_0 = builder.add(joints4[source], _UNSIGNED_SHORT, "VEC4", target=_ARRAY_BUFFER, name="JOINTS_0")
    attributes.WEIGHTS_0 = builder.add(weights4[source], _FLOAT, "VEC4", target=_ARRAY_BUFFER, name="WEIGHTS_0")
    indices = builder.add(f.reshape(-1), _UNSIGNED_INT, "SCALAR", target=_ELEMENT_ARRAY_BUFFER, name="indices")
    return attributes, indices


def _encode(
    builder: _BufferBuilder,
    joint_nodes: list[pygltflib.Node],
    roots: list[int],
    mesh_node: pygltflib.Node,
    attributes: pygltflib.Attributes,
    indices: int,
    ibm_accessor: int,
    morph: tuple[list[dict], list[str], list[float]] = ([], [], []),
    texture_view: int | None = None,
    attachments: Sequence[tuple[pygltflib.Mesh, pygltflib.Material, bool]] = (),
) -> pygltflib.GLTF2:
    """The glTF document (joint nodes ``0 .. K-1``, the mesh node ``K``, attachment nodes ``K + 1 ...``); with
    ``texture_view`` (the buffer view of a PNG image) the head material's base colour is that texture. The
    buffer is set by :func:`_document_bytes`."""
    targets, target_names, target_weights = morph
    k = len(joint_nodes)
    mesh_node_index = k
    attachment_nodes = [
        pygltflib.Node(name=m.name, mesh=1 + i, skin=0, extras={"units": GLTF_UNITS_NOTE})
        for i, (m, _, _) in enumerate(attachments)
    ]

    material_pbr = pygltflib.PbrMetallicRoughness(
        baseColorFactor=[1.0, 1.0, 1.0, 1.0],
        metallicFactor=0.0,
        roughnessFactor=0.6,
        baseColorTexture=None if texture_view is None else pygltflib.TextureInfo(index=0, texCoord=0),
    )
    gltf = pygltflib.GLTF2(
        asset=pygltflib.Asset(version="2.0", generator="jnr"),
        scene=0,
        scenes=[pygltflib.Scene(name="jnr", nodes=[mesh_node_index, *range(k + 1, k + 1 + len(attachments)), *roots])],
        nodes=[*joint_nodes, mesh_node, *attachment_nodes],
        meshes=[
            pygltflib.Mesh(
                name="mesh",
                primitives=[
                    pygltflib.Primitive(
                        attributes=attributes, indices=indices, mode=pygltflib.TRIANGLES, material=0, targets=targets
                    )
                ],
                weights=target_weights,
                extras={"targetNames": target_names} if target_names else {},
            ),
            *(m for m, _, _ in attachments),
        ],
        skins=[
            pygltflib.Skin(
                name="skin",
                joints=list(range(k)),
                inverseBindMatrices=ibm_accessor,
                skeleton=roots[0] if len(roots) == 1 else None,
            )
        ],
        materials=[
            pygltflib.Material(name="skin", doubleSided=False, pbrMetallicRoughness=material_pbr),
            *(material for _, material, _ in attachments),
        ],
        accessors=builder.accessors,
        bufferViews=builder.buffer_views,
    )
    for i, _ in enumerate(attachments):
        gltf.meshes[1 + i].primitives[0].material = 1 + i
    if texture_view is not None:
        gltf.images = [pygltflib.Image(bufferView=texture_view, mimeType="image/png", name="baseColor")]
        gltf.samplers = [
            pygltflib.Sampler(
                magFilter=pygltflib.LINEAR,
                minFilter=pygltflib.LINEAR_MIPMAP_LINEAR,
                wrapS=pygltflib.CLAMP_TO_EDGE,
                wrapT=pygltflib.CLAMP_TO_EDGE,
            )
        ]
        gltf.textures = [pygltflib.Texture(sampler=0, source=0, name="baseColor")]
    return gltf
