"""The transfer of a head's skinning onto an accessory (:func:`transfer_skinning`), the rigid alternative
(:func:`rigid_attachment`), posing it with the head (:func:`pose_accessory`), its signed distance to the
skin (:func:`signed_distance`) and the surface it rests on (:func:`outer_skin_faces`). See
:mod:`rig.accessory`; millimetres, rig space.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from rig.accessory.influences import contact_attenuation, keep_largest, reduce_influences, smooth_over_points
from rig.accessory_defaults import DEFAULT_FALLOFF_MM, DEFAULT_SMOOTHING_MM
from rig.errors import InputError, check_faces, check_shape
from rig.geometry import SurfacePoints, closest_surface_points, surface_values, vertex_normals
from rig.lbs import skin_vertices_shared_weights

__all__ = [
    "OUTER_SKIN_REGIONS",
    "AccessoryError",
    "AccessorySkinning",
    "outer_skin_face_ids",
    "outer_skin_faces",
    "pose_accessory",
    "rigid_attachment",
    "signed_distance",
    "transfer_skinning",
]

OUTER_SKIN_REGIONS = ("scalp", "forehead", "brows", "eyelids", "nose", "cheeks", "lips", "chin", "jaw", "ears", "neck")
"""The template regions an accessory rests on: the outer skin, without the eyeballs, the eye pockets behind
them, the mouth bag, teeth and tongue (a glasses rim must not take the eyeball's weights)."""


class AccessoryError(InputError):
    """An accessory that cannot be skinned (wrong shapes, non-finite vertices, nothing to anchor to)."""


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
    return check_faces(func, faces, num_vertices, AccessoryError)


def transfer_skinning(
    head_vertices: np.ndarray,
    faces: np.ndarray,
    head_weights: np.ndarray,
    head_morph_targets: np.ndarray | None,
    accessory_vertices: np.ndarray,
    *,
    falloff_mm: float = DEFAULT_FALLOFF_MM,
    smoothing_mm: float = DEFAULT_SMOOTHING_MM,
    max_influences: int | None = 4,
    joint_distance: np.ndarray | None = None,
) -> AccessorySkinning:
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
        check_shape(
            m.ndim == 3 and m.shape[1:] == (len(v), 3), func, "head_morph_targets", f"(E, {len(v)}, 3)", m.shape
        )
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
        check_shape(
            d.shape == (w.shape[1], w.shape[1]), func, "joint_distance", f"({w.shape[1]}, {w.shape[1]})", d.shape
        )
        weights = reduce_influences(weights, max_influences, d)
    else:
        weights = keep_largest(weights, max_influences)
    return AccessorySkinning(
        weights=weights,
        morph_targets=np.ascontiguousarray(offsets),
        distance=anchors.distance,
        anchors=anchors,
        falloff_mm=float(falloff_mm),
        smoothing_mm=float(smoothing_mm),
    )


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
    return AccessorySkinning(
        weights=weights,
        morph_targets=np.zeros_like(skinning.morph_targets),
        distance=skinning.distance,
        anchors=skinning.anchors,
        falloff_mm=0.0,
        smoothing_mm=math.inf,
    )


def pose_accessory(
    rest_vertices: torch.Tensor | np.ndarray,
    skinning: AccessorySkinning,
    skinning_transforms: torch.Tensor,
    coefficients: torch.Tensor | None = None,
) -> torch.Tensor:
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
        >>> _, transforms = rig.joint_transforms(theta)  # theta (B, 107)  # doctest: +SKIP
        >>> pose_accessory(glasses, transfer, transforms, c)  # (B, N, 3)  # doctest: +SKIP
    """
    func = "pose_accessory"
    dtype = skinning_transforms.dtype
    x = torch.as_tensor(
        np.asarray(rest_vertices, float) if isinstance(rest_vertices, np.ndarray) else rest_vertices, dtype=dtype
    )
    n, j = skinning.weights.shape
    check_shape(x.shape == (n, 3), func, "rest_vertices", f"({n}, 3)", tuple(x.shape))
    check_shape(
        skinning_transforms.dim() == 4 and skinning_transforms.shape[1:] == (j, 4, 4),
        func,
        "skinning_transforms",
        f"(B, {j}, 4, 4)",
        tuple(skinning_transforms.shape),
    )
    batch = skinning_transforms.shape[0]
    rest = x.expand(batch, n, 3)
    if coefficients is not None:
        e = skinning.morph_targets.shape[0]
        check_shape(
            coefficients.dim() == 2 and coefficients.shape == (batch, e),
            func,
            "coefficients",
            f"({batch}, {e})",
            tuple(coefficients.shape),
        )
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
