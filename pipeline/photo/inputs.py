"""Which files ``jnr fit`` reads: the photos named or found in folders, and the landmark files beside them.

Example:
    >>> photos, folders = photo_inputs(["portraits/", "extra.jpg"])  # doctest: +SKIP
    >>> sidecar_landmarks("portraits/face.png")  # doctest: +SKIP
    PosixPath('portraits/face.pts')
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from pathlib import Path

from landmarks.images import MAX_IMAGE_FILE_BYTES
from rig.errors import InputError
from rig.io.inputs import regular_file

_log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".gif", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pnm")
"""What ``jnr fit`` reads as photos, named directly or found in a folder (the same rule for both)."""
LANDMARK_SUFFIXES = (".pts", ".json", ".csv")
"""The landmark files ``landmarks="auto"`` looks for beside a photo, in this order."""


def photo_inputs(items: Iterable[str | Path]) -> tuple[list[Path], list[Path]]:
    """``(photos, folders)``: image files named directly, or found (non-recursively, sorted) in named
    folders; a file is a photo when its suffix is one of :data:`IMAGE_SUFFIXES`.

    Raises:
        InputError: a name that is neither a photo nor a folder, or a folder without photos.
    """
    photos: list[Path] = []
    folders: list[Path] = []
    supported = ", ".join(IMAGE_SUFFIXES)
    for item in items:
        path = Path(item)
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(f"folder {path} holds no images ({supported})")
            photos.extend(found)
            folders.append(path)
        elif path.is_file():
            if path.suffix.lower() not in IMAGE_SUFFIXES:
                raise InputError(f"{path} is not a photo jnr reads (the file name must end in one of {supported})")
            photos.append(path)
        else:  # missing, or a FIFO, a device, a loop of links: say which
            regular_file(path, "image file", MAX_IMAGE_FILE_BYTES)
            raise InputError(f"{path}: cannot read this image file")
    return _unique(photos), folders


def _unique(photos: list[Path]) -> list[Path]:
    """The photos with each file once, by its real path (the same photo named twice, or named and found in a
    named folder, was fitted twice); the first name given is kept, and the repeats are said in one line."""
    seen: set[str] = set()
    kept: list[Path] = []
    repeats = 0
    for photo in photos:
        key = os.path.realpath(photo)
        if key in seen:
            repeats += 1
            continue
        seen.add(key)
        kept.append(photo)
    if repeats:
        _log.warning("%d photo(s) named more than once (or also found in a named folder): each is fitted once", repeats)
    return kept


def sidecar_landmarks(photo: str | Path) -> Path:
    """The landmarks file beside ``photo`` with the same name (``face.png`` -> ``face.pts``, ``.json`` or
    ``.csv``, :data:`LANDMARK_SUFFIXES`), as the iBUG 300-W sets ship them.

    Raises:
        InputError: there is none.
    """
    photo = Path(photo)
    for suffix in LANDMARK_SUFFIXES:
        candidate = photo.with_suffix(suffix)
        if candidate.is_file():
            return candidate
    raise InputError(f"--landmarks auto: no {'/'.join(LANDMARK_SUFFIXES)} file beside {photo}")


__all__ = ["IMAGE_SUFFIXES", "LANDMARK_SUFFIXES", "photo_inputs", "sidecar_landmarks"]
