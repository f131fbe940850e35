"""Photo files in, output folders out: what ``jnr fit PHOTO...`` does, as library functions.

* :func:`photo_inputs` turns file and folder names into the photos to fit (:data:`IMAGE_SUFFIXES`).
* :func:`fit_photo_file` fits one photo file: reads (or detects) its landmarks, checks everything that
  can be checked cheaply before the fit, runs :func:`pipeline.photo.fit.fit_photo` and writes its
  output folder (:func:`pipeline.photo.outputs.write_photo_outputs`).
* :func:`fit_photo_faces` fits every face the detector finds in one photo file into
  ``OUT/face_<k>/`` folders (``jnr fit --face all``), with ``OUT/summary.csv`` listing the faces.
* :func:`fit_photo_files` fits several into ``OUT/<name>/`` folders, one after another or through a
  caller's ``run`` (the command line's process pool or a Dask cluster,
  :mod:`pipeline.photo.dask_runner`), reporting each photo's failure instead of stopping
  (:class:`PhotoFileResult`), and lists them all in ``OUT/summary.csv`` (:func:`summary_csv`). It
  resumes: an output folder an earlier run completed is kept and its row rebuilt from its
  ``report.json`` (:func:`earlier_output`); leftovers of a killed run are removed
  (:func:`remove_leftovers`).

Example:
    >>> summary = fit_photo_file("face.png", "out/face", landmarks="face.pts")  # doctest: +SKIP
    >>> summary["mean_error_px"]  # doctest: +SKIP
    1.27
"""

from __future__ import annotations

import csv
import errno
import io
import json
import logging
import os
import re
import shutil
import time
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from rig.errors import InputError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".gif", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pnm")
"""What ``jnr fit`` reads as photos, named directly or found in a folder (the same rule for both)."""
LANDMARK_SUFFIXES = (".pts", ".json", ".csv")
"""The landmark files ``landmarks="auto"`` looks for beside a photo, in this order."""
FACE_ALL = "all"
"""``face=FACE_ALL`` (``jnr fit --face all``): fit every detected face, each into ``face_<k>/``, k in the
detector's order (largest first, as ``--face N`` numbers them)."""
SUMMARY_FILE = "summary.csv"
"""The table of a run over several photos or faces, one row per photo (per face with ``--face all``)."""
SUMMARY_COLUMNS = ("photo", "face", "status", "error", "output", "mean_error_px", "nme", "seconds", "faces_found",
                   "box_left", "box_top", "box_right", "box_bottom", "face_score", "kept")
"""The columns of :data:`SUMMARY_FILE`: the photo file; the face index (empty: landmarks from a file, or the
photo failed before a face was picked); ``ok`` or ``error`` and the one-line error; the output folder
(empty on an error: nothing was written); the landmark error in the photo's pixels and the NME by the
outer eye corners (as in the fit's ``report.json``); the seconds spent on the photo (with ``--face all``,
on that face: its fit and outputs; the detection, once per photo, is in ``report.json``); how many faces
the detector found (0: none; empty: not detected, e.g. an unreadable file or a landmarks file); the face's
box in the photo's pixels and the detector's score; ``yes`` when the row is an earlier run's output that
was kept (resumed: not fitted again, its numbers read back from its ``report.json``; ``seconds`` is then
the time its fit took when it was made), ``no`` when it was fitted (or failed) in this run."""
_EARLIER_SUMMARY_COLUMNS = (SUMMARY_COLUMNS[:-1],)
"""The headers of the summaries earlier jnr versions wrote (before the ``kept`` column): still jnr's own."""
_log = logging.getLogger(__name__)


def photo_inputs(items: Iterable[str | Path]) -> tuple[list[Path], list[Path]]:
    """``(photos, folders)``: image files named directly, or found (non-recursively, sorted) in named
    folders; a file is a photo when its suffix is one of :data:`IMAGE_SUFFIXES`.

    Raises:
        InputError: a name that is neither a photo nor a folder, or a folder without photos.
    """
    photos: list[Path] = []
    folders: list[Path] = []
    supported = ", ".join(IMAGE_SUFFIXES)
    for item in items:
        path = Path(item)
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(f"folder {path} holds no images ({supported})")
            photos.extend(found)
            folders.append(path)
        elif path.is_file():
            if path.suffix.lower() not in IMAGE_SUFFIXES:
                raise InputError(f"{path} is not a photo jnr reads (the file name must end in one of {supported})")
            photos.append(path)
        else:
            raise InputError(f"image file not found: {path}")
    return photos, folders


def sidecar_landmarks(photo: str | Path) -> Path:
    """The landmarks file beside ``photo`` with the same name (``face.png`` -> ``face.pts``, ``.json`` or
    ``.csv``, :data:`LANDMARK_SUFFIXES`), as the iBUG 300-W sets ship them.

    Raises:
        InputError: there is none.
    """
    photo = Path(photo)
    for suffix in LANDMARK_SUFFIXES:
        candidate = photo.with_suffix(suffix)
        if candidate.is_file():
            return candidate
    raise InputError(f"--landmarks auto: no {'/'.join(LANDMARK_SUFFIXES)} file beside {photo}")


@dataclass(frozen=True)
class _Detected:
    """Every face found in a photo (largest first) and report.json's list of them (box in the photo's
    pixels, score, detector)."""

    faces: list
    listed: list[dict]
    detector_option: str
    seconds: float

    def source(self, index: int):
        """``(landmarks (68, 2) in the working image's pixels, report.json's description of their source)``
        of face ``index``."""
        chosen = self.faces[index]
        return chosen.landmarks, {"landmarks": "dlib 68-point detector", "detector": chosen.detector,
                                  "detector_option": self.detector_option,
                                  "detection_seconds": round(self.seconds, 3), "face_box": self.listed[index]["box"],
                                  "face_score": chosen.score, "face_index": index, "faces": self.listed}


def _detect(photo, detector: str) -> _Detected:
    """Every face in the working image; :class:`~landmarks.detect.NoFaceError` when there is none."""
    from landmarks.detect import NoFaceError, detect_faces

    t0 = time.perf_counter()
    faces = detect_faces(photo.image, detector=detector)
    seconds = time.perf_counter() - t0
    if not faces:
        tried = "HOG and CNN detectors" if detector == "auto" else f"{detector.upper()} detector"
        raise NoFaceError(f"no face found in the image (dlib's {tried}); pass --landmarks FILE to give the "
                          "68 landmarks yourself")
    listed = [{"box": photo.to_original(f.box.reshape(2, 2)).reshape(-1).tolist(), "score": f.score,
               "detector": f.detector} for f in faces]
    return _Detected(faces, listed, detector, seconds)


def _photo_landmarks(photo, landmarks_path: Path | None, face: int | None, detector: str = "auto"):
    """``(landmarks (68, 2) in the working image's pixels, report.json's description of their source)``:
    with detection, every face found (box in the photo's pixels, score, detector) and the one fitted."""
    from landmarks.detect import DetectionError
    from landmarks.formats import read_landmarks
    from landmarks.plausibility import check_landmarks_2d

    width, height = photo.original_size
    if landmarks_path:
        points = read_landmarks(landmarks_path)
        check_landmarks_2d(points, width, height, source=str(landmarks_path))
        return photo.to_working(points), {"landmarks": os.path.abspath(landmarks_path)}
    detected = _detect(photo, detector)
    index = 0 if face is None else int(face)
    if not 0 <= index < len(detected.faces):
        n = len(detected.faces)
        raise DetectionError(f"found {n} {'face' if n == 1 else 'faces'}; --face must be 0..{n - 1}, got {index}")
    return detected.source(index)


def _check_face(face) -> None:
    if face is None or face == FACE_ALL:
        return
    if isinstance(face, bool) or not isinstance(face, int):
        raise InputError(f"--face must be a face number (0 = the largest) or '{FACE_ALL}', got {face!r}")


def _name_photo(exc: InputError, photo_path: Path) -> InputError:
    """A detection error that names the photo (the other InputErrors name their file or option), of the
    same class (so that :class:`~landmarks.detect.NoFaceError` stays one)."""
    message = str(exc)
    return type(exc)(message if str(photo_path) in message else f"{photo_path}: {message}")


def _fit_and_write(photo_path: Path, photo, points, source: dict, out: Path, *, label: str, config, focal, force,
                   progress, rig, neural, command: str, inputs: list) -> dict:
    """Fit ``points`` on the loaded photo and write ``out``: :func:`fit_photo_file`'s summary, less the
    detection fields; errors name ``label`` (the photo, or the photo and the face)."""
    from pipeline.photo.fit import fit_photo
    from pipeline.photo.outputs import write_photo_outputs

    t0 = time.perf_counter()
    width, height = photo.original_size
    k = photo.factor
    try:
        fit = fit_photo(photo.image, points, focal=None if focal is None else focal / k, config=config,
                        rig=rig, neural=neural, progress=progress)
    except FloatingPointError as exc:  # a diverged fit
        raise FloatingPointError(f"{label}: {exc}") from None
    except ValueError as exc:  # bad image or landmarks for the fit (InputError and plain ValueError)
        raise InputError(f"{label}: {exc}") from None
    extra = {"input": {"photo": os.path.abspath(photo_path), "width": width, "height": height,
                       "fitted_width": fit.width, "fitted_height": fit.height, "reduction": k,
                       "focal_px": fit.focal * k, "focal_source": "--focal" if focal else "default 1.4 * max(W, H)",
                       **source},
             "command": command}
    write_photo_outputs(out, photo.image, fit, config=config, force=force, extra=extra, inputs=inputs,
                        image_factor=k, original_size=photo.original_size, rig=rig, neural=neural)
    return {"photo": str(photo_path), "output": str(out), "mean_error_px": float(fit.error_px.mean()) * k,
            "nme": float(fit.nme), "seconds": time.perf_counter() - t0, "fit_seconds": fit.timings["total"],
            "face": source.get("face_index"), "faces_found": len(source["faces"]) if "faces" in source else None,
            "face_box": source.get("face_box"), "face_score": source.get("face_score")}


def fit_photo_file(photo_path: str | Path, out: str | Path, *, config=None, landmarks: str | Path | None = None,
                   face: int | None = None, focal: float | None = None, force: bool = False,
                   progress: Callable[[str, int, int], None] | None = None, rig=None, neural=None,
                   command: str = "jnr fit", inputs: Iterable[str | Path] = (), detector: str = "auto") -> dict:
    """Detect (or read) the landmarks of one photo file, fit it and write its output folder.

    Everything that can be checked cheaply is checked before the fit: the output path (not an input,
    not the working directory, writable; an existing one only with ``force`` and only if jnr wrote
    it), the image (readable, at most :data:`landmarks.detect.MAX_IMAGE_PIXELS`), ``focal`` (within
    :data:`pipeline.photo.camera.FOCAL_RANGE` times the longer side), the landmarks (a readable file
    with 68 points, in or near the image, a face-like and not mirrored configuration). Photos longer
    than :data:`landmarks.detect.WORKING_MAX_SIDE` are fitted reduced by a power of two; the outputs
    give the camera and landmarks in the photo's own pixels.

    Args:
        photo_path: the image file.
        out: the output folder (:mod:`pipeline.photo.outputs` lists its files).
        config: :class:`pipeline.photo.fit.FitPhotoConfig` (default: its defaults).
        landmarks: a file of 68 landmarks (``.pts`` 1-based, ``.json``, ``.csv``; pixels of the photo
            file), ``"auto"`` for the one beside the photo (:func:`sidecar_landmarks`), or None to
            detect them (dlib).
        face: which detected face, 0 = the largest (default 0); not with ``landmarks``. For every face,
            see :func:`fit_photo_faces`.
        detector: dlib's face detector, one of :data:`landmarks.detect.DETECTORS` (default ``"auto"``:
            HOG, and the slower CNN only when HOG finds no face).
        focal: the focal length in pixels of the photo file (default: 1.4 x its longer side).
        force: replace an existing output folder (only one jnr wrote).
        progress: ``progress(stage, iteration, iterations)`` during the fit.
        rig, neural: the models to fit with, also used for the outputs (default: the committed rig and
            learned skinning; see :func:`pipeline.photo.fit.fit_photo`).
        command: recorded in ``report.json`` and the output's marker.
        inputs: more input paths the output must not be, contain or lie in (e.g. the photo's folder).

    Returns:
        ``{"photo", "output"`` (str paths), ``"mean_error_px"`` (landmark error in the photo file's
        pixels), ``"nme"`` (over the outer-eye-corner distance), ``"seconds"`` (this call),
        ``"fit_seconds"`` (the fit), ``"face"`` (the index of the detected face fitted),
        ``"faces_found"`` (how many the detector found), ``"face_box"`` (``[left, top, right, bottom]``,
        the photo's pixels), ``"face_score"`` (the last four None with a landmarks file)``}``.

    Raises:
        InputError: any of the above, or an image or landmarks the fit rejects (nothing written);
            :class:`~pipeline.files.OutputError` for the output folder.
        FloatingPointError: the fit diverged (the message names the photo).
    """
    from landmarks.detect import DetectionError, load_working_image
    from pipeline.files import check_output
    from pipeline.photo.camera import check_focal
    from pipeline.photo.fit import FitPhotoConfig

    t0 = time.perf_counter()
    photo_path, out = Path(photo_path), Path(out)
    _check_face(face)
    if face is not None and landmarks:
        raise InputError("--face picks one of the faces the detector finds; it cannot be used with --landmarks")
    if face == FACE_ALL:
        raise InputError(f"fit_photo_file fits one face; fit_photo_faces fits them all (face={FACE_ALL!r})")
    landmarks_path = sidecar_landmarks(photo_path) if landmarks == "auto" else (Path(landmarks) if landmarks else None)
    all_inputs = [photo_path, *([landmarks_path] if landmarks_path else []), *inputs]
    config = config or FitPhotoConfig()
    try:
        check_output(out, force=force, inputs=all_inputs)
        photo = load_working_image(photo_path)
        width, height = photo.original_size
        if focal is not None:
            check_focal(focal, width, height)
        points, source = _photo_landmarks(photo, landmarks_path, face, detector)
    except DetectionError as exc:
        raise _name_photo(exc, photo_path) from None
    summary = _fit_and_write(photo_path, photo, points, source, out, label=str(photo_path), config=config,
                             focal=focal, force=force, progress=progress, rig=rig, neural=neural, command=command,
                             inputs=all_inputs)
    return {**summary, "seconds": time.perf_counter() - t0}


def fit_photo_faces(photo_path: str | Path, out: str | Path, *, config=None, focal: float | None = None,
                    force: bool = False, progress: Callable[[str, int, int], None] | None = None, rig=None,
                    neural=None, command: str = "jnr fit", inputs: Iterable[str | Path] = (),
                    detector: str = "auto") -> list[PhotoFileResult]:
    """Detect every face in one photo file and fit each into ``out/face_<k>/`` (``jnr fit --face all``).

    ``k`` numbers the faces as ``face=k`` of :func:`fit_photo_file` does (largest first); each
    ``face_<k>/`` holds the complete output set of a fit (its ``report.json`` lists every face found and
    gives its own ``face_index``), and ``out/summary.csv`` (:func:`summary_csv`) has one row per face. The
    faces are fitted one after another; ``out`` is written as one folder, atomically (staged beside it and
    moved into place at the end), with the faces that could be fitted: a face whose fit fails is a row
    with status ``error``, the others are kept. The checks of :func:`fit_photo_file` come first.

    Args:
        photo_path, out, config, focal, force, progress, rig, neural, command, inputs, detector: as
            :func:`fit_photo_file` (``progress`` runs through each face's fit in turn).

    Returns:
        One :class:`PhotoFileResult` per face, in the detector's order (``face`` = k, ``faces_found``).

    Raises:
        InputError: as :func:`fit_photo_file` (an unreadable photo, no face found:
            :class:`~landmarks.detect.NoFaceError`, a refused output), or every face's fit failed (the
            first face's error; nothing written); FloatingPointError: every fit diverged.
    """
    from landmarks.detect import DetectionError, load_working_image
    from pipeline.files import check_output, staged_folder
    from pipeline.photo.camera import check_focal
    from pipeline.photo.fit import FitPhotoConfig

    photo_path, out = Path(photo_path), Path(out)
    all_inputs = [photo_path, *inputs]
    config = config or FitPhotoConfig()
    try:
        check_output(out, force=force, inputs=all_inputs)
        photo = load_working_image(photo_path)
        if focal is not None:
            check_focal(focal, *photo.original_size)
        detected = _detect(photo, detector)
    except DetectionError as exc:
        raise _name_photo(exc, photo_path) from None
    found = len(detected.faces)
    results: list[PhotoFileResult] = []
    first_failure: BaseException | None = None
    with staged_folder(out, force, inputs=all_inputs, marker={"command": command}) as staged:
        for k in range(found):
            t0 = time.perf_counter()
            points, source = detected.source(k)
            box, score = tuple(source["face_box"]), float(source["face_score"])
            try:
                summary = _fit_and_write(photo_path, photo, points, source, staged / f"face_{k}",
                                         label=f"{photo_path} (face {k})", config=config, focal=focal, force=False,
                                         progress=progress, rig=rig, neural=neural, command=command,
                                         inputs=all_inputs)
            except (InputError, FloatingPointError) as exc:
                if first_failure is None:
                    first_failure = exc
                results.append(PhotoFileResult(str(photo_path), error=str(exc), bad_input=isinstance(exc, InputError),
                                               face=k, faces_found=found, seconds=time.perf_counter() - t0,
                                               face_box=box, face_score=score))
                continue
            summary["output"] = str(out / f"face_{k}")
            results.append(PhotoFileResult(str(photo_path), summary, face=k, faces_found=found,
                                           seconds=summary["seconds"], face_box=box, face_score=score))
        if first_failure is not None and not any(r.summary for r in results):
            raise first_failure
        (staged / SUMMARY_FILE).write_text(summary_csv(results), encoding="utf-8")
    return results


# ------------------------------------------------------------------------------------------ several


@dataclass(frozen=True)
class PhotoTask:
    """One photo of :func:`fit_photo_files` (picklable: a worker process gets it whole); the fields are
    :func:`fit_photo_file`'s arguments, paths as str."""

    photo: str
    out: str
    config: object = None
    landmarks: str | None = None
    focal: float | None = None
    force: bool = False
    command: str = "jnr fit"
    inputs: tuple[str, ...] = ()
    detector: str = "auto"
    face: str | None = None
    """None: the largest face (or the landmarks file); :data:`FACE_ALL`: every face (:func:`fit_photo_faces`)."""


@dataclass(frozen=True)
class PhotoFileResult:
    """What became of one photo, or of one face of a photo with ``face="all"``: a row of
    :data:`SUMMARY_FILE`.

    Attributes:
        photo: the photo file. summary: :func:`fit_photo_file`'s summary, None when it failed.
        error: the one-line message when it failed. bad_input: whether the input is to blame (an
            :class:`~rig.errors.InputError`) rather than a failure of the fit or the machine.
        face: the index of the detected face (None: landmarks from a file, or the photo failed before a
            face was picked). faces_found: how many faces the detector found (0: none; None: not known).
        seconds: the time spent on it. face_box: ``(left, top, right, bottom)`` in the photo's pixels, and
            face_score: the detector's score, of the face (None when not detected).
        kept: the output was written by an earlier run and kept (:func:`earlier_output`), not fitted now.
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


def summary_csv(results: Iterable[PhotoFileResult]) -> str:
    """The text of :data:`SUMMARY_FILE`: a header of :data:`SUMMARY_COLUMNS` and one row per result (empty
    cells for what is not known; pixels with 3 decimals, NME with 5, seconds with 2)."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(SUMMARY_COLUMNS)
    for r in results:
        fitted = r.summary or {}
        box = r.face_box or ("",) * 4
        writer.writerow([r.photo, "" if r.face is None else r.face, "error" if r.error else "ok", r.error or "",
                         r.output or "", _number(fitted.get("mean_error_px"), 3), _number(fitted.get("nme"), 5),
                         _number(r.seconds, 2), "" if r.faces_found is None else r.faces_found,
                         *(b if b == "" else _number(b, 1) for b in box), _number(r.face_score, 4),
                         "yes" if r.kept else "no"])
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
    return list(csv.DictReader(io.StringIO(text, newline="")))


def _check_summary(path: Path, force: bool, inputs) -> None:
    """Before any fit: ``path`` may be written (a summary.csv that exists only with ``force``, and only
    one jnr wrote: it starts with the header of :data:`SUMMARY_COLUMNS`, or an earlier version's)."""
    from pipeline.files import OutputError, check_output

    check_output(path, force=force, inputs=inputs, kind="file")
    if path.is_file():
        try:
            with open(path, newline="", encoding="utf-8") as handle:
                header = handle.readline().strip()
        except (OSError, UnicodeDecodeError):
            header = ""
        if not _jnr_header(header):
            raise OutputError(f"--out {path} is not a summary jnr wrote (its first line is not jnr's header); "
                              "--force replaces only jnr's own outputs: remove it yourself or choose another --out")


def write_summary(path: str | Path, results: Iterable[PhotoFileResult], *, force: bool = False,
                  inputs: Iterable[str | Path] = ()) -> Path:
    """Write :func:`summary_csv` of ``results`` to ``path`` atomically (:func:`pipeline.files.staged_file`,
    on :mod:`rig.io.atomic`); an existing file only with ``force`` and only if jnr wrote it.

    Raises:
        pipeline.files.OutputError: ``path`` is refused or cannot be written (nothing is left behind).
    """
    from pipeline.files import staged_file

    path = Path(path)
    _check_summary(path, force, inputs)
    with staged_file(path, force, inputs=inputs) as tmp:
        tmp.write_text(summary_csv(results), encoding="utf-8")
    return path


def fit_photo_task(task: PhotoTask, *, rig=None, neural=None,
                   progress: Callable[[str, int, int], None] | None = None) -> tuple[PhotoFileResult, ...]:
    """Fit one task with :func:`fit_photo_file` (or :func:`fit_photo_faces` for ``face="all"``), returning
    its failure (one line) instead of raising it (what a worker process of :func:`fit_photo_files` runs):
    one :class:`PhotoFileResult`, or one per face. Interrupts and signals still raise."""
    from landmarks.detect import NoFaceError

    t0 = time.perf_counter()
    common = dict(config=task.config, focal=task.focal, force=task.force, command=task.command, inputs=task.inputs,
                  rig=rig, neural=neural, progress=progress, detector=task.detector)
    try:
        if task.face == FACE_ALL:
            return tuple(fit_photo_faces(task.photo, task.out, **common))
        summary = fit_photo_file(task.photo, task.out, landmarks=task.landmarks, **common)
        box = summary["face_box"]
        return (PhotoFileResult(task.photo, summary, face=summary["face"], faces_found=summary["faces_found"],
                                seconds=summary["seconds"], face_box=None if box is None else tuple(box),
                                face_score=summary["face_score"]),)
    except InputError as exc:
        return (PhotoFileResult(task.photo, error=str(exc), bad_input=True, seconds=time.perf_counter() - t0,
                                faces_found=0 if isinstance(exc, NoFaceError) else None),)
    except FloatingPointError as exc:  # a diverged fit; the message names the photo
        return (PhotoFileResult(task.photo, error=str(exc), seconds=time.perf_counter() - t0),)
    except Exception as exc:  # noqa: BLE001 - reported per photo; the batch goes on
        return (PhotoFileResult(task.photo, error=f"{task.photo}: {type(exc).__name__}: {exc}",
                                seconds=time.perf_counter() - t0),)


def output_names(photos: Sequence[str | Path]) -> list[str]:
    """The output folder name of each photo: its stem, or ``<stem>_<index>`` for stems that repeat."""
    stems = [Path(p).stem for p in photos]
    return [s if stems.count(s) == 1 else f"{s}_{i}" for i, s in enumerate(stems)]


def _sequential(rig, neural, progress):
    def run(tasks: list[PhotoTask]) -> Iterable[tuple[PhotoFileResult, ...]]:
        for i, task in enumerate(tasks):
            yield fit_photo_task(task, rig=rig, neural=neural)
            if progress is not None:
                progress("photos", i + 1, len(tasks))
    return run


# ------------------------------------------------------------------------------------------ resuming

_RANDOM = "[a-z0-9_]{8}"
"""The random part :mod:`tempfile` puts into the names of :mod:`rig.io.atomic`'s temporaries."""


def remove_leftovers(out: str | Path, folders: Iterable[str], files: Iterable[str] = (SUMMARY_FILE,)) -> list[Path]:
    """Remove what a killed run left in the batch folder ``out``: the hidden temporaries of
    :mod:`rig.io.atomic` for the output folders named ``folders`` (``.<name>.<random>.tmp``, and
    ``.<name>.old.<random>`` where ``renameat2`` is missing) and for the files named ``files``
    (``.<stem>.<random>.tmp<suffix>``). Nothing else is touched (a symbolic link with such a name
    neither). Call it only while no other process writes these outputs (:func:`fit_photo_files` holds
    the folder's lock).

    Returns:
        The paths removed.
    """
    out = Path(out)
    patterns = [(re.compile(rf"\.{re.escape(n)}\.(?:{_RANDOM}\.tmp|old\.{_RANDOM})"), True) for n in folders]
    patterns += [(re.compile(rf"\.{re.escape(Path(n).stem)}\.{_RANDOM}\.tmp{re.escape(Path(n).suffix)}"), False)
                 for n in files]
    removed = []
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


def _lock_folder(out: Path) -> int | None:
    """Take an exclusive lock on the batch folder ``out`` (``flock`` on the folder itself: no file is
    added); returns the descriptor that holds it (:func:`_unlock`), or None where the file system has no
    locks.

    Raises:
        pipeline.files.OutputError: another process holds it (a second ``jnr fit`` into ``out``).
    """
    from pipeline.files import OutputError

    try:
        import fcntl

        fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY)
    except (ImportError, OSError):
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise OutputError(f"another jnr fit is writing into --out {out} now (it holds the folder's lock); "
                              "wait for it to end or choose another --out") from None
        return None
    return fd


def _unlock(fd: int | None) -> None:
    if fd is not None:
        os.close(fd)


@dataclass(frozen=True)
class EarlierOutput:
    """What an earlier run left at a task's output folder (:func:`earlier_output`).

    Attributes:
        state: ``"absent"`` (nothing there), ``"complete"`` (kept: ``results`` are its summary rows,
            rebuilt from its report.json) or ``"incomplete"`` (a jnr output folder with files missing or
            an unreadable report.json: fitted again and replaced).
        results: the kept rows (:attr:`PhotoFileResult.kept`), for ``"complete"``.
        other_settings: a kept fit was made with other settings (configuration, landmarks source,
            detector or focal) than the task's.
    """

    state: str
    results: tuple[PhotoFileResult, ...] = ()
    other_settings: bool = False


def _read_report(folder: Path) -> dict | None:
    """The report.json of a complete single-face output folder (every file of
    :data:`pipeline.photo.outputs.OUTPUT_FILES`, a report with jnr's landmark errors and input photo), or
    None."""
    from pipeline.photo.outputs import OUTPUT_FILES

    if not all((folder / name).is_file() for name in OUTPUT_FILES):
        return None
    try:
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
        landmarks, photo = report["landmarks"], report["input"]["photo"]
        float(landmarks["mean_error_px"]), float(landmarks["nme_inter_ocular"])
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError):
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
    import math

    from pipeline.config import config_to_dict
    from pipeline.files import json_safe
    from pipeline.photo.fit import FitPhotoConfig

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
    summary = {"photo": task.photo, "output": output, "mean_error_px": _float(landmarks["mean_error_px"]),
               "nme": _float(landmarks["nme_inter_ocular"]), "seconds": seconds,
               "fit_seconds": _float((report.get("timings_s") or {}).get("total")), "face": source.get("face_index"),
               "faces_found": len(faces) if isinstance(faces, list) else None, "face_box": box,
               "face_score": source.get("face_score")}
    return PhotoFileResult(task.photo, summary, face=summary["face"], faces_found=summary["faces_found"],
                           seconds=seconds, face_box=tuple(box) if isinstance(box, list) else None,
                           face_score=summary["face_score"], kept=True)


def _other_photo(out: Path, what: str) -> Exception:
    from pipeline.files import OutputError

    return OutputError(f"--out {out} holds an earlier fit of {what}; pass --force to fit it again or choose "
                       "another --out")


def earlier_output(task: PhotoTask, earlier_seconds: dict[tuple[str, str], float | None] | None = None
                   ) -> EarlierOutput:
    """What an earlier run left at ``task.out``, to resume a batch (:func:`fit_photo_files`).

    Complete means: a folder jnr wrote holding every file of :data:`pipeline.photo.outputs.OUTPUT_FILES`
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
    from pipeline.files import check_output, is_jnr_output

    out = Path(task.out)
    if not (out.exists() or out.is_symlink()):
        return EarlierOutput("absent")
    if out.is_symlink() or not out.is_dir() or not is_jnr_output(out):
        check_output(out, force=True, inputs=task.inputs)  # raises the message for what is there
        raise _other_photo(out, "something else")  # pragma: no cover - check_output refuses all of these
    if task.face == FACE_ALL:
        return _earlier_faces(task, out)
    report = _read_report(out)
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
        if _read_report(out) is not None:
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
            results.append(PhotoFileResult(task.photo, error=row.get("error") or "failed", bad_input=True, face=face,
                                           faces_found=found, seconds=seconds,
                                           face_box=None if None in box else box,
                                           face_score=_float(row.get("face_score")), kept=True))
            continue
        report = None if face is None else _read_report(out / f"face_{face}")
        if report is None or (report.get("input") or {}).get("face_index") != face:
            return EarlierOutput("incomplete")
        results.append(_kept_row(task, str(Path(task.out) / f"face_{face}"), report, seconds))
        differ = differ or _settings_differ(task, report)
    if not any(r.summary for r in results):
        return EarlierOutput("incomplete")
    return EarlierOutput("complete", tuple(results), differ)


def _earlier_seconds(out: Path) -> dict[tuple[str, str], float | None]:
    """``{(photo file name, output folder name): seconds}`` of the fitted rows of the batch's earlier
    summary.csv (:func:`earlier_output`)."""
    rows = read_summary(out / SUMMARY_FILE) or []
    return {(Path(r["photo"]).name, Path(r["output"]).name): _float(r.get("seconds"))
            for r in rows if r.get("status") == "ok" and r.get("photo") and r.get("output")}


def fit_photo_files(photos: Sequence[str | Path], out: str | Path, *, folders: Sequence[str | Path] = (),
                    config=None, landmarks: str | None = None, focal: float | None = None, force: bool = False,
                    resume: bool = True, command: str = "jnr fit", rig=None, neural=None,
                    progress: Callable[[str, int, int], None] | None = None,
                    run: Callable[[list[PhotoTask]], Iterable[tuple[PhotoFileResult, ...]]] | None = None,
                    detector: str = "auto", face: str | None = None) -> list[PhotoFileResult]:
    """Fit several photo files, each into ``out/<name>/`` (:func:`output_names`), and list them in
    ``out/summary.csv`` (:data:`SUMMARY_FILE`, :func:`summary_csv`).

    The output folder is created if missing and every ``out/<name>`` and ``out/summary.csv`` is checked
    before any fit; a photo that fails is reported in its :class:`PhotoFileResult` (a row of the summary
    with status ``error``) and the others go on. The summary is written atomically when the photos are
    done, also when some failed; when no photo could be written, an ``out`` this call created is removed
    again instead (also on an interrupt).

    Resuming (``resume``, without ``force``): an output an earlier run completed is kept, not fitted
    again, and its rows are rebuilt from its report.json (:func:`earlier_output`; ``kept`` = yes in the
    summary; a warning when its settings differ from this call's); a photo whose fit failed has no output
    and is fitted again; an incomplete jnr output folder is fitted again and replaced; the hidden
    temporaries a killed run left are removed first (:func:`remove_leftovers`); the summary.csv of an
    earlier run (jnr's own) is replaced by this run's. What jnr did not write is refused as without
    ``resume``. ``force`` fits every photo again and replaces its output (only jnr's). While it runs,
    the call holds a lock on ``out``: a second call into the same ``out`` is refused.

    Args:
        photos: the image files (e.g. from :func:`photo_inputs`); folders: the folders they were found
            in (the outputs must not be, contain or lie in any of them, nor in a photo).
        config, focal, force, command: as :func:`fit_photo_file`, for every photo.
        resume: keep complete outputs of an earlier run (above); False: an existing output or
            summary.csv is refused without ``force``.
        landmarks: None (detect) or ``"auto"`` (the file beside each photo, :func:`sidecar_landmarks`).
        detector: as :func:`fit_photo_file`.
        face: None (the largest face of each photo) or :data:`FACE_ALL`: every face of each photo, into
            ``out/<name>/face_<k>/`` (:func:`fit_photo_faces`; each ``out/<name>/`` also has its own
            summary.csv), a summary row per face.
        rig, neural: the models, shared by all photos (default runner only; default: loaded per photo).
        progress: ``progress("photos", done, total)`` after each photo fitted (default runner only;
            ``total``: the photos to fit, without the kept ones).
        run: how the tasks are fitted: ``run(tasks)`` yields, per task as each finishes and in any order,
            the tuple of its results (e.g. from a process pool whose workers call
            :func:`fit_photo_task`, or :class:`pipeline.photo.dask_runner.DaskRunner`); default: one
            after another in this process. Not called when every output is kept.

    Returns:
        One :class:`PhotoFileResult` per photo (per face with ``face="all"``), in the order of ``photos``
        (then of the faces); kept ones with ``kept=True``.

    Raises:
        InputError: ``landmarks`` is a file, or ``landmarks`` with ``face="all"``;
            :class:`~pipeline.files.OutputError`: an output is refused, or another call holds ``out``.
    """
    from pipeline.files import OutputError, check_output, make_output_folder

    if landmarks not in (None, "auto"):
        raise InputError(f"landmarks must be None or 'auto' for several photos, got {landmarks!r}")
    if face not in (None, FACE_ALL):
        raise InputError(f"face must be None or {FACE_ALL!r} for several photos, got {face!r}")
    if face == FACE_ALL and landmarks:
        raise InputError("--face picks among the faces the detector finds; it cannot be used with --landmarks")
    out = Path(out)
    inputs = tuple(str(p) for p in (*photos, *folders))
    names = output_names(photos)
    tasks = [PhotoTask(str(p), str(out / n), config, landmarks, focal, force, command, inputs, detector, face)
             for p, n in zip(photos, names)]
    resuming = resume and not force
    created = make_output_folder(out, inputs=inputs)
    lock = None
    kept: list[PhotoFileResult] = []
    todo: list[PhotoTask] = []
    other_settings = 0
    try:
        lock = _lock_folder(out)
        if lock is not None:  # no other jnr fit writes here: what looks staged was left by a killed run
            remove_leftovers(out, names)
        earlier_seconds = _earlier_seconds(out) if resuming else {}
        for task in tasks:
            earlier = earlier_output(task, earlier_seconds) if resuming else EarlierOutput("absent")
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
        _check_summary(out / SUMMARY_FILE, force or resume, inputs)
    except OutputError:
        _unlock(lock)
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    if kept:
        _log.info("kept %d output(s) of an earlier run in %s (--force fits them again)",
                  len({r.photo for r in kept}), out)
    if other_settings:
        warnings.warn(f"kept {other_settings} earlier output(s) in {out} fitted with other settings "
                      "(configuration, landmarks, detector or focal); --force fits them again", stacklevel=2)
    order = {t.photo: i for i, t in reversed(list(enumerate(tasks)))}
    results: list[PhotoFileResult] = list(kept)
    finished = None
    try:
        try:
            if todo:
                finished = iter((run or _sequential(rig, neural, progress))(todo))
                for task_results in finished:
                    results.extend(task_results)
        finally:
            getattr(finished, "close", lambda: None)()  # a generator's clean-up runs now, not when collected
            if created and not any(r.summary for r in results):
                shutil.rmtree(out, ignore_errors=True)  # nothing of ours in it
        results.sort(key=lambda r: (order[r.photo], -1 if r.face is None else r.face))
        if out.is_dir():
            write_summary(out / SUMMARY_FILE, results, force=force or resume, inputs=inputs)
    finally:
        _unlock(lock)
    return results


__all__ = ["FACE_ALL", "IMAGE_SUFFIXES", "LANDMARK_SUFFIXES", "SUMMARY_COLUMNS", "SUMMARY_FILE", "EarlierOutput",
           "PhotoFileResult", "PhotoTask", "earlier_output", "fit_photo_faces", "fit_photo_file", "fit_photo_files",
           "fit_photo_task", "output_names", "photo_inputs", "read_summary", "remove_leftovers", "sidecar_landmarks",
           "summary_csv", "write_summary"]
