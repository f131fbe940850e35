"""The dynamic jaw contour: landmarks 0-16 on the silhouette seen from a camera, for turned heads, as
FLAME's dynamic contour does (:func:`contour_landmarks`)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch

from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.names import CHIN
from landmarks.ibug68.outline import _contour, _contour_heuristic, _ContourData
from landmarks.ibug68.positions import landmark_positions
from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.geometry import vertex_normals
from rig.lbs import ShapeError


def contour_candidates(asset: RigAsset | None = None, *, corrected: bool = True) -> tuple[np.ndarray, ...]:
    """Per jaw-contour landmark, the candidate template vertices (front -> back) of the dynamic contour;
    empty for the chin (8), which stays fixed. ``corrected``: as in
    :func:`~landmarks.ibug68.embedding.ibug68_embedding`."""
    asset = load_asset() if asset is None else asset
    return (_contour(asset) if corrected else _contour_heuristic(asset)).candidates


@dataclass(frozen=True)
class _ContourLines:
    vertices: np.ndarray  # (C,) all candidate vertices, landmark after landmark (front -> back)
    bounds: tuple[tuple[int, int], ...]  # per contour landmark: its slice of ``vertices`` (empty: the chin)
    faces: np.ndarray  # (G, 3) the faces incident to a candidate, in mesh order


def _build_lines(data: _ContourData, faces: np.ndarray) -> _ContourLines:
    verts = np.concatenate([np.asarray(c, np.int64) for c in data.candidates])
    sizes = np.cumsum([0] + [len(c) for c in data.candidates])
    bounds = tuple((int(a), int(b)) for a, b in itertools.pairwise(sizes))
    incident = np.flatnonzero(np.isin(faces, verts).any(1))
    return _ContourLines(verts, bounds, faces[incident])  # a vertex on two lines appears in both


@cached_per_asset
def _asset_lines(asset: RigAsset) -> _ContourLines:
    return _build_lines(_contour(asset), np.asarray(asset.faces, np.int64))


@cached_per_asset
def _asset_lines_heuristic(asset: RigAsset) -> _ContourLines:
    return _build_lines(_contour_heuristic(asset), np.asarray(asset.faces, np.int64))


def _contour_lines(asset: RigAsset, faces: np.ndarray, corrected: bool = True) -> _ContourLines:
    """The candidate lines of :func:`contour_candidates` flattened, with their incident faces."""
    if faces.shape == asset.faces.shape and np.array_equal(faces, asset.faces):
        return _asset_lines(asset) if corrected else _asset_lines_heuristic(asset)
    return _build_lines(_contour(asset) if corrected else _contour_heuristic(asset), faces)


def contour_support_ids(asset: RigAsset | None = None, *, corrected: bool = True) -> np.ndarray:
    """``(N,)`` sorted ids of the vertices :func:`contour_vertex_ids` reads (the candidates, their incident
    faces' corners, and the fallback vertices): a fit that only skins these can pick the contour."""
    asset = load_asset() if asset is None else asset
    faces = np.asarray(asset.faces, np.int64)
    lines = _contour_lines(asset, faces, corrected)
    data = _contour(asset) if corrected else _contour_heuristic(asset)
    return np.unique(
        np.concatenate(
            [
                np.asarray(lines.faces, np.int64).ravel(),
                np.asarray(lines.vertices, np.int64),
                np.asarray(data.vertex_ids, np.int64),
            ]
        )
    )


def contour_landmarks(
    vertices: torch.Tensor, faces, camera_center, asset: RigAsset | None = None, *, corrected: bool = True
) -> torch.Tensor:
    """Dynamic jaw contour (landmarks 0-16) as seen from a camera, for turned heads.

    For each contour landmark a precomputed line of template vertices runs across the cheek/jaw from the
    front towards the ear (:func:`contour_candidates`); among those facing the camera, the one closest to
    the silhouette (smallest ``|n . view_dir|``) is picked. The chin (8) stays at its static embedding.
    The choice is discrete; the returned positions are differentiable w.r.t. ``vertices``.

    Args:
        vertices: ``(V, 3)`` posed vertices in rig space, mm.
        faces: ``(F, 3)`` template faces.
        camera_center: ``(3,)`` camera centre in the same frame as ``vertices``, mm.
        corrected: as in :func:`~landmarks.ibug68.embedding.ibug68_embedding` (False: the lines of the
            geometric contour).

    Returns:
        ``(17, 3)`` contour positions, mm, same dtype as ``vertices``.
    """
    asset = load_asset() if asset is None else asset
    if not isinstance(vertices, torch.Tensor) or vertices.ndim != 2 or vertices.shape[-1] != 3:
        raise ShapeError(
            f"contour_landmarks: vertices must be a torch tensor of shape (V, 3), "
            f"got {type(vertices).__name__} {tuple(vertices.shape)}"
        )
    cam = torch.as_tensor(camera_center, dtype=vertices.dtype, device=vertices.device)
    if cam.shape != (3,):
        raise ShapeError(f"contour_landmarks: camera_center must have shape (3,), got {tuple(cam.shape)}")
    faces_np = np.asarray(faces.cpu() if isinstance(faces, torch.Tensor) else faces, dtype=np.int64)
    picked = contour_vertex_ids(vertices, faces_np, cam.detach().cpu().double().numpy(), asset, corrected=corrected)
    out = vertices[torch.as_tensor(picked, device=vertices.device)]
    static = landmark_positions(vertices, ibug68_embedding(asset, corrected=corrected), faces_np)[0, CHIN]
    return torch.cat([out[:CHIN], static[None], out[CHIN + 1 :]])


def contour_vertex_ids(
    vertices, faces, camera_center, asset: RigAsset | None = None, *, corrected: bool = True
) -> list[int]:
    """The 17 vertex ids :func:`contour_landmarks` picks for the jaw contour as seen from ``camera_center``
    (``(V, 3)`` torch or numpy vertices, rig space, mm); the chin's entry (8) is the vertex its static
    landmark would start from and is not used by :func:`contour_landmarks`."""
    asset = load_asset() if asset is None else asset
    faces_np = np.asarray(faces.cpu() if isinstance(faces, torch.Tensor) else faces, dtype=np.int64)
    data = _contour(asset) if corrected else _contour_heuristic(asset)
    lines = _contour_lines(asset, faces_np, corrected)
    v = (
        vertices.detach().cpu().double().numpy()
        if isinstance(vertices, torch.Tensor)
        else np.asarray(vertices, np.float64)
    )
    cam = np.asarray(camera_center, np.float64)
    n = vertex_normals(v, lines.faces)[lines.vertices]  # from the candidates' incident faces: exact there
    to_cam = cam - v[lines.vertices]
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True).clip(1e-12)
    facing = (n * to_cam).sum(1)
    score = np.where(facing > 0, facing, np.inf)
    picked = [int(i) for i in data.vertex_ids]  # the chin, and any line that faces away: the static landmark
    for k, (lo, hi) in enumerate(lines.bounds):
        if hi > lo and np.isfinite(score[lo:hi]).any():
            picked[k] = int(lines.vertices[lo + int(np.argmin(score[lo:hi]))])
    return picked


__all__ = ["contour_candidates", "contour_landmarks", "contour_support_ids", "contour_vertex_ids"]
