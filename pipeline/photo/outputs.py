"""What ``jnr fit PHOTO`` writes (the files: :data:`pipeline.head.folders.PHOTO_FOLDER`), and reading its
parameters back.

The folder is written to a temporary folder beside it, then moved into place, so a failure leaves nothing
half-written. ``mesh.obj`` is the fitted head in rig space (mm, +Y up, +Z out of the face) with vertex
colours sampled from ``texture.png`` at the vertices' UVs (sRGB, the corners of a seam vertex
averaged), the template's UVs and the material ``skin`` of ``mesh.mtl`` (``map_Kd
texture.png``); ``texture.png`` is the face unwrapped from the photo into the template's UVs (1024 x 1024
sRGB, :mod:`pipeline.photo.texture`; texels the camera does not see take the fitted albedo); ``mesh.glb``
is the skinned glTF (metres; the fitted head as its bind mesh, so that readers that do not skin load the
fit, :func:`pipeline.head.skinned.write_skinned_head`; the 52 ARKit shapes as morph targets, the fitted
coefficients baked in, the joints posed by the fitted parameters, ``texture.png`` as
``baseColorTexture``, no ``COLOR_0``, which glTF would multiply with the texture); ``params.json`` follows
:mod:`pipeline.head.params` (fit ``photo``: the
camera, the head pose, the light); ``overlay.png`` shows the fitted face regions of the photometric loss
(60 %) over the photo with the input landmarks (green) and the fitted ones (red); ``landmarks3d.json`` holds
the 68 fitted landmarks in the camera frame (OpenCV, mm) with their iBUG names.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from html import escape
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from landmarks.formats import write_landmarks
from landmarks.ibug68.names import IBUG68_NAMES
from pipeline.camera import camera_from_head_pose
from pipeline.colour import linear_to_srgb
from pipeline.config import CONFIG_FILE, config_to_dict, dump_config
from pipeline.files import check_output, json_safe, staged_folder
from pipeline.head.curves import Curves, write_curves
from pipeline.head.fitted import FittedHead, fitted_head, fitted_head_from_arrays
from pipeline.head.folders import PHOTO_OUTPUT_SETS
from pipeline.head.params import UNITS, ParamsFileError, load_params_file, read_params
from pipeline.head.params import params_payload as head_params_payload
from pipeline.head.skinned import write_skinned_head
from pipeline.photo.fit import PhotoFit
from pipeline.photo.fit_config import MESH_UNITS, FitPhotoConfig
from pipeline.photo.texture import TEXTURE_SIZE, UVTexture, texture_from_fit, vertex_colours_from_texture
from pipeline.viewer import VIEWER_FILE, ViewerView, shared_three_src, write_fit_viewer
from render.lighting import Lighting
from render.renderer import DifferentiableRenderer
from rig.asset import RigAsset, load_asset
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES
from rig.geometry import head_angles
from rig.head_model import JnrHead
from rig.io.mesh import RIG_SPACE_COMMENT, export_mesh, write_mtl
from rig.model import JointRig
from rig.skinning.neural import NeuralSkinning

_log = logging.getLogger(__name__)
PHOTO_UNITS = {**UNITS, "pixels": "OpenCV, 0-based"}
MATERIAL_NAME = "skin"
"""The material of ``mesh.obj`` (``usemtl``) in ``mesh.mtl``."""
INPUT_COLOUR = (40, 220, 60)
FIT_COLOUR = (235, 40, 40)


def landmarks3d_payload(fit: PhotoFit) -> dict:
    """``landmarks3d.json``: the fitted 3D landmarks in the camera frame (mm), by iBUG-68 name."""
    points = np.asarray(fit.landmarks3d_camera, np.float64)
    return {
        "format": "jnr-landmarks3d/1",
        "frame": "camera (OpenCV: x right, y down, z forward)",
        "units": "mm",
        "names": list(IBUG68_NAMES),
        "points": [[float(c) for c in p] for p in points],
    }


TEXTURED_MESH_FILES = ("mesh.obj", "mesh.mtl", "texture.png", "mesh.ply")
"""The files :func:`write_textured_meshes` writes."""


def write_textured_meshes(
    folder: Path,
    vertices: np.ndarray,
    asset: RigAsset,
    colours: np.ndarray,
    texture_png: bytes,
    units: str = "mm",
    files=TEXTURED_MESH_FILES,
    ply_up: str = "y",
) -> None:
    """A fit's ``mesh.obj`` (the template's UVs, the material of ``mesh.mtl``: ``map_Kd texture.png``),
    ``mesh.mtl``, ``texture.png`` and ``mesh.ply``, those of them in ``files``: ``vertices (V, 3)`` rig space,
    mm, written in ``units`` (:func:`mesh_units`); ``colours (V, 3)`` uint8 sRGB vertex colours; ``ply_up``
    ``"y"`` (rig space) or ``"z"`` (``mesh.ply`` by :func:`z_up`, for Blender's PLY importer)."""
    scale, comment = mesh_units(units)
    if "mesh.obj" in files:
        export_mesh(
            folder / "mesh.obj",
            vertices * scale,
            asset.faces,
            face_uvs=asset.face_uvs,
            vertex_colors=colours,
            mtllib="mesh.mtl",
            material=MATERIAL_NAME,
            comment=comment,
        )
    if "mesh.mtl" in files:
        write_mtl(folder / "mesh.mtl", MATERIAL_NAME, "texture.png")
    if "texture.png" in files:
        (folder / "texture.png").write_bytes(texture_png)
    if "mesh.ply" in files:
        ply = z_up(vertices) if ply_up == "z" else np.asarray(vertices)
        if ply_up == "z":
            comment = comment.replace("+Y up, +Z out of the face", "+Z up, -Y out of the face (Blender's axes)")
        export_mesh(folder / "mesh.ply", ply * scale, asset.faces, vertex_colors=colours, comment=comment)


def z_up(points: np.ndarray) -> np.ndarray:
    """``(N, 3)`` rig-space points (+Y up, +Z out of the face) in Blender's frame (+Z up, the face towards
    -Y, x unchanged): a +90 degree rotation about x, ``(x, y, z) -> (x, -z, y)``."""
    points = np.asarray(points)
    return np.stack([points[:, 0], -points[:, 2], points[:, 1]], axis=1)


def mesh_units(units: str) -> tuple[float, str]:
    """``(factor from mm, header comment)`` of ``mesh.obj`` / ``mesh.ply`` in ``units`` (``outputs.units``)."""
    if units not in MESH_UNITS:
        raise InputError(f"outputs.units must be one of {list(MESH_UNITS)}, got {units!r}")
    return MESH_UNITS[units], RIG_SPACE_COMMENT.replace("millimetres", "metres" if units == "m" else "millimetres")


def landmarks3d_mesh_points(fit: PhotoFit, camera_points: np.ndarray | None = None) -> np.ndarray:
    """``(N, 3)`` fitted landmarks in the mesh's own frame (rig space: ``mesh.obj``'s, mm): ``camera_points
    (N, 3)`` (default ``fit.landmarks3d_camera``, the 68, the jaw contour as the camera saw it) taken back
    through the head pose (the inverse of :func:`pipeline.camera.camera_from_head_pose`), so they lie on
    ``mesh.obj``."""
    extrinsics = camera_from_head_pose(fit.rotation, fit.translation)  # rig -> camera
    camera = np.asarray(fit.landmarks3d_camera if camera_points is None else camera_points, np.float64)
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


KEYS_GLB = "mesh_keys.glb"
"""The fitted head for animation tools: its expression on the 52 shape keys, not baked into the mesh."""

DENSE_LANDMARKS_FILE = "landmarks3d_mediapipe.json"
"""MediaPipe's 478 fitted points in ``mesh.obj``'s frame (fits whose landmarks came from MediaPipe)."""


def dense_landmarks_payload(fit: PhotoFit, units: str = "mm") -> dict | None:
    """``landmarks3d_mediapipe.json``: the points of the dense layout the fit used (MediaPipe's 478, in its
    Face Mesh index order; the iris points 468-477 on the eyeballs) in ``mesh.obj``'s frame and ``units``;
    None for a fit of the 68 iBUG points."""
    if fit.dense3d_camera is None:
        return None
    scale, _ = mesh_units(units)
    points = landmarks3d_mesh_points(fit, fit.dense3d_camera) * scale
    return {
        "format": "jnr-landmarks3d/1",
        "layout": fit.dense_layout,
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
    """The :class:`~pipeline.head.fitted.FittedHead` of a photo fit (float64, from ``model``: default the
    committed rig and learned skinning)."""
    return fitted_head_from_arrays(fit.theta, fit.z, fit.expressions, model=model)


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
            "ambient_rgb": [float(x) for x in fit.ambient],
            "irradiance_rgb": [float(x) for x in fit.irradiance],
            "direction_rig": [float(x) for x in fit.light_direction_rig],
            "direction_camera": [float(x) for x in fit.light_direction_camera],
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


def render_fit(
    fit: PhotoFit,
    *,
    spp: int = 16,
    seed: int = 0,
    asset: RigAsset | None = None,
    mask_regions: tuple[str, ...] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The fitted head rendered at the photo's size with its albedo and light.

    Args:
        asset: the rig asset of the fit, for its faces (default: the committed one).
        mask_regions: region names (:data:`rig.template.REGION_NAMES`): the mask then covers only the
            pixels whose visible triangle belongs to one of them (e.g. :data:`rig.template.FACE_REGIONS`);
            None: every pixel the head covers.

    Returns:
        ``(image (H, W, 3) float32 linear RGB, mask (H, W) float32)``: the mask is 1 where the ray through
        the pixel centre hits the head (in ``mask_regions``), else 0.

    Raises:
        ValueError: an unknown region name.
    """
    asset = asset or load_asset()
    region_ids = None
    if mask_regions is not None:
        unknown = [r for r in mask_regions if r not in asset.region_names]
        if unknown:
            raise InputError(f"render_fit: unknown mask_regions {unknown}; the regions are {list(asset.region_names)}")
        region_ids = [asset.region_names.index(r) for r in mask_regions]
    v = torch.as_tensor(fit.rig_vertices, dtype=torch.float32)
    albedo = torch.as_tensor(fit.albedo, dtype=torch.float32)
    light = Lighting(
        torch.as_tensor(fit.ambient, dtype=torch.float32),
        torch.as_tensor(fit.irradiance, dtype=torch.float32),
        torch.as_tensor(fit.light_direction_rig, dtype=torch.float32),
    )
    renderer = DifferentiableRenderer(
        v,
        asset.faces,
        albedo,
        fit.camera,
        light,
        spp=spp,
        seed=seed,
        regions=None if region_ids is None else asset.regions,
    )
    with torch.no_grad():
        out = renderer.render(v, albedo, light, seed=seed, aovs=region_ids is not None)
    if region_ids is None:
        return out.image.numpy(), out.mask.numpy()
    return out.image.numpy(), np.isin(out.region_ids.numpy(), region_ids).astype(np.float32)


def overlay_image(
    photo: np.ndarray,
    render: np.ndarray,
    mask: np.ndarray,
    landmarks_in: np.ndarray,
    landmarks_fit: np.ndarray,
    alpha: float = 0.6,
) -> np.ndarray:
    """``(H, W, 3)`` uint8: the render (linear RGB) blended over the photo (uint8 sRGB) by ``alpha * mask``
    (``mask`` ``(H, W)`` in [0, 1]; where it is 0 the photo is unchanged), with the input landmarks as
    green dots and the fitted ones as red crosses."""
    import cv2

    rendered = (linear_to_srgb(render) * 255.0).astype(np.float32)
    a = (alpha * np.clip(mask, 0, 1))[..., None]
    out = np.ascontiguousarray(np.clip(photo.astype(np.float32) * (1 - a) + rendered * a, 0, 255).astype(np.uint8))
    radius = max(1, round(max(photo.shape[:2]) / 300))
    for x, y in np.asarray(landmarks_in, float):
        cv2.circle(out, (round(x), round(y)), radius + 1, INPUT_COLOUR, -1, lineType=cv2.LINE_AA)
    for x, y in np.asarray(landmarks_fit, float):
        p = (round(x), round(y))
        cv2.drawMarker(out, p, FIT_COLOUR, cv2.MARKER_CROSS, 3 * radius + 2, max(1, radius // 2 + 1), cv2.LINE_AA)
    return out


def _save_png(image: np.ndarray, path: Path) -> None:
    from PIL import Image

    Image.fromarray(np.ascontiguousarray(image)).save(path)


def _png_bytes(image: np.ndarray) -> bytes:
    """``image`` encoded as a PNG file (the same bytes go to ``texture.png`` and into ``mesh.glb``)."""
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="PNG")
    return buffer.getvalue()


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
            "mean_error_px": f * float(fit.error_px.mean()),
            "median_error_px": f * float(np.median(fit.error_px)),
            "max_error_px": f * float(fit.error_px.max()),
            "nme_inter_ocular": float(fit.nme),
            "landmark_fit_mean_error_px": f * float(lfit.error_px.mean()),
            "landmark_fit_nme": float(lfit.nme),
            "fitted_at_reduction": int(image_factor),
        },
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


def write_photo_outputs(
    out_dir: str | Path,
    photo: np.ndarray,
    fit: PhotoFit,
    *,
    config: FitPhotoConfig | None = None,
    force: bool = False,
    extra: dict | None = None,
    spp: int = 16,
    inputs: tuple = (),
    image_factor: int = 1,
    original_size: tuple[int, int] | None = None,
    rig: JointRig | None = None,
    neural: NeuralSkinning | None = None,
    texture_size: int = TEXTURE_SIZE,
    shared_three: str | Path | None = None,
) -> Path:
    """Write the output folder of a fit (see the module docstring) atomically.

    Args:
        out_dir: the folder; an existing one is replaced only with ``force``.
        photo: ``(H, W, 3)`` uint8 sRGB, the fitted photo.
        fit: the result of :func:`pipeline.photo.fit.fit_photo`.
        config: the settings used (recorded in ``report.json``).
        extra: more entries for ``report.json`` (e.g. the input file, the detection).
        spp: samples per pixel of ``render.png`` / ``overlay.png``.
        inputs: the command's input files (an output that is, contains or lies in one is refused).
        image_factor: ``k`` when the photo was fitted reduced by ``k``
            (:class:`landmarks.images.LoadedImage`): ``params.json``'s camera, ``landmarks.pts`` and the
            pixel errors of ``report.json`` are given in the photo file's pixels; ``overlay.png`` and
            ``render.png`` are at the reduced size (``texture.png`` is sampled from the reduced photo).
        original_size: ``(W, H)`` of the photo file (default: the fitted image's size).
        rig, neural: the models the fit ran with (the rig's asset gives the faces, UVs, joints and
            expressions; the learned skinning the glTF's weights); the files are computed in float64
            from them (:class:`rig.head_model.JnrHead`), so they are the same whether the fit's float32 models are
            given or the defaults (the committed rig and learned skinning) are loaded here.
        texture_size: side of ``texture.png`` in texels.
        shared_three: the folder holding a folder run's shared three.js (:data:`pipeline.viewer.SHARED_THREE_FILE`,
            written by :func:`pipeline.viewer.write_shared_three`): ``viewer.html`` loads it from there (a
            relative link) instead of inlining it; None: a self-contained page.

    Raises:
        pipeline.files.OutputError: ``out_dir`` is refused (exists without ``force``, not jnr's, an
            input; :class:`~pipeline.files.OutputExistsError` when it exists) or cannot be written.
    """
    out_dir = Path(out_dir)
    check_output(out_dir, force=force, inputs=inputs)  # before the rendering below
    seconds: dict[str, float] = {}
    clock = [time.perf_counter()]

    def lap(name: str) -> None:  # the seconds since the last lap, under name (logged at the end, -v)
        now = time.perf_counter()
        seconds[name] = seconds.get(name, 0.0) + now - clock[0]
        clock[0] = now

    head = photo_head(fit, JnrHead(rig=rig, neural=neural))
    asset = head.asset
    settings = config or FitPhotoConfig()
    wanted = set(PHOTO_OUTPUT_SETS[settings.outputs.files])

    def want(*names: str) -> bool:
        return any(n in wanted for n in names)

    face_regions = tuple(settings.photometric.face_regions)
    lap("head")
    render = face_mask = None
    if want("render.png", "overlay.png"):
        render, face_mask = render_fit(fit, spp=spp, asset=asset, mask_regions=face_regions)
        lap("render")
    texture = texture_png = colours = None
    if want("texture.png", "mesh.obj", "mesh.ply", "mesh.glb", KEYS_GLB, VIEWER_FILE):
        texture = texture_from_fit(
            photo,
            fit,
            asset.faces,
            asset.face_uvs,
            regions=asset.regions,
            skin_region_ids=[asset.region_names.index(r) for r in face_regions],
            size=texture_size,
        )
        texture_png = _png_bytes(texture.image)
        # what MeshLab, CloudCompare and Open3D show of the OBJ/PLY: the texture at each vertex (seams averaged)
        colours = vertex_colours_from_texture(texture.image, asset.faces, asset.face_uvs, len(asset.vertices))
        lap("texture")
    scale, _ = mesh_units(settings.outputs.units)

    with staged_folder(out_dir, force, inputs=inputs, marker={"command": (extra or {}).get("command")}) as tmp:
        write_textured_meshes(
            tmp, fit.rig_vertices, asset, colours, texture_png, settings.outputs.units, wanted, settings.outputs.ply_up
        )
        lap("obj, ply")
        if want("mesh.glb"):
            write_skinned_head(
                tmp / "mesh.glb", asset, head.weights, head.tau, head.expressions, base_color_texture=texture_png
            )
        if want(KEYS_GLB):  # the same head for animation tools: the expression on the shape keys (issue 38)
            write_skinned_head(
                tmp / KEYS_GLB,
                asset,
                head.weights,
                head.tau,
                head.expressions,
                base_color_texture=texture_png,
                expression="keys",
            )
        lap("glb")
        params = params_payload(fit, image_factor, original_size, head)
        (tmp / "params.json").write_text(json.dumps(params, indent=2) + "\n")
        k = image_factor
        if want("render.png"):
            srgb = np.clip(np.round(linear_to_srgb(render) * 255), 0, 255).astype(np.uint8)
            _save_png(srgb, tmp / "render.png")
        if want("overlay.png"):
            _save_png(overlay_image(photo, render, face_mask, fit.landmarks2d, fit.landmarks_px), tmp / "overlay.png")
        if want("landmarks.pts"):
            write_landmarks(tmp / "landmarks.pts", np.asarray(fit.landmarks2d, float) * k + (k - 1) / 2)
        if want("landmarks_fitted.pts"):
            write_landmarks(tmp / "landmarks_fitted.pts", np.asarray(fit.landmarks_px, float) * k + (k - 1) / 2)
        if want("landmarks3d.json"):
            (tmp / "landmarks3d.json").write_text(json.dumps(landmarks3d_payload(fit), indent=2) + "\n")
        if want("landmarks3d_mesh.json"):
            mesh_landmarks = landmarks3d_mesh_payload(fit, settings.outputs.units)  # in mesh.obj's units
            (tmp / "landmarks3d_mesh.json").write_text(json.dumps(mesh_landmarks, indent=2) + "\n")
        if want("landmarks3d.pp", NOW_FILE):
            points = landmarks3d_mesh_points(fit) * scale
            if want("landmarks3d.pp"):
                (tmp / "landmarks3d.pp").write_text(meshlab_picked_points(points, IBUG68_NAMES))
            if want(NOW_FILE):
                (tmp / NOW_FILE).write_text(now_landmarks_txt(points))
        dense = dense_landmarks_payload(fit, settings.outputs.units) if want(DENSE_LANDMARKS_FILE) else None
        if dense is not None:
            (tmp / DENSE_LANDMARKS_FILE).write_text(json.dumps(dense, indent=1) + "\n")
        if want("expressions.csv"):
            (tmp / "expressions.csv").write_text(expressions_csv(fit.expressions))
        if want(LIVE_LINK_FILE):
            write_curves(tmp / LIVE_LINK_FILE, fit_curves(fit), layout="live-link-face")
        report = report_payload(fit, config=config, extra=extra, image_factor=k, texture=texture)
        (tmp / "report.json").write_text(json.dumps(report, indent=2) + "\n")
        dump_config(settings, tmp / CONFIG_FILE, command=(extra or {}).get("command"))
        lap("pngs, landmarks, json, csv")
        if want(VIEWER_FILE):
            write_fit_viewer(
                tmp / VIEWER_FILE,
                asset,
                theta=head.theta,
                expressions=head.expressions,
                weights=head.weights,
                views=[ViewerView(out_dir.name, params["camera"], photo)],
                texture=texture.image,
                latent_z=fit.z,
                three_src=None if shared_three is None else shared_three_src(out_dir, shared_three),
                title=f"jnr fit: {out_dir.name}",
                subtitle=f"landmark NME {float(fit.nme):.3f}",
            )
            lap("viewer")
    lap("staging")
    _log.info(
        "%s: outputs in %.2f s (%s)",
        out_dir,
        sum(seconds.values()),
        ", ".join(f"{name} {value:.2f} s" for name, value in seconds.items()),
    )
    return out_dir
