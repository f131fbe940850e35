"""The validated point cloud (:class:`PointCloud`, mm, rig frame) and the error for bad cloud input."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.errors import InputError


class CloudError(InputError):
    """Bad point-cloud input (message says what and how to fix)."""


@dataclass(frozen=True)
class PointCloud:
    """A validated point cloud in rig space."""

    points: np.ndarray
    """``(N, 3)`` float64 positions in mm, rig frame (+Y up, +Z out of the face)."""
    normals: np.ndarray | None
    """``(N, 3)`` float64 unit normals in the rig frame, or None when the source had none."""
    path: str
    """The source file ('' when built in memory)."""
    units: str
    """The units the source was in: 'mm', 'cm', 'm' or 'in'."""
    scale_to_mm: float
    """The factor that was applied to reach mm (1, 10, 1000 or 25.4)."""
    input_points: int | None = None
    """Points in the source; more than ``len(points)`` only when the cloud was larger than
    :data:`~pipeline.scan.pointcloud.validate.LARGE_CLOUD_POINTS` and ``points`` is a random subsample of
    it (None given: ``len(points)``)."""

    units_detected: bool = False
    """True when ``units`` was detected from the cloud's size (``units="auto"``), False when given."""

    def __post_init__(self) -> None:
        if self.input_points is None:
            object.__setattr__(self, "input_points", len(self.points))


__all__ = ["CloudError", "PointCloud"]
