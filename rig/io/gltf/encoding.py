"""How jnr lays a glTF 2.0 file out: units, the limits on skinning influences, the component types, the
node transforms (``T @ R @ S``) and the one binary buffer (:class:`_BufferBuilder`), written as ``.glb`` or
``.gltf`` (:func:`_document_bytes`). See :mod:`rig.io.gltf`.
"""

from __future__ import annotations

import base64
from collections.abc import Sequence

import numpy as np
import pygltflib
from scipy.spatial.transform import Rotation

__all__ = [
    "COMPONENT_DTYPES",
    "EXTRAS_SOURCE_COUNT",
    "EXTRAS_SPLIT_SOURCE",
    "GLTF_UNITS_NOTE",
    "MAX_DROPPED_WEIGHT",
    "MAX_INFLUENCES",
    "MM_TO_M",
    "WEIGHT_EPS",
    "compose_trs",
    "quaternion_to_matrix",
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

EXTRAS_SOURCE_COUNT = "jnr_source_vertex_count"
"""Key of the mesh node's ``extras``: ``V``, the vertices before the UV-seam split (they come first)."""
EXTRAS_SPLIT_SOURCE = "jnr_split_source"
"""Key of the mesh node's ``extras``: the source vertex of each seam duplicate (vertices ``V ...``)."""

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def is_png(data: bytes | None) -> bool:
    """Whether ``data`` are the bytes of a PNG file (its signature), what a glTF ``baseColorTexture`` takes."""
    return isinstance(data, (bytes, bytearray)) and bytes(data).startswith(_PNG_SIGNATURE)


# glTF constants.
_FLOAT = pygltflib.FLOAT  # 5126
_UNSIGNED_SHORT = pygltflib.UNSIGNED_SHORT  # 5123
_UNSIGNED_INT = pygltflib.UNSIGNED_INT  # 5125
_ARRAY_BUFFER = pygltflib.ARRAY_BUFFER  # 34962
_ELEMENT_ARRAY_BUFFER = pygltflib.ELEMENT_ARRAY_BUFFER  # 34963
COMPONENT_DTYPES = {
    pygltflib.BYTE: np.dtype("<i1"),
    pygltflib.UNSIGNED_BYTE: np.dtype("<u1"),
    pygltflib.SHORT: np.dtype("<i2"),
    pygltflib.UNSIGNED_SHORT: np.dtype("<u2"),
    pygltflib.UNSIGNED_INT: np.dtype("<u4"),
    pygltflib.FLOAT: np.dtype("<f4"),
}
"""numpy dtype of each glTF accessor component type (little-endian)."""


def _translation(t: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


def _matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` (glTF's order, scipy's too) of a 3x3 rotation matrix, ``w >= 0``."""
    q = Rotation.from_matrix(r).as_quat()
    return q if q[3] >= 0.0 else -q


def quaternion_to_matrix(q: Sequence[float]) -> np.ndarray:
    """3x3 rotation matrix of a unit quaternion ``(x, y, z, w)``."""
    return Rotation.from_quat(np.asarray(q, dtype=np.float64)).as_matrix()


def compose_trs(t: Sequence[float] | None, r: Sequence[float] | None, s: Sequence[float] | None):
    """4x4 ``T @ R @ S`` of a glTF node's ``translation``, ``rotation`` (xyzw) and ``scale`` (None: identity)."""
    m = np.eye(4)
    rot = quaternion_to_matrix(r) if r is not None else np.eye(3)
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
    recomposed = compose_trs(m[:3, 3], quat, scale)
    if not np.allclose(recomposed[:3, :3], a, rtol=0.0, atol=rtol * max(1.0, float(scale.max()))):
        return None
    return m[:3, 3].copy(), quat, scale


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
        dtype = COMPONENT_DTYPES[component_type]
        data = np.ascontiguousarray(array, dtype=dtype)
        count = data.shape[0]
        offset = len(self.blob)
        raw = data.tobytes()
        self.blob.extend(raw)
        self.blob.extend(b"\0" * (-len(raw) % 4))
        self.buffer_views.append(pygltflib.BufferView(buffer=0, byteOffset=offset, byteLength=len(raw), target=target))
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
        data = np.ascontiguousarray(array, dtype=COMPONENT_DTYPES[_FLOAT])
        rows = np.flatnonzero(np.abs(data).max(axis=1) > tol).astype(np.uint32)
        if len(rows) == 0:  # glTF needs count >= 1: store one explicit zero
            rows = np.zeros(1, np.uint32)
        index_view = self._view(rows.tobytes())
        value_view = self._view(data[rows].tobytes())
        accessor = pygltflib.Accessor(  # no bufferView, so no byteOffset either (the validator insists)
            byteOffset=None,
            componentType=_FLOAT,
            count=int(data.shape[0]),
            type="VEC3",
            name=name,
            min=[float(x) for x in np.minimum(data.min(axis=0), 0.0)],
            max=[float(x) for x in np.maximum(data.max(axis=0), 0.0)],
            sparse=pygltflib.Sparse(
                count=len(rows),
                indices=pygltflib.AccessorSparseIndices(bufferView=index_view, componentType=_UNSIGNED_INT),
                values=pygltflib.AccessorSparseValues(bufferView=value_view),
            ),
        )
        self.accessors.append(accessor)
        return len(self.accessors) - 1

    def _view(self, raw: bytes) -> int:
        offset = len(self.blob)
        self.blob.extend(raw)
        self.blob.extend(b"\0" * (-len(raw) % 4))
        self.buffer_views.append(pygltflib.BufferView(buffer=0, byteOffset=offset, byteLength=len(raw)))
        return len(self.buffer_views) - 1


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
