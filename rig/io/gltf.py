"""Writing the skinned rig as glTF 2.0 (``.glb`` / ``.gltf``) through ``pygltflib``, and reading it back.

* :func:`export_skinned_gltf` writes the mesh, the joint hierarchy and the skinning weights as a
  glTF 2.0 file (``.glb`` binary or ``.gltf`` JSON with an embedded data-URI buffer).
* :func:`read_skinned_gltf` reads such a glTF file back into numpy arrays (for tests and checks).
* :class:`GltfAttachment`: further meshes (an accessory: glasses, a cap) skinned to the same joints, with
  their own morph targets under the head's target names.
* :class:`GltfAnimation`: keyframed morph-target weights and joint transforms (``jnr animate``), stored as
  one glTF animation with ``LINEAR`` samplers.

Conventions: rig space is right-handed, +Y up, +Z forward out of the face, in millimetres; column
vectors and 4x4 homogeneous matrices. glTF shares the axes but uses metres, so positions, node
translations and inverse bind matrices are scaled by 0.001 on export (and by 1000 when read back).

A base-colour texture (``base_color_texture``: PNG bytes) is stored in the binary buffer (``.glb``) or as
a data URI (``.gltf``) and used as the material's ``pbrMetallicRoughness.baseColorTexture`` through
``TEXCOORD_0``, whose ``v`` is flipped from OBJ's (glTF: ``(0, 0)`` is the image's top-left corner).

UV seams are split as in :mod:`rig.io.mesh` (:func:`rig.io.mesh.split_uv_seams`): the ``V`` input
vertices come first, in order, then one duplicate per extra (vertex, UV) pair; the mesh node's
``extras`` record ``V`` and the source vertex of each duplicate. Files are written atomically
(:func:`rig.io.atomic.write_bytes_atomic`).
"""

from __future__ import annotations

import base64
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib
from scipy.spatial.transform import Rotation

from rig.errors import shape_error
from rig.geometry import vertex_normals
from rig.io.atomic import write_bytes_atomic
from rig.io.mesh import check_mesh_arrays, resolve_format, split_uv_seams

__all__ = [
    "GLTF_UNITS_NOTE",
    "GltfAnimation",
    "GltfAttachment",
    "MAX_DROPPED_WEIGHT",
    "MAX_INFLUENCES",
    "MM_TO_M",
    "WEIGHT_EPS",
    "export_skinned_gltf",
    "read_skinned_gltf",
]

MM_TO_M = 1e-3
"""Scale from rig millimetres to glTF metres."""

MAX_INFLUENCES = 4
"""Joint influences per vertex stored in glTF (``JOINTS_0`` / ``WEIGHTS_0``)."""

WEIGHT_EPS = 1e-6
"""Skinning weights at or below this are treated as zero."""

MAX_DROPPED_WEIGHT = 1e-3
"""Largest total weight per vertex that may be dropped when keeping the 4 largest influences."""

GLTF_UNITS_NOTE = "metres (rig space is millimetres)"


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


@dataclass(frozen=True)
class GltfAnimation:
    """Keyframes of a head's morph-target weights and joint transforms, one glTF animation (``LINEAR``).

    Attributes:
        times: ``(T,)`` strictly increasing keyframe times in seconds, ``T >= 1``.
        morph_weights: ``(T, M)`` weights of the ``M`` morph targets per keyframe (every mesh node with
            targets gets a ``weights`` channel); None: no morph channel.
        joint_transforms: ``(T, K, 4, 4)`` each joint's local pose transform ``tau_k`` per keyframe, as
            ``joint_transforms`` of :func:`export_skinned_gltf` (millimetres; translation @ rotation @
            positive scale); channels are written only for the joints and paths
            (translation/rotation/scale) that change over time. None: no joint channels.
        name: the animation's name.
    """

    times: np.ndarray
    morph_weights: np.ndarray | None = None
    joint_transforms: np.ndarray | None = None
    name: str = "animation"

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_EXTRAS_SOURCE_COUNT = "jnr_source_vertex_count"
_EXTRAS_SPLIT_SOURCE = "jnr_split_source"

# glTF constants.
_FLOAT = pygltflib.FLOAT  # 5126
_UNSIGNED_SHORT = pygltflib.UNSIGNED_SHORT  # 5123
_UNSIGNED_INT = pygltflib.UNSIGNED_INT  # 5125
_ARRAY_BUFFER = pygltflib.ARRAY_BUFFER  # 34962
_ELEMENT_ARRAY_BUFFER = pygltflib.ELEMENT_ARRAY_BUFFER  # 34963
_COMPONENT_DTYPES = {
    pygltflib.BYTE: np.dtype("<i1"),
    pygltflib.UNSIGNED_BYTE: np.dtype("<u1"),
    pygltflib.SHORT: np.dtype("<i2"),
    pygltflib.UNSIGNED_SHORT: np.dtype("<u2"),
    pygltflib.UNSIGNED_INT: np.dtype("<u4"),
    pygltflib.FLOAT: np.dtype("<f4"),
}
_TYPE_SHAPES = {
    "SCALAR": (),
    "VEC2": (2,),
    "VEC3": (3,),
    "VEC4": (4,),
    "MAT2": (2, 2),
    "MAT3": (3, 3),
    "MAT4": (4, 4),
}


# ----------------------------------------------------------------------------------------------
# geometry helpers
# ----------------------------------------------------------------------------------------------


def unit_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """:func:`rig.geometry.vertex_normals` ``(V, 3)``, with ``(0, 0, 1)`` where a vertex has none (glTF
    requires unit normals)."""
    normals = vertex_normals(vertices, faces)
    normals[np.linalg.norm(normals, axis=1) < 0.5] = (0.0, 0.0, 1.0)
    return normals


def _translation(t: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


def _matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` (glTF's order, scipy's too) of a 3x3 rotation matrix, ``w >= 0``."""
    q = Rotation.from_matrix(r).as_quat()
    return q if q[3] >= 0.0 else -q


def _quaternion_to_matrix(q: Sequence[float]) -> np.ndarray:
    return Rotation.from_quat(np.asarray(q, dtype=np.float64)).as_matrix()


def _compose_trs(t: Sequence[float] | None, r: Sequence[float] | None, s: Sequence[float] | None):
    m = np.eye(4)
    rot = _quaternion_to_matrix(r) if r is not None else np.eye(3)
    scale = np.asarray(s, dtype=np.float64) if s is not None else np.ones(3)
    m[:3, :3] = rot * scale[None, :]
    if t is not None:
        m[:3, 3] = t
    return m


def _decompose_trs(m: np.ndarray, rtol: float = 1e-5):
    """``(translation, rotation_xyzw, scale)`` with ``T @ R @ S == m``, or None.

    None when the linear part has a shear, a reflection or a zero scale, i.e. differs from the
    recomposed ``R @ S`` by more than ``rtol * max(1, max scale)`` (float32 round-off passes).
    """
    a = m[:3, :3]
    scale = np.linalg.norm(a, axis=0)
    if np.any(scale <= 1e-12 * max(1.0, float(scale.max()))):
        return None
    u, _, vt = np.linalg.svd(a / scale[None, :])
    rot = u @ vt  # nearest rotation (or reflection) to the column-normalised matrix
    if np.linalg.det(rot) <= 0.0:
        return None
    quat = _matrix_to_quaternion(rot)
    recomposed = _compose_trs(m[:3, 3], quat, scale)
    if not np.allclose(recomposed[:3, :3], a, rtol=0.0, atol=rtol * max(1.0, float(scale.max()))):
        return None
    return m[:3, 3].copy(), quat, scale


def _node_local_matrix(node: pygltflib.Node) -> np.ndarray:
    """Local 4x4 matrix of a glTF node (its ``matrix`` or its T @ R @ S), glTF units."""
    if node.matrix is not None:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T  # column-major storage
    return _compose_trs(node.translation, node.rotation, node.scale)


# ----------------------------------------------------------------------------------------------
# writing glTF
# ----------------------------------------------------------------------------------------------


class _BufferBuilder:
    """Packs arrays into one binary buffer with one 4-byte-aligned bufferView per accessor."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.buffer_views: list[pygltflib.BufferView] = []
        self.accessors: list[pygltflib.Accessor] = []

    def add(
        self,
        array: np.ndarray,
        component_type: int,
        accessor_type: str,
        *,
        target: int | None = None,
        min_max: bool = False,
        name: str | None = None,
    ) -> int:
        dtype = _COMPONENT_DTYPES[component_type]
        data = np.ascontiguousarray(array, dtype=dtype)
        count = data.shape[0]
        offset = len(self.blob)
        raw = data.tobytes()
        self.blob.extend(raw)
        self.blob.extend(b"\0" * (-len(raw) % 4))
        self.buffer_views.append(
            pygltflib.BufferView(buffer=0, byteOffset=offset, byteLength=len(raw), target=target)
        )
        accessor = pygltflib.Accessor(
            bufferView=len(self.buffer_views) - 1,
            byteOffset=0,
            componentType=component_type,
            count=count,
            type=accessor_type,
            name=name,
        )
        if min_max:
            flat = data.reshape(count, -1)
            # min/max must be given in the accessor's component type
            cast = float if dtype.kind == "f" else int
            accessor.min = [cast(x) for x in flat.min(axis=0)]
            accessor.max = [cast(x) for x in flat.max(axis=0)]
        self.accessors.append(accessor)
        return len(self.accessors) - 1

    def add_sparse(self, array: np.ndarray, *, name: str | None = None, tol: float = 0.0) -> int:
        """A float ``VEC3`` accessor ``(N, 3)`` stored sparsely (glTF ``sparse``, no base buffer view: zeros
        elsewhere): only rows with a component above ``tol`` in magnitude are written, with min/max."""
        data = np.ascontiguousarray(array, dtype=_COMPONENT_DTYPES[_FLOAT])
        rows = np.flatnonzero(np.abs(data).max(axis=1) > tol).astype(np.uint32)
        if len(rows) == 0:  # glTF needs count >= 1: store one explicit zero
            rows = np.zeros(1, np.uint32)
        index_view = self._view(rows.tobytes())
        value_view = self._view(data[rows].tobytes())
        accessor = pygltflib.Accessor(  # no bufferView, so no byteOffset either (the validator insists)
            byteOffset=None, componentType=_FLOAT, count=int(data.shape[0]), type="VEC3", name=name,
            min=[float(x) for x in np.minimum(data.min(axis=0), 0.0)],
            max=[float(x) for x in np.maximum(data.max(axis=0), 0.0)],
            sparse=pygltflib.Sparse(count=len(rows),
                                    indices=pygltflib.AccessorSparseIndices(bufferView=index_view, componentType=_UNSIGNED_INT),
                                    values=pygltflib.AccessorSparseValues(bufferView=value_view)),
        )
        self.accessors.append(accessor)
        return len(self.accessors) - 1

    def _view(self, raw: bytes) -> int:
        offset = len(self.blob)
        self.blob.extend(raw)
        self.blob.extend(b"\0" * (-len(raw) % 4))
        self.buffer_views.append(pygltflib.BufferView(buffer=0, byteOffset=offset, byteLength=len(raw)))
        return len(self.buffer_views) - 1


def _check_rig(func, n_vertices, joint_names, parents, joint_positions, weights, joint_transforms):
    names = list(joint_names) if not isinstance(joint_names, str) else None
    if names is None or any(not isinstance(n, str) for n in names):
        raise ValueError(f"{func}: joint_names must be a list of K str")
    k = len(names)
    if k == 0:
        raise ValueError(f"{func}: joint_names must name at least one joint, got an empty list")
    if len(set(names)) != k:
        raise ValueError(f"{func}: joint_names must be unique")

    par = np.asarray(parents)
    if par.shape != (k,):
        raise shape_error(func, "parents", f"(K,) = ({k},)", par.shape)
    if not np.issubdtype(par.dtype, np.integer):
        raise ValueError(f"{func}: parents must be integers, got dtype {par.dtype}")
    par = par.astype(np.int64)
    bad = np.nonzero((par < -1) | (par >= np.arange(k)))[0]
    if bad.size:
        j = int(bad[0])
        raise ValueError(
            f"{func}: parents must be -1 (root) or the index of an earlier joint; "
            f"joint {j} ({names[j]!r}) has parent {int(par[j])}"
        )

    pos = np.asarray(joint_positions)
    if pos.shape != (k, 3):
        raise shape_error(func, "joint_positions", f"(K, 3) = ({k}, 3)", pos.shape)
    pos = pos.astype(np.float64)
    if not np.isfinite(pos).all():
        raise ValueError(f"{func}: joint_positions contain NaN or infinite values")

    w = np.asarray(weights)
    if w.shape != (n_vertices, k):
        raise shape_error(func, "weights", f"(V, K) = ({n_vertices}, {k})", w.shape)
    w = w.astype(np.float64)
    if not np.isfinite(w).all():
        raise ValueError(f"{func}: weights contain NaN or infinite values")
    if w.min() < -WEIGHT_EPS:
        raise ValueError(f"{func}: weights must be non-negative, got minimum {w.min()}")
    row_sum = w.sum(axis=1)
    worst = int(np.argmax(np.abs(row_sum - 1.0)))
    if abs(row_sum[worst] - 1.0) > MAX_DROPPED_WEIGHT:
        raise ValueError(
            f"{func}: weights rows must sum to 1; vertex {worst} sums to {row_sum[worst]}"
        )

    taus = None
    if joint_transforms is not None:
        taus = np.asarray(joint_transforms)
        if taus.shape != (k, 4, 4):
            raise shape_error(func, "joint_transforms", f"(K, 4, 4) = ({k}, 4, 4)", taus.shape)
        taus = taus.astype(np.float64)
        if not np.isfinite(taus).all():
            raise ValueError(f"{func}: joint_transforms contain NaN or infinite values")
        if not np.allclose(taus[:, 3, :], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
            raise ValueError(f"{func}: joint_transforms must be affine (last row 0, 0, 0, 1)")
    return names, par, pos, w, taus


def _top_influences(func: str, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 4 largest weights per vertex, renormalised: ``(joints (V, 4) int, weights (V, 4))``."""
    n_vertices, k = weights.shape
    w = np.where(weights > WEIGHT_EPS, weights, 0.0)
    if k < MAX_INFLUENCES:
        w = np.concatenate([w, np.zeros((n_vertices, MAX_INFLUENCES - k))], axis=1)
    order = np.argsort(-w, axis=1, kind="stable")[:, :MAX_INFLUENCES]
    top = np.take_along_axis(w, order, axis=1)
    dropped = w.sum(axis=1) - top.sum(axis=1)
    lossy = np.nonzero(dropped > MAX_DROPPED_WEIGHT)[0]
    if lossy.size:
        worst = int(lossy[np.argmax(dropped[lossy])])
        n_influences = int((w[worst] > 0).sum())
        raise ValueError(
            f"{func}: weights of {lossy.size} vertices have more than {MAX_INFLUENCES} influences "
            f"and keeping the {MAX_INFLUENCES} largest would drop more than {MAX_DROPPED_WEIGHT} "
            f"of their weight (worst: vertex {worst}, {n_influences} influences, dropped weight "
            f"{dropped[worst]:.3g}); prune the weights to {MAX_INFLUENCES} joints per vertex first"
        )
    top = top / top.sum(axis=1, keepdims=True)
    order = np.where(top > 0.0, order, 0)  # unused influences point at joint 0 with weight 0
    return order.astype(np.int64), top


def _scale_affine_to_metres(m: np.ndarray) -> np.ndarray:
    out = m.copy()
    out[..., :3, 3] *= MM_TO_M
    return out


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
    record the units, ``V`` and the source vertex of each seam duplicate, which
    :func:`read_skinned_gltf` uses to undo the split.
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
        raise ValueError(f"{func}: at most 65536 joints fit JOINTS_0 (unsigned short), got {k}")

    joints4, weights4 = _top_influences(func, w)
    normals = unit_normals(v, f)
    targets, target_names, target_weights = _check_morphs(func, n_vertices, morph_targets, morph_names, morph_weights)
    if base_color_texture is not None:
        png = base_color_texture if isinstance(base_color_texture, (bytes, bytearray)) else b""
        if not bytes(png).startswith(_PNG_SIGNATURE):
            raise ValueError(f"{func}: base_color_texture must be the bytes of a PNG file")
        if uv is None:
            raise ValueError(f"{func}: base_color_texture needs face_uvs (TEXCOORD_0)")

    if uv is not None:
        f, uvs, source = split_uv_seams(f, uv, n_vertices)
    else:
        uvs, source = None, np.arange(n_vertices)

    builder = _BufferBuilder()
    attributes, indices = _add_mesh_arrays(builder, v, f, source, normals, uvs, colors, joints4, weights4)
    morphs = [pygltflib.Attributes(POSITION=builder.add_sparse(t[source] * MM_TO_M, name=f"target_{name}"))
              for t, name in zip(targets, target_names)]
    inverse_bind = np.stack([_translation(-p * MM_TO_M) for p in pos])
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
            _EXTRAS_SOURCE_COUNT: int(n_vertices),
            _EXTRAS_SPLIT_SOURCE: [int(s) for s in source[n_vertices:]],
        },
    )
    morph = (morphs, target_names, target_weights)
    extra = [_add_attachment(func, builder, a, names, target_names, target_weights) for a in attachments]
    if len({m.name for m, _, _ in extra} | {"mesh"}) != len(extra) + 1:
        raise ValueError(f"{func}: attachment names must be unique and not 'mesh'")
    texture_view = None if base_color_texture is None else builder._view(bytes(base_color_texture))
    gltf = _encode(builder, joint_nodes, roots, mesh_node, attributes, indices, ibm_accessor, morph, texture_view,
                   extra)
    if animation is not None:
        _add_animation(func, gltf, builder, animation, names, par, pos, len(target_names),
                       [k] + [k + 1 + i for i, (_, _, has_targets) in enumerate(extra) if has_targets])
    write_bytes_atomic(path, _document_bytes(fmt, gltf, builder))


def _add_attachment(func: str, builder: _BufferBuilder, attachment: GltfAttachment, joint_names: list[str],
                    target_names: list[str], target_weights: list[float]
                    ) -> tuple[pygltflib.Mesh, pygltflib.Material, bool]:
    """An attachment's arrays in the buffer: ``(mesh, material, has morph targets)``."""
    if not isinstance(attachment, GltfAttachment):
        raise ValueError(f"{func}: attachments must be GltfAttachment, got {type(attachment).__name__}")
    name = str(attachment.name)
    if not name or name in joint_names:
        raise ValueError(f"{func}: attachment name {name!r} must be non-empty and not a joint name")
    v, f, _, _ = check_mesh_arrays(f"{func}: attachment {name!r}", attachment.vertices, attachment.faces, None, None)
    _, _, _, w, _ = _check_rig(f"{func}: attachment {name!r}", v.shape[0], joint_names,
                               np.arange(len(joint_names)) - 1, np.zeros((len(joint_names), 3)),
                               attachment.weights, None)
    joints4, weights4 = _top_influences(f"{func}: attachment {name!r}", w)
    source = np.arange(v.shape[0])
    attributes, indices = _add_mesh_arrays(builder, v, f, source, unit_normals(v, f), None, None, joints4, weights4)
    targets = []
    if attachment.morph_targets is not None:
        t, _, _ = _check_morphs(f"{func}: attachment {name!r}", v.shape[0], attachment.morph_targets,
                                target_names, None)
        targets = [pygltflib.Attributes(POSITION=builder.add_sparse(x * MM_TO_M, name=f"{name}_target_{n}"))
                   for x, n in zip(t, target_names)]
    color = (0.8, 0.8, 0.8) if attachment.color is None else tuple(float(c) for c in attachment.color)
    if len(color) != 3 or not all(0.0 <= c <= 1.0 for c in color):
        raise ValueError(f"{func}: attachment {name!r} color must be 3 linear RGB values in [0, 1], got {color}")
    mesh = pygltflib.Mesh(
        name=name,
        primitives=[pygltflib.Primitive(attributes=attributes, indices=indices, mode=pygltflib.TRIANGLES,
                                        targets=targets)],
        weights=list(target_weights) if targets else None,
        extras={"targetNames": list(target_names)} if targets else {},
    )
    material = pygltflib.Material(name=name, doubleSided=True, pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
        baseColorFactor=[*color, 1.0], metallicFactor=0.0, roughnessFactor=0.5))
    return mesh, material, bool(targets)


def _joint_trs_keys(func: str, taus: np.ndarray, names: list[str], par: np.ndarray, pos: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Node TRS of every joint per keyframe: translations ``(T, K, 3)`` m, rotations ``(T, K, 4)`` xyzw with
    consecutive keys in one hemisphere, scales ``(T, K, 3)``."""
    n_keys, k = taus.shape[:2]
    trans, rots, scales = np.zeros((n_keys, k, 3)), np.zeros((n_keys, k, 4)), np.zeros((n_keys, k, 3))
    for t in range(n_keys):
        nodes, _ = _joint_nodes(f"{func}: animation keyframe {t}", names, par, pos, taus[t])
        for j, node in enumerate(nodes):
            trans[t, j] = node.translation
            rots[t, j] = node.rotation or (0.0, 0.0, 0.0, 1.0)
            scales[t, j] = node.scale or (1.0, 1.0, 1.0)
    for t in range(1, n_keys):  # LINEAR quaternion keys interpolate along the short arc only within a hemisphere
        flip = np.sum(rots[t] * rots[t - 1], axis=1) < 0.0
        rots[t, flip] *= -1.0
    return trans, rots, scales


def _add_animation(func: str, gltf: pygltflib.GLTF2, builder: _BufferBuilder, animation: GltfAnimation,
                   names: list[str], par: np.ndarray, pos: np.ndarray, n_targets: int, morph_nodes: list[int]) -> None:
    """Append ``animation`` to ``gltf`` (its accessors to ``builder``): one shared time accessor, a channel per
    animated joint path and per mesh node with morph targets."""
    if not isinstance(animation, GltfAnimation):
        raise ValueError(f"{func}: animation must be a GltfAnimation, got {type(animation).__name__}")
    times = np.asarray(animation.times, dtype=np.float64).reshape(-1)
    if times.size == 0 or not np.isfinite(times).all() or np.any(np.diff(times) <= 0.0) or times[0] < 0.0:
        raise ValueError(f"{func}: animation times must be finite, >= 0 and strictly increasing (T >= 1)")
    n_keys = times.size
    samplers: list[pygltflib.AnimationSampler] = []
    channels: list[pygltflib.AnimationChannel] = []
    time_accessor = None

    def channel(node: int, path: str, values: np.ndarray, accessor_type: str) -> None:
        nonlocal time_accessor
        if time_accessor is None:
            time_accessor = builder.add(times.astype(np.float32), _FLOAT, "SCALAR", min_max=True, name="time")
        out = builder.add(values, _FLOAT, accessor_type, name=f"{path}_{node}")
        samplers.append(pygltflib.AnimationSampler(input=time_accessor, output=out, interpolation="LINEAR"))
        channels.append(pygltflib.AnimationChannel(sampler=len(samplers) - 1,
                                                   target=pygltflib.AnimationChannelTarget(node=node, path=path)))

    if animation.joint_transforms is not None:
        taus = np.asarray(animation.joint_transforms, dtype=np.float64)
        if taus.shape != (n_keys, len(names), 4, 4):
            raise shape_error(func, "animation.joint_transforms", f"(T, K, 4, 4) = ({n_keys}, {len(names)}, 4, 4)",
                              taus.shape)
        if not np.isfinite(taus).all():
            raise ValueError(f"{func}: animation.joint_transforms contain NaN or infinite values")
        trans, rots, scales = _joint_trs_keys(func, taus, names, par, pos)
        for j in range(len(names)):
            for path, values, kind in (("translation", trans[:, j], "VEC3"), ("rotation", rots[:, j], "VEC4"),
                                       ("scale", scales[:, j], "VEC3")):
                if np.ptp(values, axis=0).max() > 1e-9:
                    channel(j, path, values, kind)
    if animation.morph_weights is not None:
        w = np.asarray(animation.morph_weights, dtype=np.float64)
        if w.shape != (n_keys, n_targets) or n_targets == 0:
            raise shape_error(func, "animation.morph_weights", f"(T, M) = ({n_keys}, {n_targets})", w.shape)
        if not np.isfinite(w).all():
            raise ValueError(f"{func}: animation.morph_weights contain NaN or infinite values")
        for node in morph_nodes:
            channel(node, "weights", w.reshape(-1), "SCALAR")
    if not channels:
        raise ValueError(f"{func}: the animation animates nothing (no morph weights, no joint transform changes)")
    gltf.animations = [pygltflib.Animation(name=animation.name, samplers=samplers, channels=channels)]


def _check_morphs(func: str, n_vertices: int, targets, names, weights
                  ) -> tuple[np.ndarray, list[str], list[float]]:
    """Validated morph targets ``(M, V, 3)`` float64 mm, their names and default weights."""
    if targets is None:
        if names is not None or weights is not None:
            raise ValueError(f"{func}: morph_names / morph_weights given without morph_targets")
        return np.zeros((0, n_vertices, 3)), [], []
    t = np.asarray(targets, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (n_vertices, 3):
        raise shape_error(func, "morph_targets", f"(M, {n_vertices}, 3)", t.shape)
    if not np.isfinite(t).all():
        raise ValueError(f"{func}: morph_targets must be finite")
    names = [str(n) for n in (names or [])]
    if len(names) != len(t) or len(set(names)) != len(names):
        raise ValueError(f"{func}: morph_names must be {len(t)} unique names, got {len(names)}")
    w = np.zeros(len(t)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (len(t),) or not np.isfinite(w).all():
        raise ValueError(f"{func}: morph_weights must be {len(t)} finite numbers")
    return t, names, [float(x) for x in w]


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
    attributes.JOINTS_0 = builder.add(
        joints4[source], _UNSIGNED_SHORT, "VEC4", target=_ARRAY_BUFFER, name="JOINTS_0"
    )
    attributes.WEIGHTS_0 = builder.add(
        weights4[source], _FLOAT, "VEC4", target=_ARRAY_BUFFER, name="WEIGHTS_0"
    )
    indices = builder.add(
        f.reshape(-1), _UNSIGNED_INT, "SCALAR", target=_ELEMENT_ARRAY_BUFFER, name="indices"
    )
    return attributes, indices


def _joint_nodes(func: str, names: list[str], par: np.ndarray, pos: np.ndarray,
                 taus: np.ndarray | None) -> tuple[list[pygltflib.Node], list[int]]:
    """One node per joint (local T @ R @ S in metres, children linked) and the root joints."""
    k = len(names)
    joint_nodes = []
    for j in range(k):
        parent_pos = pos[par[j]] if par[j] >= 0 else np.zeros(3)
        offset_m = (pos[j] - parent_pos) * MM_TO_M
        node = pygltflib.Node(name=names[j])
        if taus is None:
            node.translation = [float(x) for x in offset_m]
        else:
            local = _translation(offset_m) @ _scale_affine_to_metres(taus[j])
            trs = _decompose_trs(local)
            if trs is None:
                raise ValueError(
                    f"{func}: joint_transforms[{j}] (joint {names[j]!r}) has a shear, a reflection "
                    "or a zero scale; glTF joint nodes need translation @ rotation @ positive scale"
                )
            t, r, s = trs
            node.translation = [float(x) for x in t]
            if not np.allclose(r, [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12):
                node.rotation = [float(x) for x in r]
            if not np.allclose(s, 1.0, rtol=0.0, atol=1e-12):
                node.scale = [float(x) for x in s]
        joint_nodes.append(node)
    for j in range(k):
        if par[j] >= 0:
            joint_nodes[par[j]].children.append(j)
    roots = [j for j in range(k) if par[j] < 0]
    return joint_nodes, roots


def _encode(builder: _BufferBuilder, joint_nodes: list[pygltflib.Node], roots: list[int],
            mesh_node: pygltflib.Node, attributes: pygltflib.Attributes, indices: int, ibm_accessor: int,
            morph: tuple[list[dict], list[str], list[float]] = ([], [], []), texture_view: int | None = None,
            attachments: Sequence[tuple[pygltflib.Mesh, pygltflib.Material, bool]] = ()) -> pygltflib.GLTF2:
    """The glTF document (joint nodes ``0 .. K-1``, the mesh node ``K``, attachment nodes ``K + 1 ...``); with
    ``texture_view`` (the buffer view of a PNG image) the head material's base colour is that texture. The
    buffer is set by :func:`_document_bytes`."""
    targets, target_names, target_weights = morph
    k = len(joint_nodes)
    mesh_node_index = k
    attachment_nodes = [pygltflib.Node(name=m.name, mesh=1 + i, skin=0, extras={"units": GLTF_UNITS_NOTE})
                        for i, (m, _, _) in enumerate(attachments)]

    material_pbr = pygltflib.PbrMetallicRoughness(
        baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0, roughnessFactor=0.6,
        baseColorTexture=None if texture_view is None else pygltflib.TextureInfo(index=0, texCoord=0))
    gltf = pygltflib.GLTF2(
        asset=pygltflib.Asset(version="2.0", generator="jnr"),
        scene=0,
        scenes=[pygltflib.Scene(name="jnr", nodes=[mesh_node_index, *range(k + 1, k + 1 + len(attachments)),
                                                   *roots])],
        nodes=[*joint_nodes, mesh_node, *attachment_nodes],
        meshes=[
            pygltflib.Mesh(
                name="mesh",
                primitives=[
                    pygltflib.Primitive(attributes=attributes, indices=indices, mode=pygltflib.TRIANGLES,
                                        material=0, targets=targets)
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
        materials=[pygltflib.Material(name="skin", doubleSided=False, pbrMetallicRoughness=material_pbr),
                   *(material for _, material, _ in attachments)],
        accessors=builder.accessors,
        bufferViews=builder.buffer_views,
    )
    for i, _ in enumerate(attachments):
        gltf.meshes[1 + i].primitives[0].material = 1 + i
    if texture_view is not None:
        gltf.images = [pygltflib.Image(bufferView=texture_view, mimeType="image/png", name="baseColor")]
        gltf.samplers = [pygltflib.Sampler(magFilter=pygltflib.LINEAR, minFilter=pygltflib.LINEAR_MIPMAP_LINEAR,
                                           wrapS=pygltflib.CLAMP_TO_EDGE, wrapT=pygltflib.CLAMP_TO_EDGE)]
        gltf.textures = [pygltflib.Texture(sampler=0, source=0, name="baseColor")]
    return gltf


def _document_bytes(fmt: str, gltf: pygltflib.GLTF2, builder: _BufferBuilder) -> bytes:
    """``gltf`` with ``builder``'s buffer as ``.glb`` or ``.gltf`` (base64 data URI) bytes."""
    blob = bytes(builder.blob)
    gltf.accessors, gltf.bufferViews = builder.accessors, builder.buffer_views
    buffer = pygltflib.Buffer(byteLength=len(blob))
    if fmt == "gltf":
        buffer.uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")
    gltf.buffers = [buffer]
    if fmt == "glb":
        gltf.set_binary_blob(blob)
        return b"".join(gltf.save_to_bytes())
    return gltf.gltf_to_json().encode("utf-8")


# ----------------------------------------------------------------------------------------------
# reading glTF back
# ----------------------------------------------------------------------------------------------


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


def _view_array(gltf: pygltflib.GLTF2, view_index: int, offset: int | None, count: int, dtype: np.dtype,
                n_components: int, directory: Path, cache: dict) -> np.ndarray:
    """``count`` tightly packed elements of ``n_components`` from a buffer view (sparse indices / values)."""
    view = gltf.bufferViews[view_index]
    data = _buffer_bytes(gltf, view.buffer, directory, cache)
    start = (view.byteOffset or 0) + (offset or 0)
    return np.frombuffer(data, dtype=dtype, count=count * n_components, offset=start).reshape(count, n_components)


def _read_accessor(gltf: pygltflib.GLTF2, index: int, directory: Path, cache: dict) -> np.ndarray:
    accessor = gltf.accessors[index]
    dtype = _COMPONENT_DTYPES[accessor.componentType]
    shape = _TYPE_SHAPES[accessor.type]
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
        ids = _view_array(gltf, sparse.indices.bufferView, sparse.indices.byteOffset, sparse.count,  # (n, 1)
                          _COMPONENT_DTYPES[sparse.indices.componentType], 1, directory, cache)[:, 0].astype(np.int64)
        values = _view_array(gltf, sparse.values.bufferView, sparse.values.byteOffset, sparse.count, dtype,
                             n_components, directory, cache)
        out.reshape(accessor.count, -1)[ids] = values.reshape(sparse.count, -1)
    if accessor.normalized and dtype.kind in "iu":
        out = out.astype(np.float64) / np.iinfo(dtype).max
        if dtype.kind == "i":
            out = np.maximum(out, -1.0)
    if accessor.type.startswith("MAT"):
        out = np.swapaxes(out, -1, -2)  # column-major storage to row-major numpy matrices
    return out


def read_skinned_gltf(path: str | os.PathLike) -> dict[str, Any]:
    """Read a skinned glTF 2.0 file (as written by :func:`export_skinned_gltf`) into numpy arrays.

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
            Every other node with a mesh and the same skin (:class:`GltfAttachment`), in node order:
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

    mesh_node = next(
        (n for n in gltf.nodes if n.mesh is not None and n.skin is not None), None
    )
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
    n_source = int(extras.get(_EXTRAS_SOURCE_COUNT, n_gltf))
    duplicates = np.asarray(extras.get(_EXTRAS_SPLIT_SOURCE, []), dtype=np.int64)
    split_source = np.concatenate([np.arange(n_source, dtype=np.int64), duplicates])
    if split_source.shape[0] != n_gltf:
        raise ValueError(
            f"{func}: mesh node extras describe {split_source.shape[0]} vertices, "
            f"the primitive has {n_gltf}"
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
    targets = [_read_accessor(gltf, t["POSITION"] if isinstance(t, dict) else t.POSITION, directory, cache)
               .astype(np.float64) / MM_TO_M for t in (primitive.targets or [])]
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
        "attachments": [_attachment(gltf, node, directory, cache) for node in gltf.nodes
                        if node is not mesh_node and node.mesh is not None and node.skin == mesh_node.skin],
        "animations": [_animation(gltf, a, directory, cache) for a in (gltf.animations or [])],
    }


def _attachment(gltf: pygltflib.GLTF2, node: pygltflib.Node, directory: Path, cache: dict) -> dict[str, Any]:
    """A further skinned mesh node's arrays (see :func:`read_skinned_gltf`, ``attachments``)."""
    primitive = gltf.meshes[node.mesh].primitives[0]
    attrs = primitive.attributes
    vertices = _read_accessor(gltf, attrs.POSITION, directory, cache).astype(np.float64) / MM_TO_M
    faces = _read_accessor(gltf, primitive.indices, directory, cache).astype(np.int64).reshape(-1, 3)
    targets = [_read_accessor(gltf, t["POSITION"] if isinstance(t, dict) else t.POSITION, directory, cache)
               .astype(np.float64) / MM_TO_M for t in (primitive.targets or [])]
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


def _animation(gltf: pygltflib.GLTF2, animation: pygltflib.Animation, directory: Path, cache: dict
               ) -> dict[str, Any]:
    """One animation's channels (see :func:`read_skinned_gltf`, ``animations``)."""
    channels = []
    for ch in animation.channels:
        sampler = animation.samplers[ch.sampler]
        times = _read_accessor(gltf, sampler.input, directory, cache).astype(np.float64).reshape(-1)
        values = _read_accessor(gltf, sampler.output, directory, cache).astype(np.float64)
        values = values.reshape(len(times), -1)
        if ch.target.path == "translation":
            values = values / MM_TO_M
        channels.append({"node": gltf.nodes[ch.target.node].name, "path": ch.target.path,
                         "interpolation": sampler.interpolation or "LINEAR", "times": times, "values": values})
    return {"name": animation.name, "channels": channels}


def _base_color_image(gltf: pygltflib.GLTF2, primitive: pygltflib.Primitive, directory: Path, cache: dict
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
        return bytes(data[start:start + view.byteLength])
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
    parents = np.array(
        [node_to_joint.get(parent_node.get(node, -1), -1) for node in joint_nodes], dtype=np.int64
    )
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
    return {"joint_names": names, "parents": parents, "joint_positions": joint_positions,
            "local_matrices": local, "inverse_bind_matrices": inverse_bind_mm}
