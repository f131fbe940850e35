"""How well an accessory follows the head under joint edits and expressions (tests and
docs/accessories.md): ``python -m pipeline.accessory [--json FILE] [--figure PNG]``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.accessory.inputs import EXAMPLE_COLORS, EXAMPLE_NAMES, read_accessory
from pipeline.accessory.transfer import joint_distance
from render.preview import render_preview, save_png
from rig.accessory import (
    DEFAULT_FALLOFF_MM,
    AccessorySkinning,
    outer_skin_faces,
    pose_accessory,
    rigid_attachment,
    signed_distance,
    transfer_skinning,
)
from rig.asset import load_asset
from rig.expressions import ExpressionModel, coefficients_from_dict, morph_targets
from rig.geometry import mesh_edges, surface_values
from rig.model import JointRig
from rig.parameters import params_to_theta, random_theta

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
    (
        "edits + expressions",
        {
            "crown.translate_y": 25.0,
            "cranium.scale_x": 1.05,
            "nose_root_a.translate_z": 6.0,
            "brow_center.translate_z": 5.0,
            "left_ear_position.translate_x": 5.0,
            "skull_root.rotate_y": 10.0,
        },
        {"browInnerUp": 0.8, "eyeBlinkLeft": 1.0, "jawOpen": 0.6, "noseSneerRight": 0.7},
    ),
)
"""Joint edits at their limits, single expressions at 1 and one mix: ``(name, joints, expressions)``."""
CONTACT_MM = 5.0
"""Accessory vertices this close to the skin in the bind pose count as resting on it (attachment figure)."""


def follow_figures(
    vertices: np.ndarray,
    faces: np.ndarray,
    skinning: AccessorySkinning,
    cases: tuple = FOLLOW_CASES,
    *,
    random_edits: int = 0,
    seed: int = 0,
    spread: float = 0.5,
    asset=None,
) -> list[dict]:
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
        rows.append(
            {
                "case": name,
                "penetration_mm": float(max(0.0, -sd.min())),
                "attachment_mm": float(moved[contact].max()) if contact.any() else 0.0,
                "tear_mm": float(_nonaffine(np.asarray(vertices), posed[i], rings).max()),
            }
        )
    return rows


def _one_rings(faces: np.ndarray, n: int) -> np.ndarray:
    """``(n, m)`` each vertex and its mesh neighbours, padded by repeating the vertex itself."""
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


def follow_summary(
    name: str,
    *,
    smoothing: tuple = (0.0, 5.0, 10.0, 20.0, float("inf")),
    falloff_mm: float = DEFAULT_FALLOFF_MM,
    random_edits: int = 4,
) -> list[dict]:
    """The figures of docs/accessories.md for a shipped example: per smoothing width and for the rigid
    attachment to ``skull_root``, the worst case of :func:`follow_figures` for each figure."""
    asset = load_asset()
    item = read_accessory(name, asset)
    skin = outer_skin_faces(asset)
    variants = [
        (
            f"transfer, smoothing {s:g} mm",
            transfer_skinning(
                asset.vertices,
                skin,
                asset.weights,
                morph_targets(asset),
                item.vertices,
                falloff_mm=falloff_mm,
                smoothing_mm=s,
                joint_distance=joint_distance(asset),
            ),
        )
        for s in smoothing
    ]
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
    "glasses": (
        {
            "nose_root_a.translate_z": 10.0,
            "nose_bridge.translate_y": 6.0,
            "cranium.scale_x": 1.1,
            "left_ear_position.translate_x": 8.0,
            "right_ear_position.translate_x": -8.0,
        },
        {"eyeBlinkLeft": 1.0},
    ),
    "cap": ({"crown.translate_y": 30.0, "cranium.scale_x": 1.1}, {"browInnerUp": 1.0}),
}
"""The edit and expression each example is shown with in docs/accessories.png."""


def follow_figure(spp: int = 16) -> np.ndarray:
    """docs/accessories.png: per example, the template with it, an edited and expressive head with it
    (transferred skinning), and the same head with it glued to ``skull_root`` (the naive alternative)."""
    import torch

    asset = load_asset()
    rig = JointRig(asset, dtype=torch.float64)
    skin = outer_skin_faces(asset)
    rows = []
    for name in EXAMPLE_NAMES:
        item = read_accessory(name, asset)
        transfer = transfer_skinning(
            asset.vertices,
            skin,
            asset.weights,
            morph_targets(asset),
            item.vertices,
            joint_distance=joint_distance(asset),
        )
        rigid = rigid_attachment(transfer, asset.joint_names.index("skull_root"))
        joints, expressions = FIGURE_POSES[name]
        theta = torch.stack(
            [torch.zeros(rig.num_parameters, dtype=torch.float64), params_to_theta(joints, dtype=torch.float64)]
        )
        c = torch.stack(
            [torch.zeros(52, dtype=torch.float64), coefficients_from_dict(expressions, dtype=torch.float64)]
        )
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
            tiles.append(
                render_preview(
                    vertices,
                    faces,
                    colors=colors,
                    view="three_quarter",
                    size=(300, 330),
                    spp=spp,
                    distance=700.0,
                    target=(0.0, 10.0 if name == "cap" else -5.0, 20.0),
                )
            )
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
        save_png(follow_figure(), args.figure)
        return
    summaries = [row for name in EXAMPLE_NAMES for row in follow_summary(name)]
    print(
        "| accessory | skinning | max penetration (mm) | worst case | max attachment change (mm) | worst case "
        "| max tear (mm) | worst case |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in summaries:
        print(
            f"| {r['accessory']} | {r['variant']} | {r['penetration_mm']:.2f} | {r['penetration_case']} | "
            f"{r['attachment_mm']:.2f} | {r['attachment_case']} | {r['tear_mm']:.2f} | {r['tear_case']} |"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(summaries, indent=1) + "\n")
