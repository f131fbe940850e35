"""``jnr fit a.jpg b.jpg c.jpg --views --out DIR``: the photo files of one person, fitted together
(:func:`pipeline.photo.multiview.fit_multiview`), and the output folder.

The folder (written atomically, as every jnr output):

========================  ===========================================================================
file                      contents
========================  ===========================================================================
``mesh.obj``              the shared identity without expression, rig space (mm), the template's UVs,
                          material ``skin`` of ``mesh.mtl``
``mesh.mtl``              ``map_Kd texture.png``
``texture.png``           the face unwrapped from the most frontal view (:mod:`pipeline.photo.texture`)
``mesh.ply``              the identity, binary PLY
``mesh.glb``              skinned glTF of the identity (the 52 ARKit shapes as morph targets, weight 0)
``params.json``           ``joints``, ``latent_z``, ``expressions`` (zeros) of the identity (a ``jnr rig
                          edit`` parameter file), ``skinning``, and ``views``: per photo the file, its
                          camera (focal, principal point, rig -> camera extrinsics), head pose and its
                          own ARKit expressions
``overlay.png``           the per-view overlays side by side (same height)
``overlay_<k>.png``       view ``k`` (input order, from 0): the photo with the fitted head (that view's
                          expression and pose) over the face, input landmarks green, fitted ones red
``report.json``           landmark errors per view, the stages, timings, inputs, the configuration
``config.yaml``           the configuration used
``viewer.html``           a self-contained web page (:mod:`pipeline.viewer`): the head over each photo through
                          its camera (a view menu; each view's expression), sliders for the joints and the
                          52 ARKit shapes (an ASM identity: its mesh, expression sliders only); skipped with a
                          warning where three.js was not installed by ``make venv``
========================  ===========================================================================
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from pipeline.photo.multiview import MultiViewConfig, MultiViewFit, fit_multiview
from rig.errors import InputError

MULTIVIEW_PARAMS_FORMAT = "jnr-multiview-params/1"
MULTIVIEW_OUTPUT_FILES = ("mesh.obj", "mesh.mtl", "texture.png", "mesh.ply", "mesh.glb", "params.json",
                          "overlay.png", "overlay_<k>.png", "report.json", "config.yaml", "viewer.html")
MIN_VIEWS = 2


@dataclass(frozen=True)
class _ViewLook:
    """What :func:`pipeline.photo.outputs.render_fit` and ``texture_from_fit`` read of a fit, for one view."""

    rig_vertices: np.ndarray
    albedo: np.ndarray
    ambient: np.ndarray
    irradiance: np.ndarray
    light_direction_rig: np.ndarray
    camera: object
    width: int
    height: int
    stages: tuple = ()


def _look(view, n_vertices: int) -> _ViewLook:
    from pipeline.photo.camera import camera_direction_to_rig

    light_cam = np.array([0.3, 0.4, 1.0]) / np.linalg.norm([0.3, 0.4, 1.0])  # as the single-photo fit's pictures
    return _ViewLook(rig_vertices=view.rig_vertices, albedo=np.full((n_vertices, 3), 0.5), ambient=np.full(3, 0.35),
                     irradiance=np.full(3, 2.0), light_direction_rig=camera_direction_to_rig(light_cam, view.rotation),
                     camera=view.camera, width=view.width, height=view.height)


def multiview_params_payload(fit: MultiViewFit, photos: list[str], factors: list[int]) -> dict:
    """``params.json`` of a multi-view fit (module docstring); cameras in each photo file's pixels."""
    from scipy.spatial.transform import Rotation

    from pipeline.photo.camera import camera_from_head_pose
    from rig.expressions import EXPRESSION_NAMES
    from rig.parameters import theta_to_params

    views = []
    for photo, view, f in zip(photos, fit.views, factors):
        views.append({
            "photo": photo,
            "camera": {"width": int(view.width * f), "height": int(view.height * f), "focal_px": float(view.focal) * f,
                       "focal_start_px": float(view.focal_start) * f,
                       "principal_point_px": [((view.width - 1) / 2.0) * f + (f - 1) / 2,
                                              ((view.height - 1) / 2.0) * f + (f - 1) / 2],
                       "fitted_at_reduction": int(f),
                       "extrinsics_rig_to_camera": camera_from_head_pose(view.rotation, view.translation).tolist()},
            "pose": {"rotation_matrix": view.rotation.tolist(),
                     "rotation_vector_rad": [float(x) for x in Rotation.from_matrix(view.rotation).as_rotvec()],
                     "translation_mm": [float(x) for x in view.translation]},
            "expressions": {n: float(c) for n, c in zip(EXPRESSION_NAMES, view.expressions)},
        })
    payload = {
        "format": MULTIVIEW_PARAMS_FORMAT,
        "units": {"rotate": "deg", "translate": "mm", "scale": "factor", "pixels": "OpenCV, 0-based"},
        "skinning": fit.skinning,
        "joints": theta_to_params(torch.as_tensor(fit.theta), include_rest=True),
        "latent_z": [float(x) for x in fit.z],
        "expressions": {n: 0.0 for n in EXPRESSION_NAMES},
        "pose_description": "per view: x_cam = RIG_TO_OPENCV @ R @ x_rig + t, RIG_TO_OPENCV = diag(1, -1, -1)",
        "views": views,
    }
    if fit.asm_parameters is not None:
        payload["asm"] = {k: np.asarray(v).tolist() for k, v in fit.asm_parameters.items()}
    return payload


def _montage(images: list[np.ndarray]) -> np.ndarray:
    """The images side by side, each resized to the smallest height."""
    import cv2

    height = min(im.shape[0] for im in images)
    scaled = [im if im.shape[0] == height else cv2.resize(im, (round(im.shape[1] * height / im.shape[0]), height),
                                                          interpolation=cv2.INTER_AREA) for im in images]
    return np.concatenate(scaled, 1)


def write_multiview_outputs(out_dir: str | Path, images: list[np.ndarray], fit: MultiViewFit, *, photos: list[str],
                            factors: list[int] | None = None, config: MultiViewConfig | None = None,
                            force: bool = False, extra: dict | None = None, inputs: tuple = (), spp: int = 4,
                            rig=None, neural=None) -> Path:
    """Write the output folder of a multi-view fit (module docstring) atomically.

    Args:
        out_dir: the folder; an existing one is replaced only with ``force`` (and only a jnr one).
        images: the ``N`` photos as fitted, ``(H, W, 3)`` uint8 sRGB.
        fit: :func:`pipeline.photo.multiview.fit_multiview`'s result.
        photos: the ``N`` photo file names (recorded in params.json).
        factors: each photo's reduction factor (1: fitted at full size).
        config, extra: recorded in report.json / config.yaml.
        spp: render samples per pixel of the overlays.
        rig, neural: the fit's models (:func:`pipeline.photo.outputs.output_models`).
    """
    from pipeline.config import CONFIG_FILE, config_to_dict, dump_config
    from pipeline.edit import write_skinned_head
    from pipeline.files import check_output, json_safe, staged_folder
    from pipeline.photo.outputs import (
        MATERIAL_NAME,
        _png_bytes,
        _save_png,
        output_models,
        overlay_image,
        render_fit,
    )
    from pipeline.photo.texture import texture_from_fit
    from pipeline.viewer import VIEWER_FILE, ViewerView, fit_viewer_ready, write_viewer
    from rig.geometry import head_angles
    from rig.io.mesh import export_mesh, write_mtl
    from rig.template import FACE_REGIONS

    out_dir = Path(out_dir)
    factors = factors or [1] * len(images)
    check_output(out_dir, force=force, inputs=inputs)
    rig, neural = output_models(rig, neural)
    asset = rig.asset
    n_vertices = len(asset.vertices)
    looks = [_look(v, n_vertices) for v in fit.views]
    overlays = []
    for image, view, look in zip(images, fit.views, looks):
        render, mask = render_fit(look, spp=spp, asset=asset, mask_regions=FACE_REGIONS)
        overlays.append(overlay_image(image, render, mask, view.landmarks2d, view.landmarks_px))
    frontal = int(np.argmin([abs(head_angles(v.rotation)[0]) for v in fit.views]))
    skin_ids = [asset.region_names.index(r) for r in FACE_REGIONS]
    # the texture is unwrapped from the frontal view's own head (its expression), then put on the identity
    texture = texture_from_fit(images[frontal], looks[frontal], asset.faces, asset.face_uvs, regions=asset.regions,
                               skin_region_ids=skin_ids)
    texture_png = _png_bytes(texture.image)
    with torch.no_grad():
        weights = neural(torch.as_tensor(fit.z)[None])[0].numpy()
        tau = rig.channel_transforms(torch.as_tensor(fit.theta)[None])[0].numpy()
    report = {
        "views": [{"photo": p, "mean_error_px": float(v.error_px.mean()) * f, "nme": float(v.nme),
                   "single_view_mean_error_px": float(s.error_px.mean()) * f, "focal_px": float(v.focal) * f,
                   "yaw_pitch_roll_deg": [float(a) for a in head_angles(v.rotation)]}
                  for p, v, s, f in zip(photos, fit.views, fit.single_view_fits, factors)],
        "mean_error_px": fit.mean_error_px,
        "skinning": fit.skinning,
        "texture_view": frontal,
        "stages": [asdict(s) for s in fit.stages],
        "timings_s": fit.timings,
        "config": config_to_dict(config) if config is not None else None,
        **(extra or {}),
    }
    with staged_folder(out_dir, force, inputs=inputs, marker={"command": (extra or {}).get("command")}) as tmp:
        export_mesh(tmp / "mesh.obj", fit.identity_vertices, asset.faces, face_uvs=asset.face_uvs,
                    mtllib="mesh.mtl", material=MATERIAL_NAME)
        write_mtl(tmp / "mesh.mtl", MATERIAL_NAME, "texture.png")
        (tmp / "texture.png").write_bytes(texture_png)
        export_mesh(tmp / "mesh.ply", fit.identity_vertices, asset.faces)
        write_skinned_head(tmp / "mesh.glb", asset, weights, tau, np.zeros(len(fit.views[0].expressions)),
                           base_color_texture=texture_png)
        params = multiview_params_payload(fit, photos, factors)
        (tmp / "params.json").write_text(json.dumps(params, indent=2) + "\n")
        for k, overlay in enumerate(overlays):
            _save_png(overlay, tmp / f"overlay_{k}.png")
        _save_png(_montage(overlays), tmp / "overlay.png")
        (tmp / "report.json").write_text(json.dumps(json_safe(report), indent=2) + "\n")
        dump_config(config or MultiViewConfig(), tmp / CONFIG_FILE, command=(extra or {}).get("command"))
        if fit_viewer_ready():
            views = [ViewerView(Path(p).name, v["camera"], image, np.asarray(fv.expressions, np.float64))
                     for p, v, image, fv in zip(photos, params["views"], images, fit.views)]
            asm = fit.skinning == "asm"
            head = {"static_vertices": fit.identity_vertices} if asm else {"theta": fit.theta, "weights": weights}
            subtitle = f"{len(views)} views, mean landmark error {fit.mean_error_px:.2f} px"
            write_viewer(tmp / VIEWER_FILE, asset, views=views, texture=texture.image,
                         title=f"jnr fit --views: {out_dir.name}",
                         subtitle=subtitle + (" (ASM: expression sliders only)" if asm else ""), **head)
    return out_dir


def fit_multiview_files(photo_paths: list[str | Path], out: str | Path, *, config: MultiViewConfig | None = None,
                        landmarks: str | None = None, focal: float | None = None, force: bool = False,
                        command: str = "jnr fit --views", detector: str = "auto", rig=None, neural=None) -> dict:
    """Detect (or read beside each photo, ``landmarks="auto"``) the landmarks of ``N >= 2`` photo files of one
    person, fit them together and write ``out``.

    Raises:
        InputError: fewer than 2 photos, a photo with no face (the message names it), bad landmarks or
            focal, a refused output; FloatingPointError: a diverged fit.

    Returns:
        ``{"output", "views", "mean_error_px", "seconds"}``.
    """
    from landmarks.detect import DetectionError, load_working_image
    from pipeline.files import check_output
    from pipeline.photo.camera import check_focal
    from pipeline.photo.files import _name_photo, _photo_landmarks, sidecar_landmarks

    t0 = time.perf_counter()
    paths = [Path(p) for p in photo_paths]
    if len(paths) < MIN_VIEWS:
        raise InputError(f"--views needs at least {MIN_VIEWS} photos of the same person, got {len(paths)}")
    if landmarks not in (None, "auto"):
        raise InputError("--views takes --landmarks auto (a landmarks file beside each photo) or detection, "
                         "not one --landmarks FILE")
    out = Path(out)
    sidecars = [sidecar_landmarks(p) for p in paths] if landmarks == "auto" else [None] * len(paths)
    inputs = [*paths, *[s for s in sidecars if s]]
    check_output(out, force=force, inputs=inputs)
    images, points, sources, sizes, focals, factors = [], [], [], [], [], []
    for path, sidecar in zip(paths, sidecars):
        try:
            photo = load_working_image(path)
            width, height = photo.original_size
            if focal is not None:
                check_focal(focal, width, height)
            lm, source = _photo_landmarks(photo, sidecar, None, detector)
        except DetectionError as exc:
            raise _name_photo(exc, path) from None
        k = photo.factor
        images.append(photo.image)
        points.append(lm)
        sources.append({"photo": str(path.absolute()),
                        **{key: value for key, value in source.items() if key != "faces"}})
        sizes.append((photo.image.shape[1], photo.image.shape[0]))
        focals.append(None if focal is None else focal / k)
        factors.append(k)
    config = config or MultiViewConfig()
    try:
        fit = fit_multiview(points, sizes, images=images, focals=focals, config=config, rig=rig, neural=neural)
    except FloatingPointError as exc:
        raise FloatingPointError(f"{', '.join(map(str, paths))}: {exc}") from None
    except InputError:
        raise
    except ValueError as exc:
        raise InputError(f"jnr fit --views: {exc}") from None
    write_multiview_outputs(out, images, fit, photos=[str(p.absolute()) for p in paths], factors=factors,
                            config=config, force=force, extra={"inputs": sources, "command": command},
                            inputs=tuple(inputs), rig=rig, neural=neural)
    return {"output": str(out), "views": len(paths), "mean_error_px": fit.mean_error_px,
            "seconds": time.perf_counter() - t0}
