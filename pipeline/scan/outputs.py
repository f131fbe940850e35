"""What ``jnr fit-scan`` writes, and reading its parameters back.

The output folder (written to a temporary folder beside it, then moved into place, so a failure
leaves nothing half-written):

=====================  ===========================================================================
file                   contents
=====================  ===========================================================================
``mesh.ply``           the fitted head in the input cloud's frame and units (overlays the cloud)
``mesh.obj``           the same, OBJ
``params.json``        joints by name (deg, mm, factor), latent Z, expressions by name, the pose
                       (rig space -> cloud frame, mm), the input's units and frame; also a valid
                       ``jnr rig edit`` parameter file (its ``joints`` key)
``cloud_error.ply``    the input cloud coloured by its distance to the fitted mesh (blue 0 ->
                       red at ``vmax``), with the distance as the float property ``error_mm``
``report.json``        scan-to-mesh distance (median, mean, std, mm), pre-alignment, every loss
                       term per stage, timings, the configuration used
``config.yaml``        the configuration used, every field resolved (``--config`` repeats the fit)
``viewer.html``        a self-contained web page (:mod:`pipeline.viewer`): the fitted head in rig space to
                       orbit, sliders for the joints and the 52 ARKit shapes (skipped with a warning where
                       three.js was not installed by ``make venv``)
=====================  ===========================================================================
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from pipeline.config import CONFIG_FILE, config_to_dict, dump_config
from pipeline.evaluation.metrics import distance_stats
from pipeline.files import json_safe, staged_folder
from pipeline.fitting.state import head_vertices
from pipeline.scan.fit import FitScanConfig, ScanFit
from pipeline.scan.pointcloud import (
    PointCloud,
    error_colors,
    to_rig_frame,
    write_point_cloud_ply,
)
from rig.asset import load_asset
from rig.expressions import EXPRESSION_NAMES, coefficients_from_dict
from rig.model import JointRig
from rig.parameters import params_to_theta, theta_to_params
from rig.skinning.neural import LATENT, load_neural

PARAMS_FORMAT = "jnr-scan-params/1"
OUTPUT_FILES = ("mesh.ply", "mesh.obj", "params.json", "cloud_error.ply", "report.json", CONFIG_FILE, "viewer.html")


def report_distance_stats(distances: np.ndarray) -> dict:
    """``report.json``'s scan-to-mesh entry: :func:`pipeline.evaluation.metrics.distance_stats` (median,
    mean, std, mm) plus the 90th percentile and the fractions within 2 and 5 mm."""
    d = np.asarray(distances, float)
    return {**distance_stats(d).as_dict(""), "p90_mm": float(np.percentile(d, 90)),
            "within_2mm": float((d <= 2).mean()), "within_5mm": float((d <= 5).mean()), "points": len(d)}


def params_payload(fit: ScanFit, cloud: PointCloud, frame: str) -> dict:
    """The ``params.json`` content of a fit."""
    rot = fit.rotation
    head = ({"skinning": "asm", "asm": fit.asm} if fit.asm is not None else
            {"skinning": "jnr", "joints": theta_to_params(torch.as_tensor(fit.theta), include_rest=True),
             "latent_z": [float(x) for x in fit.z]})
    return {
        "format": PARAMS_FORMAT,
        "units": {"rotate": "deg", "translate": "mm", "scale": "factor"},
        **head,
        "expressions": {n: float(c) for n, c in zip(EXPRESSION_NAMES, fit.expressions)},
        "pose": {
            "description": "rig space (mm, +Y up, +Z out of the face) -> the cloud in mm and the rig frame: "
                           "x = scale * R x_rig + t; the input file's frame and units follow from 'input'",
            "rotation_matrix": rot.tolist(),
            "rotation_vector_rad": [float(x) for x in _rotvec(rot)],
            "translation_mm": [float(x) for x in fit.translation],
            "scale": float(fit.scale),
        },
        "input": {"units": cloud.units, "scale_to_mm": cloud.scale_to_mm, "frame": frame},
    }


def _rotvec(rot: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(rot).as_rotvec()


def mesh_from_params(params: dict | str | Path, *, rig: JointRig | None = None, use_neural: bool = True,
                     frame: str = "input") -> np.ndarray:
    """Rebuild the fitted mesh from a ``params.json`` (its dict or path).

    Args:
        frame: ``"input"`` (the input cloud's frame and units, as ``mesh.ply``), ``"cloud"`` (rig frame,
            mm, posed) or ``"rig"`` (rig space, before the pose).

    Returns:
        ``(V, 3)`` vertices.
    """
    if not isinstance(params, dict):
        params = json.loads(Path(params).read_text())
    if params.get("format") != PARAMS_FORMAT:
        raise ValueError(f"not a jnr fit-scan parameter file (format {params.get('format')!r}, "
                         f"expected {PARAMS_FORMAT!r})")
    v = rig_vertices_from_params(params, rig=rig, use_neural=use_neural)
    if frame == "rig":
        return v
    pose = params["pose"]
    v = float(pose["scale"]) * v @ np.asarray(pose["rotation_matrix"]).T + np.asarray(pose["translation_mm"])
    if frame == "cloud":
        return v
    inp = params["input"]
    return to_rig_frame(v, inp["frame"]) / float(inp["scale_to_mm"])


def rig_vertices_from_params(params: dict, *, rig: JointRig | None = None, use_neural: bool = True) -> np.ndarray:
    """``(V, 3)`` float64 rig-space head (mm) of a fit's parameters: its ``joints`` (by name), ``expressions``
    (by name) and ``latent_z`` (50 values), as written by ``jnr fit-scan`` and ``jnr fit``; or, for an ASM
    fit (``"skinning": "asm"``), its ``asm`` bones (:func:`rig.skinning.asm.asm_params_from_dict`) and
    ``expressions``.

    Raises:
        ValueError: missing keys, unknown names, values outside limits, a latent of the wrong length.
    """
    if params.get("skinning") == "asm":
        return _asm_vertices_from_params(params, rig)
    missing = [k for k in ("joints", "expressions", "latent_z") if k not in params]
    if missing:
        raise ValueError(f"parameter file lacks {missing}")
    rig = rig or JointRig()
    theta = params_to_theta(params["joints"], dtype=torch.float64)
    c = coefficients_from_dict(params["expressions"], dtype=torch.float64)
    z = np.asarray(params["latent_z"], np.float64)
    if z.shape != (LATENT,):
        raise ValueError(f"latent_z must have {LATENT} values, got {z.size}")
    return head_vertices(rig, load_neural(rig)[0] if use_neural else None, theta.numpy(), z, c.numpy())


def _asm_vertices_from_params(params: dict, rig: JointRig | None) -> np.ndarray:
    from rig.expressions import ExpressionModel
    from rig.skinning.asm import AdaptiveSkinning, asm_params_from_dict

    missing = [k for k in ("asm", "expressions") if k not in params]
    if missing:
        raise ValueError(f"parameter file lacks {missing}")
    rig = rig if rig is not None and rig.template.dtype == torch.float64 else JointRig(dtype=torch.float64)
    block = params["asm"]
    model = AdaptiveSkinning(rig, components=int(block.get("components", 2)) if isinstance(block, dict) else 2)
    p = asm_params_from_dict(block, model)
    c = coefficients_from_dict(params["expressions"], dtype=torch.float64)
    with torch.no_grad():
        rest = ExpressionModel(rig.asset, dtype=torch.float64).vertices(c[None])[0]
        return model(p, vertices=rest).vertices[0].numpy()


def head_arrays_from_params(params: dict, *, rig: JointRig | None = None
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What a fit's head is made of, from its ``params.json``: ``(posed (V, 3) mm, rest (V, 3) mm with the
    expressions applied, skinning weights (V, J) of its latent Z, joint channel transforms (J, 4, 4),
    expression coefficients (E,))``; skinning ``rest`` with ``weights`` and the transforms gives ``posed``
    (as the skinned glTF does).

    Raises:
        ValueError: as :func:`rig_vertices_from_params`.
    """
    from rig.expressions import ExpressionModel

    rig = rig if rig is not None and rig.template.dtype == torch.float64 else JointRig(dtype=torch.float64)
    posed = rig_vertices_from_params(params, rig=rig)
    theta = params_to_theta(params["joints"], dtype=torch.float64)
    c = coefficients_from_dict(params["expressions"], dtype=torch.float64)
    z = torch.as_tensor(np.asarray(params["latent_z"], np.float64))
    with torch.no_grad():
        rest = ExpressionModel(rig.asset, dtype=torch.float64).vertices(c[None])[0].numpy()
        weights = load_neural(rig)[0](z[None])[0].numpy()
        tau = rig.channel_transforms(theta[None])[0].numpy()
    return posed, rest, weights, tau, c.numpy()


def write_scan_outputs(out_dir: str | Path, cloud: PointCloud, fit: ScanFit, distances: np.ndarray, *,
                       frame: str = "y-up", config: FitScanConfig | None = None, force: bool = False,
                       extra: dict | None = None, inputs: tuple = ()) -> Path:
    """Write the output folder of a fit (see the module docstring) atomically.

    Args:
        out_dir: the folder; an existing one is replaced only with ``force``.
        cloud: the fitted cloud (rig frame, mm); frame: the input's frame (``y-up`` or ``opencv``).
        distances: ``(N,)`` distance of every cloud point to the fitted mesh, mm.
        extra: more entries for ``report.json`` (e.g. the command line).
        inputs: the command's input files (an output that is, contains or lies in one is refused).

    Raises:
        pipeline.files.OutputError: ``out_dir`` is refused (exists without ``force``, not jnr's, an input)
            or cannot be written.
    """
    from rig.io.mesh import export_mesh

    out_dir = Path(out_dir)
    faces = load_asset().faces

    def back(points: np.ndarray) -> np.ndarray:
        return to_rig_frame(np.asarray(points, float), frame) / cloud.scale_to_mm

    with staged_folder(out_dir, force, inputs=inputs, marker={"command": (extra or {}).get("command")}) as tmp:
        units = {"mm": "millimetres", "cm": "centimetres", "m": "metres"}.get(cloud.units, cloud.units)
        axes = "OpenCV camera frame: x right, y down, z forward" if frame == "opencv" else "+Y up"
        comment = f"{units} and frame of the input cloud ({axes})"
        for name in ("mesh.ply", "mesh.obj"):
            export_mesh(tmp / name, back(fit.vertices), faces, comment=comment)
        (tmp / "params.json").write_text(json.dumps(params_payload(fit, cloud, frame), indent=2) + "\n")
        vmax = max(5.0, float(np.percentile(distances, 95)))
        write_point_cloud_ply(tmp / "cloud_error.ply", back(cloud.points), colors=error_colors(distances, vmax),
                              scalars={"error_mm": np.asarray(distances, np.float32)})
        report = {
            "input": {"path": str(Path(cloud.path).absolute()) if cloud.path else "",  # exists from any folder
                      "points": len(cloud.points), "input_points": cloud.input_points,
                      "subsampled": cloud.input_points > len(cloud.points), "units": cloud.units,
                      "scale_to_mm": cloud.scale_to_mm, "frame": frame, "had_normals": cloud.normals is not None},
            "scan_to_mesh": report_distance_stats(distances),
            "error_colour_scale_mm": [0.0, vmax],
            "prealign": {"rms_mm": fit.prealign.rms_mm, "inlier_fraction": fit.prealign.inlier_fraction,
                         "hypotheses": fit.prealign.hypotheses, "scale": fit.prealign.scale},
            "stages": [asdict(s) for s in fit.stages],
            "timings_s": fit.timings,
            "config": config_to_dict(config) if config is not None else None,
        }
        report.update(extra or {})
        (tmp / "report.json").write_text(json.dumps(json_safe(report), indent=2) + "\n")
        dump_config(config or FitScanConfig(), tmp / CONFIG_FILE, command=(extra or {}).get("command"))
        _write_scan_viewer(tmp, fit, out_dir.name, report["scan_to_mesh"])
    return out_dir


def _write_scan_viewer(folder: Path, fit: ScanFit, name: str, distances: dict) -> None:
    """``viewer.html`` of a scan fit: the head in rig space (no photo: an orbit view); an ASM fit as its mesh."""
    from pipeline.photo.outputs import output_models
    from pipeline.viewer import VIEWER_FILE, fit_viewer_ready, write_viewer

    title, subtitle = f"jnr fit-scan: {name}", f"scan-to-mesh median {distances.get('median_mm', float('nan')):.2f} mm"
    if not fit_viewer_ready():
        return
    if fit.asm is not None:
        write_viewer(folder / VIEWER_FILE, load_asset(), expressions=fit.expressions, static_vertices=fit.rig_vertices,
                     title=title, subtitle=subtitle + " (ASM: expression sliders only)")
        return
    rig, neural = output_models()
    with torch.no_grad():
        weights = neural(torch.as_tensor(np.asarray(fit.z, np.float64))[None])[0].numpy()
    write_viewer(folder / VIEWER_FILE, rig.asset, theta=fit.theta, expressions=fit.expressions, weights=weights,
                 title=title, subtitle=subtitle)
