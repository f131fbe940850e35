"""Photo files in, output folders out: what ``jnr fit PHOTO...`` does, as library functions.

* :func:`photo_inputs` turns file and folder names into the photos to fit (:data:`IMAGE_SUFFIXES`).
* :func:`fit_photo_file` fits one photo file: reads (or detects) its landmarks, checks everything that
  can be checked cheaply before the fit, runs :func:`pipeline.photo.fit.fit_photo` and writes its
  output folder (:func:`pipeline.photo.outputs.write_photo_outputs`).
* :func:`fit_photo_faces` fits every face the detector finds in one photo file into
  ``OUT/face_<k>/`` folders (``jnr fit --face all``), with ``OUT/summary.csv`` listing the faces.
* :func:`fit_photo_files` fits several into ``OUT/<name>/`` folders, one after another or through a
  caller's ``run`` (the command line's process pool), reporting each photo's failure instead of
  stopping (:class:`PhotoFileResult`), and lists them all in ``OUT/summary.csv`` (:func:`summary_csv`).

Example:
    >>> summary = fit_photo_file("face.png", "out/face", landmarks="face.pts")  # doctest: +SKIP
    >>> summary["mean_error_px"]  # doctest: +SKIP
    1.27
"""

from __future__ import annotations

import csv
import io
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
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
                   "box_left", "box_top", "box_right", "box_bottom", "face_score")
"""The columns of :data:`SUMMARY_FILE`: the photo file; the face index (empty: landmarks from a file, or the
photo failed before a face was picked); ``ok`` or ``error`` and the one-line error; the output folder
(empty on an error: nothing was written); the landmark error in the photo's pixels and the NME by the
outer eye corners (as in the fit's ``report.json``); the seconds spent on the photo (with ``--face all``,
on that face: its fit and outputs; the detection, once per photo, is in ``report.json``); how many faces
the detector found (0: none; empty: not detected, e.g. an unreadable file or a landmarks file); the face's
box in the photo's pixels and the detector's score."""


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
        return photo.to_working(points), {"landmarks": str(landmarks_path)}
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
    extra = {"input": {"photo": str(photo_path), "width": width, "height": height,
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
                         *(b if b == "" else _number(b, 1) for b in box), _number(r.face_score, 4)])
    return text.getvalue()


def _check_summary(path: Path, force: bool, inputs) -> None:
    """Before any fit: ``path`` may be written (a summary.csv that exists only with ``force``, and only
    one jnr wrote: it starts with :data:`SUMMARY_COLUMNS`)."""
    from pipeline.files import OutputError, check_output

    check_output(path, force=force, inputs=inputs, kind="file")
    if path.is_file():
        try:
            with open(path, newline="", encoding="utf-8") as handle:
                header = handle.readline().strip()
        except (OSError, UnicodeDecodeError):
            header = ""
        if header != ",".join(SUMMARY_COLUMNS):
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


def fit_photo_files(photos: Sequence[str | Path], out: str | Path, *, folders: Sequence[str | Path] = (),
                    config=None, landmarks: str | None = None, focal: float | None = None, force: bool = False,
                    command: str = "jnr fit", rig=None, neural=None,
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

    Args:
        photos: the image files (e.g. from :func:`photo_inputs`); folders: the folders they were found
            in (the outputs must not be, contain or lie in any of them, nor in a photo).
        config, focal, force, command: as :func:`fit_photo_file`, for every photo.
        landmarks: None (detect) or ``"auto"`` (the file beside each photo, :func:`sidecar_landmarks`).
        detector: as :func:`fit_photo_file`.
        face: None (the largest face of each photo) or :data:`FACE_ALL`: every face of each photo, into
            ``out/<name>/face_<k>/`` (:func:`fit_photo_faces`; each ``out/<name>/`` also has its own
            summary.csv), a summary row per face.
        rig, neural: the models, shared by all photos (default runner only; default: loaded per photo).
        progress: ``progress("photos", done, total)`` after each photo (default runner only).
        run: how the tasks are fitted: ``run(tasks)`` yields, per task as each finishes and in any order,
            the tuple of its results (e.g. from a process pool whose workers call
            :func:`fit_photo_task`); default: one after another in this process.

    Returns:
        One :class:`PhotoFileResult` per photo (per face with ``face="all"``), in the order of ``photos``
        (then of the faces).

    Raises:
        InputError: ``landmarks`` is a file, or ``landmarks`` with ``face="all"``;
            :class:`~pipeline.files.OutputError`: an output is refused.
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
    outputs = [out / n for n in output_names(photos)]
    created = make_output_folder(out, inputs=inputs)
    try:
        for o in outputs:
            check_output(o, force=force, inputs=inputs)
        _check_summary(out / SUMMARY_FILE, force, inputs)
    except OutputError:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    tasks = [PhotoTask(str(p), str(o), config, landmarks, focal, force, command, inputs, detector, face)
             for p, o in zip(photos, outputs)]
    order = {t.photo: i for i, t in reversed(list(enumerate(tasks)))}
    results: list[PhotoFileResult] = []
    finished = None
    try:
        finished = iter((run or _sequential(rig, neural, progress))(tasks))
        for task_results in finished:
            results.extend(task_results)
    finally:
        getattr(finished, "close", lambda: None)()  # a generator's clean-up runs now, not when collected
        if created and not any(r.summary for r in results):
            shutil.rmtree(out, ignore_errors=True)  # nothing of ours in it
    results.sort(key=lambda r: (order[r.photo], -1 if r.face is None else r.face))
    if out.is_dir():
        write_summary(out / SUMMARY_FILE, results, force=force, inputs=inputs)
    return results


__all__ = ["FACE_ALL", "IMAGE_SUFFIXES", "LANDMARK_SUFFIXES", "SUMMARY_COLUMNS", "SUMMARY_FILE", "PhotoFileResult",
           "PhotoTask", "fit_photo_faces", "fit_photo_file", "fit_photo_files", "fit_photo_task", "output_names",
           "photo_inputs", "sidecar_landmarks", "summary_csv", "write_summary"]
