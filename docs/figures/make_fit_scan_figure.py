"""Render a simulated scan's ground truth, the jnr fit and the nricp_amberg baseline into ``docs/fit_scan.png``.

One held-out expressive head (``expressive_split("heldout", n=2)``, head 1) is scanned by
:func:`pipeline.synthetic.scans.simulate_scan` (seed ``scan_seed(0, "expressive", 1)``), fitted with
:func:`pipeline.scan.fit.fit_scan` and with :func:`pipeline.scan.baseline.nricp_baseline` (started from the
same rigid pre-alignment). Every mesh is taken back to rig space with the scan's *true* pose, so a pose
error shows up as error too. Three panels (front and three-quarter view each): the ground truth in skin
tone, then each fit coloured by its per-vertex distance to the truth on one 0-5 mm scale; the labels
give the mean distance over the face regions (:data:`pipeline.scan.fit.FACE_REGIONS`). Each rendered
tile gets a 3 x 3 median filter (less sampling grain, and a PNG under 300 KB). Takes about a minute.
Run from the repository root::

    python docs/figures/make_fit_scan_figure.py [--out docs/fit_scan.png] [--spp 16]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.evaluation.scans import scan_seed
from pipeline.scan.baseline import nricp_baseline
from pipeline.scan.fit import fit_scan
from pipeline.scan.pointcloud.error_colors import error_colors
from pipeline.scan.pointcloud.validate import validate_points
from pipeline.synthetic.expressive import expressive_split
from pipeline.synthetic.scans import simulate_scan
from rig.asset import load_asset
from rig.geometry import Similarity
from rig.template import FACE_REGIONS

VMAX_MM = 5.0
TILE = (160, 280)  # width, height of one view in pixels
HEADER, FOOTER = 28, 34  # label strip above, colour bar below
VIEWS = ("front", "three_quarter")
CAMERA = dict(distance=700.0, fov=15.3, target=(0.0, -35.0, 0.0))  # about 188 x 330 mm in view


def fit_meshes() -> tuple[np.ndarray, list[tuple[str, np.ndarray, np.ndarray | None]]]:
    """Faces and ``[(label, rig-space vertices, per-vertex error mm or None), ...]`` for the three panels."""
    asset = load_asset()
    head = expressive_split("heldout", n=2).vertices[1]
    scan = simulate_scan(head, asset.faces, rng=scan_seed(0, "expressive", 1))
    fit = fit_scan(validate_points(scan.points, scan.normals))
    base = nricp_baseline(
        asset.vertices,
        asset.faces,
        scan.points,
        rotation=fit.prealign.rotation,
        translation=fit.prealign.translation,
        scale=fit.prealign.scale,
    )
    face = asset.region_mask(*FACE_REGIONS)

    def to_rig(world: np.ndarray) -> np.ndarray:  # the true pose, scale 1, for every mesh
        return Similarity(scan.rotation, scan.translation).apply_inverse(world)

    truth = to_rig(scan.gt_vertices)  # == head
    panels: list[tuple[str, np.ndarray, np.ndarray | None]] = [("ground truth", truth, None)]
    for name, world in (("jnr fit-scan", fit.vertices), ("nricp_amberg", base.vertices)):
        rig = to_rig(world)
        err = np.linalg.norm(rig - truth, axis=1)
        print(
            f"{name}: face-region mean {err[face].mean():.2f} mm, all vertices {err.mean():.2f} mm, "
            f"face max {err[face].max():.2f} mm"
        )
        panels.append((f"{name}: {err[face].mean():.1f} mm", rig, err))
    return asset.faces, panels


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: fixed-size bitmap font
        return ImageFont.load_default()


def render_figure(spp: int = 16) -> np.ndarray:
    """``(HEADER + 280 + FOOTER, 6 * 160, 3)`` uint8 picture: truth, jnr fit, baseline; two views each."""
    from PIL import Image, ImageDraw, ImageFilter

    from render.preview import render_preview

    faces, panels = fit_meshes()
    width = len(panels) * len(VIEWS) * TILE[0]
    fig = Image.new("RGB", (width, HEADER + TILE[1] + FOOTER), (255, 255, 255))
    draw = ImageDraw.Draw(fig)
    font, small = _font(15), _font(12)
    panel_w = len(VIEWS) * TILE[0]
    for p, (label, verts, err) in enumerate(panels):
        colors = None if err is None else (error_colors(err, vmax_mm=VMAX_MM) / 255.0) ** 2.2
        for v, view in enumerate(VIEWS):
            tile = render_preview(verts, faces, colors=colors, view=view, size=TILE, spp=spp, **CAMERA)
            tile = Image.fromarray(tile).filter(ImageFilter.MedianFilter(3))
            fig.paste(tile, (p * panel_w + v * TILE[0], HEADER))
        draw.text((p * panel_w + panel_w / 2, HEADER / 2), label, fill=(0, 0, 0), font=font, anchor="mm")
        if p:
            draw.line([(p * panel_w, 4), (p * panel_w, HEADER + TILE[1])], fill=(200, 200, 200))

    # colour bar under the two fitted panels
    bar_x0, bar_x1 = panel_w + 60, width - 60
    bar_y0, bar_y1 = HEADER + TILE[1] + 6, HEADER + TILE[1] + 16
    ramp = error_colors(np.linspace(0.0, VMAX_MM, bar_x1 - bar_x0), vmax_mm=VMAX_MM)
    fig.paste(Image.fromarray(np.repeat(ramp[None], bar_y1 - bar_y0, axis=0)), (bar_x0, bar_y0))
    draw.rectangle([bar_x0 - 1, bar_y0 - 1, bar_x1, bar_y1], outline=(90, 90, 90))
    for mm in range(int(VMAX_MM) + 1):
        x = bar_x0 + (bar_x1 - bar_x0 - 1) * mm / VMAX_MM
        draw.line([(x, bar_y1), (x, bar_y1 + 3)], fill=(90, 90, 90))
        draw.text((x, bar_y1 + 4), f"{mm} mm" if mm == VMAX_MM else f"{mm}", fill=(0, 0, 0), font=small, anchor="ma")
    draw.text((8, bar_y0 - 2), "distance to the truth, true pose;", fill=(60, 60, 60), font=small)
    draw.text((8, bar_y0 + 12), "labels: mean over the face", fill=(60, 60, 60), font=small)
    return np.asarray(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "fit_scan.png"))
    parser.add_argument("--spp", type=int, default=16)
    args = parser.parse_args(argv)
    from PIL import Image

    Image.fromarray(render_figure(args.spp)).save(args.out, optimize=True)
    print(f"wrote {args.out} ({Path(args.out).stat().st_size / 1024:.0f} KB)")


if __name__ == "__main__":
    main()
