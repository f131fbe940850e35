"""Files of the rig: :mod:`rig.io.atomic` (the one atomic file/folder writer), :mod:`rig.io.mesh` (OBJ,
PLY), :mod:`rig.io.gltf` (skinned glTF/GLB, written) and :mod:`rig.io.params` (the
parameter JSON file)."""
