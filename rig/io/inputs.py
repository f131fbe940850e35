"""Opening a user's input file safely: only a regular file is read (a FIFO blocks forever, a device such as
``/dev/zero`` never ends, even behind a symbolic link named like a data file), and only up to a size stated
up front.

Example:
    >>> regular_file("scan.ply", "point cloud", 4 << 30)  # doctest: +SKIP
    PosixPath('scan.ply')
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from rig.errors import InputError


def regular_file(path: str | os.PathLike, what: str, max_bytes: int) -> Path:
    """``path`` when it is a regular file (after symbolic links) of at most ``max_bytes``.

    Raises:
        FileNotFoundError: it does not exist.
        InputError: a folder, a FIFO, a device or a socket; larger than ``max_bytes`` (one line naming it).
    """
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {path}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read this {what} ({exc.strerror or exc})") from None
    if stat.S_ISDIR(info.st_mode):
        raise InputError(f"{path}: is a folder; expected the {what}")
    if not stat.S_ISREG(info.st_mode):
        raise InputError(f"{path}: not a regular file (a pipe or a device?); jnr reads the {what} only from a file")
    if info.st_size > max_bytes:
        raise InputError(f"{path}: {info.st_size / 2**20:.0f} MB; the {what} may be at most {max_bytes / 2**20:.0f} MB")
    return path


def loads_json_strict(text: str):
    """``json.loads`` that refuses an object with a key twice (``json`` keeps the last silently, so a file
    edited by hand could hold two values of one parameter and the user would not know which one counts).

    Raises:
        json.JSONDecodeError: invalid JSON; ValueError: a duplicate key (the message names it).
    """
    import json

    def pairs(items: list[tuple[str, object]]) -> dict:
        seen: dict = {}
        for key, value in items:
            if key in seen:
                raise InputError(f"the key {key!r} appears twice in one object")
            seen[key] = value
        return seen

    return json.loads(text, object_pairs_hook=pairs)


__all__ = ["loads_json_strict", "regular_file"]
