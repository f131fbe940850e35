"""The folder of a batch (``jnr fit FOLDER --out OUT``): its lock, and what a killed run left in it.

* :func:`lock_folder` takes an exclusive lock on ``OUT`` for the run (a second ``jnr fit`` into it is
  refused); :func:`unlock` releases it.
* :func:`remove_leftovers` removes the hidden temporaries a killed run left (only jnr's, by name).

Example:
    >>> fd = lock_folder(Path("out"))  # doctest: +SKIP
    >>> remove_leftovers("out", ["face0", "face1"])  # doctest: +SKIP
    [PosixPath('out/.face1.abcd_123.tmp')]
    >>> unlock(fd)  # doctest: +SKIP
"""

from __future__ import annotations

import logging
import os
import re
import shutil
from collections.abc import Iterable
from pathlib import Path

from pipeline.files import OutputError
from pipeline.photo.summary import SUMMARY_FILE
from rig.io.atomic import lock, remove_stale_temporaries

_log = logging.getLogger(__name__)

_RANDOM = "[a-z0-9_]{8}"
"""The random part :mod:`tempfile` puts into the names of :mod:`rig.io.atomic`'s temporaries."""


def remove_leftovers(out: str | Path, folders: Iterable[str], files: Iterable[str] = (SUMMARY_FILE,)) -> list[Path]:
    """Remove what a killed run left in the batch folder ``out``: the hidden temporaries of
    :mod:`rig.io.atomic` (:func:`rig.io.atomic.remove_stale_temporaries`), and those of earlier versions
    for the output folders named ``folders`` (``.<name>.<random>.tmp``, and
    ``.<name>.old.<random>`` where ``renameat2`` is missing) and for the files named ``files``
    (``.<stem>.<random>.tmp<suffix>``). Nothing else is touched (a symbolic link with such a name
    neither). Call it only while no other process writes these outputs
    (:func:`pipeline.photo.batch.fit_photo_files` holds the folder's lock).

    Returns:
        The paths removed.
    """
    out = Path(out)
    patterns = [(re.compile(rf"\.{re.escape(n)}\.(?:{_RANDOM}\.tmp|old\.{_RANDOM})"), True) for n in folders]
    patterns += [
        (re.compile(rf"\.{re.escape(Path(n).stem)}\.{_RANDOM}\.tmp{re.escape(Path(n).suffix)}"), False) for n in files
    ]
    removed = remove_stale_temporaries(out)  # this version's names: a dead writer's, unlocked
    try:
        entries = [p for p in out.iterdir() if p.name.startswith(".")]
    except OSError:
        return removed
    for path in sorted(entries):
        for pattern, is_folder in patterns:
            if not pattern.fullmatch(path.name) or path.is_symlink():
                continue
            if is_folder and path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            elif not is_folder and path.is_file():
                path.unlink(missing_ok=True)
            else:
                continue
            removed.append(path)
            _log.info("removed %s, left by a run that was killed", path)
            break
    return removed


def lock_folder(out: Path) -> int | None:
    """Take an exclusive lock on the batch folder ``out`` (:func:`rig.io.atomic.lock`: ``flock`` on the folder
    itself, no file is added); returns the descriptor that holds it (:func:`unlock`), or None where the file
    system has no locks.

    Raises:
        pipeline.files.OutputError: another process holds it (a second ``jnr fit`` into ``out``).
    """
    try:
        return lock(out)
    except BlockingIOError:
        raise OutputError(
            f"another jnr fit is writing into --out {out} now (it holds the folder's lock); "
            "wait for it to end or choose another --out"
        ) from None


def unlock(fd: int | None) -> None:
    """Release the lock :func:`lock_folder` took (nothing for None)."""
    if fd is not None:
        os.close(fd)


__all__ = ["lock_folder", "remove_leftovers", "unlock"]
