"""A fit's head driven by curves: the keyframes of the animated glTF, the preview frames and GIF, and
``jnr animate``."""

from __future__ import annotations

import io
import logging
from pathlib import Path

import numpy as np
import torch

from pipeline.files import check_output, staged_file
from pipeline.fitting.landmark_term import expressions64
from pipeline.head.curves import HEAD_JOINT, Curves, head_rotation_matrices
from pipeline.head.fitted import FittedHead, read_fit_folder
from pipeline.head.skinned import write_skinned_head
from render.preview import render_preview
from rig.asset import load_asset
from rig.io.atomic import write_bytes_atomic
from rig.io.gltf import GltfAnimation
from rig.joints import JOINT_INDEX
from rig.lbs import joint_world_transforms, skin_vertices

log = logging.getLogger("jnr")

# ----------------------------------------------------------------------------------------------
# a fit's head
# ----------------------------------------------------------------------------------------------


ANIMATION_TASK = "animation and retargeting"


def load_fit_head(folder: str | Path) -> FittedHead:
    """The head of a ``jnr fit`` / ``jnr fit-scan`` output folder (:func:`pipeline.head.fitted.read_fit_folder`),
    posable by the joints.

    Raises:
        InputError: not a folder, no readable ``params.json``, an ASM fit (no joint rig to animate).
    """
    return read_fit_folder(folder, posable_for=ANIMATION_TASK)


def posed_frames(head: FittedHead, coefficients: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """``(T, V, 3)`` mm: the fit's head with ``coefficients (T, 52)`` and joint transforms ``taus (T, J, 4, 4)``
    (linear blend skinning of the template plus expression offsets, as the glTF is posed)."""
    head.require_posable(ANIMATION_TASK)
    rig = head.model.rig
    with torch.no_grad():
        rest = head.model.expression_model.vertices(torch.as_tensor(coefficients))
        _, skinning = joint_world_transforms(torch.as_tensor(taus), rig.bind_positions, rig.parents, rig.levels)
        return skin_vertices(rest, torch.as_tensor(head.weights), skinning).numpy()


def static_frames(head: FittedHead, coefficients: np.ndarray) -> np.ndarray:
    """``(T, V, 3)`` mm: a head the joints do not pose (:attr:`rig.head_model.HeadModel.posable`) with
    ``coefficients (T, 52)``: its vertices plus the rig's expression offsets (as its glTF's morph targets)."""
    with torch.no_grad():
        offsets = expressions64(head.asset)(torch.as_tensor(coefficients, dtype=torch.float64))
    return np.asarray(head.vertices, np.float64)[None] + offsets.numpy()


def curve_keyframes(head: FittedHead, curves: Curves):
    """The glTF animation of ``curves`` on ``head``: :class:`rig.io.gltf.GltfAnimation` with the morph weights
    and, with head angles, every joint's transforms (the fit's, ``skull_root``'s turned; a head the joints do not
    pose: its one joint's, :func:`pipeline.head.skinned.write_static_head`)."""
    taus = None
    turning = curves.head_rotation is not None and np.abs(curves.head_rotation).max() > 0.0
    if turning and not head.model.posable:
        taus = np.tile(np.eye(4), (len(curves.times), 1, 1, 1))
        taus[:, 0, :3, :3] = head_rotation_matrices(curves.head_rotation)
    elif turning:
        taus = np.repeat(head.tau[None], len(curves.times), axis=0)
        j = _joint_index(HEAD_JOINT)
        turn = np.tile(np.eye(4), (len(curves.times), 1, 1))
        turn[:, :3, :3] = head_rotation_matrices(curves.head_rotation)
        taus[:, j] = turn @ head.tau[j]
    return GltfAnimation(curves.times, curves.coefficients, taus, name="curves")


def _joint_index(name: str) -> int:
    return JOINT_INDEX[name]


MAX_PREVIEW_FRAMES = 1800
"""The most frames a preview renders (a minute at 30 fps): a longer take is shown by frames spread evenly over
it (logged), not by a clock that would need more frames than memory holds."""


POSE_CHUNK = 32
"""Preview frames posed in one batch (the skinning's per-vertex transforms take ~1 MB a frame and vertex set)."""


def _frame_indices(times: np.ndarray, fps: float) -> np.ndarray:
    """Rows of the curves nearest to a ``fps`` clock from the first to the last time (no repeats), at most
    :data:`MAX_PREVIEW_FRAMES` (then spread evenly over the take)."""
    frames = int(min(float(times[-1]) * fps, MAX_PREVIEW_FRAMES * 4)) + 1
    if frames > MAX_PREVIEW_FRAMES:
        log.warning(
            "animate: the preview shows %d frames spread over the %.0f s take (at most %d; the glTF has every row)",
            MAX_PREVIEW_FRAMES,
            float(times[-1]),
            MAX_PREVIEW_FRAMES,
        )
        frames = MAX_PREVIEW_FRAMES
        clock = np.linspace(0.0, float(times[-1]), frames)
    else:
        clock = np.arange(frames) / fps
    return np.unique(np.clip(np.searchsorted(times, clock), 0, len(times) - 1))


def render_frames(
    head: FittedHead,
    curves: Curves,
    *,
    fps: float = 12.0,
    size: tuple[int, int] = (240, 300),
    view: str = "three_quarter",
    progress=None,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Grey pictures of the animated head at ``fps`` (:func:`render.preview.render_preview`): ``(frames
    ((H, W, 3) uint8 each), the rows of the curves they show)``."""
    rows = _frame_indices(curves.times, fps)
    animation = curve_keyframes(head, curves)
    taus = (
        animation.joint_transforms
        if animation.joint_transforms is not None
        else np.repeat(head.tau[None], len(curves.times), axis=0)
    )
    faces = load_asset().faces
    frames = []
    for i in range(len(rows)):
        if i % POSE_CHUNK == 0:  # posed a chunk at a time: a batch of every frame held GBs (issue 38)
            chunk = rows[i : i + POSE_CHUNK]
            posed = posed_frames(head, curves.coefficients[chunk], taus[chunk])
        vertices = posed[i % POSE_CHUNK]
        frames.append(
            render_preview(
                vertices,
                faces,
                view=view,
                size=size,
                spp=32,
                distance=620.0,
                target=(0.0, -10.0, 0.0),
                colors=np.full((len(vertices), 3), 0.6),
            )
        )
        if progress is not None:
            progress("frames", i + 1, len(rows))
    return frames, rows


def save_gif(frames: list[np.ndarray], path: str | Path, fps: float) -> None:
    """An animated GIF of ``frames`` at ``fps``, looping, written atomically (Pillow)."""
    from PIL import Image

    # one adaptive palette per frame, no dithering (dithering a smooth grey render only adds noise)
    images = [
        Image.fromarray(f).convert("P", palette=Image.Palette.ADAPTIVE, colors=255, dither=Image.Dither.NONE)
        for f in frames
    ]
    buffer = io.BytesIO()
    images[0].save(
        buffer,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        loop=0,
        duration=max(20, int(round(1000.0 / fps))),
        optimize=False,
    )
    write_bytes_atomic(Path(path), buffer.getvalue())


def frame_strip(frames: list[np.ndarray], count: int = 6) -> np.ndarray:
    """``count`` frames evenly spaced over ``frames``, side by side: ``(H, count * W, 3)`` uint8."""
    picks = np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int)
    return np.concatenate([frames[i] for i in picks], axis=1)


def animate_fit(
    fit_dir: str | Path,
    curves: Curves,
    out: str | Path,
    *,
    preview: str | Path | None = None,
    preview_fps: float = 12.0,
    force: bool = False,
    inputs=(),
    progress=None,
) -> dict:
    """Write the fit's head driven by ``curves`` as an animated skinned glTF ``out`` (``.glb``/``.gltf``) and,
    with ``preview``, a GIF of it rendered by our renderer; both atomically.

    Returns:
        A summary: ``output``, ``preview``, ``keyframes``, ``duration_s``, ``preview_frames``,
        ``head_rotation``, ``layout``.

    Raises:
        InputError: as :func:`load_fit_head`; pipeline.files.OutputError: an output is refused.
    """
    out = Path(out)
    check_output(out, force=force, inputs=inputs, kind="file")
    if preview is not None:
        check_output(preview, force=force, inputs=inputs, kind="file", option="--preview")
    head = load_fit_head(fit_dir)
    animation = curve_keyframes(head, curves)
    frames = []
    if preview is not None:
        frames, _ = render_frames(head, curves, fps=preview_fps, progress=progress)
    with staged_file(out, force, inputs=inputs) as tmp:
        write_skinned_head(
            tmp,
            load_asset(),
            head.weights,
            head.tau,
            curves.coefficients[0],
            base_color_texture=head.texture,
            animation=animation,
        )
        if preview is not None:
            with staged_file(preview, force, inputs=inputs) as tmp_gif:
                save_gif(frames, tmp_gif, preview_fps)
    log.info(
        "animate: %d keyframes over %.2f s written to %s%s",
        len(curves.times),
        curves.times[-1],
        out,
        f" and {len(frames)} preview frames to {preview}" if preview is not None else "",
    )
    return {
        "output": str(out),
        "preview": None if preview is None else str(preview),
        "keyframes": int(len(curves.times)),
        "duration_s": float(curves.times[-1]),
        "preview_frames": len(frames),
        "head_rotation": animation.joint_transforms is not None,
        "layout": curves.layout,
    }
