"""Driving a fitted head with ARKit curves (``jnr animate``) and moving one fit's expression onto another
identity (``jnr retarget``, JNR Fig. 7).

Curves files (:func:`read_curves`) come in two CSV layouts:

* **Live Link Face** (Epic's iPhone app): ``Timecode, BlendShapeCount``, then the 52 ARKit names
  capitalised (``EyeBlinkLeft`` ...), then ``HeadYaw, HeadPitch, HeadRoll`` and six eye angles. The timecode
  is ``HH:MM:SS:FF[.sub]`` at the take's frame rate (``fps``, 60 by default, the app's rate); the head
  angles are read as radians (``head_units``), the eye angles are ignored (the ``eyeLook*`` shapes move
  the eyes).
* **Plain**: a header of ARKit names (any subset, any case; missing ones are 0), optionally a ``time``
  column in seconds (else rows are frames at ``fps``, 30 by default) and ``head_yaw``, ``head_pitch``,
  ``head_roll`` in degrees.

Head angles turn the head about the ``skull_root`` joint (the top of the neck, y = -50 mm):
``R = Ry(yaw) @ Rx(pitch) @ Rz(roll)`` in rig space, right-handed: +yaw turns the face towards +X (the
subject's left), +pitch nods it down, +roll tilts the top of the head towards +X; applied after the
fitted ``skull_root`` transform (``tau' = R @ tau``, which keeps it a glTF translation @ rotation @ scale). These sign conventions are ours; Live Link Face's own are not
documented, so check a take's direction once and negate a column if needed.

The glTF (:func:`animate_fit`) is the fit's skinned head (template bind mesh, the fit's skinning
weights, its joints posed, the 52 ARKit shapes as morph targets, its texture) with one animation: the
morph weights at every row of the curves and, with head angles, the ``skull_root`` rotation.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.errors import InputError

log = logging.getLogger("jnr")

HEAD_COLUMNS = ("head_yaw", "head_pitch", "head_roll")
"""The plain layout's head angle columns (degrees), in :attr:`Curves.head_rotation` order."""
LIVE_LINK_HEAD = ("HeadYaw", "HeadPitch", "HeadRoll")
LIVE_LINK_EYES = ("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
LIVE_LINK_FPS = 60.0
"""Live Link Face's recording rate, the default frame rate of its timecodes."""
PLAIN_FPS = 30.0
"""The default frame rate of a plain CSV without a ``time`` column."""
HEAD_JOINT = "skull_root"
"""The joint the head angles turn."""
EXAMPLE_CURVES = Path(__file__).resolve().parent / "assets" / "animation" / "blink_smile.csv"
"""The shipped example curves (:func:`example_curves`, written by :func:`write_curves`)."""


class CurvesError(InputError):
    """A curves file that cannot be read: its layout, names, times or values."""


@dataclass(frozen=True)
class Curves:
    """ARKit expression curves over time.

    Attributes:
        times: ``(T,)`` seconds from the first row, strictly increasing.
        coefficients: ``(T, 52)`` ARKit coefficients in :data:`rig.expressions.EXPRESSION_NAMES` order, in
            each shape's limits.
        head_rotation: ``(T, 3)`` head yaw, pitch, roll in degrees, or None.
        layout: ``"live-link-face"`` or ``"plain"``.
    """

    times: np.ndarray
    coefficients: np.ndarray
    head_rotation: np.ndarray | None = None
    layout: str = "plain"


def _expression_index() -> dict[str, int]:
    from rig.expressions import EXPRESSION_NAMES

    return {n.lower(): i for i, n in enumerate(EXPRESSION_NAMES)}


_TIMECODE = re.compile(r"^(\d+):(\d+):(\d+):(\d+(?:\.\d+)?)$")


def _timecode_seconds(text: str, fps: float, path: Path, row: int) -> float:
    match = _TIMECODE.match(text.strip())
    if match is None:
        raise CurvesError(f"{path}: row {row}: timecode {text!r} is not HH:MM:SS:FF[.sub]")
    h, m, s, f = (float(g) for g in match.groups())
    if f >= fps:
        raise CurvesError(f"{path}: row {row}: timecode {text!r} has frame {f:g}, not below {fps:g} fps; "
                          "pass the take's frame rate with --fps")
    return 3600.0 * h + 60.0 * m + s + f / fps


def _number(text: str, path: Path, row: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise CurvesError(f"{path}: row {row}, column {column!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise CurvesError(f"{path}: row {row}, column {column!r}: value must be finite, got {text!r}")
    return value


def read_curves(path: str | Path, *, fps: float | None = None, head_units: str | None = None) -> Curves:
    """Read a Live Link Face or plain curves CSV (module docstring).

    Args:
        fps: frames per second of the timecodes (Live Link Face, default :data:`LIVE_LINK_FPS`) or of the
            rows of a plain file without a ``time`` column (default :data:`PLAIN_FPS`).
        head_units: ``"rad"`` or ``"deg"``: the head angles' unit (default: radians for Live Link Face,
            degrees for the plain layout).

    Returns:
        :class:`Curves`; coefficients outside a shape's limits are clamped with a warning.

    Raises:
        CurvesError: unreadable file, unknown column, bad number, times not increasing, no rows.
        FileNotFoundError: no such file.
    """
    from rig.expressions import EXPRESSION_NAMES, expression_limits

    path = Path(path)
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise CurvesError(f"fps must be a positive number, got {fps}")
    if head_units not in (None, "rad", "deg"):
        raise CurvesError(f"head units must be 'rad' or 'deg', got {head_units!r}")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise CurvesError(f"{path}: not a text CSV file") from None
    rows = [r for r in csv.reader(io.StringIO(text)) if any(cell.strip() for cell in r)]
    if not rows:
        raise CurvesError(f"{path}: empty curves file")
    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    if not body:
        raise CurvesError(f"{path}: no rows under the header")
    live_link = len(header) >= 2 and header[0].lower() == "timecode" and header[1].lower() == "blendshapecount"
    index = _expression_index()
    head_names = [h.lower() for h in (LIVE_LINK_HEAD if live_link else HEAD_COLUMNS)]
    ignored = {h.lower() for h in LIVE_LINK_EYES} if live_link else set()
    time_column = None
    columns: list[tuple[int, str, int | None]] = []  # (csv column, kind, target index)
    unknown = []
    for i, name in enumerate(header):
        key = name.lower()
        if live_link and i < 2:
            continue
        if key in index:
            columns.append((i, "shape", index[key]))
        elif key in head_names:
            columns.append((i, "head", head_names.index(key)))
        elif not live_link and key in ("time", "time_s", "seconds"):
            time_column = i
        elif key in ignored:
            continue
        else:
            unknown.append(name)
    if unknown:
        raise CurvesError(f"{path}: unknown column(s) {unknown}; a curves file has the 52 ARKit names "
                          f"(e.g. eyeBlinkLeft, jawOpen), {'HeadYaw/HeadPitch/HeadRoll' if live_link else 'time, head_yaw, head_pitch, head_roll'}")
    if not any(kind == "shape" for _, kind, _ in columns):
        raise CurvesError(f"{path}: no ARKit expression column (e.g. eyeBlinkLeft, jawOpen)")
    shapes = [n for _, kind, n in columns if kind == "shape"]
    if len(set(shapes)) != len(shapes):
        raise CurvesError(f"{path}: an ARKit name appears twice in the header")

    n = len(body)
    coefficients = np.zeros((n, len(EXPRESSION_NAMES)))
    head = np.zeros((n, 3)) if any(kind == "head" for _, kind, _ in columns) else None
    times = np.zeros(n)
    rate = fps or (LIVE_LINK_FPS if live_link else PLAIN_FPS)
    for r, row in enumerate(body):
        line = r + 2
        if len(row) != len(header):
            raise CurvesError(f"{path}: row {line} has {len(row)} cells, the header {len(header)}")
        for i, kind, target in columns:
            value = _number(row[i], path, line, header[i])
            if kind == "shape":
                coefficients[r, target] = value
            else:
                head[r, target] = value
        if live_link:
            times[r] = _timecode_seconds(row[0], rate, path, line)
        elif time_column is not None:
            times[r] = _number(row[time_column], path, line, header[time_column])
        else:
            times[r] = r / rate
    times = times - times[0]
    if np.any(np.diff(times) <= 0.0):
        bad = int(np.flatnonzero(np.diff(times) <= 0.0)[0]) + 3
        raise CurvesError(f"{path}: times must increase from row to row; row {bad} does not")
    low, high = (t.numpy().astype(np.float64) for t in expression_limits())
    clamped = np.clip(coefficients, low, high)
    if np.any(np.abs(clamped - coefficients) > 1e-9):
        worst = float(np.max(np.abs(clamped - coefficients)))
        warnings.warn(f"{path}: coefficients outside their limits were clamped (by up to {worst:.3g})", stacklevel=2)
    if head is not None and (head_units or ("rad" if live_link else "deg")) == "rad":
        head = np.degrees(head)
    return Curves(times, clamped, head, "live-link-face" if live_link else "plain")


def write_curves(path: str | Path, curves: Curves, *, layout: str = "plain", fps: float = LIVE_LINK_FPS) -> None:
    """Write ``curves`` as CSV: ``layout="plain"`` (``time`` in seconds, the 52 ARKit names, head angles in
    degrees when present) or ``"live-link-face"`` (timecodes at ``fps``, capitalised names, radians, zero
    eye angles), atomically."""
    from rig.expressions import EXPRESSION_NAMES
    from rig.io.atomic import write_bytes_atomic

    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    head = curves.head_rotation
    if layout == "plain":
        writer.writerow(["time", *EXPRESSION_NAMES, *(HEAD_COLUMNS if head is not None else ())])
        for t in range(len(curves.times)):
            writer.writerow([f"{curves.times[t]:.4f}", *(f"{c:.4f}" for c in curves.coefficients[t]),
                             *((f"{a:.3f}" for a in head[t]) if head is not None else ())])
    elif layout == "live-link-face":
        names = [n[0].upper() + n[1:] for n in EXPRESSION_NAMES]
        writer.writerow(["Timecode", "BlendShapeCount", *names, *LIVE_LINK_HEAD, *LIVE_LINK_EYES])
        for t in range(len(curves.times)):
            frames = curves.times[t] * fps
            seconds = int(frames // fps)
            code = f"00:{seconds // 60:02d}:{seconds % 60:02d}:{frames - seconds * fps:06.3f}"
            angles = np.radians(head[t]) if head is not None else np.zeros(3)
            writer.writerow([code, len(EXPRESSION_NAMES), *(f"{c:.6f}" for c in curves.coefficients[t]),
                             *(f"{a:.6f}" for a in angles), *("0",) * len(LIVE_LINK_EYES)])
    else:
        raise ValueError(f"write_curves: layout must be 'plain' or 'live-link-face', got {layout!r}")
    write_bytes_atomic(Path(path), text.getvalue().encode("utf-8"))


def example_curves(fps: float = 30.0) -> Curves:
    """The shipped example (:data:`EXAMPLE_CURVES`), 2.4 s: a blink (both eyes, 0.3-0.6 s), then a smile
    that builds and fades (0.8-2.2 s) with a slight turn of the head towards the subject's left and back."""
    from rig.expressions import EXPRESSION_NAMES

    times = np.arange(int(round(2.4 * fps)) + 1) / fps
    index = {n: i for i, n in enumerate(EXPRESSION_NAMES)}

    def bump(t, start, end):
        """0 outside ``[start, end]``, a raised-cosine bump to 1 at the middle."""
        x = np.clip((t - start) / (end - start), 0.0, 1.0)
        return 0.5 - 0.5 * np.cos(2.0 * np.pi * x)

    c = np.zeros((len(times), len(EXPRESSION_NAMES)))
    blink = bump(times, 0.3, 0.6)
    smile = np.clip(1.6 * bump(times, 0.8, 2.2), 0.0, 1.0)
    for side in ("Left", "Right"):
        c[:, index[f"eyeBlink{side}"]] = blink
        c[:, index[f"mouthSmile{side}"]] = 0.9 * smile
        c[:, index[f"cheekSquint{side}"]] = 0.5 * smile
        c[:, index[f"eyeSquint{side}"]] = 0.3 * smile
    c[:, index["jawOpen"]] = 0.15 * smile
    head = np.zeros((len(times), 3))
    head[:, 0] = 12.0 * bump(times, 0.8, 2.2)
    head[:, 1] = -4.0 * bump(times, 0.8, 2.2)
    return Curves(np.round(times, 4), np.round(c, 4), np.round(head, 3), "plain")


def head_rotation_matrices(angles_deg: np.ndarray) -> np.ndarray:
    """``(T, 3)`` yaw, pitch, roll in degrees -> ``(T, 3, 3)`` rotations ``Ry(yaw) @ Rx(pitch) @ Rz(roll)`` in
    rig space (right-handed, +Y up, +Z out of the face)."""
    from scipy.spatial.transform import Rotation

    a = np.asarray(angles_deg, dtype=np.float64).reshape(-1, 3)
    return Rotation.from_euler("YXZ", a, degrees=True).as_matrix()


# ----------------------------------------------------------------------------------------------
# a fit's head
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FitHead:
    """What a fit folder's head is made of (from its ``params.json``).

    Attributes:
        folder: the fit folder. params: its ``params.json``.
        weights: ``(V, J)`` skinning weights of the fit's latent Z.
        tau: ``(J, 4, 4)`` the fit's joint channel transforms (mm).
        coefficients: ``(52,)`` the fit's ARKit coefficients.
        texture: the bytes of its ``texture.png`` (a photo fit), or None.
        vertices: ``(V, 3)`` mm, the fitted head (float64 rig).
    """

    folder: Path
    params: dict
    weights: np.ndarray
    tau: np.ndarray
    coefficients: np.ndarray
    texture: bytes | None
    vertices: np.ndarray


def load_fit_head(folder: str | Path) -> FitHead:
    """Read the head of a ``jnr fit`` / ``jnr fit-scan`` output folder.

    Raises:
        InputError: not a folder, no readable ``params.json``, an ASM fit (no joint rig to animate).
    """
    from pipeline.scan.outputs import head_arrays_from_params

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder} is not a fit folder (jnr fit / jnr fit-scan --out)")
    params_path = folder / "params.json"
    try:
        params = json.loads(params_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{folder} has no params.json: not a jnr fit folder") from None
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise InputError(f"{params_path} is not a JSON file") from None
    if not isinstance(params, dict):
        raise InputError(f"{params_path} is not a fit's parameter file")
    if params.get("skinning") == "asm":
        raise InputError(f"{folder} is an ASM fit (skinning: asm); animation and retargeting take JNR fits")
    try:
        vertices, _, weights, tau, coefficients = head_arrays_from_params(params)
    except (ValueError, TypeError, KeyError) as exc:
        raise InputError(f"{params_path}: {exc}") from None
    texture_path = folder / "texture.png"
    texture = texture_path.read_bytes() if texture_path.is_file() else None
    return FitHead(folder, params, weights, tau, coefficients, texture, vertices)


def load_fit_head_from_params(params: dict, like: FitHead) -> FitHead:
    """A :class:`FitHead` of ``params`` (a fit's parameter dict) keeping ``like``'s folder and texture."""
    from pipeline.scan.outputs import head_arrays_from_params

    vertices, _, weights, tau, coefficients = head_arrays_from_params(params)
    return FitHead(like.folder, params, weights, tau, coefficients, like.texture, vertices)


def posed_frames(head: FitHead, coefficients: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """``(T, V, 3)`` mm: the fit's head with ``coefficients (T, 52)`` and joint transforms ``taus (T, J, 4, 4)``
    (linear blend skinning of the template plus expression offsets, as the glTF is posed)."""
    import torch

    from rig.expressions import ExpressionModel
    from rig.lbs import joint_world_transforms, skin_vertices
    from rig.model import JointRig

    rig = JointRig(dtype=torch.float64)
    with torch.no_grad():
        rest = ExpressionModel(rig.asset, dtype=torch.float64).vertices(torch.as_tensor(coefficients))
        _, skinning = joint_world_transforms(torch.as_tensor(taus), rig.bind_positions, rig.parents, rig.levels)
        return skin_vertices(rest, torch.as_tensor(head.weights), skinning).numpy()


def curve_keyframes(head: FitHead, curves: Curves):
    """The glTF animation of ``curves`` on ``head``: :class:`rig.io.gltf.GltfAnimation` with the morph weights
    and, with head angles, every joint's transforms (the fit's, ``skull_root``'s turned)."""
    from rig.io.gltf import GltfAnimation

    taus = None
    if curves.head_rotation is not None and np.abs(curves.head_rotation).max() > 0.0:
        taus = np.repeat(head.tau[None], len(curves.times), axis=0)
        j = _joint_index(HEAD_JOINT)
        turn = np.tile(np.eye(4), (len(curves.times), 1, 1))
        turn[:, :3, :3] = head_rotation_matrices(curves.head_rotation)
        taus[:, j] = turn @ head.tau[j]
    return GltfAnimation(curves.times, curves.coefficients, taus, name="curves")


def _joint_index(name: str) -> int:
    from rig.joints import JOINT_INDEX

    return JOINT_INDEX[name]


def _frame_indices(times: np.ndarray, fps: float) -> np.ndarray:
    """Rows of the curves nearest to a ``fps`` clock from the first to the last time (no repeats)."""
    clock = np.arange(0.0, times[-1] + 1e-9, 1.0 / fps)
    return np.unique(np.clip(np.searchsorted(times, clock), 0, len(times) - 1))


def render_frames(head: FitHead, curves: Curves, *, fps: float = 12.0, size: tuple[int, int] = (240, 300),
                  view: str = "three_quarter", progress=None) -> tuple[list[np.ndarray], np.ndarray]:
    """Grey pictures of the animated head at ``fps`` (:func:`render.preview.render_preview`): ``(frames
    ((H, W, 3) uint8 each), the rows of the curves they show)``."""
    from render.preview import render_preview
    from rig.asset import load_asset

    rows = _frame_indices(curves.times, fps)
    animation = curve_keyframes(head, curves)
    taus = (animation.joint_transforms if animation.joint_transforms is not None
            else np.repeat(head.tau[None], len(curves.times), axis=0))
    faces = load_asset().faces
    posed = posed_frames(head, curves.coefficients[rows], taus[rows])  # one batch: the models are built once
    frames = []
    for i, vertices in enumerate(posed):
        frames.append(render_preview(vertices, faces, view=view, size=size, spp=32, distance=620.0,
                                     target=(0.0, -10.0, 0.0), colors=np.full((len(vertices), 3), 0.6)))
        if progress is not None:
            progress("frames", i + 1, len(rows))
    return frames, rows


def save_gif(frames: list[np.ndarray], path: str | Path, fps: float) -> None:
    """An animated GIF of ``frames`` at ``fps``, looping, written atomically (Pillow)."""
    from PIL import Image

    from rig.io.atomic import write_bytes_atomic

    # one adaptive palette per frame, no dithering (dithering a smooth grey render only adds noise)
    images = [Image.fromarray(f).convert("P", palette=Image.Palette.ADAPTIVE, colors=255, dither=Image.Dither.NONE)
              for f in frames]
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], loop=0,
                   duration=max(20, int(round(1000.0 / fps))), optimize=False)
    write_bytes_atomic(Path(path), buffer.getvalue())


def frame_strip(frames: list[np.ndarray], count: int = 6) -> np.ndarray:
    """``count`` frames evenly spaced over ``frames``, side by side: ``(H, count * W, 3)`` uint8."""
    picks = np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int)
    return np.concatenate([frames[i] for i in picks], axis=1)


def animate_fit(fit_dir: str | Path, curves: Curves, out: str | Path, *, preview: str | Path | None = None,
                preview_fps: float = 12.0, force: bool = False, inputs=(), progress=None) -> dict:
    """Write the fit's head driven by ``curves`` as an animated skinned glTF ``out`` (``.glb``/``.gltf``) and,
    with ``preview``, a GIF of it rendered by our renderer; both atomically.

    Returns:
        A summary: ``output``, ``preview``, ``keyframes``, ``duration_s``, ``preview_frames``,
        ``head_rotation``, ``layout``.

    Raises:
        InputError: as :func:`load_fit_head`; pipeline.files.OutputError: an output is refused.
    """
    from pipeline.edit import write_skinned_head
    from pipeline.files import check_output, staged_file
    from rig.asset import load_asset

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
        write_skinned_head(tmp, load_asset(), head.weights, head.tau, curves.coefficients[0],
                           base_color_texture=head.texture, animation=animation)
        if preview is not None:
            with staged_file(preview, force, inputs=inputs) as tmp_gif:
                save_gif(frames, tmp_gif, preview_fps)
    log.info("animate: %d keyframes over %.2f s written to %s%s", len(curves.times), curves.times[-1], out,
             f" and {len(frames)} preview frames to {preview}" if preview is not None else "")
    return {"output": str(out), "preview": None if preview is None else str(preview),
            "keyframes": int(len(curves.times)), "duration_s": float(curves.times[-1]),
            "preview_frames": len(frames), "head_rotation": animation.joint_transforms is not None,
            "layout": curves.layout}


# ----------------------------------------------------------------------------------------------
# retargeting
# ----------------------------------------------------------------------------------------------

RETARGET_FILES = ("mesh.obj", "mesh.ply", "mesh.glb", "params.json", "expressions.csv", "preview.png",
                  "report.json")
"""What ``jnr retarget`` writes."""


def retarget_params(source: dict, target: dict) -> dict:
    """The target fit's ``params.json`` with the source's expression: its 52 ARKit coefficients (the jaw's
    ``jawOpen``, ``jawForward``, ``jawLeft``, ``jawRight`` among them) replace the target's; the target keeps its
    identity (joints, latent Z), camera, pose and light."""
    out = json.loads(json.dumps(target))
    out["expressions"] = dict(source["expressions"])
    return out


def retarget_fit(source_dir: str | Path, target_dir: str | Path, out: str | Path, *, force: bool = False) -> dict:
    """Write ``out/``: the target fit's head with the source fit's expression (:func:`retarget_params`):
    ``mesh.obj``/``mesh.ply`` (mm), ``mesh.glb`` (skinned, the coefficients as morph weights),
    ``params.json`` (a fit parameter file: ``jnr rig edit`` / ``jnr animate`` take it), ``expressions.csv``,
    ``preview.png`` (source, target, retargeted; grey, three-quarter view) and ``report.json``.

    Raises:
        InputError: as :func:`load_fit_head` for either fit; pipeline.files.OutputError: ``out`` refused.
    """
    from pipeline.edit import write_skinned_head
    from pipeline.files import check_output, staged_folder
    from render.preview import render_preview, save_png
    from rig.asset import load_asset
    from rig.expressions import EXPRESSION_NAMES
    from rig.io.mesh import export_mesh

    out = Path(out)
    inputs = (str(source_dir), str(target_dir))
    check_output(out, force=force, inputs=inputs)
    source, target = load_fit_head(source_dir), load_fit_head(target_dir)
    params = retarget_params(source.params, target.params)
    params["retargeted_from"] = {"source": str(Path(source_dir)), "target": str(Path(target_dir)),
                                 "what": "the source's 52 ARKit expression coefficients on the target's identity"}
    asset = load_asset()
    head = load_fit_head_from_params(params, target)
    vertices = head.vertices
    grey = np.full((len(vertices), 3), 0.6)
    pictures = [render_preview(v, asset.faces, view="three_quarter", size=(320, 400), colors=grey)
                for v in (source.vertices, target.vertices, vertices)]
    report = {"source": str(Path(source_dir)), "target": str(Path(target_dir)),
              "expressions": dict(zip(EXPRESSION_NAMES, head.coefficients.tolist())),
              "max_vertex_change_mm": float(np.linalg.norm(vertices - target.vertices, axis=1).max()),
              "files": list(RETARGET_FILES)}
    with staged_folder(out, force, inputs=inputs) as tmp:
        export_mesh(tmp / "mesh.obj", vertices, asset.faces, face_uvs=asset.face_uvs)
        export_mesh(tmp / "mesh.ply", vertices, asset.faces)
        write_skinned_head(tmp / "mesh.glb", asset, head.weights, head.tau, head.coefficients,
                           base_color_texture=target.texture)
        (tmp / "params.json").write_text(json.dumps(params, indent=2), encoding="utf-8")
        (tmp / "expressions.csv").write_text(
            ",".join(EXPRESSION_NAMES) + "\n" + ",".join(f"{c:.6f}" for c in head.coefficients) + "\n",
            encoding="utf-8")
        save_png(np.concatenate(pictures, axis=1), tmp / "preview.png")
        (tmp / "report.json").write_text(json.dumps(report, indent=2), encoding="utf-8")
    log.info("retarget: %s's expression on %s written to %s", source_dir, target_dir, out)
    return report


__all__ = ["EXAMPLE_CURVES", "HEAD_COLUMNS", "HEAD_JOINT", "RETARGET_FILES", "Curves", "CurvesError", "FitHead",
           "animate_fit", "curve_keyframes", "example_curves", "frame_strip", "head_rotation_matrices",
           "load_fit_head", "posed_frames", "read_curves", "render_frames", "retarget_fit", "retarget_params",
           "save_gif", "write_curves"]
