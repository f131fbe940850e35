"""Resuming a batch: what an earlier run left at a photo's output folder (:func:`earlier_output`).

A complete output is kept and its summary rows are rebuilt from its ``report.json`` (and, with ``--face
all``, from the photo's own ``summary.csv``); an incomplete one is fitted again; what jnr did not write,
or a fit of another photo, is refused. Whether a single-face output is complete is decided by
:func:`complete_report` (today: every file of :data:`pipeline.head.folders.PHOTO_FOLDER` and a readable
``report.json``).

Example:
    >>> earlier_output(PhotoTask("photos/a.jpg", "out/a")).state  # doctest: +SKIP
    'complete'
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

from pipeline.config import config_to_dict
from pipeline.files import OutputError, check_output, is_jnr_output, json_safe
from pipeline.head.folders import PHOTO_FOLDER, PHOTO_OUTPUT_SETS
from pipeline.photo.detection import FACE_ALL
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.summary import SUMMARY_FILE, PhotoFileResult, read_summary
from pipeline.photo.task import PhotoTask


@dataclass(frozen=True)
class EarlierOutput:
    """What an earlier run left at a task's output folder (:func:`earlier_output`).

    Attributes:
        state: ``"absent"`` (nothing there), ``"complete"`` (kept: ``results`` are its summary rows,
            rebuilt from its report.json) or ``"incomplete"`` (a jnr output folder with files missing or
            an unreadable report.json: fitted again and replaced).
        results: the kept rows (:attr:`~pipeline.photo.summary.PhotoFileResult.kept`), for
            ``"complete"``.
        other_settings: a kept fit was made with other settings (configuration, landmarks source,
            detector or focal) than the task's.
    """

    state: str
    results: tuple[PhotoFileResult, ...] = ()
    other_settings: bool = False


def complete_report(folder: Path) -> dict | None:
    """The report.json of a complete single-face output folder (every file of its ``--outputs`` set,
    :data:`pipeline.head.folders.PHOTO_OUTPUT_SETS`, as its report's configuration records it; a report with
    jnr's landmark errors and input photo), or
    None: the resume check of one fit's folder."""
    try:
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
        landmarks, photo = report["landmarks"], report["input"]["photo"]
        float(landmarks["mean_error_px"]), float(landmarks["nme_inter_ocular"])
        # the files of the set it was written with (jnr fit --outputs; older folders: all)
        files = ((report.get("config") or {}).get("outputs") or {}).get("files", "all")
        names = PHOTO_OUTPUT_SETS[files]
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if not PHOTO_FOLDER.is_complete(folder, names):
        return None
    return report if isinstance(photo, str) else None


def _same_photo(recorded: str, photo: str) -> bool:
    """Whether the photo a report or summary recorded is ``photo``: the same file, or (a relative path that
    an earlier jnr recorded from another working directory) the same file name."""
    try:
        return os.path.samefile(recorded, photo)
    except OSError:
        return Path(recorded).name == Path(photo).name


def _float(text) -> float | None:
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def _settings_differ(task: PhotoTask, report: dict) -> bool:
    """Whether a kept fit's report.json records other settings than ``task``'s (its configuration, where
    its landmarks came from, the detector, the focal length)."""
    wanted = json.loads(json.dumps(json_safe(config_to_dict(task.config or FitPhotoConfig()))))
    source = report.get("input") or {}
    detected = "detector_option" in source
    if report.get("config") != wanted or detected == bool(task.landmarks):
        return True
    if detected and source.get("detector_option") != task.detector:
        return True
    if task.focal is None:
        return source.get("focal_source") == "--focal"
    focal = _float(source.get("focal_px"))
    return focal is None or not math.isclose(focal, task.focal, rel_tol=1e-9)


def _kept_row(task: PhotoTask, output: str, report: dict, seconds: float | None) -> PhotoFileResult:
    """The summary row of a kept single-face output, from its report.json (the numbers a fit writes in
    both, so the same as the row of the run that made it)."""
    source = report.get("input") or {}
    landmarks = report["landmarks"]
    box = source.get("face_box")
    faces = source.get("faces")
    summary = {
        "photo": task.photo,
        "output": output,
        "mean_error_px": _float(landmarks["mean_error_px"]),
        "nme": _float(landmarks["nme_inter_ocular"]),
        "seconds": seconds,
        "fit_seconds": _float((report.get("timings_s") or {}).get("total")),
        "face": source.get("face_index"),
        "faces_found": len(faces) if isinstance(faces, list) else None,
        "face_box": box,
        "face_score": source.get("face_score"),
    }
    return PhotoFileResult(
        task.photo,
        summary,
        face=summary["face"],
        faces_found=summary["faces_found"],
        seconds=seconds,
        face_box=tuple(box) if isinstance(box, list) else None,
        face_score=summary["face_score"],
        kept=True,
    )


def _other_photo(out: Path, what: str) -> OutputError:
    return OutputError(
        f"--out {out} holds an earlier fit of {what}; pass --force to fit it again or choose another --out"
    )


def earlier_output(
    task: PhotoTask, earlier_seconds: dict[tuple[str, str], float | None] | None = None
) -> EarlierOutput:
    """What an earlier run left at ``task.out``, to resume a batch
    (:func:`pipeline.photo.batch.fit_photo_files`).

    Complete means: a folder jnr wrote holding every file of :data:`pipeline.head.folders.PHOTO_FOLDER`
    and a readable report.json of the same photo; with ``task.face == "all"``, a folder with a summary.csv
    jnr wrote whose rows are all of the same photo, at least one fitted face, and each fitted face's
    ``face_<k>/`` complete as above. Its rows are rebuilt from the report.json files (landmark error, NME,
    faces found, box, score, as the fit wrote them) and, with ``face="all"``, from the photo's own
    summary.csv (the faces that failed, the seconds).

    Args:
        task: the photo and its output folder.
        earlier_seconds: ``{(photo file name, output folder name): seconds}`` from the batch's earlier
            summary.csv, for the ``seconds`` of a kept single-face row (None where not known).

    Returns:
        :class:`EarlierOutput`.

    Raises:
        pipeline.files.OutputError: something is at ``task.out`` that jnr did not write (or not a
            folder), or a complete fit of another photo (or of one face where every face is asked for,
            or the other way round): refused as before, ``--force`` replaces only jnr's own.
    """
    out = Path(task.out)
    if not (out.exists() or out.is_symlink()):
        return EarlierOutput("absent")
    if out.is_symlink() or not out.is_dir() or not is_jnr_output(out):
        check_output(out, force=True, inputs=task.inputs)  # raises the message for what is there
        raise _other_photo(out, "something else")  # pragma: no cover - check_output refuses all of these
    if task.face == FACE_ALL:
        return _earlier_faces(task, out)
    report = complete_report(out)
    if report is None:
        if read_summary(out / SUMMARY_FILE) is not None and (out / "face_0").is_dir():
            raise _other_photo(out, f"every face of {task.photo} (--face all)")
        return EarlierOutput("incomplete")
    if not _same_photo(report["input"]["photo"], task.photo):
        raise _other_photo(out, f"another photo ({report['input']['photo']})")
    seconds = (earlier_seconds or {}).get((Path(task.photo).name, out.name))
    return EarlierOutput("complete", (_kept_row(task, task.out, report, seconds),), _settings_differ(task, report))


def _earlier_faces(task: PhotoTask, out: Path) -> EarlierOutput:
    """:func:`earlier_output` for ``face="all"``."""
    rows = read_summary(out / SUMMARY_FILE)
    if rows is None:
        if complete_report(out) is not None:
            raise _other_photo(out, f"one face of {task.photo} (without --face all)")
        return EarlierOutput("incomplete")
    results, differ = [], False
    for row in rows:
        if not _same_photo(row.get("photo") or "", task.photo):
            raise _other_photo(out, f"another photo ({row.get('photo')})")
        face = int(row["face"]) if (row.get("face") or "").isdigit() else None
        found = int(row["faces_found"]) if (row.get("faces_found") or "").isdigit() else None
        seconds = _float(row.get("seconds"))
        if row.get("status") != "ok":
            box = tuple(_float(row.get(f"box_{side}")) for side in ("left", "top", "right", "bottom"))
            results.append(
                PhotoFileResult(
                    task.photo,
                    error=row.get("error") or "failed",
                    bad_input=True,
                    face=face,
                    faces_found=found,
                    seconds=seconds,
                    face_box=None if None in box else box,
                    face_score=_float(row.get("face_score")),
                    kept=True,
                )
            )
            continue
        report = None if face is None else complete_report(out / f"face_{face}")
        if report is None or (report.get("input") or {}).get("face_index") != face:
            return EarlierOutput("incomplete")
        results.append(_kept_row(task, str(Path(task.out) / f"face_{face}"), report, seconds))
        differ = differ or _settings_differ(task, report)
    if not any(r.summary for r in results):
        return EarlierOutput("incomplete")
    return EarlierOutput("complete", tuple(results), differ)


def earlier_summary_seconds(out: Path) -> dict[tuple[str, str], float | None]:
    """``{(photo file name, output folder name): seconds}`` of the fitted rows of the batch's earlier
    summary.csv (:func:`earlier_output`)."""
    rows = read_summary(out / SUMMARY_FILE) or []
    return {
        (Path(r["photo"]).name, Path(r["output"]).name): _float(r.get("seconds"))
        for r in rows
        if r.get("status") == "ok" and r.get("photo") and r.get("output")
    }


__all__ = ["EarlierOutput", "complete_report", "earlier_output", "earlier_summary_seconds"]
