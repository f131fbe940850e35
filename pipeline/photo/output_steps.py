"""The parts of :func:`pipeline.photo.outputs.write_photo_outputs`'s table of files: the state its writers
read (:class:`OutputJob`), a row (:class:`PhotoOutput`: the files, when they are wanted, the function that
writes them), the rows for JSON, text and ``.pts`` files, the timed stages the rows are grouped in
(:class:`OutputStage`) and the timer (:class:`Laps`)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from landmarks.formats import write_landmarks
from pipeline.head.fitted import FittedHead
from pipeline.photo.fit import PhotoFit
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.photo.output_payloads import landmarks3d_mesh_points, params_payload
from pipeline.photo.texture import UVTexture
from rig.asset import RigAsset


@dataclass
class OutputJob:
    """One :func:`~pipeline.photo.outputs.write_photo_outputs` call: what its writers read (the fit, its head,
    the settings, and the render and texture made before staging for the wanted files that need them)."""

    out_dir: Path
    photo: np.ndarray
    fit: PhotoFit
    head: FittedHead
    settings: FitPhotoConfig
    config: FitPhotoConfig | None
    extra: dict | None
    image_factor: int
    original_size: tuple[int, int] | None
    shared_three: str | Path | None
    wanted: set[str]
    scale: float = 1.0
    render: np.ndarray | None = None
    face_mask: np.ndarray | None = None
    texture: UVTexture | None = None
    texture_png: bytes | None = None
    colours: np.ndarray | None = None

    def wants(self, *names: str) -> bool:
        return any(n in self.wanted for n in names)

    @property
    def asset(self) -> RigAsset:
        return self.head.asset

    @property
    def units(self) -> str:
        """``mesh.obj``'s units (``outputs.units``)."""
        return self.settings.outputs.units

    @cached_property
    def params(self) -> dict:
        """``params.json``'s content (the viewer takes its camera)."""
        return params_payload(self.fit, self.image_factor, self.original_size, self.head)

    @cached_property
    def mesh_landmarks(self) -> np.ndarray:
        """The 68 fitted landmarks in ``mesh.obj``'s frame and units (``landmarks3d.pp``, NoW's file)."""
        return landmarks3d_mesh_points(self.fit) * self.scale

    def file_pixels(self, points: np.ndarray) -> np.ndarray:
        """Working-image pixels in the photo file's (``image_factor`` k: ``k x + (k - 1) / 2``)."""
        k = self.image_factor
        return np.asarray(points, float) * k + (k - 1) / 2


Writer = Callable[[OutputJob, Path], None]
"""Writes its files into the staged folder (the second argument)."""


@dataclass(frozen=True)
class PhotoOutput:
    """A row of the table: ``write`` writes ``files``; it runs when the set of ``outputs.files`` holds any of
    them, or ``always``."""

    files: tuple[str, ...]
    write: Writer
    always: bool = False

    def wanted(self, job: OutputJob) -> bool:
        return self.always or job.wants(*self.files)


def json_output(
    name: str, payload: Callable[[OutputJob], dict | None], indent: int = 2, always: bool = False
) -> PhotoOutput:
    """The output ``name`` holding ``payload(job)`` as JSON (not written when that is None)."""

    def write(job: OutputJob, folder: Path) -> None:
        content = payload(job)
        if content is not None:
            (folder / name).write_text(json.dumps(content, indent=indent) + "\n")

    return PhotoOutput((name,), write, always)


def text_output(name: str, text: Callable[[OutputJob], str]) -> PhotoOutput:
    """The output ``name`` holding ``text(job)``."""
    return PhotoOutput((name,), lambda job, folder: (folder / name).write_text(text(job)))


def pts_output(name: str, pixels: Callable[[PhotoFit], np.ndarray]) -> PhotoOutput:
    """The iBUG ``.pts`` file ``name`` of ``pixels(fit)`` (working-image pixels) in the photo file's pixels."""
    return PhotoOutput((name,), lambda job, folder: write_landmarks(folder / name, job.file_pixels(pixels(job.fit))))


@dataclass(frozen=True)
class OutputStage:
    """Outputs timed together under ``lap`` (logged, ``-v``); ``timed_when_idle``: even when none of them
    is wanted."""

    lap: str
    outputs: tuple[PhotoOutput, ...]
    timed_when_idle: bool = True

    def write(self, job: OutputJob, folder: Path, lap: Laps) -> None:
        """Write the wanted outputs into ``folder`` in order, then time them."""
        wanted = [output for output in self.outputs if output.wanted(job)]
        for output in wanted:
            output.write(job, folder)
        if wanted or self.timed_when_idle:
            lap(self.lap)


class Laps:
    """The seconds between calls, summed under each call's name (logged at the end, ``-v``)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._last = time.perf_counter()

    def __call__(self, name: str) -> None:
        now = time.perf_counter()
        self.seconds[name] = self.seconds.get(name, 0.0) + now - self._last
        self._last = now
