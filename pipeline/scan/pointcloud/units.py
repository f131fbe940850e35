"""Units and frames of a cloud: detecting mm, cm or m from its size (:func:`detect_units`; inches only when
given), the units a cloud's size also fits (:func:`plausible_units`), and the one conversion to the rig
frame (:func:`to_rig_frame`)."""

from __future__ import annotations

import warnings

import numpy as np

from pipeline.scan.pointcloud.cloud import CloudError

UNITS = ("auto", "mm", "cm", "m", "in")
FRAMES = ("y-up", "opencv")
UNIT_SCALE_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
UNIT_NAMES = {"mm": "millimetres", "cm": "centimetres", "m": "metres", "in": "inches"}
AUTO_UNITS = ("mm", "m", "cm")
"""The units ``units="auto"`` chooses from, in this order (inches are never guessed: a head in inches
is 3-18 across, which a head in cm overlaps; the fit checks a doubtful guess, :mod:`pipeline.scan.fit`)."""
HEAD_EXTENT_MM = (80.0, 450.0)
"""Largest side (mm) of the 1st-99th percentile bounding box of a head or face scan; used by ``units="auto"``."""
EXPLICIT_EXTENT_MM = (30.0, 1000.0)
"""Accepted largest side (mm) after scaling with explicit ``units`` (looser than the auto range)."""


def detect_units(points: np.ndarray, units: str = "auto", where: str = "") -> tuple[str, float]:
    """The units of a cloud and the factor to mm, detected from its size or checked against it.

    Args:
        points: ``(N, 3)`` finite positions in the file's units.
        units: ``"auto"`` (mm, m or cm, the first in which the largest side of the 1st-99th percentile box
            is :data:`HEAD_EXTENT_MM`; warns when it is not mm), or ``"mm"``, ``"cm"``, ``"m"``, ``"in"`` (the
            cloud must then be :data:`EXPLICIT_EXTENT_MM` across).
        where: the prefix of the messages (e.g. the file's path and ``": "``).

    Returns:
        ``(unit, scale_to_mm)``, e.g. ``("m", 1000.0)``.

    Raises:
        CloudError: a cloud that is not head-sized in the given (or any) units.
    """
    extent = cloud_extent(points)
    if units != "auto":
        scale = UNIT_SCALE_TO_MM[units]
        size = extent * scale
        if not EXPLICIT_EXTENT_MM[0] <= size <= EXPLICIT_EXTENT_MM[1]:
            raise CloudError(
                f"{where}with units={units!r} the cloud is {size:.4g} mm across, outside "
                f"{EXPLICIT_EXTENT_MM[0]:g}-{EXPLICIT_EXTENT_MM[1]:g} mm; check --units"
            )
        return units, scale
    lo, hi = HEAD_EXTENT_MM
    for unit in AUTO_UNITS:
        scale = UNIT_SCALE_TO_MM[unit]
        if lo <= extent * scale <= hi:
            if unit != "mm":
                warnings.warn(
                    f"{where}the cloud is {extent:.4g} across, so it looks like {unit}; converted to "
                    f"mm (x{scale:g}). Pass --units to override",
                    stacklevel=3,
                )
            return unit, scale
    raise CloudError(
        f"{where}the cloud is {extent:.4g} across, which is not head-sized in mm, cm or m; is it "
        f"a head? pass --units if the units are unusual (a head scan is {lo:g}-{hi:g} mm across)"
    )


def cloud_extent(points: np.ndarray) -> float:
    """The largest side of the 1st-99th percentile box of ``(N, 3)`` points, in their units (what
    :func:`detect_units` compares with :data:`HEAD_EXTENT_MM`)."""
    low, high = np.percentile(points, [1.0, 99.0], axis=0)
    return float((high - low).max())


def plausible_units(extent: float) -> list[str]:
    """Every unit of :data:`UNIT_SCALE_TO_MM` in which a cloud ``extent`` across (its own units) is
    head-sized (:data:`HEAD_EXTENT_MM`), e.g. ``["cm", "in"]`` for 8.6.

    Example:
        >>> plausible_units(8.6)
        ['cm', 'in']
    """
    lo, hi = HEAD_EXTENT_MM
    return [unit for unit, scale in UNIT_SCALE_TO_MM.items() if lo <= extent * scale <= hi]


def to_rig_frame(xyz: np.ndarray, frame: str) -> np.ndarray:
    """Convert points or normals from a cloud's ``frame`` to the rig frame (the only place this is done).

    Args:
        xyz: ``(*, 3)`` points or normals.
        frame: ``"y-up"`` (returned unchanged, as a copy) or ``"opencv"`` (x right, y down, z forward →
            ``(x, -y, -z)``).

    Returns:
        ``(*, 3)`` float64 array in the rig frame (+Y up, +Z out of the face). Use it for 3D landmarks
        given in the same frame as their cloud.

    Example:
        >>> to_rig_frame(np.array([1.0, 2.0, 3.0]), "opencv")
        array([ 1., -2., -3.])
    """
    if frame not in FRAMES:
        raise CloudError(f"to_rig_frame: frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    xyz = np.array(xyz, dtype=np.float64)
    if xyz.shape[-1:] != (3,):
        raise CloudError(f"to_rig_frame: xyz must have shape (*, 3), got {xyz.shape}")
    if frame == "opencv":
        xyz[..., 1:] *= -1.0
    return xyz


__all__ = [
    "AUTO_UNITS",
    "EXPLICIT_EXTENT_MM",
    "FRAMES",
    "HEAD_EXTENT_MM",
    "UNITS",
    "UNIT_NAMES",
    "UNIT_SCALE_TO_MM",
    "cloud_extent",
    "detect_units",
    "plausible_units",
    "to_rig_frame",
]
