"""An accessory on a fitted head (``jnr accessory FIT_DIR ACCESSORY.obj --out DIR``): skinning weights and
expression offsets transferred from the fit's own head (:mod:`rig.accessory`, JNR section 5.3), the
accessory posed on the fit, and the head with the accessory as one skinned glTF.

The accessory is a triangle mesh (Wavefront OBJ) placed on the jnr template in its bind pose (rig space,
millimetres; ``jnr rig export --format obj`` writes the template to model it on), or the name of a
shipped example: ``glasses`` or ``cap`` (``pipeline/assets/accessories/``, made by
:mod:`pipeline.synthetic.accessories`). ``FIT_DIR`` is the output folder of ``jnr fit`` or
``jnr fit-scan`` (its ``params.json``); the transfer uses that fit's skinning weights (its latent Z), so
the accessory follows the fitted identity's joints and expressions.

The output folder (written to a temporary folder beside it, then moved into place):

==============================  ==================================================================
file                            contents
==============================  ==================================================================
``accessory.obj``               the accessory posed on the fitted head (rig space, mm; the header
                                says so), overlays the fit's head (``jnr rig export --params``)
``head_with_accessory.glb``     skinned glTF 2.0 (metres): the fitted head (as ``jnr rig export
                                --format gltf --params``) and the accessory as a second mesh node on
                                the same skin, its morph targets under the same 52 ARKit names
``accessory_weights.npz``       ``weights (N, 52)``, ``morph_targets (E, N, 3)`` mm, ``distance (N,)``
                                mm, ``anchor_face (N,)`` (template face ids), ``anchor_barycentric
                                (N, 3)``, ``rest_vertices (N, 3)`` mm, ``faces (F, 3)``, ``joint_names``,
                                ``expression_names``, ``falloff_mm``, ``smoothing_mm``
``preview.png``                 the fitted head (grey) with the accessory (coloured), front and side
``report.json``                 the accessory's size, the settings, and how far it lies outside the
                                fitted head's skin (signed distance, mm; negative: inside)
==============================  ==================================================================
"""

from __future__ import annotations

from pipeline.accessory.follow import FOLLOW_CASES, follow_figure, follow_figures, follow_summary
from pipeline.accessory.inputs import (
    ACCESSORY_DIR,
    EXAMPLE_NAMES,
    Accessory,
    AccessoryInputError,
    accessory_path,
    read_accessory,
    read_fit_head,
)
from pipeline.accessory.outputs import preview_image, run_accessory, write_accessory_outputs
from pipeline.accessory.transfer import AccessoryOnFit, accessory_on_fit, joint_distance

__all__ = [
    "ACCESSORY_DIR",
    "Accessory",
    "AccessoryInputError",
    "AccessoryOnFit",
    "EXAMPLE_NAMES",
    "FOLLOW_CASES",
    "accessory_on_fit",
    "accessory_path",
    "follow_figure",
    "follow_figures",
    "follow_summary",
    "joint_distance",
    "preview_image",
    "read_accessory",
    "read_fit_head",
    "run_accessory",
    "write_accessory_outputs",
]
