"""What ``jnr fit-scan`` writes (the files: :data:`pipeline.head.folders.SCAN_FOLDER`), and reading its
parameters back. The folder is written to a temporary folder beside it, then moved into place, so a failure
leaves nothing half-written. ``mesh.ply``/``mesh.obj`` are in the input cloud's frame and units (they
overlay the cloud); ``cloud_error.ply`` colours the cloud by its distance to the fitted mesh (blue 0 -> red
at ``vmax``) with the distance as the float property ``error_mm``; ``params.json`` follows
:mod:`pipeline.head.params` (fit ``scan``: the pose, rig space -> cloud frame in mm, and the input's units
and frame).
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.config import CONFIG_FILE, config_to_dict, dump_config
from pipeline.files import json_safe, staged_folder
from pipeline.head.fitted import FittedHead, fitted_head, fitted_head_from_params
from pipeline.head.params import ParamsFileError, load_params_file, read_params
from pipeline.head.params import params_payload as head_params_payload
from pipeline.metrics import distance_stats
from pipeline.scan.fit import ScanFit
from pipeline.scan.fit_config import FitScanConfig
from pipeline.scan.pointcloud.cloud import PointCloud
from pipeline.scan.pointcloud.error_colors import error_colors
from pipeline.scan.pointcloud.units import to_rig_frame
from pipeline.scan.pointcloud.write import write_point_cloud_ply
from pipeline.viewer import VIEWER_FILE, fit_viewer_ready, write_viewer
from rig.asset import load_asset
from rig.head_model import HeadModel
from rig.io.mesh import export_mesh


def report_distance_stats(distances: np.ndarray) -> dict:
    """``report.json``'s scan-to-mesh entry: :func:`pipeline.metrics.distance_stats` (median,
    mean, std, mm) plus the 90th percentile and the fractions within 2 and 5 mm."""
    d = np.asarray(distances, float)
    return {
        **distance_stats(d).as_dict(""),
        "p90_mm": float(np.percentile(d, 90)),
        "within_2mm": float((d <= 2).mean()),
        "within_5mm": float((d <= 5).mean()),
        "points": len(d),
    }


def scan_head(fit: ScanFit, *, model: HeadModel | None = None) -> FittedHead:
    """The :class:`~pipeline.head.fitted.FittedHead` of a scan fit: its head model's parameters as fitted (the
    scan fit keeps the joints in their limits by a soft penalty, L_x, so they may lie slightly outside)."""
    return fitted_head_from_params(fit.head, model=model)


def params_payload(fit: ScanFit, cloud: PointCloud, frame: str, head: FittedHead | None = None) -> dict:
    """The ``params.json`` content of a fit (:mod:`pipeline.head.params`, fit ``scan``)."""
    head = head or scan_head(fit)
    rot = fit.rotation
    return head_params_payload(
        head.model,
        head.params,
        fit="scan",
        pose={
            "description": "rig space (mm, +Y up, +Z out of the face) -> the cloud in mm and the rig frame: "
            "x = scale * R x_rig + t; the input file's frame and units follow from 'input'",
            "rotation_matrix": rot.tolist(),
            "rotation_vector_rad": [float(x) for x in Rotation.from_matrix(rot).as_rotvec()],
            "translation_mm": [float(x) for x in fit.translation],
            "scale": float(fit.scale),
        },
        input={"units": cloud.units, "scale_to_mm": cloud.scale_to_mm, "frame": frame},
    )


def mesh_from_params(params: dict | str | Path, *, frame: str = "input") -> np.ndarray:
    """Rebuild the fitted mesh from a scan fit's ``params.json`` (its dict or path).

    Args:
        frame: ``"input"`` (the input cloud's frame and units, as ``mesh.ply``), ``"cloud"`` (rig frame,
            mm, posed) or ``"rig"`` (rig space, before the pose).

    Returns:
        ``(V, 3)`` vertices.

    Raises:
        ParamsFileError: not a ``jnr fit-scan`` parameter file, or bad contents.
    """
    fit = load_params_file(params) if not isinstance(params, dict) else read_params(params)
    if fit.fit != "scan":
        raise ParamsFileError(f"not a jnr fit-scan parameter file (written by {fit.fit or 'no fit'})")
    v = fitted_head(fit).vertices
    if frame == "rig":
        return v
    pose = fit.data["pose"]
    v = float(pose["scale"]) * v @ np.asarray(pose["rotation_matrix"]).T + np.asarray(pose["translation_mm"])
    if frame == "cloud":
        return v
    inp = fit.data["input"]
    return to_rig_frame(v, inp["frame"]) / float(inp["scale_to_mm"])


def write_scan_outputs(
    out_dir: str | Path,
    cloud: PointCloud,
    fit: ScanFit,
    distances: np.ndarray,
    *,
    frame: str = "y-up",
    config: FitScanConfig | None = None,
    force: bool = False,
    extra: dict | None = None,
    inputs: tuple = (),
) -> Path:
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
        head = scan_head(fit)
        (tmp / "params.json").write_text(json.dumps(params_payload(fit, cloud, frame, head), indent=2) + "\n")
        vmax = max(5.0, float(np.percentile(distances, 95)))
        write_point_cloud_ply(
            tmp / "cloud_error.ply",
            back(cloud.points),
            colors=error_colors(distances, vmax),
            scalars={"error_mm": np.asarray(distances, np.float32)},
        )
        report = {
            "input": {
                "path": str(Path(cloud.path).absolute()) if cloud.path else "",  # exists from any folder
                "points": len(cloud.points),
                "input_points": cloud.input_points,
                "subsampled": cloud.input_points > len(cloud.points),
                "units": cloud.units,
                "scale_to_mm": cloud.scale_to_mm,
                "frame": frame,
                "had_normals": cloud.normals is not None,
            },
            "scan_to_mesh": report_distance_stats(distances),
            "error_colour_scale_mm": [0.0, vmax],
            "prealign": {
                "rms_mm": fit.prealign.rms_mm,
                "inlier_fraction": fit.prealign.inlier_fraction,
                "hypotheses": fit.prealign.hypotheses,
                "scale": fit.prealign.scale,
            },
            "stages": [asdict(s) for s in fit.stages],
            "clamped_to_limits": fit.clamped,
            "timings_s": fit.timings,
            "config": config_to_dict(config) if config is not None else None,
        }
        report.update(extra or {})
        (tmp / "report.json").write_text(json.dumps(json_safe(report), indent=2) + "\n")
        dump_config(config or FitScanConfig(), tmp / CONFIG_FILE, command=(extra or {}).get("command"))
        _write_scan_viewer(tmp, head, out_dir.name, report["scan_to_mesh"])
    return out_dir


def _write_scan_viewer(folder: Path, head: FittedHead, name: str, distances: dict) -> None:
    """``viewer.html`` of a scan fit: the head in rig space (no photo: an orbit view); a head that is not
    posable by the joints (ASM) as its mesh with expression sliders."""
    title, subtitle = f"jnr fit-scan: {name}", f"scan-to-mesh median {distances.get('median_mm', float('nan')):.2f} mm"
    if not fit_viewer_ready():
        return
    if not head.model.posable:
        write_viewer(
            folder / VIEWER_FILE,
            head.asset,
            expressions=head.expressions,
            static_vertices=head.vertices,
            title=title,
            subtitle=subtitle + f" ({head.model.kind.upper()}: expression sliders only)",
        )
        return
    write_viewer(
        folder / VIEWER_FILE,
        head.asset,
        theta=head.theta,
        expressions=head.expressions,
        weights=head.weights,
        latent_z=head.params["latent"],
        title=title,
        subtitle=subtitle,
    )
