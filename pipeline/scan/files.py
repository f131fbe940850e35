"""A point-cloud file in, an output folder out: what ``jnr fit-scan CLOUD`` does, as a library function."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from pipeline.files import check_output
from pipeline.metrics import scan_to_mesh_distances
from pipeline.scan.fit import fit_scan
from pipeline.scan.outputs import write_scan_outputs
from pipeline.scan.pointcloud.landmarks3d import read_landmarks3d
from pipeline.scan.pointcloud.read import read_point_cloud
from pipeline.scan.pointcloud.units import to_rig_frame
from rig.asset import load_asset


def read_cloud_landmarks(path: str | Path, cloud, frame: str = "y-up") -> dict[str, np.ndarray]:
    """Named 3D landmarks of ``cloud`` from a JSON file (:func:`pipeline.scan.pointcloud.landmarks3d.read_landmarks3d`),
    brought where the cloud is: scaled by its ``scale_to_mm`` and turned from ``frame`` into the rig
    frame (:func:`pipeline.scan.pointcloud.units.to_rig_frame`), as
    :func:`~pipeline.scan.pointcloud.read.read_point_cloud`
    does for the cloud.

    Args:
        path: the JSON file, coordinates in the cloud file's units and frame.
        cloud: the :class:`~pipeline.scan.pointcloud.cloud.PointCloud` read from the same scan.
        frame: the cloud file's frame, ``"y-up"`` or ``"opencv"``.

    Returns:
        ``{name: (3,) float64 mm, rig frame}``.

    Raises:
        LandmarkError: an unreadable or malformed file.
    """
    raw = read_landmarks3d(path)
    return {k: to_rig_frame(np.asarray(v, float)[None] * cloud.scale_to_mm, frame)[0] for k, v in raw.items()}


def fit_scan_file(
    cloud_path: str | Path,
    out: str | Path,
    *,
    config=None,
    landmarks: str | Path | None = None,
    units: str = "auto",
    frame: str = "y-up",
    force: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
    rig=None,
    neural=None,
    command: str = "jnr fit-scan",
    inputs: Iterable[str | Path] = (),
) -> dict:
    """Read a point cloud (and its 3D landmarks), fit the rig to it and write the output folder.

    Args:
        cloud_path: the cloud file (:func:`pipeline.scan.pointcloud.read.read_point_cloud`: ``.ply``, ``.obj``,
            ``.xyz``/``.txt``/``.csv``, ``.npy``).
        out: the output folder (:mod:`pipeline.scan.outputs` lists its files; written in the cloud's
            frame and units); an existing one is replaced only with ``force`` (and only if jnr wrote it).
        config: :class:`pipeline.scan.fit.FitScanConfig` (default: its defaults).
        landmarks: optional JSON of named 3D landmarks in the cloud's units and frame
            (:func:`read_cloud_landmarks`).
        units: ``"auto"``, ``"mm"``, ``"cm"``, ``"m"`` or ``"in"``, the cloud's units; frame: ``"y-up"`` or
            ``"opencv"`` (x right, y down, z forward).
        progress: ``progress(stage, iteration, iterations)`` during the fit.
        rig, neural: the models (default: the committed rig and learned skinning, float32).
        command: recorded in ``report.json`` and the output's marker.
        inputs: more input paths the output must not be, contain or lie in (e.g. the config file).

    Returns:
        ``{"cloud", "output"`` (str), ``"points"`` (fitted), ``"input_points"`` (in the file),
        ``"units"`` (the cloud's), ``"fit_seconds"``, ``"s2m_median_mm"``, ``"s2m_mean_mm"``,
        ``"s2m_std_mm"`` (scan-to-mesh distance of the fitted points, mm)``}``.

    Raises:
        InputError: a bad cloud or landmarks (:class:`~pipeline.scan.pointcloud.cloud.CloudError`,
            :class:`~landmarks.points3d.LandmarkError`), a refused output
            (:class:`~pipeline.files.OutputError`); nothing is written.
        FloatingPointError: the fit diverged.
    """
    out = Path(out)
    inputs = [p for p in (cloud_path, landmarks, *inputs) if p]
    check_output(out, force=force, inputs=inputs)
    t0 = time.perf_counter()
    cloud = read_point_cloud(cloud_path, units=units, frame=frame)
    points = read_cloud_landmarks(landmarks, cloud, frame) if landmarks else None
    fit = fit_scan(
        cloud, config, landmarks=points, rig=rig, neural=neural, progress=progress, landmarks_source=str(landmarks)
    )
    faces = rig.asset.faces if rig is not None else load_asset().faces
    centre = cloud.points.mean(0)  # a georeferenced cloud's distances without the cancellation of 1e8 mm
    distances = scan_to_mesh_distances(cloud.points - centre, fit.vertices - centre, faces)
    write_scan_outputs(
        out,
        cloud,
        fit,
        distances,
        frame=frame,
        config=config,
        force=force,
        extra={"command": command, "wall_seconds": time.perf_counter() - t0},
        inputs=tuple(inputs),
    )
    return {
        "cloud": str(cloud_path),
        "output": str(out),
        "points": len(cloud.points),
        "input_points": cloud.input_points,
        "units": cloud.units,
        "fit_seconds": fit.timings["total"],
        "s2m_median_mm": float(np.median(distances)),
        "s2m_mean_mm": float(distances.mean()),
        "s2m_std_mm": float(distances.std()),
    }


__all__ = ["fit_scan_file", "read_cloud_landmarks"]
