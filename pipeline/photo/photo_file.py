"""One photo file in, one output folder out: what ``jnr fit PHOTO`` does, as library functions.

* :func:`fit_photo_file` fits one face of a photo file: reads (or detects) its landmarks, checks everything
  that can be checked cheaply before the fit, runs :func:`pipeline.photo.fit.fit_photo` and writes its
  output folder (:func:`pipeline.photo.outputs.write_photo_outputs`).
* :func:`fit_photo_faces` fits every face the detector finds in one photo file into ``OUT/face_<k>/``
  folders (``jnr fit --face all``), with ``OUT/summary.csv`` listing the faces
  (:mod:`pipeline.photo.summary`).

Several photo files: :func:`pipeline.photo.batch.fit_photo_files`.

Example:
    >>> summary = fit_photo_file("face.png", "out/face", landmarks="face.pts")  # doctest: +SKIP
    >>> summary["mean_error_px"]  # doctest: +SKIP
    1.27
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from landmarks.detector import DEFAULT_DETECTOR, DetectionError, check_detector_name
from landmarks.images import ImageError, LoadedImage, load_working_image
from landmarks.mediapipe.layout import mediapipe_layout_for
from pipeline.camera import check_focal
from pipeline.files import check_output, staged_folder
from pipeline.photo.detection import (
    FACE_ALL,
    DetectedFaces,
    check_face,
    dense_fit_points,
    detect_photo_faces,
    name_photo,
    photo_landmarks,
)
from pipeline.photo.fit import fit_photo
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.inputs import sidecar_landmarks
from pipeline.photo.outputs import write_photo_outputs
from pipeline.photo.summary import SUMMARY_FILE, PhotoFileResult, summary_csv
from rig.errors import InputError
from rig.model import JointRig

_log = logging.getLogger(__name__)


def _fit_and_write(
    photo_path: Path,
    photo: LoadedImage,
    points: np.ndarray,
    source: dict,
    out: Path,
    *,
    dense: np.ndarray | None = None,
    label: str,
    config,
    focal,
    force,
    progress,
    rig,
    neural,
    command: str,
    inputs: list,
    shared_three: str | Path | None = None,
) -> dict:
    """Fit ``points`` (68, or MediaPipe's ``dense`` points when given and ``config.landmarks.dense``) on the
    loaded photo and write ``out``: :func:`fit_photo_file`'s summary, less the detection fields; errors name
    ``label`` (the photo, or the photo and the face)."""
    t0 = time.perf_counter()
    width, height = photo.original_size
    k = photo.factor
    rig = rig or JointRig()
    fitted = points3d = None
    if dense is not None and config.landmarks.dense:
        pixels, points3d = dense_fit_points(dense)
        fitted = (pixels, mediapipe_layout_for(rig.asset, len(dense)))
    try:
        fit = fit_photo(
            photo.image,
            points,
            focal=None if focal is None else focal / k,
            config=config,
            rig=rig,
            neural=neural,
            progress=progress,
            dense=fitted,
            points3d=points3d,
        )
    except FloatingPointError as exc:  # a diverged fit
        raise FloatingPointError(f"{label}: {exc}") from None
    except InputError as exc:  # bad image or landmarks for the fit; anything else is a defect (exit 1)
        raise InputError(f"{label}: {exc}") from None
    _log.info(
        "%s: fitted %s points in %.2f s (landmark fit %.2f s, photometric %.2f s)",
        label,
        "ibug68" if fitted is None else fitted[1].name,
        fit.timings["total"],
        fit.timings["landmarks"],
        fit.timings["photometric"],
    )
    extra = {
        "input": {
            "photo": os.path.abspath(photo_path),
            "width": width,
            "height": height,
            "fitted_width": fit.width,
            "fitted_height": fit.height,
            "reduction": k,
            "focal_px": fit.focal * k,
            "focal_source": "--focal" if focal else "default 1.4 * max(W, H)",
            "fitted_layout": "ibug68" if fitted is None else fitted[1].name,
            **source,
        },
        "command": command,
    }
    write_photo_outputs(
        out,
        photo.image,
        fit,
        config=config,
        force=force,
        extra=extra,
        inputs=inputs,
        image_factor=k,
        original_size=photo.original_size,
        rig=rig,
        neural=neural,
        shared_three=shared_three,
    )
    return {
        "photo": str(photo_path),
        "output": str(out),
        "mean_error_px": float(fit.landmarks.error_px.mean()) * k,
        "nme": float(fit.landmarks.nme),
        "seconds": time.perf_counter() - t0,
        "fit_seconds": fit.timings["total"],
        "face": source.get("face_index"),
        "faces_found": len(source["faces"]) if "faces" in source else None,
        "face_box": source.get("face_box"),
        "face_score": source.get("face_score"),
    }


def fit_photo_file(
    photo_path: str | Path,
    out: str | Path,
    *,
    config=None,
    landmarks: str | Path | None = None,
    face: int | None = None,
    focal: float | None = None,
    force: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
    rig=None,
    neural=None,
    command: str = "jnr fit",
    inputs: Iterable[str | Path] = (),
    detector: str = DEFAULT_DETECTOR,
    shared_three: str | Path | None = None,
) -> dict:
    """Detect (or read) the landmarks of one photo file, fit it and write its output folder.

    Everything that can be checked cheaply is checked before the fit: the output path (not an input,
    not the working directory, writable; an existing one only with ``force`` and only if jnr wrote
    it), the image (readable, at most :data:`landmarks.images.MAX_IMAGE_PIXELS`), ``focal`` (within
    :data:`pipeline.camera.FOCAL_RANGE` times the longer side), the landmarks (a readable file
    with 68, 468 or 478 points, in or near the image, a face-like and not mirrored configuration). Photos longer
    than :data:`landmarks.images.WORKING_MAX_SIDE` are fitted reduced by a power of two; the outputs
    give the camera and landmarks in the photo's own pixels.

    Args:
        photo_path: the image file.
        out: the output folder (:mod:`pipeline.photo.outputs` lists its files).
        config: :class:`pipeline.photo.fit.FitPhotoConfig` (default: its defaults).
        landmarks: a file of 68 iBUG landmarks, or of MediaPipe's 468 or 478 points (``.pts`` 1-based,
            ``.json``, ``.csv``; pixels of the photo file), ``"auto"`` for the one beside the photo
            (:func:`sidecar_landmarks`), or None to detect them (``detector``).
        face: which detected face, 0 = the largest (default 0); not with ``landmarks``. For every face,
            see :func:`fit_photo_faces`.
        detector: the face detector, a name :func:`landmarks.detector.detector_names` lists (default
            ``"auto"``: MediaPipe's models, and dlib's detectors only when they find no face).
        focal: the focal length in pixels of the photo file (default: 1.4 x its longer side).
        force: replace an existing output folder (only one jnr wrote).
        progress: ``progress(stage, iteration, iterations)`` during the fit.
        rig, neural: the models to fit with, also used for the outputs (default: the committed rig and
            learned skinning; see :func:`pipeline.photo.fit.fit_photo`).
        command: recorded in ``report.json`` and the output's marker.
        inputs: more input paths the output must not be, contain or lie in (e.g. the photo's folder).
        shared_three: the folder of a folder run's shared three.js (:func:`pipeline.viewer.write_shared_three`,
            already written): ``viewer.html`` loads it from there instead of holding its own copy.

    Returns:
        ``{"photo", "output"`` (str paths), ``"mean_error_px"`` (landmark error in the photo file's
        pixels), ``"nme"`` (over the outer-eye-corner distance), ``"seconds"`` (this call),
        ``"fit_seconds"`` (the fit), ``"face"`` (the index of the detected face fitted),
        ``"faces_found"`` (how many the detector found), ``"face_box"`` (``[left, top, right, bottom]``,
        the photo's pixels), ``"face_score"`` (the last four None with a landmarks file)``}``.

    Raises:
        InputError: any of the above, an unknown ``detector``, or an image or landmarks the fit rejects
            (nothing written); :class:`~pipeline.files.OutputError` for the output folder.
        FloatingPointError: the fit diverged (the message names the photo).
    """
    t0 = time.perf_counter()
    photo_path, out = Path(photo_path), Path(out)
    check_face(face)
    check_detector_name(detector, "fit_photo_file")
    if face is not None and landmarks:
        raise InputError("--face picks one of the faces the detector finds; it cannot be used with --landmarks")
    if face == FACE_ALL:
        raise InputError(f"fit_photo_file fits one face; fit_photo_faces fits them all (face={FACE_ALL!r})")
    landmarks_path = sidecar_landmarks(photo_path) if landmarks == "auto" else (Path(landmarks) if landmarks else None)
    all_inputs = [photo_path, *([landmarks_path] if landmarks_path else []), *inputs]
    config = config or FitPhotoConfig()
    try:
        check_output(out, force=force, inputs=all_inputs)
        t_read = time.perf_counter()
        photo = load_working_image(photo_path)
        width, height = photo.original_size
        _log.info("%s: read %d x %d in %.2f s", photo_path, width, height, time.perf_counter() - t_read)
        if focal is not None:
            check_focal(focal, width, height)
        t_detect = time.perf_counter()
        points, source, dense = photo_landmarks(photo, landmarks_path, face, detector)
        _log.info(
            "%s: %s landmarks (%s) in %.2f s",
            photo_path,
            "dense" if dense is not None else "68",
            source.get("detector") or "file",
            time.perf_counter() - t_detect,
        )
    except (ImageError, DetectionError) as exc:
        raise name_photo(exc, photo_path) from None
    summary = _fit_and_write(
        photo_path,
        photo,
        points,
        source,
        out,
        dense=dense,
        label=str(photo_path),
        config=config,
        focal=focal,
        force=force,
        progress=progress,
        rig=rig,
        neural=neural,
        command=command,
        inputs=all_inputs,
        shared_three=shared_three,
    )
    return {**summary, "seconds": time.perf_counter() - t0}


def fit_photo_faces(
    photo_path: str | Path,
    out: str | Path,
    *,
    config=None,
    focal: float | None = None,
    force: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
    rig=None,
    neural=None,
    command: str = "jnr fit",
    inputs: Iterable[str | Path] = (),
    detector: str = DEFAULT_DETECTOR,
    shared_three: str | Path | None = None,
) -> list[PhotoFileResult]:
    """Detect every face in one photo file and fit each into ``out/face_<k>/`` (``jnr fit --face all``).

    ``k`` numbers the faces as ``face=k`` of :func:`fit_photo_file` does (largest first); each
    ``face_<k>/`` holds the complete output set of a fit (its ``report.json`` lists every face found and
    gives its own ``face_index``), and ``out/summary.csv`` (:func:`pipeline.photo.summary.summary_csv`)
    has one row per face. The faces are fitted one after another; ``out`` is written as one folder,
    atomically (staged beside it and moved into place at the end), with the faces that could be fitted:
    a face whose fit fails is a row with status ``error``, the others are kept. The checks of
    :func:`fit_photo_file` come first.

    Args:
        photo_path, out, config, focal, force, progress, rig, neural, command, inputs, detector, shared_three: as
            :func:`fit_photo_file` (``progress`` runs through each face's fit in turn).

    Returns:
        One :class:`PhotoFileResult` per face, in the detector's order (``face`` = k, ``faces_found``).

    Raises:
        InputError: as :func:`fit_photo_file` (an unreadable photo, no face found:
            :class:`~landmarks.detector.NoFaceError`, a refused output), or every face's fit failed (the
            first face's error; nothing written); FloatingPointError: every fit diverged.
    """
    check_detector_name(detector, "fit_photo_faces")
    photo_path, out = Path(photo_path), Path(out)
    all_inputs = [photo_path, *inputs]
    config = config or FitPhotoConfig()
    try:
        check_output(out, force=force, inputs=all_inputs)
        photo = load_working_image(photo_path)
        if focal is not None:
            check_focal(focal, *photo.original_size)
        detected = detect_photo_faces(photo, detector)
    except (ImageError, DetectionError) as exc:
        raise name_photo(exc, photo_path) from None
    fit_options = dict(config=config, focal=focal, progress=progress, rig=rig, neural=neural, command=command)
    fit_options["shared_three"] = shared_three
    results: list[PhotoFileResult] = []
    first_failure: BaseException | None = None
    with staged_folder(out, force, inputs=all_inputs, marker={"command": command}) as staged:
        for k in range(len(detected.faces)):
            result, failure = _fit_face(photo_path, photo, detected, k, staged, out, all_inputs, **fit_options)
            results.append(result)
            if first_failure is None:
                first_failure = failure
        if first_failure is not None and not any(r.summary for r in results):
            raise first_failure
        (staged / SUMMARY_FILE).write_text(summary_csv(results), encoding="utf-8")
    return results


def _fit_face(
    photo_path: Path,
    photo: LoadedImage,
    detected: DetectedFaces,
    k: int,
    staged: Path,
    out: Path,
    inputs: list,
    **fit_options,
) -> tuple[PhotoFileResult, BaseException | None]:
    """Face ``k`` of :func:`fit_photo_faces`, fitted into ``staged/face_<k>``: its row (naming
    ``out/face_<k>``), and its error when the fit failed (the row says it too)."""
    t0 = time.perf_counter()
    found = len(detected.faces)
    points, source = detected.source(k)
    box, score = tuple(source["face_box"]), float(source["face_score"])
    try:
        summary = _fit_and_write(
            photo_path,
            photo,
            points,
            source,
            staged / f"face_{k}",
            dense=detected.dense(k),
            label=f"{photo_path} (face {k})",
            force=False,
            inputs=inputs,
            **fit_options,
        )
    except (InputError, FloatingPointError) as exc:
        failed = PhotoFileResult(
            str(photo_path),
            error=str(exc),
            bad_input=isinstance(exc, InputError),
            face=k,
            faces_found=found,
            seconds=time.perf_counter() - t0,
            face_box=box,
            face_score=score,
        )
        return failed, exc
    summary["output"] = str(out / f"face_{k}")
    fitted = PhotoFileResult(
        str(photo_path), summary, face=k, faces_found=found, seconds=summary["seconds"], face_box=box, face_score=score
    )
    return fitted, None


__all__ = ["fit_photo_faces", "fit_photo_file"]
