"""Photo files in, output folders out: what ``jnr fit PHOTO...`` does, as library functions.

* :func:`photo_inputs` turns file and folder names into the photos to fit (:data:`IMAGE_SUFFIXES`).
* :func:`fit_photo_file` fits one photo file: reads (or detects) its landmarks, checks everything that
  can be checked cheaply before the fit, runs :func:`pipeline.photo.fit.fit_photo` and writes its
  output folder (:func:`pipeline.photo.outputs.write_photo_outputs`).
* :func:`fit_photo_files` fits several into ``OUT/<name>/`` folders, one after another or through a
  caller's ``run`` (the command line's process pool), reporting each photo's failure instead of
  stopping (:class:`PhotoFileResult`).

Example:
    >>> summary = fit_photo_file("face.png", "out/face", landmarks="face.pts")  # doctest: +SKIP
    >>> summary["mean_error_px"]  # doctest: +SKIP
    1.27
"""

from __future__ import annotations

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


def _photo_landmarks(photo, landmarks_path: Path | None, face: int | None, detector: str = "auto"):
    """``(landmarks (68, 2) in the working image's pixels, report.json's description of their source)``:
    with detection, every face found (box in the photo's pixels, score, detector) and the one fitted."""
    from landmarks.detect import DetectionError, detect_faces
    from landmarks.formats import read_landmarks
    from landmarks.plausibility import check_landmarks_2d

    width, height = photo.original_size
    if landmarks_path:
        points = read_landmarks(landmarks_path)
        check_landmarks_2d(points, width, height, source=str(landmarks_path))
        return photo.to_working(points), {"landmarks": str(landmarks_path)}
    t0 = time.perf_counter()
    faces = detect_faces(photo.image, detector=detector)
    seconds = time.perf_counter() - t0
    if not faces:
        tried = "HOG and CNN detectors" if detector == "auto" else f"{detector.upper()} detector"
        raise DetectionError(f"no face found in the image (dlib's {tried}); pass --landmarks FILE to give the "
                             "68 landmarks yourself")
    index = 0 if face is None else int(face)
    if not 0 <= index < len(faces):
        noun = "face" if len(faces) == 1 else "faces"
        raise DetectionError(f"found {len(faces)} {noun}; --face must be 0..{len(faces) - 1}, got {index}")
    listed = [{"box": photo.to_original(f.box.reshape(2, 2)).reshape(-1).tolist(), "score": f.score,
               "detector": f.detector} for f in faces]
    chosen = faces[index]
    return chosen.landmarks, {"landmarks": "dlib 68-point detector", "detector": chosen.detector,
                              "detector_option": detector, "detection_seconds": round(seconds, 3),
                              "face_box": listed[index]["box"], "face_score": chosen.score, "face_index": index,
                              "faces": listed}


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
        face: which detected face, 0 = the largest (default 0); not with ``landmarks``.
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
        ``"fit_seconds"`` (the fit)``}``.

    Raises:
        InputError: any of the above, or an image or landmarks the fit rejects (nothing written);
            :class:`~pipeline.files.OutputError` for the output folder.
        FloatingPointError: the fit diverged (the message names the photo).
    """
    from landmarks.detect import DetectionError, load_working_image
    from pipeline.files import check_output
    from pipeline.photo.camera import check_focal
    from pipeline.photo.fit import FitPhotoConfig, fit_photo
    from pipeline.photo.outputs import write_photo_outputs

    t0 = time.perf_counter()
    photo_path, out = Path(photo_path), Path(out)
    if face is not None and landmarks:
        raise InputError("--face picks one of the faces the detector finds; it cannot be used with --landmarks")
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
    except DetectionError as exc:  # name the photo (the other InputErrors name their file or option)
        message = str(exc)
        raise DetectionError(message if str(photo_path) in message else f"{photo_path}: {message}") from None
    k = photo.factor
    try:
        fit = fit_photo(photo.image, points, focal=None if focal is None else focal / k, config=config,
                        rig=rig, neural=neural, progress=progress)
    except FloatingPointError as exc:  # a diverged fit
        raise FloatingPointError(f"{photo_path}: {exc}") from None
    except ValueError as exc:  # bad image or landmarks for the fit (InputError and plain ValueError)
        raise InputError(f"{photo_path}: {exc}") from None
    extra = {"input": {"photo": str(photo_path), "width": width, "height": height,
                       "fitted_width": fit.width, "fitted_height": fit.height, "reduction": k,
                       "focal_px": fit.focal * k, "focal_source": "--focal" if focal else "default 1.4 * max(W, H)",
                       **source},
             "command": command}
    write_photo_outputs(out, photo.image, fit, config=config, force=force, extra=extra, inputs=all_inputs,
                        image_factor=k, original_size=photo.original_size, rig=rig, neural=neural)
    return {"photo": str(photo_path), "output": str(out), "mean_error_px": float(fit.error_px.mean()) * k,
            "nme": float(fit.nme), "seconds": time.perf_counter() - t0, "fit_seconds": fit.timings["total"]}


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


@dataclass(frozen=True)
class PhotoFileResult:
    """What became of one :class:`PhotoTask`.

    Attributes:
        photo: the photo file. summary: :func:`fit_photo_file`'s summary, None when it failed.
        error: the one-line message when it failed. bad_input: whether the input is to blame (an
            :class:`~rig.errors.InputError`) rather than a failure of the fit or the machine.
    """

    photo: str
    summary: dict | None = None
    error: str | None = None
    bad_input: bool = False


def fit_photo_task(task: PhotoTask, *, rig=None, neural=None,
                   progress: Callable[[str, int, int], None] | None = None) -> PhotoFileResult:
    """Fit one task with :func:`fit_photo_file`, returning its failure (one line) instead of raising it
    (what a worker process of :func:`fit_photo_files` runs). Interrupts and signals still raise."""
    try:
        summary = fit_photo_file(task.photo, task.out, config=task.config, landmarks=task.landmarks,
                                 focal=task.focal, force=task.force, command=task.command, inputs=task.inputs,
                                 rig=rig, neural=neural, progress=progress, detector=task.detector)
        return PhotoFileResult(task.photo, summary)
    except InputError as exc:
        return PhotoFileResult(task.photo, error=str(exc), bad_input=True)
    except FloatingPointError as exc:  # a diverged fit; the message names the photo
        return PhotoFileResult(task.photo, error=str(exc))
    except Exception as exc:  # noqa: BLE001 - reported per photo; the batch goes on
        return PhotoFileResult(task.photo, error=f"{task.photo}: {type(exc).__name__}: {exc}")


def output_names(photos: Sequence[str | Path]) -> list[str]:
    """The output folder name of each photo: its stem, or ``<stem>_<index>`` for stems that repeat."""
    stems = [Path(p).stem for p in photos]
    return [s if stems.count(s) == 1 else f"{s}_{i}" for i, s in enumerate(stems)]


def _sequential(rig, neural, progress):
    def run(tasks: list[PhotoTask]) -> Iterable[PhotoFileResult]:
        for i, task in enumerate(tasks):
            yield fit_photo_task(task, rig=rig, neural=neural)
            if progress is not None:
                progress("photos", i + 1, len(tasks))
    return run


def fit_photo_files(photos: Sequence[str | Path], out: str | Path, *, folders: Sequence[str | Path] = (),
                    config=None, landmarks: str | None = None, focal: float | None = None, force: bool = False,
                    command: str = "jnr fit", rig=None, neural=None,
                    progress: Callable[[str, int, int], None] | None = None,
                    run: Callable[[list[PhotoTask]], Iterable[PhotoFileResult]] | None = None,
                    detector: str = "auto") -> list[PhotoFileResult]:
    """Fit several photo files, each into ``out/<name>/`` (:func:`output_names`).

    The output folder is created if missing and every ``out/<name>`` is checked before any fit; a photo
    that fails is reported in its :class:`PhotoFileResult` and the others go on. When no photo could be
    written, an ``out`` this call created is removed again (also on an interrupt).

    Args:
        photos: the image files (e.g. from :func:`photo_inputs`); folders: the folders they were found
            in (the outputs must not be, contain or lie in any of them, nor in a photo).
        config, focal, force, command: as :func:`fit_photo_file`, for every photo.
        landmarks: None (detect) or ``"auto"`` (the file beside each photo, :func:`sidecar_landmarks`).
        rig, neural: the models, shared by all photos (default runner only; default: loaded per photo).
        progress: ``progress("photos", done, total)`` after each photo (default runner only).
        run: how the tasks are fitted: ``run(tasks)`` yields one :class:`PhotoFileResult` per task as
            each finishes, in any order (e.g. from a process pool whose workers call
            :func:`fit_photo_task`); default: one after another in this process.

    Returns:
        One :class:`PhotoFileResult` per photo, in the order of ``photos``.

    Raises:
        InputError: ``landmarks`` is a file; :class:`~pipeline.files.OutputError`: an output is refused.
    """
    from pipeline.files import OutputError, check_output, make_output_folder

    if landmarks not in (None, "auto"):
        raise InputError(f"landmarks must be None or 'auto' for several photos, got {landmarks!r}")
    out = Path(out)
    outputs = [out / n for n in output_names(photos)]
    inputs = tuple(str(p) for p in (*photos, *folders))
    created = make_output_folder(out, inputs=inputs)
    try:
        for o in outputs:
            check_output(o, force=force, inputs=inputs)
    except OutputError:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    tasks = [PhotoTask(str(p), str(o), config, landmarks, focal, force, command, inputs, detector)
             for p, o in zip(photos, outputs)]
    order = {t.photo: i for i, t in reversed(list(enumerate(tasks)))}
    results: list[PhotoFileResult] = []
    finished = None
    try:
        finished = iter((run or _sequential(rig, neural, progress))(tasks))
        results.extend(finished)
    finally:
        getattr(finished, "close", lambda: None)()  # a generator's clean-up runs now, not when collected
        if created and not any(r.summary for r in results):
            shutil.rmtree(out, ignore_errors=True)  # nothing of ours in it
    return sorted(results, key=lambda r: order[r.photo])


__all__ = ["IMAGE_SUFFIXES", "LANDMARK_SUFFIXES", "PhotoFileResult", "PhotoTask", "fit_photo_file",
           "fit_photo_files", "fit_photo_task", "output_names", "photo_inputs", "sidecar_landmarks"]
