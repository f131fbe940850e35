"""Compose ``docs/fit_photo.png`` from the photo fits that ``jnr demo`` writes.

Two rows: the astronaut portrait (landmarks detected by dlib) and the synthetic photo of held-out head
21 with known truth. Columns: the photo's face crop, the overlay (render blended over the photo, input
landmarks green, fitted red) and the fitted head rendered alone with its albedo and light. Run from the
repository root after ``jnr demo --out out/demo``::

    python docs/figures/make_fit_photo_figure.py [--demo out/demo] [--out docs/fit_photo.png]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

TILE = 300


def _crop_box(report: dict, size: tuple[int, int], folder: Path) -> tuple[int, int, int, int]:
    """The photometric crop of a fit (its report), or without photometric stages (jnr fit's default) a square
    around its input landmarks with the same margins (:func:`pipeline.photo.fit.face_crop`), clipped to
    the photo."""
    crop = report.get("crop")
    if crop is None:
        from landmarks.formats import read_landmarks
        from pipeline.photo.crop import face_crop
        from pipeline.photo.fit_config import PhotometricConfig

        settings = PhotometricConfig()
        box = face_crop(read_landmarks(folder / "landmarks.pts"), settings.render_size, settings.crop_margin)
        crop = {"x0": box.x0, "y0": box.y0, "side": box.side}
    w, h = size
    x0, y0, side = int(round(crop["x0"])), int(round(crop["y0"])), int(round(crop["side"]))
    return max(x0, 0), max(y0, 0), min(x0 + side, w), min(y0 + side, h)


def _row(folder: Path, photo: Path, label: str) -> Image.Image:
    report = json.loads((folder / "report.json").read_text())
    images = [Image.open(photo).convert("RGB"), Image.open(folder / "overlay.png"), Image.open(folder / "render.png")]
    box = _crop_box(report, images[0].size, folder)
    tiles = [im.crop(box).resize((TILE, TILE), Image.LANCZOS) for im in images]
    row = Image.new("RGB", (3 * TILE, TILE + 22), "white")
    for i, tile in enumerate(tiles):
        row.paste(tile, (i * TILE, 22))
    lm = report["landmarks"]
    ImageDraw.Draw(row).text(
        (4, 5),
        f"{label}: landmark error {lm['mean_error_px']:.2f} px (NME "
        f"{lm['nme_inter_ocular']:.3f}); photo / overlay / fitted head",
        fill="black",
    )
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demo", type=Path, default=Path("out/demo"), help="jnr demo's output folder")
    parser.add_argument("--out", type=Path, default=Path("docs/fit_photo.png"))
    args = parser.parse_args()
    rows = [
        _row(args.demo / "astronaut", args.demo / "inputs" / "astronaut.png", "astronaut (scikit-image)"),
        _row(
            args.demo / "synthetic",
            args.demo / "inputs" / "synthetic" / "photo.png",
            "synthetic photo, held-out head 21 (known truth)",
        ),
    ]
    figure = Image.fromarray(np.concatenate([np.asarray(r) for r in rows], 0))
    figure.quantize(256, dither=Image.Dither.FLOYDSTEINBERG).save(args.out, optimize=True)  # a smaller PNG
    print(f"wrote {args.out} ({figure.size[0]}x{figure.size[1]})")


if __name__ == "__main__":
    main()
