"""Regenerate the pictures in docs/ (template views, region map, joints).

.venv/bin/python docs/figures/make_figures.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from render.preview import render_preview, save_png
from rig.asset import load_asset

DOCS = Path(__file__).resolve().parents[1]  # the pictures stay in docs/, beside the pages that show them
REGION_COLORS = {
    "scalp": (0.32, 0.22, 0.15),
    "forehead": (0.85, 0.70, 0.58),
    "brows": (0.45, 0.30, 0.18),
    "eyelids": (0.90, 0.50, 0.50),
    "nose": (0.92, 0.76, 0.30),
    "cheeks": (0.80, 0.58, 0.47),
    "lips": (0.80, 0.18, 0.22),
    "chin": (0.55, 0.72, 0.92),
    "jaw": (0.45, 0.78, 0.45),
    "ears": (0.68, 0.40, 0.80),
    "neck": (0.60, 0.60, 0.60),
    "eyeballs": (0.95, 0.95, 0.95),
    "mouth_interior": (0.40, 0.05, 0.05),
    "teeth": (0.95, 0.93, 0.85),
    "tongue": (0.75, 0.30, 0.32),
    "eye_pockets": (0.30, 0.10, 0.10),
}
VIEWS = ("front", "three_quarter", "side")


def main() -> None:
    asset = load_asset()
    v = asset.vertices
    f = asset.faces[~asset.region_mask("mouth_interior", "eye_pockets", "teeth", "tongue")[asset.faces].all(1)]
    kw = dict(size=(420, 520), spp=64, distance=620.0, target=(0.0, -25.0, 15.0))
    tiles = [render_preview(v, f, view=view, **kw) for view in VIEWS]
    save_png(np.concatenate(tiles, 1), DOCS / "template_views.png")
    colors = np.array([REGION_COLORS[n] for n in asset.region_names])[asset.regions]
    tiles = [render_preview(v, f, colors=colors, view=view, **kw) for view in VIEWS]
    save_png(np.concatenate(tiles, 1), DOCS / "template_regions.png")
    tiles = [render_preview(v, f, view=view, markers=asset.joint_positions, **kw) for view in ("front", "side")]
    save_png(np.concatenate(tiles, 1), DOCS / "template_joints.png")
    # Initial skinning weights of a few joints (red = 1), as JNR's Fig. 1.
    w = asset.weights
    tiles = []
    for joints in (
        ("nose_tip", "nose_ridge_a", "left_cheek", "right_cheek"),
        ("left_upper_eyelid", "right_lower_eyelid", "chin", "top_lip", "bottom_lip"),
        ("left_ear_rotate_scale", "crown", "left_jaw_root", "left_brow_outer"),
    ):
        heat = np.clip(sum(w[:, asset.joint_names.index(j)] for j in joints), 0.0, 1.0)[:, None]
        colors = (1 - heat) * np.array([0.75, 0.75, 0.78]) + heat * np.array([0.85, 0.08, 0.06])
        tiles.append(render_preview(v, f, colors=colors, view="three_quarter", **kw))
    save_png(np.concatenate(tiles, 1), DOCS / "template_weights.png")


if __name__ == "__main__":
    main()
