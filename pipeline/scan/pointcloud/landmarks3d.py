"""Named 3D landmarks of a scan, read from JSON (:func:`read_landmarks3d`)."""

from __future__ import annotations

import json
import os

import numpy as np

from pipeline.scan.pointcloud.cloud import CloudError
from rig.io.inputs import regular_file


def read_landmarks3d(path) -> dict[str, np.ndarray]:
    """Read named 3D landmarks from JSON.

    The file is ``{"landmarks": {"nose_tip": [x, y, z], ...}}`` or the bare mapping ``{"nose_tip": [x, y, z]}``.
    Coordinates are in the same units and frame as the cloud they belong to and are returned unchanged:
    scale them by the cloud's ``scale_to_mm`` and apply :func:`to_rig_frame` as for the cloud. Names are
    not checked here (the model checks them).

    Args:
        path: the JSON file.

    Returns:
        name → ``(3,)`` float64 position, in file order.

    Raises:
        FileNotFoundError: the file does not exist.
        CloudError: bad JSON, no landmarks, or an entry that is not 3 finite numbers.

    Example:
        >>> read_landmarks3d("scan_landmarks.json")["nose_tip"]  # doctest: +SKIP
        array([  1.2,  10.5, 112. ])
    """
    path = os.fspath(path)
    regular_file(path, "landmark file", 64 << 20)  # a FIFO or a device is not "not found"
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CloudError(f"{path}: not valid JSON ({exc})") from exc
    except RecursionError:
        raise CloudError(f"{path}: JSON nested too deeply to be a landmark file") from None
    if isinstance(data, dict) and isinstance(data.get("landmarks"), dict):
        data = data["landmarks"]
    if not isinstance(data, dict) or not data:
        raise CloudError(
            f'{path}: expected {{"landmarks": {{name: [x, y, z], ...}}}} or {{name: [x, y, z]}}, '
            f"got {type(data).__name__ if data else 'no landmarks'}"
        )
    landmarks = {}
    for name, value in data.items():
        is_vector = (
            isinstance(value, list)
            and len(value) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        )
        if not is_vector:
            raise CloudError(f"{path}: landmark {name!r} must be a list of 3 numbers [x, y, z], got {value!r}")
        xyz = np.array(value, dtype=np.float64)
        if not np.isfinite(xyz).all():
            raise CloudError(f"{path}: landmark {name!r} has a non-finite coordinate: {value!r}")
        landmarks[name] = xyz
    return landmarks


__all__ = ["read_landmarks3d"]
