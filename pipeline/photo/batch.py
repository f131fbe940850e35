"""Several photo files in, one folder of outputs out: ``jnr fit FOLDER --out OUT``.

:func:`fit_photo_files` fits each photo (:class:`~pipeline.photo.task.PhotoTask`) into ``OUT/<name>/``
(:func:`output_names`), one after another or through a caller's ``run`` (the command line's process pool
or a Dask cluster, :mod:`pipeline.photo.dask_runner`), reporting each photo's failure instead of
stopping, and lists them all in ``OUT/summary.csv`` (:mod:`pipeline.photo.summary`). It resumes: an
output folder an earlier run completed is kept and its row rebuilt from its ``report.json``
(:mod:`pipeline.photo.resume`); leftovers of a killed run are removed, under the folder's lock
(:mod:`pipeline.photo.batch_folder`).

Example:
    >>> results = fit_photo_files(["a.jpg", "b.jpg"], "out/fits")  # doctest: +SKIP
    >>> [r.output for r in results]  # doctest: +SKIP
    ['out/fits/a', 'out/fits/b']
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace
from pathlib import Path

from landmarks.detector import DEFAULT_DETECTOR, check_detector_name
from pipeline.files import OutputError, check_output, make_output_folder
from pipeline.photo.batch_folder import lock_folder, remove_leftovers, unlock
from pipeline.photo.detection import FACE_ALL
from pipeline.photo.resume import EarlierOutput, earlier_output, earlier_summary_seconds
from pipeline.photo.summary import SUMMARY_FILE, PhotoFileResult, check_summary, write_summary
from pipeline.photo.task import PhotoTask, fit_photo_task
from pipeline.viewer import SHARED_THREE_FILE
from rig.errors import InputError

_log = logging.getLogger(__name__)


MAX_NAME_CHARS = 100
"""The longest output folder name taken from a photo's stem (the rest is cut)."""


def safe_name(stem: str) -> str:
    """A photo stem as a folder name that stays inside ``--out``: control characters (a newline, an escape)
    replaced by ``_``, leading dots removed (``..``, ``.``, a hidden name), a leading ``-`` guarded, at most
    :data:`MAX_NAME_CHARS` characters; ``photo`` when nothing is left."""
    name = re.sub(r"[\x00-\x1f\x7f/\\]", "_", stem).strip().lstrip(".")
    if name.startswith("-"):
        name = "_" + name
    return name[:MAX_NAME_CHARS] or "photo"


def output_names(photos: Sequence[str | Path], reserved: Iterable[str] = ()) -> list[str]:
    """The output folder name of each photo, unique by construction: its :func:`safe_name`, or
    ``<name>_<index>`` for names that repeat, and ``_`` added until no name is taken twice or is one of
    ``reserved`` (the run's own files: ``summary.csv``, ``three.jnr.js``). The same photos always get the
    same names (a resumed run finds its folders)."""
    base = [safe_name(Path(p).stem) for p in photos]
    taken = {n.lower() for n in reserved}
    names = []
    for i, b in enumerate(base):
        name = b if base.count(b) == 1 else f"{b}_{i}"
        while name.lower() in taken:
            name += "_"
        taken.add(name.lower())
        names.append(name)
    return names


def _share_three(tasks: list[PhotoTask], out: Path, config) -> list[PhotoTask]:
    """The tasks with ``shared_three``: one copy of three.js in ``out`` (:func:`pipeline.viewer.write_shared_three`)
    for every fit's ``viewer.html`` instead of one inlined in each (when the fits write a page at all and
    three.js was vendored)."""
    from pipeline.head.folders import PHOTO_OUTPUT_SETS
    from pipeline.viewer import VIEWER_FILE, ThreeModuleError, fit_viewer_ready, write_shared_three

    files = "all" if config is None else config.outputs.files
    if not tasks or VIEWER_FILE not in PHOTO_OUTPUT_SETS[files] or not fit_viewer_ready():
        return tasks
    try:
        write_shared_three(out)
    except OSError as exc:
        raise OutputError(f"{out}: cannot write {SHARED_THREE_FILE} ({exc.strerror or exc})") from None
    except ThreeModuleError as exc:  # three.js vendored in another shape: the pages keep their own copy
        _log.warning("%s; the pages inline three.js", exc)
        return tasks
    return [replace(t, shared_three=str(out)) for t in tasks]


def _sequential(rig, neural, progress):
    def run(tasks: list[PhotoTask]) -> Iterable[tuple[PhotoFileResult, ...]]:
        for i, task in enumerate(tasks):
            yield fit_photo_task(task, rig=rig, neural=neural)
            if progress is not None:
                progress("photos", i + 1, len(tasks))

    return run


def _check_options(landmarks: str | None, face: str | None, detector: str) -> None:
    if landmarks not in (None, "auto"):
        raise InputError(f"landmarks must be None or 'auto' for several photos, got {landmarks!r}")
    if face not in (None, FACE_ALL):
        raise InputError(f"face must be None or {FACE_ALL!r} for several photos, got {face!r}")
    if face == FACE_ALL and landmarks:
        raise InputError("--face picks among the faces the detector finds; it cannot be used with --landmarks")
    check_detector_name(detector, "fit_photo_files")


def _plan(
    tasks: list[PhotoTask], out: Path, *, resuming: bool, force: bool, inputs: tuple[str, ...]
) -> tuple[list[PhotoFileResult], list[PhotoTask], int]:
    """``(kept rows, tasks to fit, how many kept outputs have other settings)``: every task's output
    checked before any fit; with ``resuming``, complete earlier outputs kept, incomplete ones replaced.

    Raises:
        pipeline.files.OutputError: an output is refused.
    """
    kept: list[PhotoFileResult] = []
    todo: list[PhotoTask] = []
    other_settings = 0
    seconds = earlier_summary_seconds(out) if resuming else {}
    for task in tasks:
        earlier = earlier_output(task, seconds) if resuming else EarlierOutput("absent")
        if earlier.state == "complete":
            kept.extend(earlier.results)
            other_settings += earlier.other_settings
            continue
        if earlier.state == "incomplete":
            check_output(task.out, force=True, inputs=inputs)
            task = replace(task, force=True)
        else:
            check_output(task.out, force=force, inputs=inputs)
        todo.append(task)
    return kept, todo, other_settings


def _fit_all(todo: list[PhotoTask], run, results: list[PhotoFileResult], out: Path, created: bool) -> None:
    """Fit ``todo`` through ``run``, adding each task's rows to ``results`` as it finishes; an ``out`` this
    call created is removed again when nothing could be written into it (also on an interrupt)."""
    finished = None
    try:
        if todo:
            finished = iter(run(todo))
            for task_results in finished:
                results.extend(task_results)
    finally:
        getattr(finished, "close", lambda: None)()  # a generator's clean-up runs now, not when collected
        if created and not any(r.summary for r in results):
            _remove_if_nothing_finished(out)


def _remove_if_nothing_finished(out: Path) -> None:
    """Remove the ``out`` this run created when nothing finished in it: only the shared three.js file and
    hidden temporaries may be there. An output a worker finished but the run had not yet collected (Ctrl-C
    just after it was moved into place) keeps the folder and everything in it."""
    try:
        entries = [e.name for e in os.scandir(out)]
    except OSError:
        return
    if any(name != SHARED_THREE_FILE and not name.startswith(".") for name in entries):
        _log.info("kept %s: it holds outputs that finished (%s)", out, ", ".join(sorted(entries)[:5]))
        return
    shutil.rmtree(out, ignore_errors=True)


def fit_photo_files(
    photos: Sequence[str | Path],
    out: str | Path,
    *,
    folders: Sequence[str | Path] = (),
    config=None,
    landmarks: str | None = None,
    focal: float | None = None,
    force: bool = False,
    resume: bool = True,
    command: str = "jnr fit",
    rig=None,
    neural=None,
    progress: Callable[[str, int, int], None] | None = None,
    run: Callable[[list[PhotoTask]], Iterable[tuple[PhotoFileResult, ...]]] | None = None,
    detector: str = DEFAULT_DETECTOR,
    face: str | None = None,
) -> list[PhotoFileResult]:
    """Fit several photo files, each into ``out/<name>/`` (:func:`output_names`), and list them in
    ``out/summary.csv`` (:mod:`pipeline.photo.summary`).

    The output folder is created if missing and every ``out/<name>`` and ``out/summary.csv`` is checked
    before any fit; a photo that fails is reported in its :class:`PhotoFileResult` (a row of the summary
    with status ``error``) and the others go on. The summary is written atomically when the photos are
    done, also when some failed; when no photo could be written, an ``out`` this call created is removed
    again instead (also on an interrupt).

    Resuming (``resume``, without ``force``): an output an earlier run completed is kept, not fitted
    again, and its rows are rebuilt from its report.json (:func:`~pipeline.photo.resume.earlier_output`;
    ``kept`` = yes in the
    summary; a warning when its settings differ from this call's); a photo whose fit failed has no output
    and is fitted again; an incomplete jnr output folder is fitted again and replaced; the hidden
    temporaries a killed run left are removed first (:func:`~pipeline.photo.batch_folder.remove_leftovers`);
    the summary.csv of an
    earlier run (jnr's own) is replaced by this run's. What jnr did not write is refused as without
    ``resume``. ``force`` fits every photo again and replaces its output (only jnr's). While it runs,
    the call holds a lock on ``out``: a second call into the same ``out`` is refused.

    Args:
        photos: the image files (e.g. from :func:`~pipeline.photo.inputs.photo_inputs`); folders: the
            folders they were found
            in (the outputs must not be, contain or lie in any of them, nor in a photo).
        config, focal, force, command: as :func:`~pipeline.photo.photo_file.fit_photo_file`, for every photo.
        resume: keep complete outputs of an earlier run (above); False: an existing output or
            summary.csv is refused without ``force``.
        landmarks: None (detect) or ``"auto"`` (the file beside each photo,
            :func:`~pipeline.photo.inputs.sidecar_landmarks`).
        detector: as :func:`~pipeline.photo.photo_file.fit_photo_file`.
        face: None (the largest face of each photo) or :data:`~pipeline.photo.detection.FACE_ALL`: every
            face of each photo, into ``out/<name>/face_<k>/``
            (:func:`~pipeline.photo.photo_file.fit_photo_faces`; each ``out/<name>/`` also has its own
            summary.csv), a summary row per face.
        rig, neural: the models, shared by all photos (default runner only; default: loaded per photo).
        progress: ``progress("photos", done, total)`` after each photo fitted (default runner only;
            ``total``: the photos to fit, without the kept ones).
        run: how the tasks are fitted: ``run(tasks)`` yields, per task as each finishes and in any order,
            the tuple of its results (e.g. from a process pool whose workers call
            :func:`~pipeline.photo.task.fit_photo_task`, or :class:`pipeline.photo.dask_runner.DaskRunner`);
            default: one
            after another in this process. Not called when every output is kept.

    Returns:
        One :class:`~pipeline.photo.summary.PhotoFileResult` per photo (per face with ``face="all"``), in
        the order of ``photos``
        (then of the faces); kept ones with ``kept=True``.

    Raises:
        InputError: ``landmarks`` is a file, or ``landmarks`` with ``face="all"``, an unknown ``detector``;
            :class:`~pipeline.files.OutputError`: an output is refused, or another call holds ``out``.
    """
    _check_options(landmarks, face, detector)
    out = Path(out)
    inputs = tuple(str(p) for p in (*photos, *folders))
    names = output_names(photos, reserved=(SUMMARY_FILE, SHARED_THREE_FILE))
    tasks = [
        PhotoTask(str(p), str(out / n), config, landmarks, focal, force, command, inputs, detector, face)
        for p, n in zip(photos, names)
    ]
    created = make_output_folder(out, inputs=inputs)
    lock = None
    try:
        lock = lock_folder(out)
        if lock is not None:  # no other jnr fit writes here: what looks staged was left by a killed run
            remove_leftovers(out, names, files=(SUMMARY_FILE, SHARED_THREE_FILE))
        kept, todo, other_settings = _plan(tasks, out, resuming=resume and not force, force=force, inputs=inputs)
        check_summary(out / SUMMARY_FILE, force or resume, inputs)
        todo = _share_three(todo, out, config)
    except OutputError:
        unlock(lock)
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    if kept:
        _log.info(
            "kept %d output(s) of an earlier run in %s (--force fits them again)", len({r.photo for r in kept}), out
        )
    if other_settings:
        warnings.warn(
            f"kept {other_settings} earlier output(s) in {out} fitted with other settings "
            "(configuration, landmarks, detector or focal); --force fits them again",
            stacklevel=2,
        )
    order = {t.photo: i for i, t in reversed(list(enumerate(tasks)))}
    results: list[PhotoFileResult] = list(kept)
    try:
        try:
            _fit_all(todo, run or _sequential(rig, neural, progress), results, out, created)
        except BaseException:
            # stopped (Ctrl-C, SIGTERM, a failure outside any one photo): the summary still says which photos
            # were fitted and which were not, then the stop goes on (issue 38: a stopped run wrote none)
            done = {r.photo for r in results}
            results.extend(
                PhotoFileResult(t.photo, error=f"{t.photo}: not fitted: the run was stopped first")
                for t in todo
                if t.photo not in done
            )
            _write_summary_of(results, order, out, force or resume, inputs, stopping=True)
            raise
        _write_summary_of(results, order, out, force or resume, inputs)
    finally:
        unlock(lock)
    return results


def _write_summary_of(results, order, out: Path, force: bool, inputs, stopping: bool = False) -> None:
    """``out/summary.csv`` of ``results`` in the photos' order; while stopping, only where the folder is still
    there and only as well as it goes (the stop, not a failure of the summary, is what is reported)."""
    results.sort(key=lambda r: (order[r.photo], -1 if r.face is None else r.face))
    if not out.is_dir():
        return
    try:
        write_summary(out / SUMMARY_FILE, results, force=force, inputs=inputs)
    except (OSError, InputError):
        if not stopping:
            raise
        _log.warning("the stopped run's summary could not be written in %s", out)


__all__ = ["fit_photo_files", "output_names"]
