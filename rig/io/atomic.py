"""The one atomic writer of files and folders: nothing half-written is ever left at a destination.

A file or folder is written under a hidden temporary name beside its destination and moved into place
in one step at the end:

* ``renameat2(RENAME_NOREPLACE)`` (:func:`rename_noreplace`) when nothing may be replaced: a
  destination that appeared meanwhile (e.g. from a second process writing the same path) is refused
  with :class:`TargetExistsError`, never overwritten, not even an empty folder;
* ``renameat2(RENAME_EXCHANGE)`` (:func:`rename_exchange`) when the destination may be replaced: the
  new and the old one are swapped in one step, then the old one is deleted. A folder cannot be
  replaced by :func:`os.rename` unless it is empty, and a swap never leaves a moment without a
  destination.

Without ``renameat2`` (not Linux, or a file system that does not support it) :func:`os.link` (files)
and :func:`os.rename` are used instead, which keep the same guarantees except that replacing a folder
moves the old one aside first. On any error, signal (a ``BaseException``) or interrupt the temporary is
removed and an existing destination is left as it was. What is written gets the usual (umask)
permissions, unlike the 0600/0700 of :func:`tempfile.mkstemp`/:func:`tempfile.mkdtemp`.

The temporaries are named ``.<name>.jnr<pid>-<random>.tmp`` (the output's name cut to 48 characters, so a
long ``--out`` stays legal) and locked while written; each staging first removes the ones of its output that
a killed process left (:func:`remove_stale_temporaries`), so no command leaves debris past its next run.

:func:`staged_file` and :func:`staged_folder` yield the temporary path to write into;
:func:`write_bytes_atomic` writes bytes that are already in memory. The policy of what the ``jnr``
commands may replace (``--force``, the ``.jnr-output`` marker, messages naming the user's path) is in
:mod:`pipeline.files`, which is built on this module.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from rig.errors import InputError

__all__ = [
    "TargetExistsError",
    "lock",
    "move_into_place",
    "remove_stale_temporaries",
    "rename_exchange",
    "rename_noreplace",
    "staged_file",
    "staged_folder",
    "write_bytes_atomic",
]

_RENAME_NOREPLACE, _RENAME_EXCHANGE = 1, 2
_AT_FDCWD = -100
_NO_RENAMEAT2 = (errno.ENOSYS, errno.EINVAL)
"""``renameat2`` is missing (ENOSYS) or the file system does not support the flag (EINVAL)."""


class TargetExistsError(FileExistsError):
    """The destination exists (or appeared while it was being written) and may not be replaced; it was
    left as it is. ``filename`` is the destination."""


def _renameat2():
    """libc's ``renameat2`` (Linux, glibc >= 2.28), or None."""
    if not hasattr(_renameat2, "fn"):
        fn = None
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            fn = libc.renameat2
            fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
            fn.restype = ctypes.c_int
        except (OSError, AttributeError):
            fn = None
        _renameat2.fn = fn
    return _renameat2.fn


def _rename(src: Path, dst: Path, flags: int) -> None:
    fn = _renameat2()
    if fn is None:
        raise OSError(errno.ENOSYS, "renameat2 is not available")
    if fn(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), flags) != 0:
        code = ctypes.get_errno()
        raise OSError(code, os.strerror(code), str(dst))


def rename_noreplace(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Rename ``src`` to ``dst`` in one step, failing if ``dst`` exists (``renameat2(RENAME_NOREPLACE)``).

    Raises:
        FileExistsError: ``dst`` exists (errno EEXIST).
        OSError: errno ENOSYS without ``renameat2``, EINVAL where the file system does not support it,
            or any other error of the rename.
    """
    _rename(Path(src), Path(dst), _RENAME_NOREPLACE)


def rename_exchange(a: str | os.PathLike, b: str | os.PathLike) -> None:
    """Swap the two existing paths ``a`` and ``b`` in one step (``renameat2(RENAME_EXCHANGE)``).

    Raises:
        FileNotFoundError: either path does not exist (errno ENOENT).
        OSError: errno ENOSYS / EINVAL as :func:`rename_noreplace`, or any other error of the rename.
    """
    _rename(Path(a), Path(b), _RENAME_EXCHANGE)


def _exists(path: Path) -> bool:
    return path.is_symlink() or path.exists()


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif _exists(path):
        path.unlink(missing_ok=True)


STAGING_TAG = 48
"""How many characters of the output's name a temporary's name keeps (a 250-byte ``--out`` name stays
legal: the temporary's name is at most about 80 bytes)."""
_STAGING = re.compile(r"\.(?P<tag>.*)\.jnr(?P<pid>[0-9]+)-(?:old-)?[a-z0-9_]{8}(?:\.tmp.*)?", re.S)
"""The names of this module's temporaries: ``.<tag>.jnr<pid>-<random>.tmp[<suffix>]`` (and
``.<tag>.jnr<pid>-old-<random>`` for an old folder moved aside): the writing process's id in the name, and a
lock on it while it is written (:func:`remove_stale_temporaries`)."""


def _prefix(name: str) -> str:
    return f".{name[:STAGING_TAG]}.jnr{os.getpid()}-"


def lock(path: str | os.PathLike) -> int | None:
    """Take an exclusive ``flock`` on ``path`` (a folder or a file, not followed if a symbolic link) without
    waiting; returns the descriptor that holds it (close it to release), or None where the file system has no
    locks.

    Raises:
        BlockingIOError: another process holds it.
    """
    path = Path(path)
    try:
        import fcntl

        fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if path.is_dir() else 0) | getattr(os, "O_NOFOLLOW", 0))
    except (ImportError, OSError):
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise BlockingIOError(exc.errno, f"{path} is locked by another process") from None
        return None
    return fd


def _lock(path: Path) -> int | None:
    """:func:`lock`, None also when another process holds it."""
    try:
        return lock(path)
    except BlockingIOError:
        return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def remove_stale_temporaries(folder: str | os.PathLike, names: tuple[str, ...] | None = None) -> list[Path]:
    """Remove the temporaries of this module in ``folder`` that a killed process left (SIGKILL, a lost
    terminal, a power cut): those whose writing process no longer exists and that no process holds locked;
    with ``names``, only those of the outputs so named. Every staging calls it for its own output, so the
    next run of any command cleans what a killed run of it left. Nothing else is touched (a symbolic link
    with such a name neither).

    Returns:
        The paths removed.
    """
    folder = Path(folder)
    tags = None if names is None else {n[:STAGING_TAG] for n in names}
    removed = []
    try:
        entries = [e for e in os.scandir(folder) if e.name.startswith(".") and ".jnr" in e.name]
    except OSError:
        return removed
    for entry in entries:
        match = _STAGING.fullmatch(entry.name)
        if match is None or entry.is_symlink() or (tags is not None and match["tag"] not in tags):
            continue
        pid = int(match["pid"])
        if pid == os.getpid() or _alive(pid):
            continue
        path = Path(entry.path)
        fd = _lock(path)
        if fd is None:  # in use (a process of another PID namespace?) or no locks here: leave it
            continue
        try:
            _remove(path)
        finally:
            os.close(fd)
        removed.append(path)
    return removed


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _check_kind(out: Path, kind: str) -> None:
    """A file never replaces a folder and a folder never replaces anything but a folder (a swap would
    delete what it replaced): the errors :func:`os.replace` gives."""
    is_folder = out.is_dir() and not out.is_symlink()
    if kind == "file" and is_folder:
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(out))
    if kind == "folder" and not is_folder:
        raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(out))


def _replace(tmp: Path, out: Path, kind: str) -> bool:
    """Swap ``tmp`` in for the existing ``out`` and delete the old one; False if ``out`` vanished meanwhile."""
    try:
        rename_exchange(tmp, out)  # tmp now holds the old destination
    except OSError as exc:
        if exc.errno == errno.ENOENT:
            return False
        if exc.errno not in _NO_RENAMEAT2:
            raise
        if kind == "file":
            os.replace(tmp, out)
            return True
        # No exchange here: move the old folder aside, then the new one in.
        aside = Path(tempfile.mkdtemp(prefix=_prefix(out.name) + "old-", dir=out.parent))
        os.rename(out, aside / "old")
        try:
            os.rename(tmp, out)
        except BaseException:
            os.rename(aside / "old", out)
            shutil.rmtree(aside, ignore_errors=True)
            raise
        shutil.rmtree(aside, ignore_errors=True)
        return True
    _remove(tmp)
    return True


def _place_new(tmp: Path, out: Path, kind: str) -> bool:
    """Move ``tmp`` to the absent ``out``; False if ``out`` appeared meanwhile (nothing moved)."""
    try:
        rename_noreplace(tmp, out)
    except OSError as exc:
        if exc.errno == errno.EEXIST:
            return False
        if exc.errno not in _NO_RENAMEAT2:
            raise
        # link() of a file fails on an existing target; rename() of a folder fails on a non-empty one.
        if kind == "file":
            try:
                os.link(tmp, out)
            except FileExistsError:
                return False
            os.unlink(tmp)
        else:
            if _exists(out):
                return False
            os.rename(tmp, out)
    return True


def move_into_place(
    tmp: str | os.PathLike,
    out: str | os.PathLike,
    *,
    replace: bool = False,
    kind: str = "file",
    check_replace: Callable[[Path], None] | None = None,
) -> None:
    """Move the finished temporary ``tmp`` to ``out`` in one atomic step (module docstring).

    Args:
        tmp: the temporary file or folder, on the same file system as ``out`` (beside it).
        out: the destination.
        replace: an existing ``out`` is replaced (swapped, then deleted); otherwise it is refused.
        kind: ``"file"`` or ``"folder"``: what ``tmp`` is. A file never replaces a folder and a folder
            only replaces a folder.
        check_replace: called with ``out`` just before an existing ``out`` is replaced; raises to refuse
            (e.g. a folder that is not one's own output).

    Raises:
        TargetExistsError: ``out`` exists (or appeared) and ``replace`` is false; ``tmp`` is left as it is.
        IsADirectoryError, NotADirectoryError: ``out`` is of the other kind.
        OSError: the move failed; ``out`` is unchanged.
    """
    if kind not in ("file", "folder"):
        raise InputError(f"move_into_place: kind must be 'file' or 'folder', got {kind!r}")
    tmp, out = Path(tmp), Path(out)
    for _ in range(100):  # each round lost a race with another process creating or removing ``out``
        if _exists(out):
            if not replace:
                break
            if check_replace is not None:
                check_replace(out)
            _check_kind(out, kind)
            if _replace(tmp, out, kind):
                return
        elif _place_new(tmp, out, kind):
            return
        elif not replace:
            break
    error = TargetExistsError(f"{out} exists (or appeared while it was being written) and was not replaced")
    error.errno, error.filename = errno.EEXIST, str(out)
    raise error


@contextmanager
def _staged(tmp: Path, finish: Callable[[Path], None], lock: int | None) -> Iterator[Path]:
    """Yield ``tmp``, then ``finish(tmp)``; any error, signal or interrupt removes ``tmp``. ``lock`` (a
    descriptor holding ``tmp`` locked, or None) is released at the end."""
    try:
        yield tmp
        finish(tmp)
    except BaseException:
        _remove(tmp)
        raise
    finally:
        if lock is not None:
            os.close(lock)


@contextmanager
def staged_folder(
    out: str | os.PathLike,
    *,
    replace: bool = False,
    check_replace: Callable[[Path], None] | None = None,
    before_move: Callable[[Path], None] | None = None,
) -> Iterator[Path]:
    """Write a folder atomically: yields a new hidden temporary folder beside ``out`` to fill; when the
    block ends without an error it is moved to ``out`` (:func:`move_into_place`), otherwise removed.

    Args:
        out: the destination folder; its parent folder must exist.
        replace: an existing ``out`` folder is replaced as a whole.
        check_replace: see :func:`move_into_place`.
        before_move: called with the temporary folder after the block, just before the move (e.g. to
            add a marker file).

    Raises:
        TargetExistsError: ``out`` exists or appeared and ``replace`` is false.
        OSError: the temporary folder cannot be made or moved (``out`` is unchanged).
    """
    out = Path(out)
    remove_stale_temporaries(out.parent, (out.name,))
    tmp = Path(tempfile.mkdtemp(prefix=_prefix(out.name), suffix=".tmp", dir=out.parent))

    def finish(tmp: Path) -> None:
        if before_move is not None:
            before_move(tmp)
        os.chmod(tmp, 0o777 & ~_umask())
        move_into_place(tmp, out, replace=replace, kind="folder", check_replace=check_replace)

    with _staged(tmp, finish, _lock(tmp)) as staged:
        yield staged


@contextmanager
def staged_file(
    out: str | os.PathLike, *, replace: bool = False, check_replace: Callable[[Path], None] | None = None
) -> Iterator[Path]:
    """Write one file atomically: yields a new, empty hidden temporary file beside ``out`` with the same
    suffix (writers that pick the format from the suffix still work); when the block ends without an
    error it is moved to ``out`` (:func:`move_into_place`), otherwise removed.

    Args:
        out: the destination file; its folder must exist.
        replace: an existing ``out`` is replaced.
        check_replace: see :func:`move_into_place`.

    Raises:
        TargetExistsError: ``out`` exists or appeared and ``replace`` is false.
        OSError: the temporary file cannot be made or moved (``out`` is unchanged).
    """
    out = Path(out)
    remove_stale_temporaries(out.parent, (out.stem,))
    suffix = out.suffix if len(out.suffix) <= 16 else ""  # writers pick the format from it
    fd, name = tempfile.mkstemp(prefix=_prefix(out.stem), suffix=f".tmp{suffix}", dir=out.parent)
    os.close(fd)

    def finish(tmp: Path) -> None:
        os.chmod(tmp, 0o666 & ~_umask())
        move_into_place(tmp, out, replace=replace, kind="file", check_replace=check_replace)

    with _staged(Path(name), finish, _lock(Path(name))) as staged:
        yield staged


def write_bytes_atomic(path: str | os.PathLike, payload: bytes, *, make_parents: bool = False) -> None:
    """Write ``payload`` to ``path`` atomically (:func:`staged_file`, replacing an existing file), flushed
    to disk before the move, with the usual (umask) permissions.

    Args:
        path: the destination file; its folder must exist unless ``make_parents``.
        payload: the bytes.
        make_parents: create missing parent folders first.

    Raises:
        OSError: the temporary file cannot be written or moved (it is removed; ``path`` is unchanged),
            e.g. :class:`IsADirectoryError` when ``path`` is a folder.
    """
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    with staged_file(path, replace=True) as tmp, open(tmp, "wb") as handle:
        handle.write(payload)
        handle.flush()
        os.fsync(handle.fileno())
