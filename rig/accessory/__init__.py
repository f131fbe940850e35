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

Modules: :mod:`rig.accessory.transfer` (the transfer, posing, signed distance, the outer skin) and
:mod:`rig.accessory.influences` (falloff, smoothing, the limit of joints per vertex); the closest points
are :func:`rig.geometry.closest_surface_points`, the defaults :mod:`rig.accessory_defaults` (torch-free,
for ``jnr --help``). Every public name is re-exported here.

Pure numpy/scipy/torch; imports nothing of ``pipeline`` or ``render``. Coordinates: millimetres, rig
space (right-handed, +Y up, +Z out of the face, +X the subject's left).
"""

from rig.accessory.influences import (
    channel_reach,
    contact_attenuation,
    joint_motion_distance,
    keep_largest,
    reduce_influences,
    smooth_over_points,
)
from rig.accessory.transfer import (
    OUTER_SKIN_REGIONS,
    AccessoryError,
    AccessorySkinning,
    outer_skin_face_ids,
    outer_skin_faces,
    pose_accessory,
    rigid_attachment,
    signed_distance,
    transfer_skinning,
)
from rig.accessory_defaults import DEFAULT_FALLOFF_MM, DEFAULT_SMOOTHING_MM

__all__ = [
    "DEFAULT_FALLOFF_MM",
    "DEFAULT_SMOOTHING_MM",
    "OUTER_SKIN_REGIONS",
    "AccessoryError",
    "AccessorySkinning",
    "channel_reach",
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
    "transfer_skinning",
]
