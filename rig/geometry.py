"""Geometry shared by the packages: mesh edges, vertex normals, closest points on triangles, barycentric
coordinates, the head rotation convention and the rig -> OpenCV axis flip. Pure numpy; millimetres in,
millimetres out."""

from __future__ import annotations

import numpy as np

RIG_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
RIG_TO_OPENCV.flags.writeable = False
"""``(3, 3)`` axis flip from the rig frame (+X the subject's left, +Y up, +Z out of the face) to OpenCV
camera axes (x right, y down, z forward) for a camera looking at the face; the one definition
(:mod:`pipeline.photo.camera` holds the camera conversions built on it)."""


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


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``(V, 3)`` of a triangle mesh (outward for a CCW mesh)."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # length = 2 * area
    n = np.zeros_like(v)
    for c in range(3):
        n[:, c] = np.bincount(f.ravel(), weights=np.repeat(fn[:, c], 3), minlength=len(v))
    return n / np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)


def closest_points_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points on triangles ``(a, b, c)`` to points ``p`` (all ``(..., 3)``), Ericson's regions."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    tiny = 1e-300
    # Interior (default), then override by edge and vertex regions in increasing priority.
    denom = va + vb + vc
    v_ = vb / np.where(np.abs(denom) > tiny, denom, tiny)
    w_ = vc / np.where(np.abs(denom) > tiny, denom, tiny)
    out = a + ab * v_[..., None] + ac * w_[..., None]
    # Edge BC.
    e_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    t = (d4 - d3) / np.where(((d4 - d3) + (d5 - d6)) > tiny, (d4 - d3) + (d5 - d6), tiny)
    out = np.where(e_bc[..., None], b + (c - b) * t[..., None], out)
    # Edge AC.
    e_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    t = d2 / np.where((d2 - d6) > tiny, d2 - d6, tiny)
    out = np.where(e_ac[..., None], a + ac * t[..., None], out)
    # Edge AB.
    e_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    t = d1 / np.where((d1 - d3) > tiny, d1 - d3, tiny)
    out = np.where(e_ab[..., None], a + ab * t[..., None], out)
    # Vertex regions.
    out = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, out)
    return out


def barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(N, 3)`` of points ``p`` in the planes of triangles ``(a, b, c)`` (each ``(N, 3)``)."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = np.where(np.abs(d00 * d11 - d01 * d01) > 1e-300, d00 * d11 - d01 * d01, 1e-300)
    w1 = (d11 * d20 - d01 * d21) / den
    w2 = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - w1 - w2, w1, w2], 1)


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
            raise ValueError(f"Similarity: rotation must be (3, 3) and translation (3,), got {rotation.shape} "
                             f"and {translation.shape}")
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"Similarity: scale must be a finite number > 0, got {scale}")
        self.rotation, self.translation, self.scale = rotation, translation, float(scale)

    def __repr__(self) -> str:
        return f"Similarity(rotation={self.rotation.tolist()}, translation={self.translation.tolist()}, scale={self.scale})"

    def __eq__(self, other) -> bool:
        return (isinstance(other, Similarity) and np.array_equal(self.rotation, other.rotation)
                and np.array_equal(self.translation, other.translation) and self.scale == other.scale)

    __hash__ = None  # mutable arrays inside

    @classmethod
    def identity(cls) -> Similarity:
        return cls(np.eye(3), np.zeros(3), 1.0)

    @classmethod
    def fit(cls, source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None,
            with_scale: bool = False) -> Similarity:
        """Least-squares ``target ~ scale * R @ source + t`` (Umeyama 1991, weighted), ``det R = +1``.

        Args:
            source, target: ``(N, 3)`` corresponding points, mm (N >= 3, not collinear).
            weights: optional ``(N,)`` non-negative weights.
            with_scale: also estimate the scale (else 1).
        """
        source = np.asarray(source, float)
        target = np.asarray(target, float)
        if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or len(source) < 3:
            raise ValueError(f"Similarity.fit: source and target must both be (N >= 3, 3), got {source.shape} and "
                             f"{target.shape}")
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
            var = float(w @ (s0 ** 2).sum(1))
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
        return Similarity(other.rotation @ self.rotation,
                          other.scale * other.rotation @ self.translation + other.translation,
                          other.scale * self.scale)

    def matrix(self) -> np.ndarray:
        """``(4, 4)`` homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = self.translation
        return m
