"""An accessory on a fitted head (``jnr accessory FIT_DIR ACCESSORY.obj --out DIR``): skinning weights and
expression offsets transferred from the fit's own head (:mod:`rig.accessory`, JNR section 5.3), the
accessory posed on the fit, and the head with the accessory as one skinned glTF.

The accessory is a triangle mesh (Wavefront OBJ) placed on the jnr template in its bind pose (rig space,
millimetres; ``jnr rig export --format obj`` writes the template to model it on), or the name of a
shipped example: ``glasses`` or ``cap`` (``pipeline/assets/accessories/``, made by
:mod:`pipeline.synthetic.accessories`). ``FIT_DIR`` is the output folder of ``jnr fit`` or
``jnr fit-scan`` (its ``params.json``); the transfer uses that fit's skinning weights (its latent Z), so
the accessory follows the fitted identity's joints and expressions.

The output folder (written to a temporary folder beside it, then moved into place):

==============================  ==================================================================
file                            contents
==============================  ==================================================================
``accessory.obj``               the accessory posed on the fitted head (rig space, mm; the header
                                says so), overlays the fit's head (``jnr rig export --params``)
``head_with_accessory.glb``     skinned glTF 2.0 (metres): the fitted head (as ``jnr rig export
                                --format gltf --params``) and the accessory as a second mesh node on
                                the same skin, its morph targets under the same 52 ARKit names
``accessory_weights.npz``       ``weights (N, 52)``, ``morph_targets (E, N, 3)`` mm, ``distance (N,)``
                                mm, ``anchor_face (N,)`` (template face ids), ``anchor_barycentric
                                (N, 3)``, ``rest_vertices (N, 3)`` mm, ``faces (F, 3)``, ``joint_names``,
                                ``expression_names``, ``falloff_mm``, ``smoothing_mm``
``preview.png``                 the fitted head (grey) with the accessory (coloured), front and side
``report.json``                 the accessory's size, the settings, and how far it lies outside the
                                fitted head's skin (signed distance, mm; negative: inside)
==============================  ==================================================================
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.accessory import (
    DEFAULT_FALLOFF_MM,
    DEFAULT_SMOOTHING_MM,
    AccessorySkinning,
    outer_skin_face_ids,
    outer_skin_faces,
    pose_accessory,
    signed_distance,
    transfer_skinning,
)
from rig.errors import InputError

ACCESSORY_DIR = Path(__file__).resolve().parent / "assets" / "accessories"
"""The shipped example accessories (``<name>.obj``)."""
EXAMPLE_NAMES = ("glasses", "cap")
"""Names ``jnr accessory`` accepts instead of a file."""
EXAMPLE_COLORS = {"glasses": (0.05, 0.18, 0.65), "cap": (0.75, 0.12, 0.08)}
"""Linear RGB of the examples in previews and glTF; any other accessory is teal."""
OTHER_COLOR = (0.05, 0.45, 0.40)
MAX_ACCESSORY_VERTICES = 200_000
"""An accessory with more vertices is refused (the transfer is exact and per vertex; decimate it first)."""
MAX_SKIN_DISTANCE_MM = 40.0
"""An accessory whose nearest vertex is farther than this from the template's skin is not placed on it."""
MAX_EXTENT_MM = 1000.0
"""An accessory larger than this (bounding-box diagonal) is not in millimetres."""
OUTPUT_FILES = ("accessory.obj", "head_with_accessory.glb", "accessory_weights.npz", "preview.png", "report.json")


class AccessoryInputError(InputError):
    """A bad accessory file or fit folder (one line; exit status 2 on the command line)."""


@dataclass(frozen=True)
class Accessory:
    """An accessory mesh on the template's bind pose.

    Attributes:
        name: the example's name or the file's stem; path: where it was read from.
        vertices: ``(N, 3)`` mm, rig space; faces: ``(F, 3)`` int64.
    """

    name: str
    path: Path
    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True)
class FitHead:
    """A fitted head, from a fit's ``params.json`` (:func:`pipeline.scan.outputs.head_arrays_from_params`).

    Attributes:
        params_path: the file.
        posed: ``(V, 3)`` the fitted head, rig space, mm.
        weights: ``(V, J)`` its skinning weights (template space).
        tau: ``(J, 4, 4)`` the joints' channel transforms.
        coefficients: ``(E,)`` its expression coefficients (ARKit order).
    """

    params_path: Path
    posed: np.ndarray
    weights: np.ndarray
    tau: np.ndarray
    coefficients: np.ndarray


@dataclass(frozen=True)
class AccessoryOnFit:
    """An accessory transferred to and posed on a fitted head (:func:`accessory_on_fit`).

    Attributes:
        accessory: the input; head: the fit.
        skinning: the transfer (:class:`rig.accessory.AccessorySkinning`, from the fit's weights).
        posed: ``(N, 3)`` the accessory posed on the fit, mm.
        signed_distance: ``(N,)`` of the posed accessory's vertices to the fitted head's outer skin, mm
            (negative: inside).
    """

    accessory: Accessory
    head: FitHead
    skinning: AccessorySkinning
    posed: np.ndarray
    signed_distance: np.ndarray


def accessory_path(accessory: str | Path) -> Path:
    """The file of an accessory argument: an existing file as it is, else a shipped example's name."""
    path = Path(accessory)
    if not path.exists() and str(accessory) in EXAMPLE_NAMES:
        return ACCESSORY_DIR / f"{accessory}.obj"
    return path


def read_accessory(accessory: str | Path, asset=None) -> Accessory:
    """Read and check an accessory (an OBJ file or a shipped example's name, :func:`accessory_path`).

    Raises:
        AccessoryInputError: missing, not an OBJ, unreadable, no triangles, non-finite vertices, more than
            :data:`MAX_ACCESSORY_VERTICES`, larger than :data:`MAX_EXTENT_MM` (not millimetres?) or farther
            than :data:`MAX_SKIN_DISTANCE_MM` from the template (not placed on it?).
    """
    import trimesh

    from rig.accessory import closest_surface_points
    from rig.asset import load_asset

    path = accessory_path(accessory)
    if not path.exists():
        raise AccessoryInputError(f"accessory {accessory} not found (give a Wavefront .obj file or one of "
                                  f"{', '.join(EXAMPLE_NAMES)})")
    if not path.is_file():
        raise AccessoryInputError(f"accessory {path} is not a file")
    if path.suffix.lower() != ".obj":
        raise AccessoryInputError(f"accessory {path} must be a Wavefront .obj file")
    try:
        mesh = trimesh.load(str(path), file_type="obj", force="mesh", process=False)
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
    except Exception as exc:  # trimesh's OBJ parser raises many types
        raise AccessoryInputError(f"accessory {path} is unreadable as OBJ: {exc}") from None
    if faces.ndim != 2 or faces.shape[1:] != (3,) or len(faces) == 0 or len(vertices) < 3:
        raise AccessoryInputError(f"accessory {path} holds no triangles")
    if not np.isfinite(vertices).all():
        raise AccessoryInputError(f"accessory {path} has non-finite vertex coordinates")
    if len(vertices) > MAX_ACCESSORY_VERTICES:
        raise AccessoryInputError(f"accessory {path} has {len(vertices)} vertices; at most "
                                  f"{MAX_ACCESSORY_VERTICES} (decimate it)")
    extent = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    if extent > MAX_EXTENT_MM:
        raise AccessoryInputError(f"accessory {path} is {extent:.0f} units across; accessories are in millimetres "
                                  f"on the jnr template (a head is about 250 mm)")
    asset = asset or load_asset()
    nearest = float(closest_surface_points(vertices, asset.vertices, outer_skin_faces(asset)).distance.min())
    if nearest > MAX_SKIN_DISTANCE_MM:
        raise AccessoryInputError(f"accessory {path} lies {nearest:.0f} mm from the template's skin at its nearest; "
                                  f"place it on the jnr template in millimetres (jnr rig export --format obj "
                                  f"writes the template)")
    name = str(accessory) if str(accessory) in EXAMPLE_NAMES and path.parent == ACCESSORY_DIR else path.stem
    return Accessory(name=name, path=path, vertices=vertices, faces=faces)


def read_fit_head(fit_dir: str | Path) -> FitHead:
    """The fitted head of a ``jnr fit`` / ``jnr fit-scan`` output folder (its ``params.json``).

    Raises:
        AccessoryInputError: not a folder, no ``params.json``, unreadable, an ASM fit (``"skinning": "asm"``:
            its weights are not the rig's), or parameters out of their limits.
    """
    from pipeline.scan.outputs import head_arrays_from_params

    folder = Path(fit_dir)
    if not folder.is_dir():
        raise AccessoryInputError(f"fit folder {folder} not found (give the --out folder of jnr fit or jnr fit-scan)")
    path = folder / "params.json"
    if not path.is_file():
        raise AccessoryInputError(f"{folder} holds no params.json; give the --out folder of jnr fit or jnr fit-scan")
    try:
        params = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise AccessoryInputError(f"{path} is unreadable: {exc}") from None
    if not isinstance(params, dict):
        raise AccessoryInputError(f"{path} is not a jnr fit's parameter file")
    if params.get("skinning") == "asm":
        raise AccessoryInputError(f"{path} is an ASM fit (skinning: asm); accessories take JNR fits, whose "
                                  f"skinning weights they inherit")
    missing = [k for k in ("joints", "latent_z", "expressions") if k not in params]
    if missing:
        raise AccessoryInputError(f"{path} is not a jnr fit's parameter file ({missing} missing)")
    try:
        posed, _, weights, tau, coefficients = head_arrays_from_params(params)
    except (ValueError, TypeError) as exc:
        raise AccessoryInputError(f"{path}: {exc}") from None
    return FitHead(params_path=path, posed=posed, weights=weights, tau=tau, coefficients=coefficients)


def joint_distance(asset) -> np.ndarray:
    """``(J, J)`` mm: :func:`rig.accessory.joint_motion_distance` of the rig's joints (their channels' reach
    at 100 mm), for the transfer's choice of kept influences."""
    from rig.accessory import channel_reach, joint_motion_distance

    return joint_motion_distance(asset.parents, channel_reach(len(asset.joint_names)))


def accessory_on_fit(head: FitHead, accessory: Accessory, *, falloff_mm: float = DEFAULT_FALLOFF_MM,
                     smoothing_mm: float = DEFAULT_SMOOTHING_MM, asset=None) -> AccessoryOnFit:
    """Transfer the fit's skinning to the accessory (:func:`rig.accessory.transfer_skinning` on the template's
    outer skin with the fit's weights and the 52 ARKit shapes) and pose it with the fit's joints and
    expressions (:func:`rig.accessory.pose_accessory`)."""
    import torch

    from rig.asset import load_asset
    from rig.expressions import morph_targets
    from rig.lbs import joint_world_transforms

    asset = asset or load_asset()
    skin = outer_skin_faces(asset)
    transfer = transfer_skinning(asset.vertices, skin, head.weights, morph_targets(asset), accessory.vertices,
                                 falloff_mm=falloff_mm, smoothing_mm=smoothing_mm, joint_distance=joint_distance(asset))
    _, transforms = joint_world_transforms(torch.as_tensor(head.tau[None], dtype=torch.float64),
                                           torch.as_tensor(asset.joint_positions, dtype=torch.float64),
                                           torch.as_tensor(asset.parents, dtype=torch.long))
    with torch.no_grad():
        posed = pose_accessory(accessory.vertices, transfer, transforms,
                               torch.as_tensor(head.coefficients[None], dtype=torch.float64))[0].numpy()
    distance = signed_distance(posed, head.posed, skin)
    return AccessoryOnFit(accessory, head, transfer, posed, distance)


def preview_image(head_vertices: np.ndarray, accessory_vertices: np.ndarray, accessory_faces: np.ndarray,
                  color: tuple[float, float, float], *, spp: int = 16, size: tuple[int, int] = (360, 440)) -> np.ndarray:
    """``(H, 2W, 3)`` uint8: the head (grey) with the accessory (``color``, linear RGB), front and side
    (:func:`render.preview.render_preview`)."""
    from render.preview import render_preview
    from rig.asset import load_asset

    asset = load_asset()
    vertices = np.concatenate([head_vertices, accessory_vertices])
    faces = np.concatenate([asset.faces, np.asarray(accessory_faces) + len(head_vertices)])
    colors = np.concatenate([np.full((len(head_vertices), 3), 0.55), np.tile(color, (len(accessory_vertices), 1))])
    tiles = [render_preview(vertices, faces, colors=colors, view=view, size=size, spp=spp, distance=750.0,
                            target=(0.0, -5.0, 15.0)) for view in ("front", "side")]
    return np.concatenate(tiles, 1)


def report_payload(result: AccessoryOnFit, command: str | None = None) -> dict:
    """``report.json``: the accessory, the settings and its signed distance to the fitted head."""
    sd = result.signed_distance
    return {
        "command": command,
        "fit": str(result.head.params_path),
        "accessory": {"name": result.accessory.name, "path": str(result.accessory.path),
                      "vertices": len(result.accessory.vertices), "faces": len(result.accessory.faces)},
        "falloff_mm": result.skinning.falloff_mm,
        "smoothing_mm": result.skinning.smoothing_mm,
        "bind_distance_to_template_mm": {"min": float(result.skinning.distance.min()),
                                         "median": float(np.median(result.skinning.distance))},
        "signed_distance_to_fit_mm": {"min": float(sd.min()), "median": float(np.median(sd)),
                                      "inside_vertices": int((sd < 0).sum())},
        "units": "millimetres, rig space",
    }


def write_accessory_outputs(out: str | Path, result: AccessoryOnFit, *, force: bool = False, spp: int = 16,
                            inputs: tuple = (), command: str | None = None) -> Path:
    """Write the output folder (module docstring) atomically.

    Raises:
        pipeline.files.OutputError: ``out`` is refused (exists without ``force``, not jnr's, an input) or
            cannot be written.
    """
    from pipeline.edit import write_skinned_head
    from pipeline.files import staged_folder
    from render.preview import save_png
    from rig.asset import load_asset
    from rig.expressions import EXPRESSION_NAMES
    from rig.io.gltf import GltfAttachment
    from rig.io.mesh import RIG_SPACE_COMMENT, export_mesh

    asset = load_asset()
    out = Path(out)
    accessory, skinning = result.accessory, result.skinning
    color = EXAMPLE_COLORS.get(accessory.name, OTHER_COLOR)
    with staged_folder(out, force, inputs=inputs, marker={"command": command}) as tmp:
        export_mesh(tmp / "accessory.obj", result.posed, accessory.faces,
                    comment=f"accessory {accessory.name} posed on a fitted head; {RIG_SPACE_COMMENT}")
        attachment = GltfAttachment(name=accessory.name if accessory.name not in asset.joint_names + ("mesh",)
                                    else f"accessory_{accessory.name}", vertices=accessory.vertices,
                                    faces=accessory.faces, weights=skinning.weights,
                                    morph_targets=skinning.morph_targets, color=color)
        write_skinned_head(tmp / "head_with_accessory.glb", asset, result.head.weights, result.head.tau,
                           result.head.coefficients, attachments=[attachment])
        np.savez_compressed(
            tmp / "accessory_weights.npz", weights=skinning.weights, morph_targets=skinning.morph_targets,
            distance=skinning.distance, anchor_face=outer_skin_face_ids(asset)[skinning.anchors.face],
            anchor_barycentric=skinning.anchors.barycentric, rest_vertices=accessory.vertices,
            faces=accessory.faces, joint_names=np.array(asset.joint_names), expression_names=np.array(EXPRESSION_NAMES),
            falloff_mm=np.float64(skinning.falloff_mm), smoothing_mm=np.float64(skinning.smoothing_mm))
        save_png(preview_image(result.head.posed, result.posed, accessory.faces, color, spp=spp), tmp / "preview.png")
        (tmp / "report.json").write_text(json.dumps(report_payload(result, command), indent=2) + "\n")
    return out


def run_accessory(fit_dir: str | Path, accessory: str | Path, out: str | Path, *, force: bool = False,
                  falloff_mm: float = DEFAULT_FALLOFF_MM, smoothing_mm: float = DEFAULT_SMOOTHING_MM, spp: int = 16,
                  command: str | None = None) -> AccessoryOnFit:
    """What ``jnr accessory`` does: check the output, read the fit and the accessory, transfer, pose, write.

    Raises:
        pipeline.files.OutputError: ``out`` is refused; AccessoryInputError: a bad fit folder or accessory,
            ``falloff_mm`` or ``smoothing_mm`` negative or not finite (``smoothing_mm`` may be ``inf``).
    """
    import math

    from pipeline.files import check_output

    inputs = (fit_dir, accessory_path(accessory))
    check_output(out, force=force, inputs=inputs, kind="folder")
    if not (math.isfinite(falloff_mm) and falloff_mm >= 0):
        raise AccessoryInputError(f"--falloff must be a finite number of mm >= 0, got {falloff_mm}")
    if not smoothing_mm >= 0:
        raise AccessoryInputError(f"--smoothing must be a number of mm >= 0 (or inf), got {smoothing_mm}")
    head = read_fit_head(fit_dir)
    item = read_accessory(accessory)
    result = accessory_on_fit(head, item, falloff_mm=falloff_mm, smoothing_mm=smoothing_mm)
    write_accessory_outputs(out, result, force=force, spp=spp, inputs=inputs, command=command)
    return result


# ----------------------------------------------------------------------------------------------------
# How well an accessory follows the head (tests and docs/accessories.md)
# ----------------------------------------------------------------------------------------------------

FOLLOW_CASES: tuple[tuple[str, dict, dict], ...] = (
    ("crown.translate_y +40", {"crown.translate_y": 40.0}, {}),
    ("crown.translate_y -40", {"crown.translate_y": -40.0}, {}),
    ("cranium.scale_x 1.1", {"cranium.scale_x": 1.1}, {}),
    ("cranium.scale_z 0.8", {"cranium.scale_z": 0.8}, {}),
    ("skull_root.rotate_x 25", {"skull_root.rotate_x": 25.0}, {}),
    ("skull_root.scale_x 0.8", {"skull_root.scale_x": 0.8}, {}),
    ("nose_root_a.translate_z +10", {"nose_root_a.translate_z": 10.0}, {}),
    ("nose_bridge.translate_y +8", {"nose_bridge.translate_y": 8.0}, {}),
    ("brow_center.translate_z +10", {"brow_center.translate_z": 10.0}, {}),
    ("left_brow_outer.translate_z +10", {"left_brow_outer.translate_z": 10.0}, {}),
    ("left_eye_socket.scale 1.5", {"left_eye_socket.scale": 1.5}, {}),
    ("left_orbital.translate_x +10", {"left_orbital.translate_x": 10.0}, {}),
    ("left_ear_position.translate_x +10", {"left_ear_position.translate_x": 10.0}, {}),
    ("left_ear_position.translate_z -14", {"left_ear_position.translate_z": -14.0}, {}),
    ("jawOpen 1", {}, {"jawOpen": 1.0}),
    ("browInnerUp 1", {}, {"browInnerUp": 1.0}),
    ("browOuterUpLeft 1", {}, {"browOuterUpLeft": 1.0}),
    ("browDownLeft 1", {}, {"browDownLeft": 1.0}),
    ("eyeBlinkLeft 1", {}, {"eyeBlinkLeft": 1.0}),
    ("eyeWideLeft 1", {}, {"eyeWideLeft": 1.0}),
    ("cheekSquintLeft 1", {}, {"cheekSquintLeft": 1.0}),
    ("noseSneerLeft 1", {}, {"noseSneerLeft": 1.0}),
    ("mouthSmileLeft 1", {}, {"mouthSmileLeft": 1.0}),
    ("edits + expressions", {"crown.translate_y": 25.0, "cranium.scale_x": 1.05, "nose_root_a.translate_z": 6.0,
                             "brow_center.translate_z": 5.0, "left_ear_position.translate_x": 5.0,
                             "skull_root.rotate_y": 10.0},
     {"browInnerUp": 0.8, "eyeBlinkLeft": 1.0, "jawOpen": 0.6, "noseSneerRight": 0.7}),
)
"""Joint edits at their limits, single expressions at 1 and one mix: ``(name, joints, expressions)``."""
CONTACT_MM = 5.0
"""Accessory vertices this close to the skin in the bind pose count as resting on it (attachment figure)."""


def follow_figures(vertices: np.ndarray, faces: np.ndarray, skinning: AccessorySkinning,
                   cases: tuple = FOLLOW_CASES, *, random_edits: int = 0, seed: int = 0, spread: float = 0.5,
                   asset=None) -> list[dict]:
    """How an accessory follows the template head under joint edits and expressions.

    The head is the rig with the template's weights and jnr's expressions (``jawOpen`` as an arc); the
    accessory is posed by :func:`rig.accessory.pose_accessory` (its ``skinning`` should come from the
    template's weights). Per case:

    * ``penetration_mm``: the deepest accessory vertex inside the head's outer skin (0 if none;
      :func:`rig.accessory.signed_distance` against the posed head);
    * ``attachment_mm``: the largest change of the distance from a vertex resting on the skin (within
      :data:`CONTACT_MM` in the bind pose) to its anchor (the same surface point on the posed head);
    * ``tear_mm``: the largest RMS residual, over the vertices, of the best affine map from a vertex's bind
      1-ring (itself and its mesh neighbours) to its posed 1-ring: 0 wherever the accessory moves, turns,
      scales or shears smoothly, large where neighbouring vertices are pulled apart or kinked.

    Args:
        vertices, faces: the accessory on the bind pose, mm. cases: ``(name, joints, expressions)`` (names and
            values as in parameter files). random_edits: that many random joint settings
            (:func:`rig.parameters.random_theta` with ``seed`` and ``spread``) added as cases.

    Returns:
        One dict per case: ``case``, ``penetration_mm``, ``attachment_mm``, ``tear_mm``.
    """
    import torch

    from rig.accessory import surface_values
    from rig.asset import load_asset
    from rig.expressions import ExpressionModel, coefficients_from_dict
    from rig.model import JointRig
    from rig.parameters import params_to_theta, random_theta

    asset = asset or load_asset()
    rig = JointRig(asset, dtype=torch.float64)
    names = [c[0] for c in cases]
    thetas = [params_to_theta(j, dtype=torch.float64) for _, j, _ in cases]
    coefs = [coefficients_from_dict(e, dtype=torch.float64) for _, _, e in cases]
    if random_edits:
        generator = torch.Generator().manual_seed(seed)
        for i, theta in enumerate(random_theta(generator, random_edits, spread=spread, dtype=torch.float64)):
            names.append(f"random joints {i} (spread {spread:g})")
            thetas.append(theta)
            coefs.append(torch.zeros_like(coefs[0]) if coefs else torch.zeros(52, dtype=torch.float64))
    theta, c = torch.stack(thetas), torch.stack(coefs)
    with torch.no_grad():
        out = rig(theta, vertices=ExpressionModel(asset, dtype=torch.float64).vertices(c))
        posed = pose_accessory(vertices, skinning, out.skinning, c if skinning.morph_targets.shape[0] else None).numpy()
    heads = out.vertices.numpy()
    skin = outer_skin_faces(asset)
    rings = _one_rings(faces, len(vertices))
    contact = skinning.distance <= CONTACT_MM
    rows = []
    for i, name in enumerate(names):
        sd = signed_distance(posed[i], heads[i], skin)
        anchor = surface_values(heads[i], skin, skinning.anchors)
        moved = np.abs(np.linalg.norm(posed[i] - anchor, axis=1) - skinning.distance)
        rows.append({"case": name, "penetration_mm": float(max(0.0, -sd.min())),
                     "attachment_mm": float(moved[contact].max()) if contact.any() else 0.0,
                     "tear_mm": float(_nonaffine(np.asarray(vertices), posed[i], rings).max())})
    return rows


def _one_rings(faces: np.ndarray, n: int) -> np.ndarray:
    """``(n, m)`` each vertex and its mesh neighbours, padded by repeating the vertex itself."""
    from rig.geometry import mesh_edges

    e = mesh_edges(faces)
    pairs = np.concatenate([e, e[:, ::-1]])
    pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
    counts = np.bincount(pairs[:, 0], minlength=n)
    rings = np.repeat(np.arange(n)[:, None], counts.max() + 1, axis=1)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(pairs)) - np.repeat(starts, counts)
    rings[pairs[:, 0], 1 + slot] = pairs[:, 1]
    return rings


def _nonaffine(rest: np.ndarray, posed: np.ndarray, rings: np.ndarray) -> np.ndarray:
    """``(n,)`` RMS residual (mm) of the best affine map from each bind 1-ring to its posed 1-ring."""
    x = np.concatenate([rest[rings], np.ones(rings.shape + (1,))], axis=2)  # (n, m, 4)
    y = posed[rings]  # (n, m, 3)
    fitted = x @ (np.linalg.pinv(x) @ y)
    return np.sqrt(((y - fitted) ** 2).sum(2).mean(1))


def follow_summary(name: str, *, smoothing: tuple = (0.0, 5.0, 10.0, 20.0, float("inf")),
                   falloff_mm: float = DEFAULT_FALLOFF_MM, random_edits: int = 4) -> list[dict]:
    """The figures of docs/accessories.md for a shipped example: per smoothing width and for the rigid
    attachment to ``skull_root``, the worst case of :func:`follow_figures` for each figure."""
    from rig.accessory import rigid_attachment
    from rig.asset import load_asset
    from rig.expressions import morph_targets

    asset = load_asset()
    item = read_accessory(name, asset)
    skin = outer_skin_faces(asset)
    variants = [(f"transfer, smoothing {s:g} mm", transfer_skinning(
        asset.vertices, skin, asset.weights, morph_targets(asset), item.vertices, falloff_mm=falloff_mm,
        smoothing_mm=s, joint_distance=joint_distance(asset))) for s in smoothing]
    variants.append(("rigid to skull_root", rigid_attachment(variants[0][1], asset.joint_names.index("skull_root"))))
    out = []
    for label, skinning in variants:
        rows = follow_figures(item.vertices, item.faces, skinning, random_edits=random_edits, asset=asset)
        summary = {"accessory": name, "variant": label}
        for key in ("penetration_mm", "attachment_mm", "tear_mm"):
            worst = max(rows, key=lambda r: r[key])
            summary[key] = worst[key]
            summary[key.replace("_mm", "_case")] = worst["case"]
        summary["cases"] = rows
        out.append(summary)
    return out


FIGURE_POSES = {
    "glasses": ({"nose_root_a.translate_z": 10.0, "nose_bridge.translate_y": 6.0, "cranium.scale_x": 1.1,
                 "left_ear_position.translate_x": 8.0, "right_ear_position.translate_x": -8.0}, {"eyeBlinkLeft": 1.0}),
    "cap": ({"crown.translate_y": 30.0, "cranium.scale_x": 1.1}, {"browInnerUp": 1.0}),
}
"""The edit and expression each example is shown with in docs/accessories.png."""


def follow_figure(spp: int = 16) -> np.ndarray:
    """docs/accessories.png: per example, the template with it, an edited and expressive head with it
    (transferred skinning), and the same head with it glued to ``skull_root`` (the naive alternative)."""
    import torch

    from render.preview import render_preview
    from rig.accessory import rigid_attachment
    from rig.asset import load_asset
    from rig.expressions import ExpressionModel, coefficients_from_dict, morph_targets
    from rig.model import JointRig
    from rig.parameters import params_to_theta

    asset = load_asset()
    rig = JointRig(asset, dtype=torch.float64)
    skin = outer_skin_faces(asset)
    rows = []
    for name in EXAMPLE_NAMES:
        item = read_accessory(name, asset)
        transfer = transfer_skinning(asset.vertices, skin, asset.weights, morph_targets(asset), item.vertices,
                                     joint_distance=joint_distance(asset))
        rigid = rigid_attachment(transfer, asset.joint_names.index("skull_root"))
        joints, expressions = FIGURE_POSES[name]
        theta = torch.stack([torch.zeros(rig.num_parameters, dtype=torch.float64),
                             params_to_theta(joints, dtype=torch.float64)])
        c = torch.stack([torch.zeros(52, dtype=torch.float64), coefficients_from_dict(expressions, dtype=torch.float64)])
        with torch.no_grad():
            out = rig(theta, vertices=ExpressionModel(asset, dtype=torch.float64).vertices(c))
            moved = pose_accessory(item.vertices, transfer, out.skinning, c).numpy()
            glued = pose_accessory(item.vertices, rigid, out.skinning, c).numpy()
        heads = out.vertices.numpy()
        color = EXAMPLE_COLORS[name]
        tiles = []
        for head, acc in ((heads[0], item.vertices), (heads[1], moved[1]), (heads[1], glued[1])):
            vertices = np.concatenate([head, acc])
            faces = np.concatenate([asset.faces, item.faces + len(head)])
            colors = np.concatenate([np.full((len(head), 3), 0.55), np.tile(color, (len(acc), 1))])
            tiles.append(render_preview(vertices, faces, colors=colors, view="three_quarter", size=(300, 330), spp=spp,
                                        distance=700.0, target=(0.0, 10.0 if name == "cap" else -5.0, 20.0)))
        rows.append(np.concatenate(tiles, 1))
    return np.concatenate(rows, 0)


def main(argv: list[str] | None = None) -> None:
    """``python -m pipeline.accessory [--json FILE] [--figure PNG]``: the follow figures of the shipped examples (a
    markdown table; ``--json``: every case), or the picture of docs/accessories.png."""
    import argparse

    parser = argparse.ArgumentParser(description="How jnr's example accessories follow joint edits and expressions.")
    parser.add_argument("--json", help="also write every case's figures to this JSON file")
    parser.add_argument("--figure", help="write docs/accessories.png's picture to this PNG instead of the table")
    args = parser.parse_args(argv)
    if args.figure:
        from render.preview import save_png

        save_png(follow_figure(), args.figure)
        return
    summaries = [row for name in EXAMPLE_NAMES for row in follow_summary(name)]
    print("| accessory | skinning | max penetration (mm) | worst case | max attachment change (mm) | worst case "
          "| max tear (mm) | worst case |")
    print("|---|---|---|---|---|---|---|---|")
    for r in summaries:
        print(f"| {r['accessory']} | {r['variant']} | {r['penetration_mm']:.2f} | {r['penetration_case']} | "
              f"{r['attachment_mm']:.2f} | {r['attachment_case']} | {r['tear_mm']:.2f} | {r['tear_case']} |")
    if args.json:
        Path(args.json).write_text(json.dumps(summaries, indent=1) + "\n")


__all__ = ["ACCESSORY_DIR", "EXAMPLE_NAMES", "OUTPUT_FILES", "Accessory", "AccessoryInputError", "AccessoryOnFit",
           "FitHead", "accessory_on_fit", "accessory_path", "preview_image", "read_accessory", "read_fit_head",
           "run_accessory", "write_accessory_outputs", "FOLLOW_CASES", "follow_figure", "follow_figures", "follow_summary",
           "joint_distance"]


if __name__ == "__main__":
    main()
