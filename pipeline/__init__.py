"""jnr's fitting pipeline: reconstruct a head from photos or a point cloud with the joint rig.

The public entry points (imported lazily, so ``import pipeline`` stays cheap)::

    from pipeline import fit_photo, FitPhotoConfig           # one photo in memory -> PhotoFit
    from pipeline import fit_photo_file, fit_photo_files     # photo files -> output folders
    from pipeline import fit_photo_faces                     # every face of a photo -> face_<k>/ folders
    from pipeline import fit_scan, FitScanConfig             # a point cloud -> ScanFit
    from pipeline import read_point_cloud, load_config
    from pipeline import read_fit_folder, FittedHead         # a fit's output folder -> its head (any model)

Layout by task: :mod:`pipeline.fitting` (the staged engine, the loss terms, the fit state),
:mod:`pipeline.head` (the fitted head, ``params.json``, the output folders), :mod:`pipeline.photo`,
:mod:`pipeline.scan`, :mod:`pipeline.synthetic` (data with known truth), :mod:`pipeline.evaluation`,
:mod:`pipeline.cli` (the ``jnr`` command); the layers are the import contract in ``pyproject.toml``.
"""

from __future__ import annotations

import importlib

_PUBLIC = {
    "fit_photo": "pipeline.photo.fit",
    "FitPhotoConfig": "pipeline.photo.fit",
    "PhotoFit": "pipeline.photo.fit",
    "fit_landmarks": "pipeline.photo.landmark_fit",
    "LandmarkFitConfig": "pipeline.photo.landmark_fit",
    "fit_photo_file": "pipeline.photo.photo_file",
    "fit_photo_files": "pipeline.photo.batch",
    "fit_photo_faces": "pipeline.photo.photo_file",
    "fit_scan": "pipeline.scan.fit",
    "FitScanConfig": "pipeline.scan.fit",
    "ScanFit": "pipeline.scan.fit",
    "read_point_cloud": "pipeline.scan.pointcloud.read",
    "load_config": "pipeline.config",
    "FittedHead": "pipeline.head.fitted",
    "fitted_head": "pipeline.head.fitted",
    "read_fit_folder": "pipeline.head.fitted",
}

__all__ = [
    "FitPhotoConfig",
    "FittedHead",
    "FitScanConfig",
    "LandmarkFitConfig",
    "PhotoFit",
    "ScanFit",
    "fit_landmarks",
    "fit_photo",
    "fit_photo_faces",
    "fit_photo_file",
    "fit_photo_files",
    "fit_scan",
    "fitted_head",
    "load_config",
    "read_fit_folder",
    "read_point_cloud",
]


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'pipeline' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
