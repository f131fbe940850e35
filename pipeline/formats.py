"""The mesh formats jnr writes (no heavy imports: the command line's parsers read them)."""

MESH_FORMATS = {"obj": ".obj", "ply": ".ply", "gltf": ".glb"}
"""Each mesh format and the suffix it is written with by default."""
MESH_SUFFIXES = {"obj": (".obj",), "ply": (".ply",), "gltf": (".glb", ".gltf")}
"""The suffixes each mesh format may be written with."""
