"""Geometry shared by the packages: mesh edges, face and vertex normals, closest points on triangles and
on triangle meshes, barycentric coordinates, the head rotation convention, the rig -> OpenCV axis flip,
similarity transforms and deformation transfer.

The one implementation of each: :func:`vertex_normals` (numpy, or torch and differentiable) and
:func:`closest_surface_points` (exact, built on the point-triangle :func:`closest_points_on_triangles`).
The closest points, barycentric coordinates and :func:`surface_values` live in :mod:`rig.surface_points`
and are re-exported here.
``render`` imports nothing of ``rig``: Mitsuba computes its own shading normals there, and what needs ours
(the photo fit's SH shading) is computed by the caller and handed to the renderer as tensors. Numpy unless a
function says otherwise; millimetres in, millimetres out.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

import numpy as np

from rig.errors import InputError, check_shape
from rig.surface_points import SurfacePoints as SurfacePoints
from rig.surface_points import barycentric as barycentric
from rig.surface_points import closest_points_on_triangles as closest_points_on_triangles
from rig.surface_points import closest_surface_points as closest_surface_points
from rig.surface_points import surface_values as surface_values

if TYPE_CHECKING:
    import torch

RIG_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
RIG_TO_OPENCV.flags.writeable = False
"""``(3, 3)`` axis flip from the rig frame (+X the subject's left, +Y up, +Z out of the face) to OpenCV
camera axes (x right, y down, z forward) for a camera looking at the face; the one definition
(:mod:`pipeline.camera` holds the camera conversions built on it)."""


def head_rotation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """``(3, 3)`` head rotation ``R_z(roll) R_x(pitch) R_y(yaw)`` in rig axes (degrees). Positive yaw turns
    the face (+Z) towards +X (the subject's left, the image's right); positive pitch tips it down;
    positive roll turns +X towards +Y.

    Example:
        >>> np.round(head_rotation(90.0, 0.0, 0.0) @ [0.0, 0.0, 1.0], 6)
        array([1., 0., 0.])
    """
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("yxz", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_matrix()


def head_angles(rotation: np.ndarray) -> tuple[float, float, float]:
    """``(yaw, pitch, roll)`` in degrees of a ``(3, 3)`` head rotation: the inverse of :func:`head_rotation`.

    Example:
        >>> [round(a, 6) for a in head_angles(head_rotation(20.0, -5.0, 3.0))]
        [20.0, -5.0, 3.0]
    """
    from scipy.spatial.transform import Rotation

    yaw, pitch, roll = Rotation.from_matrix(np.asarray(rotation, np.float64)).as_euler("yxz", degrees=True)
    return float(yaw), float(pitch), float(roll)


def face_edges(faces: np.ndarray) -> np.ndarray:
    """``(3F, 2)`` the directed edges of every triangle, ``(a, b), (b, c), (c, a)`` stacked by corner
    pair (all ``(a, b)`` first), each interior edge twice (once per side)."""
    f = np.asarray(faces)
    return np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """``(E, 2)`` the undirected edges of a triangle mesh, each once as ``(low, high)`` vertex ids, sorted.

    Example:
        >>> mesh_edges(np.array([[0, 1, 2], [2, 1, 3]]))
        array([[0, 1],
               [0, 2],
               [1, 2],
               [1, 3],
               [2, 3]])
    """
    return np.unique(np.sort(face_edges(faces), axis=1), axis=0)


def _torch_of(x):
    """The ``torch`` module when ``x`` is a tensor, else None. Without importing torch: a tensor means it is
    imported already (so numpy callers of this module never load it)."""
    torch = sys.modules.get("torch")
    return torch if torch is not None and isinstance(x, torch.Tensor) else None


def face_normals(vertices: np.ndarray | torch.Tensor, faces: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """Unnormalised face normals ``(e1 x e2)``, of length twice the face's area, outward for a counter-clockwise
    (seen from outside) mesh.

    Args:
        vertices: ``(..., V, 3)`` numpy array or torch tensor, mm (any leading batch shape).
        faces: ``(F, 3)`` integer vertex ids (a torch ``int64`` tensor on ``vertices``' device for torch).

    Returns:
        ``(..., F, 3)`` mm^2, the type of ``vertices`` (torch: differentiable).

    Example:
        >>> face_normals(np.array([[0.0, 0, 0], [2, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
        array([[0., 0., 2.]])
    """
    th = _torch_of(vertices)
    t = (vertices if th is not None else np.asarray(vertices))[..., faces, :]  # (..., F, 3, 3)
    e1, e2 = t[..., 1, :] - t[..., 0, :], t[..., 2, :] - t[..., 0, :]
    return th.linalg.cross(e1, e2) if th is not None else np.cross(e1, e2)


def vertex_normals(vertices: np.ndarray | torch.Tensor, faces: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """Area-weighted unit vertex normals of a triangle mesh: each vertex's normal is the sum of its faces'
    :func:`face_normals`, normalised (outward for a counter-clockwise mesh; ``(0, 0, 0)`` for a vertex in no
    face or only in degenerate ones).

    Args:
        vertices: ``(V, 3)`` numpy array (any float; computed in float64) or torch tensor (its dtype and
            device; differentiable), mm.
        faces: ``(F, 3)`` integer vertex ids (numpy or torch).

    Returns:
        ``(V, 3)`` unit vectors: numpy float64 for numpy ``vertices``, a tensor for a tensor.

    Example:
        >>> v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])  # a tetrahedron
        >>> vertex_normals(v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))[0].round(3)
        array([-0.577, -0.577, -0.577])
    """
    th = _torch_of(vertices)
    if th is not None:
        f = th.as_tensor(faces, dtype=th.int64, device=vertices.device)
        fn = face_normals(vertices, f)
        n = th.zeros_like(vertices).index_add(0, f.reshape(-1), fn.repeat_interleave(3, 0))
        return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    v = np.asarray(vertices, float)
    f = np.asarray(faces)
    fn = face_normals(v, f)  # length = 2 * area
    n = np.zeros_like(v)
    for c in range(3):
        n[:, c] = np.bincount(f.ravel(), weights=np.repeat(fn[:, c], 3), minlength=len(v))
    return n / np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)


class Similarity:
    """A similarity transform ``x -> scale * R @ x + t`` (mm), the one type jnr uses for every alignment:
    rig space -> a point cloud's frame, a fitted head -> the true one, landmarks -> landmarks.

    Args:
        rotation: ``(3, 3)`` proper rotation. translation: ``(3,)`` mm. scale: > 0.

    Example:
        >>> s = Similarity(np.eye(3), np.array([0.0, 0.0, 10.0]), 2.0)
        >>> s.apply(np.array([[1.0, 0.0, 0.0]]))
        array([[ 2.,  0., 10.]])
        >>> np.allclose(s.inverse().apply(s.apply(np.ones((1, 3)))), 1.0)
        True
    """

    __slots__ = ("rotation", "scale", "translation")

    def __init__(self, rotation: np.ndarray, translation: np.ndarray, scale: float = 1.0) -> None:
        rotation = np.asarray(rotation, float)
        translation = np.asarray(translation, float)
        if rotation.shape != (3, 3) or translation.shape != (3,):
            raise InputError(
                f"Similarity: rotation must be (3, 3) and translation (3,), got {rotation.shape} "
                f"and {translation.shape}"
            )
        if not (np.isfinite(scale) and scale > 0):
            raise InputError(f"Similarity: scale must be a finite number > 0, got {scale}")
        self.rotation, self.translation, self.scale = rotation, translation, float(scale)

    def __repr__(self) -> str:
        return (
            f"Similarity(rotation={self.rotation.tolist()}, translation={self.translation.tolist()}, "
            f"scale={self.scale})"
        )

    def __eq__(self, other) -> bool:
        return (
            isinstance(other, Similarity)
            and np.array_equal(self.rotation, other.rotation)
            and np.array_equal(self.translation, other.translation)
            and self.scale == other.scale
        )

    __hash__ = None  # mutable arrays inside

    @classmethod
    def identity(cls) -> Similarity:
        return cls(np.eye(3), np.zeros(3), 1.0)

    @classmethod
    def fit(
        cls, source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None, with_scale: bool = False
    ) -> Similarity:
        """Least-squares ``target ~ scale * R @ source + t`` (Umeyama 1991, weighted), ``det R = +1``.

        Args:
            source, target: ``(N, 3)`` corresponding points, mm (N >= 3, not collinear).
            weights: optional ``(N,)`` non-negative weights.
            with_scale: also estimate the scale (else 1).
        """
        source = np.asarray(source, float)
        target = np.asarray(target, float)
        if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or len(source) < 3:
            raise InputError(
                f"Similarity.fit: source and target must both be (N >= 3, 3), got {source.shape} and {target.shape}"
            )
        w = np.ones(len(source)) if weights is None else np.asarray(weights, float)
        w = w / max(w.sum(), 1e-300)
        mu_s, mu_t = w @ source, w @ target
        s0, t0 = source - mu_s, target - mu_t
        cov = (t0 * w[:, None]).T @ s0
        u, d, vt = np.linalg.svd(cov)
        fix = np.eye(3)
        fix[2, 2] = np.sign(np.linalg.det(u) * np.linalg.det(vt)) or 1.0
        rot = u @ fix @ vt
        scale = 1.0
        if with_scale:
            var = float(w @ (s0**2).sum(1))
            scale = float((d * np.diag(fix)).sum() / max(var, 1e-300))
        return cls(rot, mu_t - scale * rot @ mu_s, scale)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """``(N, 3) -> (N, 3)``: ``scale * R @ x + t``."""
        return self.scale * np.asarray(points, float) @ self.rotation.T + self.translation

    def apply_inverse(self, points: np.ndarray) -> np.ndarray:
        """``(N, 3) -> (N, 3)``: ``R.T @ (x - t) / scale`` (undoes :meth:`apply`)."""
        return (np.asarray(points, float) - self.translation) @ self.rotation / self.scale

    def inverse(self) -> Similarity:
        return Similarity(self.rotation.T, -self.rotation.T @ self.translation / self.scale, 1.0 / self.scale)

    def then(self, other: Similarity) -> Similarity:
        """``other`` applied after ``self``."""
        return Similarity(
            other.rotation @ self.rotation,
            other.scale * other.rotation @ self.translation + other.translation,
            other.scale * self.scale,
        )

    def matrix(self) -> np.ndarray:
        """``(4, 4)`` homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = self.translation
        return m


def _triangle_frames(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(..., F, 3, 3)``: each triangle's two edges and its scaled normal (``n / sqrt|n|``) as columns."""
    a, b, c = (vertices[..., faces[:, k], :] for k in range(3))
    e1, e2 = b - a, c - a
    n = np.cross(e1, e2)
    n = n / np.sqrt(np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12))
    return np.stack([e1, e2, n], axis=-1)


def deformation_transfer(
    source: np.ndarray, deformed: np.ndarray, target: np.ndarray, faces: np.ndarray, anchor: float = 1e-3
) -> np.ndarray:
    """Carry shapes sculpted on one mesh onto another of the same topology, triangle by triangle.

    Each source triangle's deformation gradient ``S = [e1' e2' n'] [e1 e2 n]^-1`` (edges and scaled normal,
    Sumner and Popovic 2004) is applied to the target's edges; the target's displaced vertices are the least-
    squares solution of ``(y_b + d_b) - (y_a + d_a) = S (y_b - y_a)`` over every triangle edge, plus
    ``anchor^2 |d - (deformed - source)|^2`` (which fixes each connected piece's translation; small, so
    the raw offsets hardly count where edges constrain). The vertices a shape does not move on the source
    stay still (so a local shape stays local and sparse). On the source itself it returns the offsets.

    Args:
        source: ``(V, 3)`` the mesh the shapes were made on, mm.
        deformed: ``(E, V, 3)`` the shapes on it (positions), mm.
        target: ``(V, 3)`` the other mesh, mm; faces: ``(F, 3)`` shared.
        anchor: weight of the raw offsets (relative to an edge residual of 1 mm).

    Returns:
        ``(E, V, 3)`` float64 displacements of ``target``, mm.
    """
    source, target = np.asarray(source, float), np.asarray(target, float)
    deformed = np.asarray(deformed, float)
    faces = np.asarray(faces, np.int64)
    check_shape(target.shape == source.shape, "deformation_transfer", "target", f"{source.shape}", target.shape)
    expected = f"(E, {len(source)}, 3)"
    check_shape(deformed.shape[-2:] == source.shape, "deformation_transfer", "deformed", expected, deformed.shape)
    frames = _triangle_frames(source, faces)
    ok = np.abs(np.linalg.det(frames)) > 1e-10
    frames, f = frames[ok], faces[ok]
    grads = _triangle_frames(deformed, f) @ np.linalg.inv(frames)  # (E, F, 3, 3)
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    rows, cols, vals, rhs = [], [], [], []
    for k, (i, j) in enumerate(((0, 1), (0, 2))):
        e = target[f[:, j]] - target[f[:, i]]  # (F, 3)
        w = 1.0 / np.maximum(np.linalg.norm(e, axis=1), 1e-3)  # relative residuals: small triangles count
        r = np.arange(len(f)) + k * len(f)
        rows += [r, r]
        cols += [f[:, j], f[:, i]]
        vals += [w, -w]
        rhs.append(w[:, None] * (np.einsum("efij,fj->efi", grads, e) - e))  # (E, F, 3)
    d_op = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(2 * len(f), len(source))
    ).tocsc()
    b = np.concatenate(rhs, axis=1)  # (E, 2F, 3)
    raw = deformed - source
    out = np.zeros_like(raw)
    for s in range(len(raw)):
        moved = np.flatnonzero(np.abs(raw[s]).max(1) > 0)  # the rest stay still (exactly: sparse shapes)
        if len(moved) == 0:
            continue
        d = d_op[:, moved]
        system = spla.splu((d.T @ d + anchor**2 * sp.identity(len(moved))).tocsc())
        out[s, moved] = system.solve(np.asarray(d.T @ b[s]) + anchor**2 * raw[s, moved])
    return out
