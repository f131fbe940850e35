"""One task of a batch (:func:`pipeline.photo.batch.fit_photo_files`): a photo and its output folder
(:class:`PhotoTask`), and :func:`fit_photo_task`, what a worker process (or a Dask worker) runs for it.

Example:
    >>> fit_photo_task(PhotoTask("photos/a.jpg", "out/a"))  # doctest: +SKIP
    (PhotoFileResult(photo='photos/a.jpg', summary={...}, ...),)
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from landmarks.detector import DEFAULT_DETECTOR, NoFaceError
from pipeline.photo.detection import FACE_ALL
from pipeline.photo.photo_file import fit_photo_faces, fit_photo_file
from pipeline.photo.summary import PhotoFileResult
from rig.errors import InputError


@dataclass(frozen=True)
class PhotoTask:
    """One photo of :func:`pipeline.photo.batch.fit_photo_files` (picklable: a worker process gets it
    whole); the fields are :func:`~pipeline.photo.photo_file.fit_photo_file`'s arguments, paths as str."""

    photo: str
    out: str
    config: object = None
    landmarks: str | None = None
    focal: float | None = None
    force: bool = False
    command: str = "jnr fit"
    inputs: tuple[str, ...] = ()
    detector: str = DEFAULT_DETECTOR
    """A registered detector name (a worker process knows only those its imports register)."""
    face: str | None = None
    """None: the largest face (or the landmarks file); :data:`~pipeline.photo.detection.FACE_ALL`: every
    face (:func:`~pipeline.photo.photo_file.fit_photo_faces`)."""
    shared_three: str | None = None
    """The folder run's shared three.js folder (``viewer.html`` links to it), or None."""


def fit_photo_task(
    task: PhotoTask, *, rig=None, neural=None, progress: Callable[[str, int, int], None] | None = None
) -> tuple[PhotoFileResult, ...]:
    """Fit one task with :func:`~pipeline.photo.photo_file.fit_photo_file` (or
    :func:`~pipeline.photo.photo_file.fit_photo_faces` for ``face="all"``), returning its failure (one
    line) instead of raising it (what a worker process of :func:`pipeline.photo.batch.fit_photo_files`
    runs): one :class:`~pipeline.photo.summary.PhotoFileResult`, or one per face. Interrupts and signals
    still raise."""
    t0 = time.perf_counter()
    common = dict(
        config=task.config,
        focal=task.focal,
        force=task.force,
        command=task.command,
        inputs=task.inputs,
        rig=rig,
        neural=neural,
        progress=progress,
        detector=task.detector,
        shared_three=task.shared_three,
    )
    try:
        if task.face == FACE_ALL:
            return tuple(fit_photo_faces(task.photo, task.out, **common))
        summary = fit_photo_file(task.photo, task.out, landmarks=task.landmarks, **common)
        box = summary["face_box"]
        return (
            PhotoFileResult(
                task.photo,
                summary,
                face=summary["face"],
                faces_found=summary["faces_found"],
                seconds=summary["seconds"],
                face_box=None if box is None else tuple(box),
                face_score=summary["face_score"],
            ),
        )
    except InputError as exc:
        return (
            PhotoFileResult(
                task.photo,
                error=str(exc),
                bad_input=True,
                seconds=time.perf_counter() - t0,
                faces_found=0 if isinstance(exc, NoFaceError) else None,
            ),
        )
    except FloatingPointError as exc:  # a diverged fit; the message names the photo
        return (PhotoFileResult(task.photo, error=str(exc), seconds=time.perf_counter() - t0),)
    except Exception as exc:
        return (
            PhotoFileResult(
                task.photo, error=f"{task.photo}: {type(exc).__name__}: {exc}", seconds=time.perf_counter() - t0
            ),
        )


__all__ = ["PhotoTask", "fit_photo_task"]
