"""Where each of MediaPipe's 478 points lies on the template (issue 26): one face and three barycentric
weights per point, read from the committed table ``embedding_table.npz`` (:func:`mediapipe_embedding`).

The table was fitted by ``benchmarks/fit_mediapipe_embedding.py`` on renders with known cameras (method and
figures: ``docs/landmarks.md``). Points on MediaPipe's face outline slide with the silhouette as the head
turns; they are flagged ``contour`` and carry a frontal placement only. Positions on a posed mesh:
:func:`landmarks.ibug68.positions.landmark_positions`, which takes any embedding with ``faces`` and
``barycentric``::

    embedding = mediapipe_embedding()
    points = landmark_positions(vertices, embedding, asset.faces)  # (B, 478, 3) mm
    fixed = points[:, ~embedding.contour]

The table is in MediaPipe's order (``FaceDetection.dense``): the 468 mesh points, then the subject's right
iris (468-472) and left iris (473-477), centre first.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.asset import AssetError, RigAsset, cached_per_asset, load_asset, write_npz_atomic
from rig.template import TEMPLATE_VERSION

EMBEDDING_TABLE = Path(__file__).resolve().parent / "embedding_table.npz"
"""The committed table (arrays ``faces``, ``barycentric``, ``contour``, ``sigma_px``, ``template_faces``,
``template_version``)."""
N_DENSE = 478
"""MediaPipe's points: the 468-point mesh and two irises of 5."""
_REMEDY = "refit it with `.venv/bin/python benchmarks/fit_mediapipe_embedding.py --write`"


@dataclass(frozen=True)
class DenseEmbedding:
    """MediaPipe's 478 points as points on template faces, in MediaPipe's order.

    Attributes:
        faces: ``(478,)`` int64 template face index of each point.
        barycentric: ``(478, 3)`` float64 weights of that face's three vertices (non-negative, sum 1).
        contour: ``(478,)`` bool, points on MediaPipe's face outline: they follow the silhouette as the head
            turns, so ``faces``/``barycentric`` give their frontal place only (a start, not a fixed point).
        sigma_px: ``(478,)`` float64 RMS distance between MediaPipe's point and the embedded point's
            projection on the fit's evaluation renders, pixels at an inter-ocular distance of 100 (outer
            eye corners); for contour points that of the frontal place (large: weight them down or treat
            them apart).
    """

    faces: np.ndarray
    barycentric: np.ndarray
    contour: np.ndarray
    sigma_px: np.ndarray


def read_embedding_table(path: str | Path = EMBEDDING_TABLE) -> DenseEmbedding:
    """The table at ``path`` (no caching, no check against an asset: :func:`mediapipe_embedding` does both).

    Raises:
        FileNotFoundError: no file at ``path``.
        AssetError: the file is unreadable or its arrays have the wrong shapes or values.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MediaPipe embedding table not found: {path} ({_REMEDY})")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in ("faces", "barycentric", "contour", "sigma_px")}
    except Exception as exc:  # zip/npz errors come in many types, a missing key is a KeyError
        raise AssetError(f"MediaPipe embedding table {path} is unreadable: {exc}") from None
    shapes = {k: v.shape for k, v in arrays.items()}
    if shapes != {"faces": (N_DENSE,), "barycentric": (N_DENSE, 3), "contour": (N_DENSE,), "sigma_px": (N_DENSE,)}:
        raise AssetError(f"MediaPipe embedding table {path} has arrays of shapes {shapes} ({_REMEDY})")
    bary = arrays["barycentric"].astype(np.float64)
    if not np.isfinite(bary).all() or bary.min() < 0 or np.abs(bary.sum(1) - 1.0).max() > 1e-4:
        raise AssetError(f"MediaPipe embedding table {path}: barycentric rows must be non-negative and sum to 1")
    return DenseEmbedding(
        faces=arrays["faces"].astype(np.int64),
        barycentric=bary / bary.sum(1, keepdims=True),
        contour=arrays["contour"].astype(bool),
        sigma_px=arrays["sigma_px"].astype(np.float64),
    )


def write_embedding_table(embedding: DenseEmbedding, asset: RigAsset, path: str | Path = EMBEDDING_TABLE) -> None:
    """Write ``embedding`` as the table :func:`read_embedding_table` reads (atomically): face ids int32,
    weights, sigma float32, and the asset's face count and version it was fitted on."""
    write_npz_atomic(
        path,
        {
            "faces": np.asarray(embedding.faces, np.int32),
            "barycentric": np.asarray(embedding.barycentric, np.float32),
            "contour": np.asarray(embedding.contour, bool),
            "sigma_px": np.asarray(embedding.sigma_px, np.float32),
            "template_faces": np.asarray(len(asset.faces), np.int64),
            "template_version": np.asarray(asset.version, np.int64),
        },
    )


@cached_per_asset
def _checked(asset: RigAsset) -> DenseEmbedding:
    embedding = read_embedding_table(EMBEDDING_TABLE)
    with np.load(EMBEDDING_TABLE, allow_pickle=False) as data:
        fitted_faces = int(data["template_faces"]) if "template_faces" in data.files else len(asset.faces)
    if fitted_faces != len(asset.faces) or embedding.faces.min() < 0 or embedding.faces.max() >= len(asset.faces):
        raise AssetError(
            f"MediaPipe embedding table {EMBEDDING_TABLE} was fitted on a template of {fitted_faces} faces "
            f"(face ids up to {embedding.faces.max()}); this asset has {len(asset.faces)} "
            f"(template version {asset.version}, code {TEMPLATE_VERSION}): {_REMEDY}"
        )
    return embedding


def mediapipe_embedding(asset: RigAsset | None = None) -> DenseEmbedding:
    """MediaPipe's 478 points on the template (the committed table, read and checked once per asset).

    Args:
        asset: the template (default :func:`rig.asset.load_asset`); the table must have been fitted on a
            template with its face count.

    Returns:
        :class:`DenseEmbedding`.

    Raises:
        FileNotFoundError: the table is missing. AssetError: it is unreadable or does not fit the asset.

    Example:
        >>> embedding = mediapipe_embedding()
        >>> embedding.faces.shape, embedding.barycentric.shape, int(embedding.contour.sum()) > 0
        ((478,), (478, 3), True)
    """
    return _checked(load_asset() if asset is None else asset)


__all__ = ["EMBEDDING_TABLE", "DenseEmbedding", "mediapipe_embedding", "read_embedding_table", "write_embedding_table"]
