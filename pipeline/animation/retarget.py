"""``jnr retarget``: one fit's expression on another fit's identity."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from pipeline.animation.keyframes import load_fit_head
from pipeline.files import check_output, staged_folder
from pipeline.head.folders import RETARGET_FOLDER
from pipeline.head.skinned import write_skinned_head
from render.preview import render_preview, save_png
from rig.asset import load_asset
from rig.expressions import EXPRESSION_NAMES
from rig.io.mesh import export_mesh

log = logging.getLogger("jnr")


def retarget_params(source: dict, target: dict) -> dict:
    """The target fit's ``params.json`` with the source's expression: its 52 ARKit coefficients (the jaw's
    ``jawOpen``, ``jawForward``, ``jawLeft``, ``jawRight`` among them) replace the target's; the target keeps its
    identity (joints, latent Z), camera, pose and light."""
    out = json.loads(json.dumps(target))
    out["expressions"] = dict(source["expressions"])
    return out


def retarget_fit(source_dir: str | Path, target_dir: str | Path, out: str | Path, *, force: bool = False) -> dict:
    """Write ``out/``: the target fit's head with the source fit's expression (:func:`retarget_params`):
    ``mesh.obj``/``mesh.ply`` (mm), ``mesh.glb`` (skinned, the coefficients as morph weights),
    ``params.json`` (a fit parameter file: ``jnr rig edit`` / ``jnr animate`` take it), ``expressions.csv``,
    ``preview.png`` (source, target, retargeted; grey, three-quarter view) and ``report.json``.

    Raises:
        InputError: as :func:`load_fit_head` for either fit; pipeline.files.OutputError: ``out`` refused.
    """
    out = Path(out)
    inputs = (str(source_dir), str(target_dir))
    check_output(out, force=force, inputs=inputs)
    source, target = load_fit_head(source_dir), load_fit_head(target_dir)
    params = retarget_params(source.fit.data, target.fit.data)
    params["retargeted_from"] = {
        "source": str(Path(source_dir)),
        "target": str(Path(target_dir)),
        "what": "the source's 52 ARKit expression coefficients on the target's identity",
    }
    asset = load_asset()
    head = target.with_params(target.model.from_dict(params))
    vertices = head.vertices
    grey = np.full((len(vertices), 3), 0.6)
    pictures = [
        render_preview(v, asset.faces, view="three_quarter", size=(320, 400), colors=grey)
        for v in (source.vertices, target.vertices, vertices)
    ]
    report = {
        "source": str(Path(source_dir)),
        "target": str(Path(target_dir)),
        "expressions": dict(zip(EXPRESSION_NAMES, head.expressions.tolist())),
        "max_vertex_change_mm": float(np.linalg.norm(vertices - target.vertices, axis=1).max()),
        "files": list(RETARGET_FOLDER.names),
    }
    with staged_folder(out, force, inputs=inputs) as tmp:
        export_mesh(tmp / "mesh.obj", vertices, asset.faces, face_uvs=asset.face_uvs)
        export_mesh(tmp / "mesh.ply", vertices, asset.faces)
        write_skinned_head(
            tmp / "mesh.glb", asset, head.weights, head.tau, head.expressions, base_color_texture=target.texture
        )
        (tmp / "params.json").write_text(json.dumps(params, indent=2), encoding="utf-8")
        (tmp / "expressions.csv").write_text(
            ",".join(EXPRESSION_NAMES) + "\n" + ",".join(f"{c:.6f}" for c in head.expressions) + "\n", encoding="utf-8"
        )
        save_png(np.concatenate(pictures, axis=1), tmp / "preview.png")
        (tmp / "report.json").write_text(json.dumps(report, indent=2), encoding="utf-8")
    log.info("retarget: %s's expression on %s written to %s", source_dir, target_dir, out)
    return report
