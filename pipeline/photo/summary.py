"""The table of a run over several photos or faces: ``summary.csv``, one row per photo (per face with
``--face all``), and :class:`PhotoFileResult`, what became of each.

Example:
    >>> write_summary("out/summary.csv", results)  # doctest: +SKIP
    >>> [row["status"] for row in read_summary("out/summary.csv")]  # doctest: +SKIP
    ['ok', 'error']
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from pipeline.files import SMALL_FILE_FREE_BYTES, OutputError, check_output, staged_file

SUMMARY_FILE = "summary.csv"
"""The table of a run over several photos or faces, one row per photo (per face with ``--face all``)."""
SUMMARY_COLUMNS = (
    "photo",
    "face",
    "status",
    "error",
    "output",
    "mean_error_px",
    "nme",
    "seconds",
    "fit_seconds",
    "faces_found",
    "box_left",
    "box_top",
    "box_right",
    "box_bottom",
    "face_score",
    "kept",
)
"""The columns of :data:`SUMMARY_FILE`: the photo file; the face index (empty: landmarks from a file, or the
photo failed before a face was picked); ``ok`` or ``error`` and the one-line error; the output folder
(empty on an error: nothing was written); the landmark error in the photo's pixels and the NME by the
outer eye corners (as in the fit's ``report.json``); the seconds spent on the photo in all (with ``--face
all``, on that face: its fit and outputs; the detection, once per photo, is in ``report.json``) and those of
the fit alone (``fit_seconds``: what ``jnr fit`` prints after "fitted ... in"); how many faces
the detector found (0: none; empty: not detected, e.g. an unreadable file or a landmarks file); the face's
box in the photo's pixels and the detector's score; ``yes`` when the row is an earlier run's output that
was kept (resumed: not fitted again, its numbers read back from its ``report.json``; ``seconds`` is then
the time its fit took when it was made), ``no`` when it was fitted (or failed) in this run."""
_EARLIER_SUMMARY_COLUMNS = (
    tuple(c for c in SUMMARY_COLUMNS if c not in ("fit_seconds", "kept")),
    tuple(c for c in SUMMARY_COLUMNS if c != "fit_seconds"),
)
"""The headers of the summaries earlier jnr versions wrote (before the ``kept`` column, and before the
``fit_seconds`` one): still jnr's own."""


@dataclass(frozen=True)
class PhotoFileResult:
    """What became of one photo, or of one face of a photo with ``face="all"``: a row of
    :data:`SUMMARY_FILE`.

    Attributes:
        photo: the photo file. summary: :func:`pipeline.photo.photo_file.fit_photo_file`'s summary, None
            when it failed.
        error: the one-line message when it failed. bad_input: whether the input is to blame (an
            :class:`~rig.errors.InputError`) rather than a failure of the fit or the machine.
        face: the index of the detected face (None: landmarks from a file, or the photo failed before a
            face was picked). faces_found: how many faces the detector found (0: none; None: not known).
        seconds: the time spent on it. face_box: ``(left, top, right, bottom)`` in the photo's pixels, and
            face_score: the detector's score, of the face (None when not detected).
        kept: the output was written by an earlier run and kept (:func:`pipeline.photo.resume.earlier_output`),
            not fitted now.
    """

    photo: str
    summary: dict | None = None
    error: str | None = None
    bad_input: bool = False
    face: int | None = None
    faces_found: int | None = None
    seconds: float | None = None
    face_box: tuple[float, float, float, float] | None = None
    face_score: float | None = None
    kept: bool = False

    @property
    def output(self) -> str | None:
        """The output folder written (None on an error: nothing was written)."""
        return None if self.summary is None else self.summary["output"]


def _number(value, digits: int) -> str:
    return "" if value is None else f"{float(value):.{digits}f}"


FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")
"""What makes a spreadsheet take a cell for a formula (a photo named ``=1+2.jpg``)."""
TEXT_COLUMNS = ("photo", "error", "output")
"""The columns holding names and messages (:func:`text_cell`)."""


def text_cell(text: str) -> str:
    """A name or a message as a CSV cell no spreadsheet runs: one starting like a formula gets a leading
    ``'`` (:func:`read_text_cell` takes it off)."""
    return "'" + text if text.startswith(FORMULA_STARTS) else text


def read_text_cell(text: str) -> str:
    """The name or message :func:`text_cell` wrote."""
    return text[1:] if text.startswith("'") and text[1:].startswith(FORMULA_STARTS) else text


def summary_csv(results: Iterable[PhotoFileResult]) -> str:
    """The text of :data:`SUMMARY_FILE`: a header of :data:`SUMMARY_COLUMNS` and one row per result (empty
    cells for what is not known; pixels with 3 decimals, NME with 5, seconds with 2)."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(SUMMARY_COLUMNS)
    for r in results:
        fitted = r.summary or {}
        box = r.face_box or ("",) * 4
        writer.writerow(
            [
                text_cell(r.photo),
                "" if r.face is None else r.face,
                "error" if r.error else "ok",
                text_cell(r.error or ""),
                text_cell(r.output or ""),
                _number(fitted.get("mean_error_px"), 3),
                _number(fitted.get("nme"), 5),
                _number(r.seconds, 2),
                _number(fitted.get("fit_seconds"), 2),
                "" if r.faces_found is None else r.faces_found,
                *(b if b == "" else _number(b, 1) for b in box),
                _number(r.face_score, 4),
                "yes" if r.kept else "no",
            ]
        )
    return text.getvalue()


def _jnr_header(line: str) -> bool:
    """Whether ``line`` (without its line end) is the header of a summary some jnr version wrote."""
    return tuple(line.split(",")) in (SUMMARY_COLUMNS, *_EARLIER_SUMMARY_COLUMNS)


def read_summary(path: str | Path) -> list[dict[str, str]] | None:
    """The rows of a :data:`SUMMARY_FILE` jnr wrote (this version or an earlier one), as ``{column: text}``;
    None when there is none, it cannot be read or another program wrote it (its first line is not jnr's
    header)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    if not _jnr_header(text.split("\n", 1)[0].rstrip("\r")):
        return None
    rows = list(csv.DictReader(io.StringIO(text, newline="")))
    return [{k: read_text_cell(v) if k in TEXT_COLUMNS else v for k, v in row.items()} for row in rows]


def check_summary(path: Path, force: bool, inputs: Iterable[str | Path]) -> None:
    """Before any fit: ``path`` may be written (a summary.csv that exists only with ``force``, and only
    one jnr wrote: it starts with the header of :data:`SUMMARY_COLUMNS`, or an earlier version's).

    Raises:
        pipeline.files.OutputError: it may not.
    """
    check_output(path, force=force, inputs=inputs, kind="file", free_bytes=SMALL_FILE_FREE_BYTES)
    if path.is_file():
        try:
            with open(path, newline="", encoding="utf-8") as handle:
                header = handle.readline().strip()
        except (OSError, UnicodeDecodeError):
            header = ""
        if not _jnr_header(header):
            raise OutputError(
                f"--out {path} is not a summary jnr wrote (its first line is not jnr's header); "
                "--force replaces only jnr's own outputs: remove it yourself or choose another --out"
            )


def write_summary(
    path: str | Path, results: Iterable[PhotoFileResult], *, force: bool = False, inputs: Iterable[str | Path] = ()
) -> Path:
    """Write :func:`summary_csv` of ``results`` to ``path`` atomically (:func:`pipeline.files.staged_file`,
    on :mod:`rig.io.atomic`); an existing file only with ``force`` and only if jnr wrote it.

    Raises:
        pipeline.files.OutputError: ``path`` is refused or cannot be written (nothing is left behind).
    """
    path = Path(path)
    check_summary(path, force, inputs)
    with staged_file(path, force, inputs=inputs, free_bytes=SMALL_FILE_FREE_BYTES) as tmp:
        tmp.write_text(summary_csv(results), encoding="utf-8")
    return path


__all__ = [
    "SUMMARY_COLUMNS",
    "SUMMARY_FILE",
    "PhotoFileResult",
    "check_summary",
    "read_summary",
    "summary_csv",
    "write_summary",
]
