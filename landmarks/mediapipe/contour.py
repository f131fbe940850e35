"""Sliding contour points of a dense layout: per point a line of candidate template vertices in its radial
plane, and the pick of the one on the silhouette seen from a camera (issue 26).

A detector marks the face's outline where the skin turns away from the camera, not at a fixed skin point:
as the head turns away, the outline slides over the cheek and the jaw. As for iBUG-68's jaw contour
(:mod:`landmarks.ibug68.contour`), each such point gets a line of candidate vertices, and a fit re-picks
it on the silhouette (facing vertices whose normal is nearly perpendicular to the line of sight) once its
own vertex nears or passes the silhouette (:func:`pick_contour`).

The line of a point ``p`` (its frontal position on the template, rig space, mm) lies in the plane through
``p`` spanned by the outward radial direction ``r = (p_x - c_x, p_y - c_y, 0)`` from the face's centre
``c`` and the depth axis ``z``: the skin vertices (the face's outer regions; not the ears, the eyes, the
nose, the mouth or what is inside the head) within :data:`LINE_HALF_WIDTH_MM` of that plane, from
:data:`INWARD_MM` inside ``p`` outwards, from :data:`FORWARD_MM` in front of ``p`` to :data:`LINE_DEPTH_MM`
behind it, ordered front to back. Seen from the front the pick stays near ``p`` (the frontal outline);
turned towards the camera it slides back towards the ear, turned away it slides in over the cheek.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from rig.asset import RigAsset
from rig.errors import InputError
from rig.geometry import vertex_normals

LINE_REGIONS = ("forehead", "brows", "cheeks", "chin", "jaw", "scalp", "neck")
"""Template regions a contour line may run over (the outline's skin; ears, eyes, nose, lips and the hidden
parts are left out)."""
LINE_HALF_WIDTH_MM = 5.0
"""Half-width of a line across its radial plane, mm (as :mod:`landmarks.ibug68.outline`'s lines: wide
enough that every line holds a vertex near the silhouette at the template's edge lengths)."""
LINE_DEPTH_MM = 70.0
"""How far behind the point (along -z) its line runs, mm: past the silhouette of a head turned 60 degrees,
short of the back of the head."""
INWARD_MM = 45.0
"""How far inside the point (against ``r``, towards the face's centre) a candidate may lie, mm: on the side
turned away from the camera the silhouette moves inwards and forwards over the cheek."""
FORWARD_MM = 70.0
"""How far in front of the point (along +z) a candidate may lie, mm."""
GRAZING = 0.25
"""``n . view`` at or below which a facing vertex counts as on the silhouette (about 75 degrees between its
normal and the line of sight)."""


@dataclass(frozen=True)
class ContourLines:
    """The candidate lines of ``C`` contour points.

    Attributes:
        vertices: ``(M,)`` int64 candidate vertex ids, point after point (front to back).
        bounds: per point, its ``(start, stop)`` slice of :attr:`vertices`.
        faces: ``(G, 3)`` the template faces incident to a candidate (their normals are exact there).
        start: ``(C,)`` int64 the vertex nearest each point's frontal position (a line that faces away from
            the camera picks it).
    """

    vertices: np.ndarray
    bounds: tuple[tuple[int, int], ...]
    faces: np.ndarray
    start: np.ndarray

    @property
    def support(self) -> np.ndarray:
        """``(S,)`` sorted vertex ids :func:`pick_contour` reads."""
        return np.unique(np.concatenate([self.faces.ravel(), self.vertices, self.start]))


def contour_lines(asset: RigAsset, points: np.ndarray) -> ContourLines:
    """The candidate lines of contour points at ``points`` ``(C, 3)`` (their frontal positions on
    ``asset``'s template, rig space, mm; module docstring).

    Raises:
        ValueError: ``points`` is not ``(C, 3)`` and finite.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
        raise InputError(f"contour_lines: points must be a finite (C, 3) array, got shape {points.shape}")
    v = np.asarray(asset.vertices, np.float64)
    faces = np.asarray(asset.faces, np.int64)
    allowed = np.flatnonzero(asset.region_mask(*LINE_REGIONS))
    face = asset.region_mask("forehead", "brows", "eyelids", "nose", "cheeks", "lips", "chin", "jaw")
    centre = v[face, :2].mean(axis=0)
    lines, start = [], []
    for p in points:
        radial = np.array([p[0] - centre[0], p[1] - centre[1], 0.0])
        radial /= max(float(np.linalg.norm(radial)), 1e-9)
        normal = np.cross(radial, [0.0, 0.0, 1.0])
        d = v[allowed] - p
        keep = (np.abs(d @ normal) <= LINE_HALF_WIDTH_MM) & (d @ radial >= -INWARD_MM)
        keep &= (d[:, 2] <= FORWARD_MM) & (d[:, 2] >= -LINE_DEPTH_MM)
        ids = allowed[keep]
        lines.append(ids[np.argsort(-v[ids, 2], kind="stable")])
        start.append(int(np.argmin(((v - p) ** 2).sum(1))))
    sizes = np.cumsum([0] + [len(line) for line in lines])
    vertices = np.concatenate(lines) if lines else np.zeros(0, np.int64)
    incident = faces[np.isin(faces, vertices).any(axis=1)]
    return ContourLines(
        vertices=vertices.astype(np.int64),
        bounds=tuple((int(a), int(b)) for a, b in itertools.pairwise(sizes)),
        faces=incident,
        start=np.asarray(start, np.int64),
    )


def pick_contour(lines: ContourLines, vertices: np.ndarray, camera_centre: np.ndarray) -> np.ndarray:
    """``(C,)`` int64 the vertex of each contour point seen from ``camera_centre`` (3,): the point's own
    vertex (:attr:`ContourLines.start`) while it faces the camera clearly (``n . view >``
    :data:`GRAZING`: a face border on the side turned towards the camera stays where it is on the skin);
    once it nears or passes the silhouette, the candidate of its line nearest to it among those on the
    silhouette (facing, ``n . view <=`` :data:`GRAZING`), or the most grazing facing candidate if none is.

    Args:
        lines: :func:`contour_lines`. vertices: ``(V, 3)`` the posed head, rig space, mm (only
            :attr:`ContourLines.support` is read). camera_centre: ``(3,)`` rig space, mm.
    """
    v = np.asarray(vertices, np.float64)
    cam = np.asarray(camera_centre, np.float64)
    picked = lines.start.copy()
    if len(lines.vertices) == 0:
        return picked
    ids = np.concatenate([lines.vertices, lines.start])
    n = vertex_normals(v, lines.faces)[ids]
    to_cam = cam - v[ids]
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True).clip(1e-12)
    facing = (n * to_cam).sum(axis=1)
    facing, start_facing = facing[: len(lines.vertices)], facing[len(lines.vertices) :]
    for k, (lo, hi) in enumerate(lines.bounds):
        if start_facing[k] > GRAZING or hi <= lo:
            continue
        f = facing[lo:hi]
        on = (f > 0) & (f <= GRAZING)
        if on.any():
            d = np.linalg.norm(v[lines.vertices[lo:hi]] - v[lines.start[k]], axis=1)
            picked[k] = lines.vertices[lo + int(np.argmin(np.where(on, d, np.inf)))]
        elif (f > 0).any():
            picked[k] = lines.vertices[lo + int(np.argmin(np.where(f > 0, f, np.inf)))]
    return picked


__all__ = [
    "INWARD_MM",
    "LINE_DEPTH_MM",
    "LINE_HALF_WIDTH_MM",
    "LINE_REGIONS",
    "ContourLines",
    "contour_lines",
    "pick_contour",
]
