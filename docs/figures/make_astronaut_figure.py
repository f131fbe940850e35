"""Render the demo's fitted astronaut grey-shaded from the front and the side into ``docs/astronaut_grey.png``.

The head ``jnr demo`` fits to scikit-image's astronaut portrait (``OUT/astronaut/params.json``), rebuilt in
rig space from its joints, latent Z and expressions, drawn without albedo beside the unfitted template, so
that the shape alone can be judged. Run from the repository root after ``jnr demo --out out/demo``::

    python docs/figures/make_astronaut_figure.py [--demo out/demo] [--out docs/astronaut_grey.png] [--spp 32]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.head.fitted import fitted_head
from render.preview import render_preview, save_png
from rig.asset import load_asset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo", type=Path, default=ROOT / "out" / "demo")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "astronaut_grey.png")
    parser.add_argument("--spp", type=int, default=32)
    args = parser.parse_args()
    asset = load_asset()
    params = json.loads((args.demo / "astronaut" / "params.json").read_text())
    fitted = fitted_head(params).vertices
    faces = asset.faces[~asset.region_mask("mouth_interior", "eye_pockets", "teeth", "tongue")[asset.faces].all(1)]
    grey = np.full((len(asset.vertices), 3), 0.6)
    kw = {"colors": grey, "size": (360, 440), "spp": args.spp, "distance": 620.0, "target": (0.0, -25.0, 15.0)}
    tiles = [render_preview(v, faces, view=view, **kw) for v in (asset.vertices, fitted) for view in ("front", "side")]
    save_png(np.concatenate(tiles, 1), args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
