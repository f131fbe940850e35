"""Writing outputs without ever losing a user's file; JSON without NaN.

Every output of the ``jnr`` commands goes through this module:

* :func:`check_output` refuses, before any work is done, an output path that is, contains or lies
  inside one of the command's inputs, or is (or contains) the working directory; an existing output
  without ``force``; with ``force``, an existing folder that jnr did not write (:func:`is_jnr_output`:
  it has no :data:`OUTPUT_MARKER` file of jnr's), one holding entries jnr did not write
  (:func:`foreign_entries`: the user's files are never deleted with it), or a folder where a file is
  expected; a parent folder that does not
  exist, is not writable or has less than :data:`MIN_FREE_BYTES` free. Messages name the user's path.
* :func:`staged_folder` / :func:`staged_file` check the output, then write it with the one atomic
  writer, :mod:`rig.io.atomic`: into a hidden temporary folder/file beside the output, moved into place
  in one atomic step at the end: ``renameat2(RENAME_NOREPLACE)`` when nothing may be replaced (a target
  that appeared meanwhile, e.g. from a second ``jnr`` process with the same ``--out``, is refused, not
  overwritten) and ``RENAME_EXCHANGE`` (swap, then delete the old one) with ``force`` (a folder only if
  it is still jnr's). On any error or signal (SIGINT, SIGTERM: see :mod:`pipeline.signals`) the
  temporary is removed and the old output is untouched; errors name the user's path.
* Outputs get the user's umask permissions (``mkdtemp``/``mkstemp`` make 0700/0600).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from rig.errors import InputError
from rig.io import atomic
from rig.io.atomic import TargetExistsError

OUTPUT_MARKER = ".jnr-output"
"""The file that marks a folder written by jnr; ``--force`` replaces only folders that hold it."""
MIN_FREE_BYTES = 16 * 1024 * 1024
"""An output's folder must have this much free space before a fit starts: about three times a photo fit's
default outputs (5.5 MB for a 512 x 512 portrait; 64 MB refused outputs that fitted, issue 38). A disk that
fills anyway fails the write, which leaves nothing half-written (:func:`staged_folder`)."""
SMALL_FILE_FREE_BYTES = 1024 * 1024
"""The free space a small report (a folder run's ``summary.csv``) needs: it is still written when a disk that
filled during the run refuses the next photo's output (which needs :data:`MIN_FREE_BYTES`), so the run says
which photos were fitted and which were not."""


LEGACY_OUTPUT_FILES = frozenset(
    {
        "mesh.obj",
        "mesh.ply",
        "mesh.glb",
        "params.json",
        "overlay.png",
        "render.png",
        "landmarks.pts",
        "report.json",
        "cloud_error.ply",
        "template.obj",
        "template.ply",
        "template.glb",
        "edited.obj",
        "edited.glb",
        "edited.png",
        "edited_params.json",
        "summary.json",
        "astronaut",
        "synthetic",
        "inputs",
        "viewer.html",
    }
)
"""What the output folders of jnr versions before :data:`OUTPUT_MARKER` held (``jnr fit``, ``fit-scan``,
``demo``); see :func:`is_jnr_output`."""


def read_marker(folder: str | Path) -> dict | None:
    """The :data:`OUTPUT_MARKER` of ``folder`` when it is jnr's (a JSON object with ``"written_by": "jnr"``),
    else None (missing, unreadable, or a marker anyone could have made, such as ``{}``)."""
    path = Path(folder) / OUTPUT_MARKER
    try:
        if path.is_symlink() or not path.is_file() or path.stat().st_size > 1_000_000:
            return None
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return None
    return data if isinstance(data, dict) and data.get("written_by") == "jnr" else None


def is_jnr_output(folder: str | Path) -> bool:
    """Whether ``folder`` is an output folder jnr wrote: it holds jnr's :data:`OUTPUT_MARKER`
    (:func:`read_marker`), or (written before the marker existed) nothing but jnr's own output names and a
    ``params.json`` in a jnr format or the demo's ``summary.json``."""
    folder = Path(folder)
    if read_marker(folder) is not None:
        return True
    if (folder / OUTPUT_MARKER).exists():
        return False  # a marker jnr did not write
    try:
        names = {p.name for p in folder.iterdir()}
        if not names or not names <= LEGACY_OUTPUT_FILES:
            return False
        if "params.json" in names:
            return str(json.loads((folder / "params.json").read_text()).get("format", "")).startswith("jnr-")
        if "summary.json" in names:
            return "rebuild_max_difference_mm" in json.loads((folder / "summary.json").read_text())
    except (OSError, ValueError, AttributeError):
        return False
    return False


MARKER_SLACK_S = 2.0
"""A marker without a list of files (jnr before 2026-12-04): an entry changed more than this after the
marker was written is taken for the user's."""


def foreign_entries(folder: str | Path) -> list[str]:
    """The entries of jnr's output folder ``folder`` that jnr did not write (the user's: a note, an edited
    mesh, a sub-folder), sorted: those not in its marker's ``files`` list; for a marker without the list,
    those changed after the marker was written (:data:`MARKER_SLACK_S`); for a folder from before the
    marker, none (:func:`is_jnr_output` admits only jnr's names there)."""
    folder = Path(folder)
    marker = read_marker(folder)
    if marker is None:
        return []
    try:
        entries = [p for p in folder.iterdir() if p.name != OUTPUT_MARKER]
        files = marker.get("files")
        if isinstance(files, list):
            known = {str(f) for f in files}
            return sorted(p.name for p in entries if p.name not in known)
        written = (folder / OUTPUT_MARKER).stat().st_mtime
        return sorted(p.name for p in entries if p.lstat().st_mtime > written + MARKER_SLACK_S)
    except OSError:
        return []


def _refuse_foreign(out: Path, option: str) -> None:
    """``--force`` replaces a jnr output folder only when everything in it is jnr's (the user's files would
    go with it)."""
    foreign = foreign_entries(out)
    if foreign:
        shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
        raise OutputError(
            f"{option} {out} holds what jnr did not write ({shown}); --force replaces only jnr's own outputs: "
            "move those out of it or choose another --out"
        )


class OutputError(InputError):
    """An output path jnr refuses to write (message names the path and why); exit status 2."""


class OutputExistsError(OutputError, FileExistsError):
    """The output exists (and ``force`` was not given), or appeared while jnr was writing it."""


def _resolved(path: str | Path) -> Path:
    return Path(os.path.realpath(os.path.abspath(os.fspath(path))))


def _inside(child: Path, parent: Path) -> bool:
    """``child`` is ``parent`` or lies below it (both resolved)."""
    return child == parent or parent in child.parents


MAX_NAME_BYTES = 255
"""The longest file or folder name (bytes) of Linux's file systems; the temporaries' names stay shorter
(:data:`rig.io.atomic.STAGING_TAG`)."""


def _check_paths(out: Path, inputs: Iterable[str | Path], option: str) -> None:
    """Refuse an output that is, contains or lies inside an input, or is/contains the working directory, and a
    name longer than a file name may be (255 bytes)."""
    size = len(os.fsencode(out.name))
    if size > MAX_NAME_BYTES:
        raise OutputError(
            f"{option} {out}: the name is {size} bytes long; a file or folder name holds at most {MAX_NAME_BYTES}"
        )
    real = _resolved(out)
    cwd = _resolved(Path.cwd())
    if _inside(cwd, real):
        what = "is" if real == cwd else "contains"
        raise OutputError(f"{option} {out} {what} the working directory; choose a new folder for the output")
    for item in inputs:
        source = _resolved(item)
        if real == source:
            raise OutputError(f"{option} {out} is the input {item}; choose another output path")
        if _inside(source, real):
            raise OutputError(f"{option} {out} contains the input {item}; choose another output path")
        if Path(item).is_dir() and _inside(real, source):
            raise OutputError(f"{option} {out} lies inside the input folder {item}; choose another output path")


def check_output(
    out: str | Path,
    *,
    force: bool = False,
    inputs: Iterable[str | Path] = (),
    kind: str = "folder",
    option: str = "--out",
    free_bytes: int = MIN_FREE_BYTES,
) -> Path:
    """Check an output path before any work is done (module docstring); returns it as given.

    Args:
        out: the output folder (``kind="folder"``) or file (``kind="file"``).
        force: an existing output may be replaced (a folder only if jnr wrote it).
        inputs: the command's input files and folders.
        option: how the user named the output, for messages.
        free_bytes: the free space its folder must have (:data:`MIN_FREE_BYTES`; a small report:
            :data:`SMALL_FILE_FREE_BYTES`).

    Raises:
        OutputError: the output is refused (one line that says why).
    """
    if kind not in ("folder", "file"):
        raise InputError(f"check_output: kind must be 'folder' or 'file', got {kind!r}")
    out = Path(out)
    _check_paths(out, inputs, option)
    if out.is_symlink() or out.exists():
        if not force:
            noun = "folder" if out.is_dir() else "file"
            raise OutputExistsError(f"output {noun} {out} exists; pass --force to replace it")
        if kind == "folder":
            if not out.is_dir() or out.is_symlink():
                raise OutputError(f"{option} {out} exists and is not a folder; jnr will not replace it")
            if not is_jnr_output(out):
                raise OutputError(
                    f"{option} {out} is a folder jnr did not write (no {OUTPUT_MARKER} file of jnr's in it); "
                    "--force replaces only jnr's own outputs: remove it yourself or choose another"
                )
            _refuse_foreign(out, option)
        elif out.is_dir() or not out.is_file():
            raise OutputError(f"{option} {out} exists and is not a regular file; jnr will not replace it")
    _check_parent(out, option, free_bytes)
    return out


def _check_parent(out: Path, option: str, free_bytes: int = MIN_FREE_BYTES) -> None:
    """The folder that will hold ``out`` exists and is writable (:func:`check_writable`)."""
    if not out.parent.is_dir():
        raise OutputError(f"the folder of {option} {out} does not exist ({out.parent})")
    check_writable(out.parent, what=f"{option} {out}", free_bytes=free_bytes)


def check_writable(folder: str | Path, *, what: str | None = None, free_bytes: int = MIN_FREE_BYTES) -> None:
    """Prove that files can be created in ``folder`` (creates and removes a hidden temporary folder,
    which also works as root and on read-only or virtual file systems) and that it has ``free_bytes``.

    Raises:
        OutputError: not writable, or too little free space.
    """
    folder = Path(folder)
    what = what or str(folder)
    try:
        probe = tempfile.mkdtemp(prefix=".jnr-probe-", dir=folder)
        os.rmdir(probe)
    except OSError as exc:
        raise OutputError(f"cannot write {what}: {exc.strerror or exc} ({folder})") from None
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if free < free_bytes:
        raise OutputError(
            f"cannot write {what}: only {free / 2**20:.0f} MB free in {folder} (jnr needs {free_bytes / 2**20:.0f} MB)"
        )


# ---------------------------------------------------------------------------------------- staging


def _write_error(exc: OSError, out: Path) -> OutputError:
    """An OSError while writing, reported with the user's path instead of the temporary one (our own
    :class:`OutputExistsError`, also an OSError, is passed on as it is)."""
    if isinstance(exc, OutputError):
        return exc
    return OutputError(f"cannot write {out}: {exc.strerror or exc}")


@contextmanager
def _output_errors(out: Path) -> Iterator[None]:
    """The staging's OSErrors as :class:`OutputError` naming ``out``; a target that appeared meanwhile as
    :class:`OutputExistsError`."""
    try:
        yield
    except TargetExistsError as exc:
        if exc.filename != str(out):
            raise _write_error(exc, out) from None
        raise OutputExistsError(
            f"output {out} appeared while jnr was writing it (another process?); "
            "it was not replaced and nothing was written"
        ) from None
    except OSError as exc:
        raise _write_error(exc, out) from None


def _still_jnr_output(out: Path) -> None:
    """Just before ``--force`` swaps a folder in: the folder there must still be one jnr wrote, holding
    nothing of the user's."""
    if not (out.is_dir() and is_jnr_output(out)):
        raise OutputError(
            f"output {out} changed while jnr was writing it and is no longer a jnr output folder; it was not replaced"
        )
    _refuse_foreign(out, "--out")


@contextmanager
def staged_folder(
    out_dir: str | Path, force: bool = False, *, inputs: Iterable[str | Path] = (), marker: dict | None = None
) -> Iterator[Path]:
    """Write an output folder atomically (module docstring; :func:`rig.io.atomic.staged_folder`).

    Yields a hidden temporary folder beside ``out_dir``; when the block ends without an error the
    :data:`OUTPUT_MARKER` file is added and the folder is moved into place atomically; on an error, a
    signal or an interrupt it is removed and nothing is left behind.

    Args:
        out_dir: the output folder.
        force: replace an existing jnr output folder.
        inputs: the command's inputs (an output that is, contains or lies in one is refused).
        marker: what to record in the marker file (e.g. the command).

    Raises:
        OutputError: the output is refused (:func:`check_output`), appeared meanwhile, or cannot be
            written (the message names ``out_dir``, not the temporary folder).
    """
    out_dir = Path(out_dir)
    check_output(out_dir, force=force, inputs=inputs, kind="folder")

    def add_marker(tmp: Path) -> None:  # last: it lists every entry jnr wrote (foreign_entries)
        files = sorted(p.name for p in tmp.iterdir())
        (tmp / OUTPUT_MARKER).write_text(json.dumps({"written_by": "jnr", **(marker or {}), "files": files}) + "\n")

    with (
        _output_errors(out_dir),
        atomic.staged_folder(out_dir, replace=force, check_replace=_still_jnr_output, before_move=add_marker) as tmp,
    ):
        yield tmp


@contextmanager
def staged_file(
    out: str | Path, force: bool = False, *, inputs: Iterable[str | Path] = (), free_bytes: int = MIN_FREE_BYTES
) -> Iterator[Path]:
    """Write one output file atomically (:func:`rig.io.atomic.staged_file`): yields a hidden temporary
    path beside ``out`` with the same suffix (writers pick the format from it); moved into place when the
    block succeeds (refusing a file that appeared meanwhile unless ``force``), removed otherwise.

    Raises:
        OutputError: as :func:`staged_folder`.
    """
    out = Path(out)
    check_output(out, force=force, inputs=inputs, kind="file", free_bytes=free_bytes)
    with _output_errors(out), atomic.staged_file(out, replace=force) as tmp:
        yield tmp


def make_output_folder(out: str | Path, *, inputs: Iterable[str | Path] = ()) -> bool:
    """Create the folder that holds several outputs (``jnr fit FOLDER --out DIR``); an existing folder
    is kept as it is (its sub-folders are checked one by one). It is not marked as a jnr output, so
    that ``--force`` never replaces it as a whole. Returns whether it was created (so that an empty one
    can be removed if every fit fails).

    Raises:
        OutputError: ``out`` is refused or exists and is not a folder.
    """
    out = Path(out)
    _check_paths(out, inputs, "--out")
    existed = out.exists() or out.is_symlink()
    if existed and not out.is_dir():
        raise OutputError(f"--out {out} exists and is not a folder")
    if existed:
        check_writable(out, what=f"--out {out}")
        return False
    _check_parent(out, "--out")
    try:
        out.mkdir()
    except FileExistsError:
        return False
    except OSError as exc:
        raise _write_error(exc, out) from None
    return True


def json_safe(obj):
    """JSON has no NaN/inf: nested dicts/lists with those floats written as null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj
