"""ASM's initial GMM skinning weights next to the painted weights they were fitted to (docs/asm_weights.png).

    .venv/bin/python docs/figures/make_asm_figure.py

Rows: the painted initial weights, the GMM fit with K = 2, with K = 5 (rig/assets/jnr_asm_init_v3.npz);
columns: three groups of joints (red = weight 1), seen three-quarter. Vertices off the skin UV island keep
the painted weights in every row.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from render.preview import render_preview, save_png
from rig.asset import load_asset
from rig.model import JointRig
from rig.skinning.asm import AdaptiveSkinning

DOCS = Path(__file__).resolve().parents[1]  # the pictures stay in docs/, beside the pages that show them
GROUPS = (
    ("nose_tip", "nose_ridge_a", "left_cheek", "right_cheek"),
    ("left_upper_eyelid", "right_lower_eyelid", "chin", "top_lip", "bottom_lip"),
    ("left_ear_rotate_scale", "crown", "left_jaw_root", "left_brow_outer"),
)


def main() -> None:
    asset = load_asset()
    rig = JointRig(asset, dtype=torch.float64)
    v = asset.vertices
    f = asset.faces[~asset.region_mask("mouth_interior", "eye_pockets", "teeth", "tongue")[asset.faces].all(1)]
    kw = dict(size=(300, 370), spp=32, distance=620.0, target=(0.0, -25.0, 15.0))
    rows = [asset.weights]
    for k in (2, 5):
        model = AdaptiveSkinning(rig, components=k)
        with torch.no_grad():
            rows.append(model.weights(model.initial(1))[0].numpy())
    image = []
    for w in rows:
        tiles = []
        for joints in GROUPS:
            heat = np.clip(sum(w[:, asset.joint_names.index(j)] for j in joints), 0.0, 1.0)[:, None]
            colors = (1 - heat) * np.array([0.75, 0.75, 0.78]) + heat * np.array([0.85, 0.08, 0.06])
            tiles.append(render_preview(v, f, colors=colors, view="three_quarter", **kw))
        image.append(np.concatenate(tiles, 1))
    save_png(np.concatenate(image, 0), DOCS / "asm_weights.png")


if __name__ == "__main__":
    main()
