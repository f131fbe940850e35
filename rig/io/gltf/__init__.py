"""Writing the skinned rig as glTF 2.0 (``.glb`` / ``.gltf``) through ``pygltflib``.

* :func:`export_skinned_gltf` writes the mesh, the joint hierarchy and the skinning weights as a
  glTF 2.0 file (``.glb`` binary or ``.gltf`` JSON with an embedded data-URI buffer).
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

Modules: :mod:`~rig.io.gltf.export` (the head and its attachments), :mod:`~rig.io.gltf.animation`,
:mod:`~rig.io.gltf.skin` (joints and weights), :mod:`~rig.io.gltf.encoding` (units, limits, node transforms,
the buffer). jnr never reads its glTF files back; the tests do (``tests/support/gltf_reader.py``).
"""

from rig.io.gltf.animation import GltfAnimation
from rig.io.gltf.encoding import GLTF_UNITS_NOTE, MAX_DROPPED_WEIGHT, MAX_INFLUENCES, MM_TO_M, WEIGHT_EPS
from rig.io.gltf.export import GltfAttachment, export_skinned_gltf

__all__ = [
    "GLTF_UNITS_NOTE",
    "GltfAnimation",
    "GltfAttachment",
    "MAX_DROPPED_WEIGHT",
    "MAX_INFLUENCES",
    "MM_TO_M",
    "WEIGHT_EPS",
    "export_skinned_gltf",
]
