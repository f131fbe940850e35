"""What ``jnr accessory`` writes (:data:`pipeline.head.folders.ACCESSORY_FOLDER`), atomically."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.accessory.inputs import (
    EXAMPLE_COLORS,
    OTHER_COLOR,
    AccessoryInputError,
    accessory_path,
    read_accessory,
    read_fit_head,
)
from pipeline.accessory.transfer import AccessoryOnFit, accessory_on_fit
from pipeline.files import check_output, staged_folder
from pipeline.head.params import PARAMS_FILE
from pipeline.head.skinned import write_skinned_head
from pipeline.signals import run_interruptibly
from render.preview import render_preview, save_png
from rig.accessory import (
    DEFAULT_FALLOFF_MM,
    DEFAULT_SMOOTHING_MM,
    outer_skin_face_ids,
)
from rig.asset import load_asset
from rig.expressions import EXPRESSION_NAMES
from rig.io.gltf import GltfAttachment
from rig.io.mesh import RIG_SPACE_COMMENT, export_mesh


def preview_image(
    head_vertices: np.ndarray,
    accessory_vertices: np.ndarray,
    accessory_faces: np.ndarray,
    color: tuple[float, float, float],
    *,
    spp: int = 16,
    size: tuple[int, int] = (360, 440),
) -> np.ndarray:
    """``(H, 2W, 3)`` uint8: the head (grey) with the accessory (``color``, linear RGB), front and side
    (:func:`render.preview.render_preview`)."""
    asset = load_asset()
    vertices = np.concatenate([head_vertices, accessory_vertices])
    faces = np.concatenate([asset.faces, np.asarray(accessory_faces) + len(head_vertices)])
    colors = np.concatenate([np.full((len(head_vertices), 3), 0.55), np.tile(color, (len(accessory_vertices), 1))])
    # each render in a thread the main thread waits on: Ctrl-C and SIGTERM are acted on during a long render
    tiles = [
        run_interruptibly(
            render_preview,
            vertices,
            faces,
            colors=colors,
            view=view,
            size=size,
            spp=spp,
            distance=750.0,
            target=(0.0, -5.0, 15.0),
        )
        for view in ("front", "side")
    ]
    return np.concatenate(tiles, 1)


def report_payload(result: AccessoryOnFit, command: str | None = None) -> dict:
    """``report.json``: the accessory, the settings and its signed distance to the fitted head."""
    sd = result.signed_distance
    return {
        "command": command,
        "fit": str(result.head.folder / PARAMS_FILE),
        "accessory": {
            "name": result.accessory.name,
            "path": str(result.accessory.path),
            "vertices": len(result.accessory.vertices),
            "faces": len(result.accessory.faces),
        },
        "falloff_mm": result.skinning.falloff_mm,
        "smoothing_mm": result.skinning.smoothing_mm,
        "bind_distance_to_template_mm": {
            "min": float(result.skinning.distance.min()),
            "median": float(np.median(result.skinning.distance)),
        },
        "signed_distance_to_fit_mm": {
            "min": float(sd.min()),
            "median": float(np.median(sd)),
            "inside_vertices": int((sd < 0).sum()),
        },
        "units": "millimetres, rig space",
    }


def write_accessory_outputs(
    out: str | Path,
    result: AccessoryOnFit,
    *,
    force: bool = False,
    spp: int = 16,
    inputs: tuple = (),
    command: str | None = None,
) -> Path:
    """Write the output folder (module docstring) atomically.

    Raises:
        pipeline.files.OutputError: ``out`` is refused (exists without ``force``, not jnr's, an input) or
            cannot be written.
    """
    asset = load_asset()
    out = Path(out)
    accessory, skinning = result.accessory, result.skinning
    color = EXAMPLE_COLORS.get(accessory.name, OTHER_COLOR)
    with staged_folder(out, force, inputs=inputs, marker={"command": command}) as tmp:
        export_mesh(
            tmp / "accessory.obj",
            result.posed,
            accessory.faces,
            comment=f"accessory {accessory.name} posed on a fitted head; {RIG_SPACE_COMMENT}",
        )
        attachment = GltfAttachment(
            name=accessory.name
            if accessory.name not in asset.joint_names + ("mesh",)
            else f"accessory_{accessory.name}",
            vertices=accessory.vertices,
            faces=accessory.faces,
            weights=skinning.weights,
            morph_targets=skinning.morph_targets,
            color=color,
        )
        write_skinned_head(
            tmp / "head_with_accessory.glb",
            asset,
            result.head.weights,
            result.head.tau,
            result.head.expressions,
            attachments=[attachment],
            base_color_texture=result.head.texture,  # a photo fit's texture.png (read_fit_head checked it)
        )
        np.savez_compressed(
            tmp / "accessory_weights.npz",
            weights=skinning.weights,
            morph_targets=skinning.morph_targets,
            distance=skinning.distance,
            anchor_face=outer_skin_face_ids(asset)[skinning.anchors.face],
            anchor_barycentric=skinning.anchors.barycentric,
            rest_vertices=accessory.vertices,
            faces=accessory.faces,
            joint_names=np.array(asset.joint_names),
            expression_names=np.array(EXPRESSION_NAMES),
            falloff_mm=np.float64(skinning.falloff_mm),
            smoothing_mm=np.float64(skinning.smoothing_mm),
        )
        save_png(
            preview_image(result.head.vertices, result.posed, accessory.faces, color, spp=spp), tmp / "preview.png"
        )
        (tmp / "report.json").write_text(json.dumps(report_payload(result, command), indent=2) + "\n")
    return out


def run_accessory(
    fit_dir: str | Path,
    accessory: str | Path,
    out: str | Path,
    *,
    force: bool = False,
    falloff_mm: float = DEFAULT_FALLOFF_MM,
    smoothing_mm: float = DEFAULT_SMOOTHING_MM,
    spp: int = 16,
    command: str | None = None,
) -> AccessoryOnFit:
    """What ``jnr accessory`` does: check the output, read the fit and the accessory, transfer, pose, write.

    Raises:
        pipeline.files.OutputError: ``out`` is refused; AccessoryInputError: a bad fit folder or accessory,
            ``falloff_mm`` or ``smoothing_mm`` negative or not finite (``smoothing_mm`` may be ``inf``).
    """
    import math

    inputs = (fit_dir, accessory_path(accessory))
    check_output(out, force=force, inputs=inputs, kind="folder")
    if not (math.isfinite(falloff_mm) and falloff_mm >= 0):
        raise AccessoryInputError(f"--falloff must be a finite number of mm >= 0, got {falloff_mm}")
    if not smoothing_mm >= 0:
        raise AccessoryInputError(f"--smoothing must be a number of mm >= 0 (or inf), got {smoothing_mm}")
    head = read_fit_head(fit_dir)
    item = read_accessory(accessory)
    result = accessory_on_fit(head, item, falloff_mm=falloff_mm, smoothing_mm=smoothing_mm)
    write_accessory_outputs(out, result, force=force, spp=spp, inputs=inputs, command=command)
    return result
