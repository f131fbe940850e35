"""One simulated depth scan of a held-out head fitted with JNR's rig and with ASM (docs/asm_scan.png).

    .venv/bin/python docs/figures/make_asm_scan_figure.py

Columns: the true head, the JNR fit (52 joints + neural skinning), the ASM fit (K = 2), each in rig space
(before the fitted pose and scale), grey from the front and the side (rows); the face-region vertex
error of each fit (in the scan's frame) is printed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.scan.fit import fit_scan
from pipeline.scan.fit_config import FitScanConfig
from pipeline.scan.pointcloud.validate import validate_points
from pipeline.synthetic.expressive import expressive_split
from pipeline.synthetic.scans import simulate_scan
from render.preview import render_preview, save_png
from rig.asset import load_asset
from rig.template import FACE_REGIONS

DOCS = Path(__file__).resolve().parents[1]  # the pictures stay in docs/, beside the pages that show them


def main() -> None:
    asset = load_asset()
    heads = expressive_split("heldout", 0, n=2, asset=asset)
    truth = heads.vertices[1]
    scan = simulate_scan(truth, asset.faces, rng=7)
    cloud = validate_points(scan.points, scan.normals, units="mm", frame="y-up")
    face = asset.region_mask(*FACE_REGIONS)
    meshes = [truth]  # rig space, unposed
    for skinning in ("jnr", "asm"):
        fit = fit_scan(cloud, FitScanConfig(skinning=skinning))
        err = np.linalg.norm(fit.vertices - scan.gt_vertices, axis=1)[face].mean()
        print(f"{skinning}: face vertex error {err:.2f} mm, {fit.timings['total']:.0f} s")
        meshes.append(fit.rig_vertices)
    f = asset.faces[~asset.region_mask("mouth_interior", "eye_pockets", "teeth", "tongue")[asset.faces].all(1)]
    rows = []
    for view in ("front", "side"):
        tiles = []
        for v in meshes:
            tiles.append(
                render_preview(v, f, view=view, size=(320, 380), spp=32, distance=620.0, target=(0.0, -25.0, 15.0))
            )
        rows.append(np.concatenate(tiles, 1))
    save_png(np.concatenate(rows, 0), DOCS / "asm_scan.png")


if __name__ == "__main__":
    main()
