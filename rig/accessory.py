"""Accessories (glasses, hats, hair) that follow the head: skinning weights and expression offsets
transferred from the closest point of the head's surface (JNR section 5.3).

An accessory is a triangle mesh placed on the template in its bind pose (rig space, mm). Every accessory
vertex gets

* **skinning weights** ``(J,)``: the barycentric interpolation of the corner weights of the closest point
  on the head's surface (its *anchor*), so a vertex on the skin moves exactly as the skin under it, and a
  vertex a few mm off the skin moves with the anchor's blended joint transform;
* **expression offsets** ``(E, 3)`` mm: the surface's morph-target offset at the anchor, times a contact
  attenuation :func:`contact_attenuation` that is 1 up to ``falloff_mm / 2`` from the skin and falls
  smoothly to 0 at ``falloff_mm`` (a cap resting on the forehead rises with ``browInnerUp``; a glasses
  rim 12 mm in front of the eye does not blink with ``eyeBlink``).

Both are then smoothed over the accessory with a Gaussian kernel of width ``smoothing_mm`` in 3D
(:func:`smooth_over_points`), so that a rigid part (a glasses frame spanning the nose, the orbits and the
temples) does not shear where its anchors' weights change quickly. The kernel works on the vertices'
positions, not on the mesh's edges: an OBJ file often comes as separate pieces or as unwelded triangles,
and parts that touch (a bridge ending in a rim) should move together. ``smoothing_mm = 0`` keeps the
closest-point values; ``inf`` gives every vertex the accessory's mean (one blended transform: rigid
apart from the blend's own scale). Last, each vertex keeps at most ``max_influences`` weights
(glTF's ``JOINTS_0``/``WEIGHTS_0`` hold 4): the extra weight goes to the kept joints that move most like
the dropped ones (:func:`reduce_influences` with the joint tree's :func:`joint_motion_distance`), or, without
the tree, the kept weights are renormalised (:func:`keep_largest`); both are continuous, so neighbouring
vertices do not tear apart.

:func:`pose_accessory` poses the accessory with the head's linear blend skinning
(:func:`rig.lbs.skin_vertices_shared_weights`): rest vertices plus the coefficient-weighted offsets,
skinned by the rig's skinning transforms, as the head is (``template + expression offsets``, then LBS).
``jawOpen`` is linear here (its morph target at 1, as in glTF), the head's is an arc: the difference is
at most 1.8 mm at 0.5 and only near the jaw.

Pure numpy/scipy/torch; imports nothing of ``pipeline`` or ``render``. Coordinates: millimetres, rig
space (right-handed, +Y up, +Z out of the face, +X the subject's left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from scipy.spatial import cKDTree

from rig.errors import InputError, check_shape
from rig.geometry import barycentric, closest_points_on_triangles, vertex_normals
from rig.lbs import skin_vertices_shared_weights

__all__ = [
    "DEFAULT_FALLOFF_MM",
    "DEFAULT_SMOOTHING_MM",
    "OUTER_SKIN_REGIONS",
    "AccessoryError",
    "AccessorySkinning",
    "SurfacePoints",
    "channel_reach",
    "closest_surface_points",
    "contact_attenuation",
    "joint_motion_distance",
    "keep_largest",
    "outer_skin_face_ids",
    "outer_skin_faces",
    "pose_accessory",
    "reduce_influences",
    "rigid_attachment",
    "signed_distance",
    "smooth_over_points",
    "surface_values",
    "transfer_skinning",
]

DEFAULT_FALLOFF_MM = 10.0
"""Contact falloff (mm): expression offsets are followed fully up to half of it from the skin, not at all
beyond it (a glasses rim sits 12-20 mm in front of the eyelids, a cap 3-6 mm off the scalp)."""
DEFAULT_SMOOTHING_MM = 5.0
"""Width (sigma, mm) of the Gaussian kernel that smooths weights and offsets over the accessory, chosen on
the shipped glasses and cap (docs/accessories.md): against none it halves the glasses' tearing (1.77 ->
0.76 mm) and their deepest penetration (0.57 -> 0.34 mm); wider kernels let contact points drift from
the skin (10 mm: glasses 0.92 mm deep, cap 3.3 mm)."""
OUTER_SKIN_REGIONS = ("scalp", "forehead", "brows", "eyelids", "nose", "cheeks", "lips", "chin", "jaw", "ears",
                      "neck")
"""The template regions an accessory rests on: the outer skin, without the eyeballs, the eye pockets behind
them, the mouth bag, teeth and tongue (a glasses rim must not take the eyeball's weights)."""


class AccessoryError(InputError):
    """An accessory that cannot be skinned (wrong shapes, non-finite vertices, nothing to anchor to)."""


@dataclass(frozen=True)
class SurfacePoints:
    """Closest points on a triangle surface.

    Attributes:
        face: ``(N,)`` int64 row of the surface's ``faces`` holding the closest point.
        barycentric: ``(N, 3)`` its barycentric coordinates in that triangle (non-negative, summing to 1).
        closest: ``(N, 3)`` the closest points, mm.
        distance: ``(N,)`` unsigned distance to them, mm.
    """

    face: np.ndarray
    barycentric: np.ndarray
    closest: np.ndarray
    distance: np.ndarray


@dataclass(frozen=True)
class AccessorySkinning:
    """An accessory's skinning, transferred from the head (:func:`transfer_skinning`).

    Attributes:
        weights: ``(N, J)`` skinning weights, non-negative, rows summing to 1, at most ``max_influences``
            non-zero per row.
        morph_targets: ``(E, N, 3)`` expression offsets at coefficient 1, mm.
        distance: ``(N,)`` distance of each vertex to the head's surface in the bind pose, mm.
        anchors: the closest surface points (:class:`SurfacePoints`, rows of the surface ``faces`` given).
        falloff_mm: the contact falloff used; smoothing_mm: the smoothing kernel's sigma used.
    """

    weights: np.ndarray
    morph_targets: np.ndarray
    distance: np.ndarray
    anchors: SurfacePoints
    falloff_mm: float
    smoothing_mm: float


def _points(func: str, arg: str, points) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    check_shape(p.ndim == 2 and p.shape[1] == 3 and len(p) > 0, func, arg, "(N, 3) with N > 0", p.shape)
    if not np.isfinite(p).all():
        raise AccessoryError(f"{func}: {arg} holds non-finite values")
    return p


def _faces(func: str, faces, num_vertices: int) -> np.ndarray:
    f = np.asarray(faces)
    check_shape(f.ndim == 2 and f.shape[1] == 3 and len(f) > 0 and np.issubdtype(f.dtype, np.integer), func, "faces",
                "(F, 3) integer with F > 0", f.shape)
    if f.min() < 0 or f.max() >= num_vertices:
        raise AccessoryError(f"{func}: faces index outside the {num_vertices} vertices")
    return f.astype(np.int64)


def closest_surface_points(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, *, k: int = 8,
                           chunk: int = 400_000) -> SurfacePoints:
    """Exact closest points on a triangle surface (scipy KD-trees of the triangles' centroids, then exact
    point-triangle projection, :func:`rig.geometry.closest_points_on_triangles`).

    The triangles are grouped by their radius (largest centroid-to-corner distance: a few large triangles
    would loosen the bound for all), with one KD-tree per group. In a group, the ``k`` triangles with the
    nearest centroids are tested first; any other is at least ``d_k - r`` away (``d_k``: the k-th centroid
    distance, ``r``: the group's largest radius), so points whose best distance exceeds that bound are
    searched again with ``4 k`` triangles, until none is left. The result equals the brute-force minimum
    over all triangles.

    Args:
        points: ``(N, 3)`` mm.
        vertices: ``(V, 3)`` mm; faces: ``(F, 3)`` int, the surface (e.g. :func:`outer_skin_faces`).
        k: triangles tested per point and group in the first pass; chunk: points x triangles tested at once.

    Returns:
        :class:`SurfacePoints` (``face`` indexes ``faces``).
    """
    func = "closest_surface_points"
    p = _points(func, "points", points)
    v = _points(func, "vertices", vertices)
    f = _faces(func, faces, len(v))
    tri = v[f]  # (F, 3, 3)
    centroids = tri.mean(1)
    radius = np.linalg.norm(tri - centroids[:, None], axis=-1).max(1)
    group = np.searchsorted(np.array([4.0, 8.0, 16.0]) * max(float(np.median(radius)), 1e-9) / 3.0, radius)
    best = np.full(len(p), np.inf)
    face = np.zeros(len(p), np.int64)
    closest = np.zeros_like(p)
    for g in np.unique(group):
        ids = np.flatnonzero(group == g)
        tree, reach = cKDTree(centroids[ids]), float(radius[ids].max())
        todo, kk = np.arange(len(p)), min(max(int(k), 1), len(ids))
        while todo.size:
            unsure = []
            step = max(1, chunk // kk)
            for s in range(0, len(todo), step):
                rows = todo[s:s + step]
                dk, nn = tree.query(p[rows], k=kk)
                dk, nn = dk.reshape(len(rows), kk), ids[nn.reshape(len(rows), kk)]
                t = tri[nn]  # (n, k, 3, 3)
                q = closest_points_on_triangles(p[rows, None], t[..., 0, :], t[..., 1, :], t[..., 2, :])
                d = np.linalg.norm(q - p[rows, None], axis=-1)
                j = d.argmin(1)
                i = np.arange(len(rows))
                better = d[i, j] < best[rows]
                best[rows[better]] = d[i, j][better]
                face[rows[better]] = nn[i, j][better]
                closest[rows[better]] = q[i, j][better]
                if kk < len(ids):
                    unsure.append(rows[dk[:, -1] - reach < best[rows]])
            todo = np.concatenate(unsure) if unsure else np.zeros(0, np.int64)
            kk = min(4 * kk, len(ids))
    t = tri[face]
    bary = np.clip(barycentric(closest, t[:, 0], t[:, 1], t[:, 2]), 0.0, 1.0)
    bary /= bary.sum(1, keepdims=True)
    return SurfacePoints(face, bary, closest, best)


def surface_values(values: np.ndarray, faces: np.ndarray, anchors: SurfacePoints) -> np.ndarray:
    """Per-vertex values interpolated at surface points: ``sum_c bary_c * values[..., faces[face, c], :]``.

    Args:
        values: ``(..., V, C)`` per-vertex values (weights ``(V, J)``, offsets ``(E, V, 3)``).
        faces: ``(F, 3)`` the surface ``anchors`` refer to.

    Returns:
        ``(..., N, C)``.
    """
    corners = np.asarray(faces)[anchors.face]  # (N, 3)
    return np.einsum("nc,...ncd->...nd", anchors.barycentric, np.asarray(values)[..., corners, :])


def contact_attenuation(distance: np.ndarray, falloff_mm: float) -> np.ndarray:
    """How much of the skin's expression offset a point at ``distance`` from the skin follows.

    ``1`` up to ``falloff_mm / 2``, then a smoothstep down to ``0`` at ``falloff_mm`` (C1: no kink where a
    surface crosses either distance); ``falloff_mm = 0`` gives 0 everywhere.

    Args:
        distance: ``(N,)`` mm (non-negative). falloff_mm: mm.

    Returns:
        ``(N,)`` in [0, 1].

    Example:
        >>> contact_attenuation(np.array([0.0, 5.0, 7.5, 10.0, 12.0]), 10.0)
        array([1. , 1. , 0.5, 0. , 0. ])
    """
    d = np.asarray(distance, float)
    if falloff_mm <= 0:
        return np.zeros_like(d)
    t = np.clip((d - 0.5 * falloff_mm) / (0.5 * falloff_mm), 0.0, 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


def smooth_over_points(points: np.ndarray, values: np.ndarray, sigma_mm: float) -> np.ndarray:
    """Gaussian-kernel average of per-point values over the points' 3D neighbourhood.

    ``out_i = sum_j g_ij values_j / sum_j g_ij`` with ``g_ij = exp(-|x_i - x_j|^2 / (2 sigma^2))`` over the
    neighbours within ``3 sigma`` (a sparse KD-tree distance matrix). ``sigma_mm = 0`` returns the values;
    ``inf`` their plain mean for every point. Convex combinations: weight rows that sum to 1 still do.

    Args:
        points: ``(N, 3)`` mm; values: ``(N, C)``; sigma_mm: the kernel's sigma, mm.

    Returns:
        ``(N, C)``.
    """
    x = np.asarray(points, float)
    vals = np.asarray(values, float)
    if sigma_mm == 0 or len(x) == 1:
        return vals.copy()
    if math.isinf(sigma_mm):
        return np.broadcast_to(vals.mean(0), vals.shape).copy()
    tree = cKDTree(x)
    pairs = tree.sparse_distance_matrix(tree, 3.0 * sigma_mm, output_type="coo_matrix")
    off = pairs.row != pairs.col  # scipy stores the diagonal or not (distance 0): add it once, ourselves
    g = sp.coo_matrix((np.exp(-0.5 * (pairs.data[off] / sigma_mm) ** 2), (pairs.row[off], pairs.col[off])),
                      shape=(len(x), len(x))) + sp.identity(len(x), format="coo")
    g = g.tocsr()
    return (g @ vals) / np.asarray(g.sum(1))


def keep_largest(weights: np.ndarray, max_influences: int | None) -> np.ndarray:
    """At most ``max_influences`` non-zero weights per row, continuously: each row minus its
    ``(max_influences + 1)``-th largest value, clipped at 0 and renormalised to sum 1.

    Hard pruning (keep the 4 largest) jumps where the 4th and 5th largest weights of neighbouring
    vertices swap, which tears a smoothed accessory apart under a pose; subtracting the first dropped
    value makes the kept weights go to zero where they would be dropped. Rows with at most
    ``max_influences`` non-zero weights are unchanged.

    Args:
        weights: ``(N, J)`` non-negative, rows summing to 1. max_influences: None keeps every weight.

    Returns:
        ``(N, J)`` rows summing to 1.

    Example:
        >>> keep_largest(np.array([[0.4, 0.3, 0.2, 0.1]]), 2)
        array([[0.66666667, 0.33333333, 0.        , 0.        ]])
    """
    w = np.where(weights > 1e-12, weights, 0.0)
    if max_influences is not None and w.shape[1] > max_influences:
        threshold = -np.partition(-w, max_influences, axis=1)[:, max_influences:max_influences + 1]
        reduced = np.clip(w - threshold, 0.0, None)
        # A tie among the largest values (all equal to the threshold) leaves nothing: keep the hard top-k.
        tie = reduced.sum(1) <= 1e-12
        if tie.any():
            drop = np.argsort(-w[tie], axis=1, kind="stable")[:, max_influences:]
            hard = w[tie].copy()
            np.put_along_axis(hard, drop, 0.0, axis=1)
            reduced[tie] = hard
        w = reduced
    return w / w.sum(1, keepdims=True)


def joint_motion_distance(parents: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """How differently two joints can move: ``(J, J)`` mm, the sum of :func:`channel_reach` over the joints on
    the tree path between them (their common ancestor excluded).

    A joint's skinning transform is its parent's times its own channel transform, so two joints differ only
    by the channels on the path between them: a joint without channels moves exactly as its parent
    (distance 0), ``left_crown_outer`` (translations of +-1 mm) nearly as ``crown``, and ``crown`` (+-40 mm)
    quite unlike ``cranium``.

    Args:
        parents: ``(J,)`` parent of each joint, ``-1`` for a root. reach: ``(J,)`` mm per joint.

    Returns:
        ``(J, J)`` symmetric, zero on the diagonal.
    """
    parents = np.asarray(parents)
    n = len(parents)
    chains = []
    for j in range(n):
        chain, k = [], j
        while k >= 0:
            chain.append(k)
            k = parents[k]
        chains.append(chain)
    up = [np.concatenate([[0.0], np.cumsum(np.asarray(reach, float)[c])]) for c in chains]  # reach below each
    out = np.zeros((n, n))
    for a in range(n):
        ancestors_a = {k: i for i, k in enumerate(chains[a])}
        for b in range(a + 1, n):
            ib = next(i for i, k in enumerate(chains[b]) if k in ancestors_a)  # the common ancestor on b's chain
            ia = ancestors_a[chains[b][ib]]
            out[a, b] = out[b, a] = up[a][ia] + up[b][ib]
    return out


def channel_reach(num_joints: int, lever_mm: float = 100.0) -> np.ndarray:
    """``(J,)`` mm: how far each joint's own channels can move a point ``lever_mm`` from it, summed over its
    channels at their limits (a rotation's angle in radians or a scale's change times the lever, a
    translation as it is; :data:`rig.parameters.CHANNELS`)."""
    from rig.parameters import CHANNELS

    reach = np.zeros(num_joints)
    for c in CHANNELS:
        span = max(abs(c.low - (1.0 if c.is_scale else 0.0)), abs(c.high - (1.0 if c.is_scale else 0.0)))
        reach[c.joint] += span * (math.pi / 180.0 * lever_mm if c.unit == "deg" else
                                  lever_mm if c.unit == "factor" else 1.0)
    return reach


def reduce_influences(weights: np.ndarray, max_influences: int, joint_distance: np.ndarray,
                      scale_mm: float = 5.0, floor: float = 0.05) -> np.ndarray:
    """At most ``max_influences`` non-zero weights per row, moving the extra weight to the kept joints that
    move most alike, continuously.

    With ``t`` the row's ``(max_influences + 1)``-th largest weight, each joint keeps ``e_j = max(w_j - t, 0)``
    (so at most ``max_influences`` keep anything) and gives up ``r_j = min(w_j, t)``, which is shared among
    the kept joints ``k`` in proportion to ``e_k / (e_k + t) * exp(-D[j, k] / scale_mm) + floor * e_k / sum(e)``
    (``D``: :func:`joint_motion_distance`; the floor keeps a barely kept joint from taking everything). So the weight of a dropped ``crown`` goes to a kept ``left_crown_outer``
    (its child, +-1 mm of its own) rather than to ``cranium`` (+-40 mm apart): renormalising the kept
    weights instead (:func:`keep_largest`) moves a cap's side 7 mm off under a 30 mm crown edit. Every step
    is continuous in the weights (a joint about to be dropped receives nothing), so neighbouring vertices
    do not tear apart where two weights change order, as they do with hard pruning. Rows with at most
    ``max_influences`` weights are unchanged.

    Args:
        weights: ``(N, J)`` non-negative, rows summing to 1. max_influences: at least 1.
        joint_distance: ``(J, J)`` mm. scale_mm: how sharply the nearest kept joint is preferred.
        floor: the part shared in proportion to the kept weights (against jumps).

    Returns:
        ``(N, J)`` rows summing to 1, at most ``max_influences`` non-zero.

    Example:
        >>> d = np.array([[0.0, 40.0, 1.0], [40.0, 0.0, 41.0], [1.0, 41.0, 0.0]])
        >>> reduce_influences(np.array([[0.3, 0.5, 0.2]]), 2, d).round(3)   # joint 2 goes mostly to joint 0
        array([[0.461, 0.539, 0.   ]])
    """
    w = np.where(weights > 1e-12, weights, 0.0)
    if w.shape[1] <= max_influences:
        return w / w.sum(1, keepdims=True)
    t = -np.partition(-w, max_influences, axis=1)[:, max_influences:max_influences + 1]  # (N, 1)
    kept = np.clip(w - t, 0.0, None)
    given = np.minimum(w, t)
    pull = kept / np.where(kept + t > 0, kept + t, 1.0)  # (N, J): 0 for a dropped joint, -> 1 for a strong one
    affinity = np.exp(-np.asarray(joint_distance, float) / scale_mm)  # (J, J)
    share = pull[:, None, :] * affinity[None]  # (N, j, k)
    # A floor shared in proportion to the kept weights: where no kept joint is near, nor one barely kept
    # may take everything (the share must not jump when a joint's kept weight leaves 0).
    share = share + floor * (kept / np.where(kept.sum(1, keepdims=True) > 0, kept.sum(1, keepdims=True), 1.0))[:, None]
    share = share / share.sum(2, keepdims=True)
    out = kept + np.einsum("nj,njk->nk", given, share)
    return out / out.sum(1, keepdims=True)


def transfer_skinning(head_vertices: np.ndarray, faces: np.ndarray, head_weights: np.ndarray,
                      head_morph_targets: np.ndarray | None, accessory_vertices: np.ndarray, *,
                      falloff_mm: float = DEFAULT_FALLOFF_MM, smoothing_mm: float = DEFAULT_SMOOTHING_MM,
                      max_influences: int | None = 4, joint_distance: np.ndarray | None = None) -> AccessorySkinning:
    """Skinning weights and expression offsets for an accessory, from the closest point of the head.

    Args:
        head_vertices: ``(V, 3)`` the head in its bind pose (the template), mm.
        faces: ``(F, 3)`` the surface the accessory rests on (e.g. :func:`outer_skin_faces`), into
            ``head_vertices``.
        head_weights: ``(V, J)`` the head's skinning weights (rows summing to 1), e.g. a fit's.
        head_morph_targets: ``(E, V, 3)`` the expression shapes' offsets at coefficient 1, mm
            (:func:`rig.expressions.morph_targets`), or None (no expressions: ``E = 0``).
        accessory_vertices: ``(N, 3)`` the accessory placed on the head's bind pose, mm.
        falloff_mm: contact falloff of the expression offsets (:func:`contact_attenuation`), mm.
        smoothing_mm: sigma of the smoothing over the accessory (:func:`smooth_over_points`), mm;
            0: none, ``inf``: one set of weights and offsets for the whole accessory.
        max_influences: non-zero weights kept per vertex; None keeps all.
        joint_distance: ``(J, J)`` mm, how differently the joints move (:func:`joint_motion_distance`): the
            extra weights go to the kept joints that move most alike (:func:`reduce_influences`, what jnr
            uses); None: the largest are kept and renormalised, continuously (:func:`keep_largest`).

    Returns:
        :class:`AccessorySkinning`.

    Raises:
        AccessoryError (an InputError): wrong shapes, non-finite values, negative falloff or smoothing.
    """
    func = "transfer_skinning"
    v = _points(func, "head_vertices", head_vertices)
    f = _faces(func, faces, len(v))
    w = np.asarray(head_weights, float)
    check_shape(w.ndim == 2 and w.shape[0] == len(v), func, "head_weights", f"({len(v)}, J)", w.shape)
    if head_morph_targets is None:
        m = np.zeros((0, len(v), 3))
    else:
        m = np.asarray(head_morph_targets, float)
        check_shape(m.ndim == 3 and m.shape[1:] == (len(v), 3), func, "head_morph_targets", f"(E, {len(v)}, 3)",
                    m.shape)
    x = _points(func, "accessory_vertices", accessory_vertices)
    for name, value in (("falloff_mm", falloff_mm), ("smoothing_mm", smoothing_mm)):
        if not (value >= 0):  # also NaN
            raise AccessoryError(f"{func}: {name} must be >= 0 mm, got {value}")
    if max_influences is not None and max_influences < 1:
        raise AccessoryError(f"{func}: max_influences must be >= 1 or None, got {max_influences}")

    anchors = closest_surface_points(x, v, f)
    weights = surface_values(w, f, anchors)  # (N, J)
    attenuation = contact_attenuation(anchors.distance, falloff_mm)
    offsets = surface_values(m, f, anchors) * attenuation[:, None]  # (E, N, 3)
    if smoothing_mm > 0:
        weights = smooth_over_points(x, weights, smoothing_mm)
        flat = offsets.transpose(1, 0, 2).reshape(len(x), -1)
        offsets = smooth_over_points(x, flat, smoothing_mm).reshape(len(x), -1, 3).transpose(1, 0, 2)
    if joint_distance is not None and max_influences is not None:
        d = np.asarray(joint_distance)
        check_shape(d.shape == (w.shape[1], w.shape[1]), func, "joint_distance", f"({w.shape[1]}, {w.shape[1]})",
                    d.shape)
        weights = reduce_influences(weights, max_influences, d)
    else:
        weights = keep_largest(weights, max_influences)
    return AccessorySkinning(weights=weights, morph_targets=np.ascontiguousarray(offsets),
                             distance=anchors.distance, anchors=anchors, falloff_mm=float(falloff_mm),
                             smoothing_mm=float(smoothing_mm))


def rigid_attachment(skinning: AccessorySkinning, joint: int) -> AccessorySkinning:
    """The naive alternative to the transfer: every vertex bound to one joint with weight 1 (parenting the
    accessory to the head joint in a DCC tool), no expression offsets; the anchors are kept for comparisons.

    Args:
        skinning: a transfer (for its shapes and anchors). joint: the joint index (e.g. ``skull_root``).
    """
    n, j = skinning.weights.shape
    if not 0 <= joint < j:
        raise AccessoryError(f"rigid_attachment: joint must be in [0, {j}), got {joint}")
    weights = np.zeros((n, j))
    weights[:, joint] = 1.0
    return AccessorySkinning(weights=weights, morph_targets=np.zeros_like(skinning.morph_targets),
                             distance=skinning.distance, anchors=skinning.anchors, falloff_mm=0.0,
                             smoothing_mm=math.inf)


def pose_accessory(rest_vertices: torch.Tensor | np.ndarray, skinning: AccessorySkinning,
                   skinning_transforms: torch.Tensor, coefficients: torch.Tensor | None = None) -> torch.Tensor:
    """Pose an accessory as the head is posed: expression offsets, then linear blend skinning (JNR eq. 2).

    Args:
        rest_vertices: ``(N, 3)`` the accessory in the bind pose, mm.
        skinning: its :class:`AccessorySkinning`.
        skinning_transforms: ``(B, J, 4, 4)`` the rig's skinning transforms (``JointRig.joint_transforms(theta)[1]``
            or :func:`rig.lbs.joint_world_transforms`).
        coefficients: ``(B, E)`` expression coefficients (ARKit order), or None.

    Returns:
        ``(B, N, 3)`` posed vertices, mm, in the transforms' dtype.

    Example:
        >>> _, transforms = rig.joint_transforms(theta)             # theta (B, 105)
        >>> pose_accessory(glasses, transfer, transforms, c)        # (B, N, 3)
    """
    func = "pose_accessory"
    dtype = skinning_transforms.dtype
    x = torch.as_tensor(np.asarray(rest_vertices, float) if isinstance(rest_vertices, np.ndarray) else rest_vertices,
                        dtype=dtype)
    n, j = skinning.weights.shape
    check_shape(x.shape == (n, 3), func, "rest_vertices", f"({n}, 3)", tuple(x.shape))
    check_shape(skinning_transforms.dim() == 4 and skinning_transforms.shape[1:] == (j, 4, 4), func,
                "skinning_transforms", f"(B, {j}, 4, 4)", tuple(skinning_transforms.shape))
    batch = skinning_transforms.shape[0]
    rest = x.expand(batch, n, 3)
    if coefficients is not None:
        e = skinning.morph_targets.shape[0]
        check_shape(coefficients.dim() == 2 and coefficients.shape == (batch, e), func, "coefficients",
                    f"({batch}, {e})", tuple(coefficients.shape))
        offsets = torch.as_tensor(skinning.morph_targets, dtype=dtype)
        rest = rest + torch.einsum("be,enk->bnk", coefficients.to(dtype), offsets)
    weights = torch.as_tensor(skinning.weights, dtype=dtype)
    return skin_vertices_shared_weights(rest, weights, skinning_transforms)


def signed_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Signed distance of points to an open surface, mm: positive outside (where the normals point).

    The sign is that of ``(p - q) . n(q)`` with ``q`` the closest surface point and ``n(q)`` the
    barycentric interpolation of the area-weighted vertex normals there (smooth across edges, where a
    single face normal can give the wrong sign); the surface need not be watertight, so use it where the
    points sit over the surface (an accessory on a head), not around an open border.

    Args:
        points: ``(N, 3)``; vertices: ``(V, 3)``; faces: ``(F, 3)`` (CCW seen from outside), mm.

    Returns:
        ``(N,)`` mm.
    """
    v = np.asarray(vertices, float)
    anchors = closest_surface_points(points, v, faces)
    normals = surface_values(vertex_normals(v, faces), faces, anchors)
    side = np.einsum("nk,nk->n", np.asarray(points, float) - anchors.closest, normals)
    return np.where(side < 0, -anchors.distance, anchors.distance)


def outer_skin_face_ids(asset) -> np.ndarray:
    """``(F',)`` int64 ids of the template faces whose three corners are all in :data:`OUTER_SKIN_REGIONS`.

    Args:
        asset: a :class:`rig.asset.RigAsset`.
    """
    skin = asset.region_mask(*OUTER_SKIN_REGIONS)
    return np.flatnonzero(skin[asset.faces].all(1))


def outer_skin_faces(asset) -> np.ndarray:
    """``(F', 3)`` the template faces of :func:`outer_skin_face_ids`, into the asset's vertices: the surface
    accessories rest on."""
    return asset.faces[outer_skin_face_ids(asset)]
