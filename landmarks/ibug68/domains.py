"""Where each corrected landmark may lie (its domain: region faces, a rim or the midline) and the snap of a
corrected point back onto it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from landmarks.ibug68.mesh import _HIDDEN_REGIONS, _closest_point_on_faces, _edge_point
from landmarks.ibug68.names import CHIN, IBUG68_MIRROR
from rig.asset import RigAsset, cached_per_asset
from rig.geometry import face_edges


@dataclass(frozen=True)
class _Domain:
    """The surface a landmark is snapped onto: template faces, or mesh edges (a rim or the midline)."""

    faces: np.ndarray  # (F,) face ids (empty when ``edges`` is used)
    edges: np.ndarray  # (E, 2) vertex ids


_DOMAIN_REGIONS = {  # landmark -> the regions of its domain (left side and midline)
    **{k: ("brows",) for k in range(22, 27)},
    **{k: ("nose", "forehead", "brows", "eyelids") for k in (27, 28, 29, 30)},
    **{k: ("nose",) for k in (33, 34, 35)},
    **{k: ("lips",) for k in range(51, 58)},
    CHIN: ("chin",),
}


@cached_per_asset
def _domains(asset: RigAsset) -> dict[int, _Domain]:
    v, faces, mirror = asset.vertices, np.asarray(asset.faces, np.int64), asset.mirror
    hidden = asset.region_mask(*_HIDDEN_REGIONS)
    skin = np.flatnonzero(~hidden[faces].any(1))
    edges = np.unique(np.sort(face_edges(faces[skin]), 1), axis=0)
    on_mid = mirror == np.arange(len(v))
    midline_edges = edges[on_mid[edges].all(1)]
    empty_f, empty_e = np.zeros(0, np.int64), np.zeros((0, 2), np.int64)

    def loop_edges(loop) -> np.ndarray:
        loop = np.asarray(loop, np.int64)
        return np.stack([loop, np.roll(loop, -1)], 1)

    left_eye = int(np.argmax([v[loop, 0].mean() for loop in asset.eye_loops]))
    out: dict[int, _Domain] = {}
    for k, regions in _DOMAIN_REGIONS.items():
        mask = asset.region_mask(*regions)
        if IBUG68_MIRROR[k] == k:
            out[k] = _Domain(empty_f, midline_edges[mask[midline_edges].any(1)])
        else:
            out[k] = _Domain(skin[mask[faces[skin]].any(1)], empty_e)
    for k in range(42, 48):
        out[k] = _Domain(empty_f, loop_edges(asset.eye_loops[left_eye]))
    for k in (63, 64, 65):
        out[k] = _Domain(empty_f, loop_edges(asset.mouth_loop))
    return out


def _snap(asset: RigAsset, domain: _Domain, p: np.ndarray) -> tuple[int, np.ndarray]:
    """The point of ``domain`` closest to ``p``, as ``(face, barycentric)``."""
    v, faces = asset.vertices, asset.faces
    if len(domain.faces):
        return _closest_point_on_faces(v, faces, domain.faces, p)
    a, b = v[domain.edges[:, 0]], v[domain.edges[:, 1]]
    t = np.clip(((p - a) * (b - a)).sum(1) / ((b - a) ** 2).sum(1), 0.0, 1.0)
    q = a + t[:, None] * (b - a)
    best = int(np.argmin(((q - p) ** 2).sum(1)))
    return _edge_point(faces, int(domain.edges[best, 0]), int(domain.edges[best, 1]), float(t[best]))


def snap_domain_points(asset: RigAsset, k: int, steps: int = 6) -> np.ndarray:
    """``(N, 3)`` sample points (mm) of the surface that landmark ``k`` (left side or midline, 17-67 or the
    chin) is snapped onto after its correction: a barycentric grid of ``steps`` per edge on each face, or
    ``steps`` per edge along a rim / the midline. For fitting
    :data:`~landmarks.ibug68.corrections.LANDMARK_CORRECTIONS_MM`."""
    domain = _domains(asset).get(int(k))
    if domain is None:
        raise KeyError(f"ibug68: landmark {k} has no correction domain")
    v = asset.vertices
    if len(domain.faces):
        grid = np.array([(i, j, steps - i - j) for i in range(steps + 1) for j in range(steps + 1 - i)], float) / steps
        return np.einsum("gk,fkc->fgc", grid, v[asset.faces[domain.faces]]).reshape(-1, 3)
    t = np.linspace(0.0, 1.0, steps + 1)[None, :, None]
    a, b = v[domain.edges[:, 0]][:, None], v[domain.edges[:, 1]][:, None]
    return (a + t * (b - a)).reshape(-1, 3)


__all__ = ["snap_domain_points"]
