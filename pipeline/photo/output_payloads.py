"""What the text files of a photo fit hold (:mod:`pipeline.photo.outputs` writes them), and reading its
``params.json`` back: ``params.json`` (:func:`params_payload`, :func:`mesh_from_photo_params`), ``report.json``
(:func:`report_payload`), the landmark files (``landmarks3d.json``, ``landmarks3d_mesh.json``, MeshLab's
``landmarks3d.pp``, NoW's ``landmarks_now.txt``, ``landmarks3d_mediapipe.json``) and the expression files
(``expressions.csv``, Live Link Face's ``expressions_livelink.csv``). Plain functions of the fit: they
return the contents, they write nothing.
"""

from __future__ import annotations

from dataclasses import asdict
from html import escape
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from landmarks.ibug68.names import IBUG68_NAMES
from pipeline.camera import camera_from_head_pose
from pipeline.config import config_to_dict
from pipeline.files import json_safe
from pipeline.head.curves import Curves
from pipeline.head.fitted import FittedHead, fitted_head, fitted_head_from_params
from pipeline.head.params import UNITS, ParamsFileError, load_params_file, read_params
from pipeline.head.params import params_payload as head_params_payload
from pipeline.photo.fit import PhotoFit
from pipeline.photo.fit_config import MESH_UNITS, FitPhotoConfig
from pipeline.photo.texture import UVTexture
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES
from rig.geometry import head_angles
from rig.head_model import JnrHead
from rig.io.mesh import RIG_SPACE_COMMENT

PHOTO_UNITS = {**UNITS, "pixels": "OpenCV, 0-based"}


def landmarks3d_payload(fit: PhotoFit) -> dict:
    """``landmarks3d.json``: the fitted 3D landmarks in the camera frame (mm), by iBUG-68 name."""
    points = np.asarray(fit.landmarks.camera3d, np.float64)
    return {
        "format": "jnr-landmarks3d/1",
        "frame": "camera (OpenCV: x right, y down, z forward)",
        "units": "mm",
        "names": list(IBUG68_NAMES),
        "points": [[float(c) for c in p] for p in points],
    }


def mesh_units(units: str) -> tuple[float, str]:
    """``(factor from mm, header comment)`` of ``mesh.obj`` / ``mesh.ply`` in ``units`` (``outputs.units``)."""
    if units not in MESH_UNITS:
        raise InputError(f"outputs.units must be one of {list(MESH_UNITS)}, got {units!r}")
    return MESH_UNITS[units], RIG_SPACE_COMMENT.replace("millimetres", "metres" if units == "m" else "millimetres")


def landmarks3d_mesh_points(fit: PhotoFit, camera_points: np.ndarray | None = None) -> np.ndarray:
    """``(N, 3)`` fitted landmarks in the mesh's own frame (rig space: ``mesh.obj``'s, mm): ``camera_points
    (N, 3)`` (default ``fit.landmarks.camera3d``, the 68, the jaw contour as the camera saw it) taken back
    through the head pose (the inverse of :func:`pipeline.camera.camera_from_head_pose`), so they lie on
    ``mesh.obj``."""
    extrinsics = camera_from_head_pose(fit.rotation, fit.translation)  # rig -> camera
    camera = np.asarray(fit.landmarks.camera3d if camera_points is None else camera_points, np.float64)
    return (camera - extrinsics[:3, 3]) @ extrinsics[:3, :3]


def landmarks3d_mesh_payload(fit: PhotoFit, units: str = "mm") -> dict:
    """``landmarks3d_mesh.json``: :func:`landmarks3d_mesh_points` by iBUG-68 name, in ``units`` (mesh.obj's)."""
    scale, _ = mesh_units(units)
    return {
        "format": "jnr-landmarks3d/1",
        "frame": "mesh (mesh.obj's rig space: x the subject's left, +Y up, +Z out of the face)",
        "units": units,
        "names": list(IBUG68_NAMES),
        "points": [[float(c) for c in p] for p in landmarks3d_mesh_points(fit) * scale],
    }


DENSE_LANDMARKS_FILE = "landmarks3d_mediapipe.json"
"""MediaPipe's 478 fitted points in ``mesh.obj``'s frame (fits whose landmarks came from MediaPipe)."""


def dense_landmarks_payload(fit: PhotoFit, units: str = "mm") -> dict | None:
    """``landmarks3d_mediapipe.json``: the points of the dense layout the fit used (MediaPipe's 478, in its
    Face Mesh index order; the iris points 468-477 on the eyeballs) in ``mesh.obj``'s frame and ``units``;
    None for a fit of the 68 iBUG points."""
    if fit.landmarks.dense_camera3d is None:
        return None
    scale, _ = mesh_units(units)
    points = landmarks3d_mesh_points(fit, fit.landmarks.dense_camera3d) * scale
    return {
        "format": "jnr-landmarks3d/1",
        "layout": fit.landmarks.dense_layout,
        "frame": "mesh (mesh.obj's rig space: x the subject's left, +Y up, +Z out of the face)",
        "units": units,
        "names": [str(i) for i in range(len(points))],
        "points": [[float(c) for c in p] for p in points],
    }


NOW_FILE = "landmarks_now.txt"
"""The 7 points the NoW benchmark aligns a predicted mesh with (its ``.txt`` landmark file)."""
NOW_IBUG_INDICES = (36, 39, 42, 45, 33, 48, 54)
"""NoW's 7 landmarks as iBUG-68 indices, in NoW's order: right eye outer and inner corner, left eye inner and
outer corner, nose bottom (subnasale), right and left mouth corner (the subject's sides; the order the NoW
evaluation's scan landmarks and RingNet/DECA/MICA/metrical-tracker's predictions use)."""


def now_landmarks_txt(points68: np.ndarray) -> str:
    """NoW's landmark text file of a mesh: the :data:`NOW_IBUG_INDICES` rows of ``points68 (68, 3)`` (in the
    mesh's frame and units), one ``x y z`` line each, single spaces (the evaluation splits on ``" "``)."""
    points = np.asarray(points68, np.float64)
    if points.shape != (68, 3):
        raise InputError(f"now_landmarks_txt: expected (68, 3) iBUG points, got {points.shape}")
    return "\n".join(" ".join(f"{c:.6f}" for c in points[i]) for i in NOW_IBUG_INDICES) + "\n"


def meshlab_picked_points(points: np.ndarray, names, mesh_file: str = "mesh.obj") -> str:
    """MeshLab's picked-points file (``.pp``, Edit > PickPoints > Load) of ``points (N, 3)`` in ``mesh_file``'s
    frame and units, one ``<point>`` per name (no date, so the same fit writes the same file)."""
    rows = "".join(
        f' <point x="{x:.6f}" y="{y:.6f}" z="{z:.6f}" active="1" name="{escape(str(n), quote=True)}"/>\n'
        for (x, y, z), n in zip(np.asarray(points, np.float64), names, strict=True)
    )
    head = (
        '<!DOCTYPE PickedPoints>\n<PickedPoints>\n <DocumentData>\n  <User name="jnr"/>\n'
        f'  <DataFileName name="{escape(mesh_file, quote=True)}"/>\n  <templateName name=""/>\n </DocumentData>\n'
    )
    return head + rows + "</PickedPoints>\n"


LIVE_LINK_FILE = "expressions_livelink.csv"
"""The fit's ARKit coefficients in Live Link Face's CSV layout (:func:`fit_curves`)."""


def fit_curves(fit: PhotoFit) -> Curves:
    """The fit as one frame of ARKit curves: its 52 coefficients and its head angles (yaw, pitch, roll of
    the head pose, :func:`rig.geometry.head_angles`, degrees), written by
    :func:`pipeline.head.curves.write_curves` in Live Link Face's layout (Timecode, BlendShapeCount,
    capitalised names, radians) and read back by ``jnr animate``."""
    angles = np.asarray(head_angles(np.asarray(fit.rotation, np.float64)), np.float64)
    return Curves(np.zeros(1), np.asarray(fit.expressions, np.float64)[None], angles[None], "live-link-face")


def expressions_csv(coefficients) -> str:
    """One CSV row of the 52 ARKit coefficients under a header of their ARKit names (the Live Link Face
    column names, without its timecode columns)."""
    values = np.asarray(coefficients, np.float64)
    return ",".join(EXPRESSION_NAMES) + "\n" + ",".join(f"{v:.6f}" for v in values) + "\n"


def photo_head(fit: PhotoFit, model: JnrHead | None = None) -> FittedHead:
    """The :class:`~pipeline.head.fitted.FittedHead` of a photo fit (float64, from ``model`` when it is of the
    fit's head model: default the committed rig and learned skinning), from the head model's parameters the fit
    returned."""
    return fitted_head_from_params(fit.head, model=model)


def params_payload(
    fit: PhotoFit,
    image_factor: int = 1,
    original_size: tuple[int, int] | None = None,
    head: FittedHead | None = None,
) -> dict:
    """The ``params.json`` content of a fit (:mod:`pipeline.head.params`, fit ``photo``); the camera in the
    photo file's pixels when the fit ran on the photo reduced by ``image_factor`` (working pixel ``x`` is
    file pixel ``f x + (f - 1) / 2``)."""
    head = head or photo_head(fit)
    f = int(image_factor)
    k = fit.camera.intrinsics[0].double().numpy()
    return head_params_payload(
        head.model,
        head.params,
        fit="photo",
        units=PHOTO_UNITS,
        camera={
            "description": "pinhole, OpenCV axes (x right, y down, z forward); x_cam = extrinsics @ [x_rig, 1]",
            "width": int(original_size[0] if original_size else fit.width),
            "height": int(original_size[1] if original_size else fit.height),
            "focal_px": float(fit.focal) * f,
            "principal_point_px": [float(k[0, 2]) * f + (f - 1) / 2, float(k[1, 2]) * f + (f - 1) / 2],
            "fitted_at_reduction": f,
            "extrinsics_rig_to_camera": camera_from_head_pose(fit.rotation, fit.translation).tolist(),
        },
        pose={
            "description": "head pose: x_cam = RIG_TO_OPENCV @ R @ x_rig + t, RIG_TO_OPENCV = diag(1, -1, -1)",
            "rotation_matrix": fit.rotation.tolist(),
            "rotation_vector_rad": [float(x) for x in Rotation.from_matrix(fit.rotation).as_rotvec()],
            "translation_mm": [float(x) for x in fit.translation],
        },
        light={
            "model": "ambient + directional, Lambertian: a * ambient + a / pi * irradiance * max(0, n . -d)",
            "ambient_rgb": [float(x) for x in fit.appearance.ambient],
            "irradiance_rgb": [float(x) for x in fit.appearance.irradiance],
            "direction_rig": [float(x) for x in fit.appearance.light_rig],
            "direction_camera": [float(x) for x in fit.appearance.light_camera],
        },
        albedo="per-vertex linear RGB in mesh.ply / mesh.obj (sRGB-encoded there)",
    )


def mesh_from_photo_params(params: dict | str | Path, *, frame: str = "rig") -> np.ndarray:
    """Rebuild the fitted head from a photo fit's ``params.json`` (its dict or path).

    Args:
        frame: ``"rig"`` (rig space, as ``mesh.obj``) or ``"camera"`` (the photo camera's frame, mm).

    Returns:
        ``(V, 3)`` float64 vertices, mm.

    Raises:
        ParamsFileError: not a ``jnr fit`` parameter file, or bad contents. ValueError: an unknown frame.
    """
    if frame not in ("rig", "camera"):
        raise InputError(f"frame must be 'rig' or 'camera', got {frame!r}")
    fit = load_params_file(params) if not isinstance(params, dict) else read_params(params)
    if fit.fit != "photo":
        raise ParamsFileError(f"not a jnr fit parameter file of one photo (written by {fit.fit or 'no fit'})")
    v = fitted_head(fit).vertices
    if frame == "camera":
        e = np.asarray(fit.data["camera"]["extrinsics_rig_to_camera"], float)
        v = v @ e[:3, :3].T + e[:3, 3]
    return v


def texture_payload(texture: UVTexture) -> dict:
    """``report.json``'s ``texture`` entry: the file, its size, how much of it the photo gives, the fill."""
    return {
        "file": "texture.png",
        "size_px": int(texture.image.shape[0]),
        "seen_fraction": round(texture.visible_fraction, 4),
        "description": "share of the texels inside the UV triangles whose point the camera sees",
        "fill": texture.fill,
        "seconds": round(texture.seconds, 3),
    }


def report_payload(
    fit: PhotoFit,
    *,
    config: FitPhotoConfig | None = None,
    extra: dict | None = None,
    image_factor: int = 1,
    texture: UVTexture | None = None,
) -> dict:
    """The ``report.json`` content of a fit (without the input description, see ``extra``); pixel errors
    in the photo file's pixels (the fit's ones times ``image_factor``); with ``texture`` its
    :func:`texture_payload`."""
    lfit = fit.landmark_fit
    f = float(image_factor)
    report = {
        "landmarks": {
            "mean_error_px": f * float(fit.landmarks.error_px.mean()),
            "median_error_px": f * float(np.median(fit.landmarks.error_px)),
            "max_error_px": f * float(fit.landmarks.error_px.max()),
            "nme_inter_ocular": float(fit.landmarks.nme),
            "landmark_fit_mean_error_px": f * float(lfit.error_px.mean()),
            "landmark_fit_nme": float(lfit.nme),
            "fitted_at_reduction": int(image_factor),
        },
        "identity_prior": "population" if lfit.identity is None else "regressed from the detector's 3D points",
        "landmark_stages": lfit.losses,
        "landmark_stage_logs": [asdict(s) for s in lfit.stages],
        "photometric_stages": [asdict(s) for s in fit.stages],
        "crop": None if fit.crop is None else dict(fit.crop.__dict__),
        "timings_s": fit.timings,
        "config": config_to_dict(config) if config is not None else None,
    }
    if texture is not None:
        report["texture"] = texture_payload(texture)
    report.update(extra or {})
    return json_safe(report)
