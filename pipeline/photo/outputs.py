"""What ``jnr fit PHOTO`` writes, and reading its parameters back.

The output folder (written to a temporary folder beside it, then moved into place, so a failure
leaves nothing half-written):

========================  ===========================================================================
file                   contents
========================  ===========================================================================
``mesh.obj``              the fitted head in rig space (mm, +Y up, +Z out of the face), vertex colours
                          = fitted albedo (sRGB), the template's UVs, the material ``skin`` of ``mesh.mtl``
``mesh.mtl``              the material: ``map_Kd texture.png`` (white ``Kd``)
``texture.png``           the face unwrapped from the photo into the template's UVs (1024 x 1024 sRGB,
                          :mod:`pipeline.photo.texture`); texels the camera does not see take the fitted
                          albedo (the median skin colour seen without photometric stages)
``mesh.ply``              the same, binary PLY with vertex colours
``mesh.glb``              skinned glTF 2.0 (metres): the template with the 52 ARKit shapes as morph targets
                          named by ARKit, weighted by the fitted coefficients; the 52 joints posed by the
                          fitted parameters, the fitted skinning weights, ``texture.png`` as the material's
                          ``baseColorTexture`` (``TEXCOORD_0``, v flipped from OBJ's); no ``COLOR_0``,
                          which glTF would multiply with the texture
``params.json``           joints by name (deg, mm, factor), latent Z, expressions by name, the camera
                          (focal, principal point, image size, rig -> camera extrinsics), the head pose,
                          the light (ambient, irradiance, direction in rig space and camera frame);
                          its ``joints`` key is also a valid ``jnr rig edit`` parameter file
``overlay.png``           the photo with the fitted face rendered over it (60 %; the face regions only,
                          those of the photometric loss: no neck, scalp or ears over the photo), the input
                          landmarks (green) and the fitted ones (red)
``render.png``            the fitted head, albedo and light, rendered alone at the photo's size
``landmarks.pts``         the 68 input landmarks (iBUG .pts, 1-based pixels)
``landmarks_fitted.pts``  the 68 fitted landmarks: the fitted head's, projected (iBUG .pts, 1-based)
``landmarks3d.json``      the 68 fitted landmarks in 3D, camera frame (OpenCV: x right, y down, z forward),
                          mm, with their iBUG names (projected with ``params.json``'s camera: the .pts)
``expressions.csv``       the 52 ARKit expression coefficients as one CSV row under their ARKit names
``report.json``           landmark error (px, NME), every loss term per stage, timings, input, configuration,
                          the texture's seen fraction and fill
``config.yaml``           the configuration used, every field resolved (``--config`` repeats the fit)
``viewer.html``           a self-contained web page (:mod:`pipeline.viewer`): the fitted head over the photo
                          through ``params.json``'s camera, sliders for the joints and the 52 ARKit shapes
                          (skipped with a warning where three.js was not installed by ``make venv``)
========================  ===========================================================================
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from pipeline.config import CONFIG_FILE, config_to_dict, dump_config
from pipeline.files import check_output, json_safe, staged_folder
from pipeline.photo.camera import camera_from_head_pose
from pipeline.photo.colour import linear_to_srgb
from pipeline.photo.fit import FitPhotoConfig, PhotoFit
from pipeline.photo.texture import TEXTURE_SIZE, UVTexture, texture_from_fit
from pipeline.scan.outputs import rig_vertices_from_params
from rig.asset import RigAsset, load_asset
from rig.expressions import EXPRESSION_NAMES
from rig.model import JointRig
from rig.parameters import theta_to_params
from rig.skinning.neural import NeuralSkinning, load_neural

PARAMS_FORMAT = "jnr-photo-params/1"
OUTPUT_FILES = ("mesh.obj", "mesh.mtl", "texture.png", "mesh.ply", "mesh.glb", "params.json", "overlay.png",
                "render.png", "landmarks.pts", "landmarks_fitted.pts", "landmarks3d.json", "expressions.csv",
                "report.json", CONFIG_FILE, "viewer.html")
MATERIAL_NAME = "skin"
"""The material of ``mesh.obj`` (``usemtl``) in ``mesh.mtl``."""
INPUT_COLOUR = (40, 220, 60)
FIT_COLOUR = (235, 40, 40)


def landmarks3d_payload(fit: PhotoFit) -> dict:
    """``landmarks3d.json``: the fitted 3D landmarks in the camera frame (mm), by iBUG-68 name."""
    from landmarks.ibug68 import IBUG68_NAMES

    points = np.asarray(fit.landmarks3d_camera, np.float64)
    return {"format": "jnr-landmarks3d/1", "frame": "camera (OpenCV: x right, y down, z forward)", "units": "mm",
            "names": list(IBUG68_NAMES), "points": [[float(c) for c in p] for p in points]}


def expressions_csv(coefficients) -> str:
    """One CSV row of the 52 ARKit coefficients under a header of their ARKit names (the Live Link Face
    column names, without its timecode columns)."""
    values = np.asarray(coefficients, np.float64)
    return ",".join(EXPRESSION_NAMES) + "\n" + ",".join(f"{v:.6f}" for v in values) + "\n"


def params_payload(fit: PhotoFit, image_factor: int = 1, original_size: tuple[int, int] | None = None) -> dict:
    """The ``params.json`` content of a fit; the camera in the photo file's pixels when the fit ran on
    the photo reduced by ``image_factor`` (working pixel ``x`` is file pixel ``f x + (f - 1) / 2``)."""
    from scipy.spatial.transform import Rotation

    f = int(image_factor)
    k = fit.camera.intrinsics[0].double().numpy()
    return {
        "format": PARAMS_FORMAT,
        "units": {"rotate": "deg", "translate": "mm", "scale": "factor", "pixels": "OpenCV, 0-based"},
        "joints": theta_to_params(torch.as_tensor(fit.theta), include_rest=True),
        "latent_z": [float(x) for x in fit.z],
        "expressions": {n: float(c) for n, c in zip(EXPRESSION_NAMES, fit.expressions)},
        "camera": {
            "description": "pinhole, OpenCV axes (x right, y down, z forward); x_cam = extrinsics @ [x_rig, 1]",
            "width": int(original_size[0] if original_size else fit.width),
            "height": int(original_size[1] if original_size else fit.height), "focal_px": float(fit.focal) * f,
            "principal_point_px": [float(k[0, 2]) * f + (f - 1) / 2, float(k[1, 2]) * f + (f - 1) / 2],
            "fitted_at_reduction": f,
            "extrinsics_rig_to_camera": camera_from_head_pose(fit.rotation, fit.translation).tolist(),
        },
        "pose": {
            "description": "head pose: x_cam = RIG_TO_OPENCV @ R @ x_rig + t, RIG_TO_OPENCV = diag(1, -1, -1)",
            "rotation_matrix": fit.rotation.tolist(),
            "rotation_vector_rad": [float(x) for x in Rotation.from_matrix(fit.rotation).as_rotvec()],
            "translation_mm": [float(x) for x in fit.translation],
        },
        "light": {
            "model": "ambient + directional, Lambertian: a * ambient + a / pi * irradiance * max(0, n . -d)",
            "ambient_rgb": [float(x) for x in fit.ambient],
            "irradiance_rgb": [float(x) for x in fit.irradiance],
            "direction_rig": [float(x) for x in fit.light_direction_rig],
            "direction_camera": [float(x) for x in fit.light_direction_camera],
        },
        "albedo": "per-vertex linear RGB in mesh.ply / mesh.obj (sRGB-encoded there)",
    }


def mesh_from_photo_params(params: dict | str | Path, *, rig: JointRig | None = None, frame: str = "rig"
                           ) -> np.ndarray:
    """Rebuild the fitted head from a ``params.json`` (its dict or path).

    Args:
        frame: ``"rig"`` (rig space, as ``mesh.obj``) or ``"camera"`` (the photo camera's frame, mm).

    Returns:
        ``(V, 3)`` float64 vertices, mm.

    Raises:
        ValueError: not a ``jnr fit`` parameter file, or bad contents.
    """
    if not isinstance(params, dict):
        params = json.loads(Path(params).read_text())
    if params.get("format") != PARAMS_FORMAT:
        raise ValueError(f"not a jnr fit parameter file (format {params.get('format')!r}, expected {PARAMS_FORMAT!r})")
    if frame not in ("rig", "camera"):
        raise ValueError(f"frame must be 'rig' or 'camera', got {frame!r}")
    v = rig_vertices_from_params(params, rig=rig)
    if frame == "camera":
        e = np.asarray(params["camera"]["extrinsics_rig_to_camera"], float)
        v = v @ e[:3, :3].T + e[:3, 3]
    return v


def render_fit(fit: PhotoFit, *, spp: int = 16, seed: int = 0, asset: RigAsset | None = None,
               mask_regions: tuple[str, ...] | None = None) -> tuple[np.ndarray, np.ndarray]:
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
    from render.lighting import Lighting
    from render.renderer import DifferentiableRenderer

    asset = asset or load_asset()
    region_ids = None
    if mask_regions is not None:
        unknown = [r for r in mask_regions if r not in asset.region_names]
        if unknown:
            raise ValueError(f"render_fit: unknown mask_regions {unknown}; the regions are {list(asset.region_names)}")
        region_ids = [asset.region_names.index(r) for r in mask_regions]
    v = torch.as_tensor(fit.rig_vertices, dtype=torch.float32)
    albedo = torch.as_tensor(fit.albedo, dtype=torch.float32)
    light = Lighting(torch.as_tensor(fit.ambient, dtype=torch.float32),
                     torch.as_tensor(fit.irradiance, dtype=torch.float32),
                     torch.as_tensor(fit.light_direction_rig, dtype=torch.float32))
    renderer = DifferentiableRenderer(v, asset.faces, albedo, fit.camera, light, spp=spp, seed=seed,
                                      regions=None if region_ids is None else asset.regions)
    with torch.no_grad():
        out = renderer.render(v, albedo, light, seed=seed, aovs=region_ids is not None)
    if region_ids is None:
        return out.image.numpy(), out.mask.numpy()
    return out.image.numpy(), np.isin(out.region_ids.numpy(), region_ids).astype(np.float32)


def overlay_image(photo: np.ndarray, render: np.ndarray, mask: np.ndarray, landmarks_in: np.ndarray,
                  landmarks_fit: np.ndarray, alpha: float = 0.6) -> np.ndarray:
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
    return {"file": "texture.png", "size_px": int(texture.image.shape[0]),
            "seen_fraction": round(texture.visible_fraction, 4),
            "description": "share of the texels inside the UV triangles whose point the camera sees",
            "fill": texture.fill, "seconds": round(texture.seconds, 3)}


def report_payload(fit: PhotoFit, *, config: FitPhotoConfig | None = None, extra: dict | None = None,
                   image_factor: int = 1, texture: UVTexture | None = None) -> dict:
    """The ``report.json`` content of a fit (without the input description, see ``extra``); pixel errors
    in the photo file's pixels (the fit's ones times ``image_factor``); with ``texture`` its
    :func:`texture_payload`."""
    lfit = fit.landmark_fit
    f = float(image_factor)
    report = {
        "landmarks": {
            "mean_error_px": f * float(fit.error_px.mean()), "median_error_px": f * float(np.median(fit.error_px)),
            "max_error_px": f * float(fit.error_px.max()), "nme_inter_ocular": float(fit.nme),
            "landmark_fit_mean_error_px": f * float(lfit.error_px.mean()), "landmark_fit_nme": float(lfit.nme),
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


def output_models(rig: JointRig | None = None, neural: NeuralSkinning | None = None
                  ) -> tuple[JointRig, NeuralSkinning]:
    """The float64 models the output files of a fit are computed with, from the fit's own ones.

    Args:
        rig: the fit's rig; a float64 one is used as it is, another one is rebuilt in float64 on its
            asset (default: the committed asset).
        neural: the fit's learned skinning; one on the float64 ``rig`` is used as it is, another one is
            converted (its learned linear weights and a float64 copy of its decoder; a float32 model's
            linear weights are float32-rounded). Default: the committed learned skinning.

    Returns:
        ``(rig, neural)``, float64, ``neural`` on ``rig``; nothing that was given is reloaded.
    """
    import copy

    f64 = torch.float64
    if rig is None or rig.template.dtype != f64:
        rig = JointRig(rig.asset if rig is not None else load_asset(), dtype=f64)
    if neural is None:
        neural = load_neural(rig)[0]
    elif neural.rig is not rig:
        neural = NeuralSkinning(rig, neural.linear_free.to(f64), copy.deepcopy(neural.decoder))
    return rig, neural


def write_photo_outputs(out_dir: str | Path, photo: np.ndarray, fit: PhotoFit, *,
                        config: FitPhotoConfig | None = None, force: bool = False, extra: dict | None = None,
                        spp: int = 16, inputs: tuple = (), image_factor: int = 1,
                        original_size: tuple[int, int] | None = None, rig: JointRig | None = None,
                        neural: NeuralSkinning | None = None, texture_size: int = TEXTURE_SIZE) -> Path:
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
            (:class:`landmarks.detect.LoadedImage`): ``params.json``'s camera, ``landmarks.pts`` and the
            pixel errors of ``report.json`` are given in the photo file's pixels; ``overlay.png`` and
            ``render.png`` are at the reduced size (``texture.png`` is sampled from the reduced photo).
        original_size: ``(W, H)`` of the photo file (default: the fitted image's size).
        rig, neural: the models the fit ran with (the rig's asset gives the faces, UVs, joints and
            expressions; the learned skinning the glTF's weights); :func:`output_models` computes the
            files in float64 from them, so they are the same whether the fit's float32 models are
            given or the defaults (the committed rig and learned skinning) are loaded here.
        texture_size: side of ``texture.png`` in texels.

    Raises:
        pipeline.files.OutputError: ``out_dir`` is refused (exists without ``force``, not jnr's, an
            input; :class:`~pipeline.files.OutputExistsError` when it exists) or cannot be written.
    """
    from landmarks.formats import write_landmarks
    from pipeline.edit import write_skinned_head
    from pipeline.viewer import VIEWER_FILE, ViewerView, write_fit_viewer
    from rig.io.mesh import export_mesh, write_mtl

    out_dir = Path(out_dir)
    check_output(out_dir, force=force, inputs=inputs)  # before the rendering below
    rig, neural = output_models(rig, neural)
    asset = rig.asset
    colours = np.clip(np.round(linear_to_srgb(fit.albedo) * 255.0), 0, 255).astype(np.uint8)
    face_regions = tuple((config or FitPhotoConfig()).photometric.face_regions)
    render, face_mask = render_fit(fit, spp=spp, asset=asset, mask_regions=face_regions)
    texture = texture_from_fit(photo, fit, asset.faces, asset.face_uvs, regions=asset.regions,
                               skin_region_ids=[asset.region_names.index(r) for r in face_regions], size=texture_size)
    texture_png = _png_bytes(texture.image)

    with torch.no_grad():
        weights = neural(torch.as_tensor(fit.z)[None])[0].numpy()
        tau = rig.channel_transforms(torch.as_tensor(fit.theta)[None])[0].numpy()

    with staged_folder(out_dir, force, inputs=inputs, marker={"command": (extra or {}).get("command")}) as tmp:
        export_mesh(tmp / "mesh.obj", fit.rig_vertices, asset.faces, face_uvs=asset.face_uvs, vertex_colors=colours,
                    mtllib="mesh.mtl", material=MATERIAL_NAME)
        write_mtl(tmp / "mesh.mtl", MATERIAL_NAME, "texture.png")
        (tmp / "texture.png").write_bytes(texture_png)
        export_mesh(tmp / "mesh.ply", fit.rig_vertices, asset.faces, vertex_colors=colours)
        write_skinned_head(tmp / "mesh.glb", asset, weights, tau, np.asarray(fit.expressions, np.float64),
                           base_color_texture=texture_png)
        params = params_payload(fit, image_factor, original_size)
        (tmp / "params.json").write_text(json.dumps(params, indent=2) + "\n")
        _save_png(np.clip(np.round(linear_to_srgb(render) * 255), 0, 255).astype(np.uint8), tmp / "render.png")
        _save_png(overlay_image(photo, render, face_mask, fit.landmarks2d, fit.landmarks_px), tmp / "overlay.png")
        k = image_factor
        write_landmarks(tmp / "landmarks.pts", np.asarray(fit.landmarks2d, float) * k + (k - 1) / 2)
        write_landmarks(tmp / "landmarks_fitted.pts", np.asarray(fit.landmarks_px, float) * k + (k - 1) / 2)
        (tmp / "landmarks3d.json").write_text(json.dumps(landmarks3d_payload(fit), indent=2) + "\n")
        (tmp / "expressions.csv").write_text(expressions_csv(fit.expressions))
        report = report_payload(fit, config=config, extra=extra, image_factor=k, texture=texture)
        (tmp / "report.json").write_text(json.dumps(report, indent=2) + "\n")
        dump_config(config or FitPhotoConfig(), tmp / CONFIG_FILE, command=(extra or {}).get("command"))
        write_fit_viewer(tmp / VIEWER_FILE, asset, theta=fit.theta, expressions=fit.expressions, weights=weights,
                         views=[ViewerView(out_dir.name, params["camera"], photo)], texture=texture.image,
                         title=f"jnr fit: {out_dir.name}", subtitle=f"landmark NME {float(fit.nme):.3f}")
    return out_dir
