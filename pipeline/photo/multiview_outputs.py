"""``jnr fit a.jpg b.jpg c.jpg --views --out DIR``: the photo files of one person, fitted together
(:func:`pipeline.photo.multiview.fit_multiview`), and the output folder (its files:
:data:`pipeline.head.folders.VIEWS_FOLDER`; written atomically, as every jnr output).

The meshes are the shared identity without expression (rig space, mm; ``texture.png`` unwrapped from the
most frontal view); ``params.json`` (:mod:`pipeline.head.params`, fit ``views``) holds the identity's head
model parameters and, per photo, the file, its camera (focal, principal point, rig -> camera extrinsics),
head pose and ARKit expressions; ``overlay_<k>.png`` is view ``k`` (input order, from 0) with the fitted head
(that view's expression and pose) over the face, input landmarks green, fitted ones red; ``viewer.html``
shows the head over each photo through its camera (an identity that is not posable by the joints, ASM: its
mesh, expression sliders only).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from landmarks.detector import DetectionError
from landmarks.images import ImageError, load_working_image
from landmarks.mediapipe.layout import mediapipe_layout_for
from pipeline.camera import camera_direction_to_rig, camera_from_head_pose, check_focal
from pipeline.config import CONFIG_FILE, config_to_dict, dump_config
from pipeline.files import check_output, json_safe, staged_folder
from pipeline.head.fitted import FittedHead, fitted_head_from_params
from pipeline.head.params import params_payload as head_params_payload
from pipeline.head.skinned import write_skinned_head
from pipeline.photo.detection import dense_fit_points, name_photo, photo_landmarks
from pipeline.photo.fit import PhotoAppearance
from pipeline.photo.inputs import sidecar_landmarks
from pipeline.photo.multiview import MultiViewConfig, MultiViewFit, fit_multiview
from pipeline.photo.outputs import (
    PHOTO_UNITS,
    _png_bytes,
    _save_png,
    overlay_image,
    render_fit,
    write_textured_meshes,
)
from pipeline.photo.texture import texture_from_fit, vertex_colours_from_texture
from pipeline.viewer import VIEWER_FILE, ViewerView, fit_viewer_ready, write_viewer
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES
from rig.geometry import head_angles
from rig.head_model import JnrHead
from rig.model import JointRig
from rig.template import FACE_REGIONS

MIN_VIEWS = 2


@dataclass(frozen=True)
class _ViewLook:
    """What :func:`pipeline.photo.outputs.render_fit` and ``texture_from_fit`` read of a fit, for one view."""

    rig_vertices: np.ndarray
    appearance: PhotoAppearance
    camera: object
    width: int
    height: int
    stages: tuple = ()


def _look(view, n_vertices: int) -> _ViewLook:
    light_cam = np.array([0.3, 0.4, 1.0]) / np.linalg.norm([0.3, 0.4, 1.0])  # as the single-photo fit's pictures
    return _ViewLook(
        rig_vertices=view.rig_vertices,
        appearance=PhotoAppearance(
            np.full((n_vertices, 3), 0.5),
            np.full(3, 0.35),
            np.full(3, 2.0),
            light_cam,
            camera_direction_to_rig(light_cam, view.rotation),
        ),
        camera=view.camera,
        width=view.width,
        height=view.height,
    )


def multiview_head(fit: MultiViewFit, model: JnrHead | None = None) -> tuple[FittedHead, FittedHead]:
    """``(identity, rig)``: the shared identity in its own head model without expression, and the JNR rig's
    part of the fit (its joints and Z: what ``mesh.glb`` and the viewer pose); the same head when the
    identity model is the rig's."""
    rig = fitted_head_from_params(fit.rig_identity, model=model)
    identity = fit.identity
    return (rig if identity.kind == rig.params.kind else fitted_head_from_params(identity)), rig


def multiview_params_payload(
    fit: MultiViewFit, photos: list[str], factors: list[int], head: FittedHead | None = None
) -> dict:
    """``params.json`` of a multi-view fit (:mod:`pipeline.head.params`, fit ``views``); cameras in each photo
    file's pixels."""
    head = head or multiview_head(fit)[0]
    views = []
    for photo, view, f in zip(photos, fit.views, factors):
        views.append(
            {
                "photo": photo,
                "camera": {
                    "width": int(view.width * f),
                    "height": int(view.height * f),
                    "focal_px": float(view.focal) * f,
                    "focal_start_px": float(view.focal_start) * f,
                    "principal_point_px": [
                        ((view.width - 1) / 2.0) * f + (f - 1) / 2,
                        ((view.height - 1) / 2.0) * f + (f - 1) / 2,
                    ],
                    "fitted_at_reduction": int(f),
                    "extrinsics_rig_to_camera": camera_from_head_pose(view.rotation, view.translation).tolist(),
                },
                "pose": {
                    "rotation_matrix": view.rotation.tolist(),
                    "rotation_vector_rad": [float(x) for x in Rotation.from_matrix(view.rotation).as_rotvec()],
                    "translation_mm": [float(x) for x in view.translation],
                },
                "expressions": {n: float(c) for n, c in zip(EXPRESSION_NAMES, view.expressions)},
            }
        )
    return head_params_payload(
        head.model,
        head.params,
        fit="views",
        units=PHOTO_UNITS,
        pose_description="per view: x_cam = RIG_TO_OPENCV @ R @ x_rig + t, RIG_TO_OPENCV = diag(1, -1, -1)",
        views=views,
    )


def _montage(images: list[np.ndarray]) -> np.ndarray:
    """The images side by side, each resized to the smallest height."""
    import cv2

    height = min(im.shape[0] for im in images)
    scaled = [
        im
        if im.shape[0] == height
        else cv2.resize(im, (round(im.shape[1] * height / im.shape[0]), height), interpolation=cv2.INTER_AREA)
        for im in images
    ]
    return np.concatenate(scaled, 1)


def write_multiview_outputs(
    out_dir: str | Path,
    images: list[np.ndarray],
    fit: MultiViewFit,
    *,
    photos: list[str],
    factors: list[int] | None = None,
    config: MultiViewConfig | None = None,
    force: bool = False,
    extra: dict | None = None,
    inputs: tuple = (),
    spp: int = 4,
    rig=None,
    neural=None,
) -> Path:
    """Write the output folder of a multi-view fit (module docstring) atomically.

    Args:
        out_dir: the folder; an existing one is replaced only with ``force`` (and only a jnr one).
        images: the ``N`` photos as fitted, ``(H, W, 3)`` uint8 sRGB.
        fit: :func:`pipeline.photo.multiview.fit_multiview`'s result.
        photos: the ``N`` photo file names (recorded in params.json).
        factors: each photo's reduction factor (1: fitted at full size).
        config, extra: recorded in report.json / config.yaml.
        spp: render samples per pixel of the overlays.
        rig, neural: the fit's models (the files are computed in float64 from them, :class:`rig.head_model.JnrHead`).
    """
    out_dir = Path(out_dir)
    factors = factors or [1] * len(images)
    check_output(out_dir, force=force, inputs=inputs)
    identity, jnr = multiview_head(fit, JnrHead(rig=rig, neural=neural))
    asset = jnr.asset
    n_vertices = len(asset.vertices)
    looks = [_look(v, n_vertices) for v in fit.views]
    overlays = []
    for image, view, look in zip(images, fit.views, looks):
        render, mask = render_fit(look, spp=spp, asset=asset, mask_regions=FACE_REGIONS)
        overlays.append(overlay_image(image, render, mask, view.landmarks2d, view.landmarks_px))
    frontal = int(np.argmin([abs(head_angles(v.rotation)[0]) for v in fit.views]))
    skin_ids = [asset.region_names.index(r) for r in FACE_REGIONS]
    # the texture is unwrapped from the frontal view's own head (its expression), then put on the identity
    texture = texture_from_fit(
        images[frontal], looks[frontal], asset.faces, asset.face_uvs, regions=asset.regions, skin_region_ids=skin_ids
    )
    texture_png = _png_bytes(texture.image)
    colours = vertex_colours_from_texture(texture.image, asset.faces, asset.face_uvs, len(asset.vertices))
    report = {
        "views": [
            {
                "photo": p,
                "mean_error_px": float(v.error_px.mean()) * f,
                "nme": float(v.nme),
                "single_view_mean_error_px": float(s.error_px.mean()) * f,
                "focal_px": float(v.focal) * f,
                "yaw_pitch_roll_deg": [float(a) for a in head_angles(v.rotation)],
                "landmark_weight": v.weight,
            }
            for p, v, s, f in zip(photos, fit.views, fit.single_view_fits, factors)
        ],
        "mean_error_px": fit.mean_error_px,
        "skinning": fit.skinning,
        "texture_view": frontal,
        "stages": [asdict(s) for s in fit.stages],
        "timings_s": fit.timings,
        "config": config_to_dict(config) if config is not None else None,
        **(extra or {}),
    }
    with staged_folder(out_dir, force, inputs=inputs, marker={"command": (extra or {}).get("command")}) as tmp:
        outputs = (config or MultiViewConfig()).outputs
        write_textured_meshes(
            tmp, fit.identity_vertices, asset, colours, texture_png, outputs.units, ply_up=outputs.ply_up
        )
        write_skinned_head(
            tmp / "mesh.glb", asset, jnr.weights, jnr.tau, jnr.expressions, base_color_texture=texture_png
        )
        params = multiview_params_payload(fit, photos, factors, identity)
        (tmp / "params.json").write_text(json.dumps(params, indent=2) + "\n")
        for k, overlay in enumerate(overlays):
            _save_png(overlay, tmp / f"overlay_{k}.png")
        _save_png(_montage(overlays), tmp / "overlay.png")
        (tmp / "report.json").write_text(json.dumps(json_safe(report), indent=2) + "\n")
        dump_config(config or MultiViewConfig(), tmp / CONFIG_FILE, command=(extra or {}).get("command"))
        if fit_viewer_ready():
            views = [
                ViewerView(Path(p).name, v["camera"], image, np.asarray(fv.expressions, np.float64))
                for p, v, image, fv in zip(photos, params["views"], images, fit.views)
            ]
            posable = identity.model.posable
            head = (
                {"theta": jnr.theta, "weights": jnr.weights, "latent_z": np.asarray(fit.z, np.float64)}
                if posable
                else {"static_vertices": fit.identity_vertices}
            )
            subtitle = f"{len(views)} views, mean landmark error {fit.mean_error_px:.2f} px"
            write_viewer(
                tmp / VIEWER_FILE,
                asset,
                views=views,
                texture=texture.image,
                title=f"jnr fit --views: {out_dir.name}",
                subtitle=subtitle + ("" if posable else f" ({identity.model.kind.upper()}: expression sliders only)"),
                **head,
            )
    return out_dir


def fit_multiview_files(
    photo_paths: list[str | Path],
    out: str | Path,
    *,
    config: MultiViewConfig | None = None,
    landmarks: str | None = None,
    focal: float | None = None,
    force: bool = False,
    command: str = "jnr fit --views",
    detector: str = "auto",
    rig=None,
    neural=None,
) -> dict:
    """Detect (or read beside each photo, ``landmarks="auto"``) the landmarks of ``N >= 2`` photo files of one
    person, fit them together and write ``out``.

    Raises:
        InputError: fewer than 2 photos, a photo with no face (the message names it), bad landmarks or
            focal, a refused output; FloatingPointError: a diverged fit.

    Returns:
        ``{"output", "views", "mean_error_px", "seconds"}``.
    """
    t0 = time.perf_counter()
    paths = [Path(p) for p in photo_paths]
    if len(paths) < MIN_VIEWS:
        raise InputError(f"--views needs at least {MIN_VIEWS} photos of the same person, got {len(paths)}")
    if landmarks not in (None, "auto"):
        raise InputError(
            "--views takes --landmarks auto (a landmarks file beside each photo) or detection, not one --landmarks FILE"
        )
    out = Path(out)
    sidecars = [sidecar_landmarks(p) for p in paths] if landmarks == "auto" else [None] * len(paths)
    inputs = [*paths, *[s for s in sidecars if s]]
    check_output(out, force=force, inputs=inputs)
    config = config or MultiViewConfig()
    rig = rig or JointRig()
    images, points, layouts, sources, sizes, focals, factors, points3d = [], [], [], [], [], [], [], []
    for path, sidecar in zip(paths, sidecars):
        try:
            photo = load_working_image(path)
            width, height = photo.original_size
            if focal is not None:
                check_focal(focal, width, height)
            lm, source, dense = photo_landmarks(photo, sidecar, None, detector)
        except (ImageError, DetectionError) as exc:
            raise name_photo(exc, path) from None
        k = photo.factor
        images.append(photo.image)
        if dense is not None and config.landmarks.dense:  # MediaPipe's points, as for one photo
            pixels, depth = dense_fit_points(dense)
            points.append(pixels)
            layouts.append(mediapipe_layout_for(rig.asset, len(dense)))
        else:
            points.append(lm)
            layouts.append(None)
            depth = None
        points3d.append(depth)
        sources.append(
            {"photo": str(path.absolute()), **{key: value for key, value in source.items() if key != "faces"}}
        )
        sizes.append((photo.image.shape[1], photo.image.shape[0]))
        focals.append(None if focal is None else focal / k)
        factors.append(k)
    try:
        fit = fit_multiview(
            points,
            sizes,
            images=images,
            focals=focals,
            config=config,
            rig=rig,
            neural=neural,
            layouts=layouts,
            points3d=points3d,
        )
    except FloatingPointError as exc:
        raise FloatingPointError(f"{', '.join(map(str, paths))}: {exc}") from None
    write_multiview_outputs(
        out,
        images,
        fit,
        photos=[str(p.absolute()) for p in paths],
        factors=factors,
        config=config,
        force=force,
        extra={"inputs": sources, "command": command},
        inputs=tuple(inputs),
        rig=rig,
        neural=neural,
    )
    return {
        "output": str(out),
        "views": len(paths),
        "mean_error_px": fit.mean_error_px,
        "seconds": time.perf_counter() - t0,
    }
