"""What a saved notebook keeps of its pictures and of the 3D view: one encoded picture per image
(:func:`picture`), and the fit's ``viewer.html`` by reference (:func:`viewer_frame`).

Displaying a PIL image directly stores it twice in the notebook (Pillow offers both ``_repr_png_`` and
``_repr_jpeg_``, and Jupyter keeps every representation); :func:`picture` encodes it once, in one format.
The 3D view is the fit's own ``viewer.html`` (:mod:`pipeline.viewer`: three.js and the head in one file,
no network) in an ``<iframe>`` whose ``src`` is relative to the notebook's folder, which Jupyter serves: the
saved output is one line of HTML that points at the file instead of a copy of the page or of widget state,
and it shows offline as long as the output folder stays beside the notebook.
"""

from __future__ import annotations

import io
import urllib.parse
from pathlib import Path

import numpy as np

from pipeline.notebook.extra import require
from rig.errors import InputError

PICTURE_FORMATS = ("jpeg", "png")
JPEG_QUALITY = 85
"""The JPEG quality of :func:`picture` (photos, renders and colour maps; PNG is for line art)."""


def picture(image, *, format: str = "jpeg", quality: int = JPEG_QUALITY):
    """An image as an ``IPython.display.Image`` with one representation (``image/jpeg`` or ``image/png``).

    Args:
        image: a PIL image or an ``(H, W, 3)`` / ``(H, W)`` uint8 array (sRGB).
        format: ``jpeg`` (photo-like pictures) or ``png`` (line art, exact pixels).
        quality: the JPEG quality (1-95).

    Raises:
        InputError: an unknown format.
    """
    if format not in PICTURE_FORMATS:
        raise InputError(f"picture: format must be one of {PICTURE_FORMATS}, got {format!r}")
    pil = require("PIL.Image")
    display = require("IPython.display")
    if not isinstance(image, pil.Image):
        image = pil.fromarray(np.ascontiguousarray(image))
    if format == "jpeg" and image.mode not in ("RGB", "L"):
        image = image.convert("RGB")
    buffer = io.BytesIO()
    if format == "jpeg":
        image.save(buffer, "JPEG", quality=int(quality), optimize=True)
    else:
        image.save(buffer, "PNG", optimize=True)
    return display.Image(data=buffer.getvalue(), format=format)


def relative_src(page: str | Path, base: str | Path | None = None) -> str:
    """The address of ``page`` relative to ``base`` (default: the working directory, which is the
    notebook's folder in a Jupyter kernel), with ``/`` separators and URL-quoted.

    Raises:
        InputError: the page does not exist, or it is not inside ``base`` (Jupyter serves only files
            under the folder it was started in; a page beside the notebook or below it is safe).
    """
    page = Path(page)
    if not page.is_file():
        raise InputError(f"viewer_frame: {page} does not exist")
    base = Path.cwd() if base is None else Path(base)
    try:
        rel = page.resolve().relative_to(base.resolve())
    except ValueError:
        raise InputError(
            f"viewer_frame: {page} is not inside {base}; write the output folder beside the notebook "
            f"(Jupyter serves files relative to the notebook, not from elsewhere)"
        ) from None
    return "/".join(urllib.parse.quote(part) for part in rel.parts)


def viewer_frame(page: str | Path, *, base: str | Path | None = None, width: str | int = "100%", height: int = 640):
    """The fit's ``viewer.html`` in an ``IPython.display.IFrame`` with a relative ``src``.

    Args:
        page: the page (e.g. ``out_dir / "viewer.html"``, :data:`pipeline.viewer.VIEWER_FILE`).
        base: the notebook's folder (default: the working directory, which Jupyter sets to it).
        width, height: of the frame (pixels, or a CSS length such as ``"100%"``).

    The saved output is ``<iframe src="out/.../viewer.html" ...>``: Jupyter resolves the relative address
    against the notebook's folder, so the view shows, offline, while the page stays there.

    Raises:
        InputError: as :func:`relative_src`.
    """
    display = require("IPython.display")
    return display.IFrame(relative_src(page, base), width=width, height=height)


__all__ = ["JPEG_QUALITY", "PICTURE_FORMATS", "picture", "relative_src", "viewer_frame"]
