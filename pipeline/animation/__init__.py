"""Driving a fitted head with ARKit curves (``jnr animate``) and moving one fit's expression onto another
identity (``jnr retarget``, JNR Fig. 7).

Curves files (:func:`read_curves`) come in two CSV layouts:

* **Live Link Face** (Epic's iPhone app): ``Timecode, BlendShapeCount``, then the 52 ARKit names
  capitalised (``EyeBlinkLeft`` ...), then ``HeadYaw, HeadPitch, HeadRoll`` and six eye angles. The timecode
  is ``HH:MM:SS:FF[.sub]`` at the take's frame rate (``fps``, 60 by default, the app's rate); the head
  angles are read as radians (``head_units``), the eye angles are ignored (the ``eyeLook*`` shapes move
  the eyes).
* **Plain**: a header of ARKit names (any subset, any case; missing ones are 0), optionally a ``time``
  column in seconds (else rows are frames at ``fps``, 30 by default) and ``head_yaw``, ``head_pitch``,
  ``head_roll`` in degrees.

Head angles turn the head about the ``skull_root`` joint (the top of the neck, y = -50 mm):
``R = Ry(yaw) @ Rx(pitch) @ Rz(roll)`` in rig space, right-handed: +yaw turns the face towards +X (the
subject's left), +pitch nods it down, +roll tilts the top of the head towards +X; applied after the
fitted ``skull_root`` transform (``tau' = R @ tau``, which keeps it a glTF translation @ rotation @ scale). These
sign conventions are ours; Live Link Face's own are not
documented, so check a take's direction once and negate a column if needed.

The glTF (:func:`animate_fit`) is the fit's skinned head (template bind mesh, the fit's skinning
weights, its joints posed, the 52 ARKit shapes as morph targets, its texture) with one animation: the
morph weights at every row of the curves and, with head angles, the ``skull_root`` rotation.
"""

from __future__ import annotations

from pipeline.animation.keyframes import (
    animate_fit,
    curve_keyframes,
    frame_strip,
    load_fit_head,
    posed_frames,
    render_frames,
    save_gif,
)
from pipeline.animation.retarget import retarget_fit, retarget_params
from pipeline.head.curves import (
    EXAMPLE_CURVES,
    HEAD_COLUMNS,
    HEAD_JOINT,
    Curves,
    CurvesError,
    example_curves,
    head_rotation_matrices,
    read_curves,
    write_curves,
)

__all__ = [
    "Curves",
    "CurvesError",
    "EXAMPLE_CURVES",
    "HEAD_COLUMNS",
    "HEAD_JOINT",
    "animate_fit",
    "curve_keyframes",
    "example_curves",
    "frame_strip",
    "head_rotation_matrices",
    "load_fit_head",
    "posed_frames",
    "read_curves",
    "render_frames",
    "retarget_fit",
    "retarget_params",
    "save_gif",
    "write_curves",
]
