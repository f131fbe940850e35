"""Output folders written all at once, and JSON without NaN: shared by ``jnr fit`` and ``jnr fit-scan``."""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def staged_folder(out_dir: str | Path, force: bool = False) -> Iterator[Path]:
    """Write an output folder atomically: yields a temporary folder beside ``out_dir``; when the block
    ends without an error it replaces ``out_dir``, otherwise it is removed and nothing is left behind.

    Raises:
        FileExistsError: ``out_dir`` exists and ``force`` is false.
        FileNotFoundError: the parent folder of ``out_dir`` does not exist.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not force:
        raise FileExistsError(f"output folder {out_dir} exists; pass --force to replace it")
    if not out_dir.parent.is_dir():
        raise FileNotFoundError(f"the parent folder of {out_dir} does not exist")
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".tmp", dir=out_dir.parent))
    try:
        yield tmp
        if out_dir.exists():
            shutil.rmtree(out_dir) if out_dir.is_dir() else out_dir.unlink()
        tmp.rename(out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def json_safe(obj):
    """JSON has no NaN/inf: nested dicts/lists with those floats written as null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj
