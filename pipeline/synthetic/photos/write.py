"""Writing a synthetic photo and its ground truth into a folder (:func:`write_synthetic_photo`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from landmarks.formats import write_landmarks
from pipeline.synthetic.photos.settings import SyntheticPhoto
from rig.asset import RigAsset, load_asset
from rig.errors import InputError


def write_synthetic_photo(photo: SyntheticPhoto, out_dir: str | Path, asset: RigAsset | None = None) -> Path:
    """Write a photo and its ground truth into ``out_dir`` (created if needed; files are overwritten).

    Files: ``photo.png`` (the sRGB image), ``landmarks.pts`` (the noisy landmarks, iBUG ``.pts``,
    :func:`landmarks.formats.write_landmarks`), ``truth.ply`` (the true mesh in rig space, mm, with the
    template's faces) and ``truth.json`` (name, image size, focal, principal point, pose, angles, light
    in rig space, the exact landmarks).

    Args:
        photo: :class:`SyntheticPhoto`.
        out_dir: the folder.
        asset: the template whose faces the mesh uses (default :func:`rig.asset.load_asset`).

    Returns:
        ``out_dir`` as a ``Path``.

    Raises:
        ValueError: the photo's mesh does not have the template's vertex count.
    """
    import trimesh
    from PIL import Image

    asset = load_asset() if asset is None else asset
    if photo.gt_vertices.shape != asset.vertices.shape:
        raise InputError(
            f"write_synthetic_photo: expected gt_vertices of shape {asset.vertices.shape}, "
            f"got {photo.gt_vertices.shape}"
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.asarray(photo.image, np.uint8)).save(out / "photo.png")
    write_landmarks(out / "landmarks.pts", photo.landmarks2d)
    mesh = trimesh.Trimesh(vertices=photo.gt_vertices, faces=asset.faces, process=False)
    mesh.export(out / "truth.ply")
    truth = {
        "name": photo.name,
        "width": int(photo.width),
        "height": int(photo.height),
        "focal": float(photo.focal),
        "principal": [(photo.width - 1) / 2.0, (photo.height - 1) / 2.0],
        "pose_convention": "x_cam = diag(1, -1, -1) @ rotation @ x_rig + translation (OpenCV camera, mm)",
        "rotation": np.asarray(photo.rotation, float).tolist(),
        "translation": np.asarray(photo.translation, float).tolist(),
        "yaw_deg": float(photo.yaw_deg),
        "pitch_deg": float(photo.pitch_deg),
        "roll_deg": float(photo.roll_deg),
        "light": {**photo.light.to_dict(), "frame": "rig"},
        "landmarks2d_true": np.asarray(photo.landmarks2d_true, float).tolist(),
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
    return out


__all__ = ["write_synthetic_photo"]
