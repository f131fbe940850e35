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

:func:`write_photo_outputs` walks a table of the files (rows of :mod:`pipeline.photo.output_steps`); what
the text files hold is :mod:`pipeline.photo.output_payloads`, the render and the overlay
:mod:`pipeline.photo.overlay` (their names are importable from here too, as before they moved).
"""

from __future__ import annotations

import logging
from functools import partial
from pathlib import Path

import numpy as np

from landmarks.ibug68.names import IBUG68_NAMES
from pipeline.colour import linear_to_srgb
from pipeline.config import CONFIG_FILE, dump_config
from pipeline.files import check_output, staged_folder
from pipeline.head.curves import write_curves
from pipeline.head.folders import PHOTO_OUTPUT_SETS
from pipeline.head.skinned import write_skinned_head, write_static_head
from pipeline.photo.fit import PhotoFit
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.output_payloads import (
    DENSE_LANDMARKS_FILE,
    LIVE_LINK_FILE,
    NOW_FILE,
    dense_landmarks_payload,
    expressions_csv,
    fit_curves,
    landmarks3d_mesh_payload,
    landmarks3d_payload,
    mesh_units,
    meshlab_picked_points,
    now_landmarks_txt,
    photo_head,
    report_payload,
)
from pipeline.photo.output_payloads import NOW_IBUG_INDICES as NOW_IBUG_INDICES
from pipeline.photo.output_payloads import PHOTO_UNITS as PHOTO_UNITS
from pipeline.photo.output_payloads import landmarks3d_mesh_points as landmarks3d_mesh_points
from pipeline.photo.output_payloads import mesh_from_photo_params as mesh_from_photo_params
from pipeline.photo.output_payloads import params_payload as params_payload
from pipeline.photo.output_payloads import texture_payload as texture_payload
from pipeline.photo.output_steps import Laps, OutputJob, OutputStage, PhotoOutput, json_output, pts_output, text_output
from pipeline.photo.overlay import FIT_COLOUR as FIT_COLOUR
from pipeline.photo.overlay import INPUT_COLOUR as INPUT_COLOUR
from pipeline.photo.overlay import overlay_image, render_fit
from pipeline.photo.texture import TEXTURE_SIZE, texture_from_fit, vertex_colours_from_texture
from pipeline.viewer import VIEWER_FILE, ViewerView, shared_three_src, write_fit_viewer
from rig.asset import RigAsset
from rig.head_model import JnrHead
from rig.io.mesh import export_mesh, write_mtl
from rig.model import JointRig
from rig.skinning.neural import NeuralSkinning

_log = logging.getLogger(__name__)
MATERIAL_NAME = "skin"
"""The material of ``mesh.obj`` (``usemtl``) in ``mesh.mtl``."""


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


KEYS_GLB = "mesh_keys.glb"
"""The fitted head for animation tools: its expression on the 52 shape keys, not baked into the mesh."""


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


# ------------------------------------------------------------------------------------------ the files


def _write_meshes(job: OutputJob, folder: Path) -> None:
    colours, png, out = job.colours, job.texture_png, job.settings.outputs
    write_textured_meshes(folder, job.fit.rig_vertices, job.asset, colours, png, out.units, job.wanted, out.ply_up)


def _write_glb(job: OutputJob, folder: Path, name: str = "mesh.glb", **options) -> None:
    head, png = job.head, job.texture_png
    if not head.model.posable:  # a head model the joints do not pose: its mesh as it is (both files)
        write_static_head(folder / name, job.asset, head.vertices, base_color_texture=png)
        return
    write_skinned_head(
        folder / name, job.asset, head.weights, head.tau, head.expressions, base_color_texture=png, **options
    )


def _write_render(job: OutputJob, folder: Path) -> None:
    srgb = np.clip(np.round(linear_to_srgb(job.render) * 255), 0, 255).astype(np.uint8)
    _save_png(srgb, folder / "render.png")


def _write_overlay(job: OutputJob, folder: Path) -> None:
    fit = job.fit
    overlay = overlay_image(job.photo, job.render, job.face_mask, fit.landmarks.detected, fit.landmarks.fitted)
    _save_png(overlay, folder / "overlay.png")


def _report(job: OutputJob) -> dict:
    return report_payload(
        job.fit, config=job.config, extra=job.extra, image_factor=job.image_factor, texture=job.texture
    )


def _write_config(job: OutputJob, folder: Path) -> None:
    dump_config(job.settings, folder / CONFIG_FILE, command=(job.extra or {}).get("command"))


def _write_viewer(job: OutputJob, folder: Path) -> None:
    head, name, shared = job.head, job.out_dir.name, job.shared_three
    posable = head.model.posable
    rig = {"theta": head.theta, "weights": head.weights} if posable else {"static_vertices": head.vertices}
    write_fit_viewer(
        folder / VIEWER_FILE,
        job.asset,
        expressions=head.expressions,
        **rig,
        views=[ViewerView(name, job.params["camera"], job.photo)],
        texture=job.texture.image,
        latent_z=job.fit.z,
        three_src=None if shared is None else shared_three_src(job.out_dir, shared),
        title=f"jnr fit: {name}",
        subtitle=f"landmark NME {float(job.fit.landmarks.nme):.3f}",
    )


_STAGES = (
    OutputStage("obj, ply", (PhotoOutput(TEXTURED_MESH_FILES, _write_meshes),)),
    OutputStage(
        "glb",
        (
            PhotoOutput(("mesh.glb",), _write_glb),
            # the same head for animation tools: the expression on the shape keys (issue 38)
            PhotoOutput((KEYS_GLB,), partial(_write_glb, name=KEYS_GLB, expression="keys")),
        ),
    ),
    OutputStage(
        "pngs, landmarks, json, csv",
        (
            json_output("params.json", lambda job: job.params, always=True),
            PhotoOutput(("render.png",), _write_render),
            PhotoOutput(("overlay.png",), _write_overlay),
            pts_output("landmarks.pts", lambda fit: fit.landmarks.detected),
            pts_output("landmarks_fitted.pts", lambda fit: fit.landmarks.fitted),
            json_output("landmarks3d.json", lambda job: landmarks3d_payload(job.fit)),
            json_output("landmarks3d_mesh.json", lambda job: landmarks3d_mesh_payload(job.fit, job.units)),
            text_output("landmarks3d.pp", lambda job: meshlab_picked_points(job.mesh_landmarks, IBUG68_NAMES)),
            text_output(NOW_FILE, lambda job: now_landmarks_txt(job.mesh_landmarks)),
            # None (not written) for a fit of the 68 iBUG points
            json_output(DENSE_LANDMARKS_FILE, lambda job: dense_landmarks_payload(job.fit, job.units), indent=1),
            text_output("expressions.csv", lambda job: expressions_csv(job.fit.expressions)),
            PhotoOutput(
                (LIVE_LINK_FILE,),
                lambda job, folder: write_curves(folder / LIVE_LINK_FILE, fit_curves(job.fit), layout="live-link-face"),
            ),
            json_output("report.json", _report, always=True),
            PhotoOutput((CONFIG_FILE,), _write_config, always=True),
        ),
    ),
    OutputStage("viewer", (PhotoOutput((VIEWER_FILE,), _write_viewer),), timed_when_idle=False),
)
"""What :func:`write_photo_outputs` writes into the staged folder, in this order, in timed stages."""

_RENDER_USERS = ("render.png", "overlay.png")
_TEXTURE_USERS = ("texture.png", "mesh.obj", "mesh.ply", "mesh.glb", KEYS_GLB, VIEWER_FILE)
"""The files that need the render (:func:`render_fit`) or the texture (:func:`texture_from_fit`)."""


def _render_and_texture(job: OutputJob, spp: int, texture_size: int, lap: Laps) -> None:
    """The render and the texture (and the vertex colours sampled from it), each when a wanted file needs it."""
    asset = job.asset
    face_regions = tuple(job.settings.photometric.face_regions)
    if job.wants(*_RENDER_USERS):
        job.render, job.face_mask = render_fit(job.fit, spp=spp, asset=asset, mask_regions=face_regions)
        lap("render")
    if job.wants(*_TEXTURE_USERS):
        job.texture = texture_from_fit(
            job.photo,
            job.fit,
            asset.faces,
            asset.face_uvs,
            regions=asset.regions,
            skin_region_ids=[asset.region_names.index(r) for r in face_regions],
            size=texture_size,
        )
        job.texture_png = _png_bytes(job.texture.image)
        # what MeshLab, CloudCompare and Open3D show of the OBJ/PLY: the texture at each vertex (seams averaged)
        job.colours = vertex_colours_from_texture(job.texture.image, asset.faces, asset.face_uvs, len(asset.vertices))
        lap("texture")


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
    lap = Laps()
    head = photo_head(fit, JnrHead(rig=rig, neural=neural))
    settings = config or FitPhotoConfig()
    wanted = set(PHOTO_OUTPUT_SETS[settings.outputs.files])
    job = OutputJob(
        out_dir, photo, fit, head, settings, config, extra, image_factor, original_size, shared_three, wanted
    )
    lap("head")
    _render_and_texture(job, spp, texture_size, lap)
    job.scale, _ = mesh_units(settings.outputs.units)

    with staged_folder(out_dir, force, inputs=inputs, marker={"command": (extra or {}).get("command")}) as tmp:
        for stage in _STAGES:
            stage.write(job, tmp, lap)
    lap("staging")
    _log.info(
        "%s: outputs in %.2f s (%s)",
        out_dir,
        sum(lap.seconds.values()),
        ", ".join(f"{name} {value:.2f} s" for name, value in lap.seconds.items()),
    )
    return out_dir
