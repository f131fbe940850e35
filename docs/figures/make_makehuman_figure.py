"""Render MakeHuman's head as issue 13's template will start from it into ``docs/makehuman_head.png``.

The head cut of :func:`rig.makehuman.head_mesh` at the adult-average phenotype
(:class:`rig.makehuman.Phenotype`: gender 0.5, 40 years, average build and height, equal race
weights), grey-shaded from the front and the side, and once more with two of the 52 ARKit face units
applied (``jawOpen`` 1, ``mouthSmileLeft`` 0.8), as a look at the data before it is rigged. Run from the
repository root::

    python docs/figures/make_makehuman_figure.py [--out docs/makehuman_head.png] [--spp 32]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from render.preview import render_preview
from rig.makehuman.face_units import ARKIT_NAMES, arkit_offsets
from rig.makehuman.head import PIECES, head_mesh
from rig.makehuman.phenotype import phenotype_offsets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "makehuman_head.png")
    parser.add_argument("--spp", type=int, default=32)
    args = parser.parse_args()
    from PIL import Image
    from scipy.ndimage import median_filter

    head = head_mesh()
    shown = np.isin(head.face_piece, [PIECES.index(p) for p in ("skin", "neck", "eyeballs")])
    faces = head.faces[shown]
    used = np.unique(faces)
    # only the drawn vertices: the renderer computes normals for every vertex it is given
    remap = np.full(len(head.vertices), -1)
    remap[used] = np.arange(len(used))
    average = head.vertices + phenotype_offsets()
    expression = (
        average
        + arkit_offsets()[ARKIT_NAMES.index("jawOpen")]
        + 0.8 * arkit_offsets()[ARKIT_NAMES.index("mouthSmileLeft")]
    )
    centre = average[used].mean(0)
    grey = np.full((len(used), 3), 0.6)
    tiles = [
        render_preview(
            v[used] - centre,
            remap[faces],
            colors=grey,
            view=view,
            size=(320, 400),
            spp=args.spp,
            distance=800.0,
            target=(0.0, -10.0, 0.0),
        )
        for v, view in ((average, "front"), (average, "side"), (expression, "front"))
    ]
    tiles = [median_filter(t, size=(3, 3, 1)) for t in tiles]
    Image.fromarray(np.concatenate(tiles, 1)).save(args.out, optimize=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
