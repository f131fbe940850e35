"""The one atomic file writer of the rig package: a file is written to a temporary file in the same
folder and moved over the destination with :func:`os.replace`, so no half-written file is ever left at
the destination (an old file stays as it was when writing fails). Whole output folders and the checks
the command line makes before it writes are in :mod:`pipeline.files`."""

from __future__ import annotations

import os
import secrets
from pathlib import Path


def write_bytes_atomic(path: str | Path, payload: bytes, *, make_parents: bool = False) -> None:
    """Write ``payload`` to ``path`` atomically, with the usual (umask) permissions.

    Args:
        path: the destination file; its folder must exist unless ``make_parents``.
        payload: the bytes.
        make_parents: create missing parent folders first.

    Raises:
        OSError: the temporary file cannot be written or moved (it is removed; ``path`` is unchanged).
    """
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
        try:
            # os.open with mode 0o666 honours the umask (unlike tempfile.mkstemp's 0o600).
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
        except FileExistsError:
            continue
        break
    else:  # pragma: no cover - 100 collisions of a 48-bit random name
        raise FileExistsError(f"could not create a temporary file next to {str(path)!r}")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(payload)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
