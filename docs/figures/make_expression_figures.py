"""Render the 52 ARKit expression shapes at coefficient 1 into ``docs/expressions.png``.

A 13 x 4 grid of small front views (template + the shape's offsets at 1), each tile labelled with the
shape's ARKit name, in ARKit's order. Run from the repository root::

    python docs/figures/make_expression_figures.py [--out docs/expressions.png] [--spp 16]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from rig.asset import load_asset
from rig.expressions import EXPRESSIONS, ExpressionModel

COLUMNS, ROWS = 13, 4
TILE = (160, 192)  # width, height in pixels


def render_grid(spp: int = 16, view: str = "front") -> np.ndarray:
    """``(ROWS * 192, COLUMNS * 160, 3)`` uint8 picture of every shape at coefficient ``high``."""
    from PIL import Image, ImageDraw

    from render.preview import render_preview

    asset = load_asset()
    model = ExpressionModel(asset, dtype=torch.float64)
    faces = asset.faces[~asset.region_mask("mouth_interior", "eye_pockets")[asset.faces].all(1)]
    grid = Image.new("RGB", (COLUMNS * TILE[0], ROWS * TILE[1]), (255, 255, 255))
    for i, spec in enumerate(EXPRESSIONS):
        c = torch.zeros(1, len(EXPRESSIONS), dtype=torch.float64)
        c[0, i] = spec.high
        with torch.no_grad():
            verts = model.vertices(c)[0].numpy()
        tile = Image.fromarray(
            render_preview(verts, faces, view=view, size=TILE, spp=spp, distance=520.0, target=(0.0, -25.0, 40.0))
        )
        draw = ImageDraw.Draw(tile)
        label = spec.name if spec.high == 1.0 else f"{spec.name} = {spec.high:g}"
        draw.text((6, 6), label, fill=(0, 0, 0))
        grid.paste(tile, ((i % COLUMNS) * TILE[0], (i // COLUMNS) * TILE[1]))
    return np.asarray(grid)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "expressions.png"))
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--view", default="front")
    args = parser.parse_args(argv)
    from render.preview import save_png

    save_png(render_grid(args.spp, args.view), args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
