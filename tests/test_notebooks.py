"""Run every ``notebooks/*.ipynb`` top to bottom, as CI does: short schedules (``JNR_NOTEBOOK_FAST=1``),
a fresh folder as working directory (what a notebook writes beside itself lands there), and the kernel on
this test's own interpreter. The executed notebook must stay small and show offline once saved: under
:data:`MAX_EXECUTED_BYTES`, one image per picture, no widgets (their saved state is megabytes and is drawn
by scripts from a CDN), no ``http(s)://`` in HTML or script outputs, and every ``<iframe>`` pointing at a
file it wrote beside itself (the 3D view: a fit's ``viewer.html``)."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

import nbformat
import pytest
from jupyter_client.kernelspec import KernelSpecManager, NoSuchKernel
from jupyter_client.manager import KernelManager
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError

from pipeline.viewer import VIEWER_FILE, read_viewer_data, viewer_available

NOTEBOOK_DIR = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
KERNEL_NAME = "python3"
CELL_TIMEOUT_S = 300
PREFIX_PROBE = "import sys\nprint('jnr-test kernel prefix:', sys.prefix)"
PREFIX_LINE = re.compile(r"^jnr-test kernel prefix: (.+)$", re.MULTILINE)
ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")  # IPython colours its tracebacks
MAX_EXECUTED_BYTES = 2_000_000
"""The executed notebook, serialised (``nbformat.writes``), in fast mode."""
VIEWER_NOTEBOOKS = {"explore_photo_fit.ipynb"}
"""Notebooks whose 3D view is a fit's ``viewer.html`` in an ``<iframe>`` (when three.js is vendored)."""
SCRIPTED_MIME = re.compile(r"text/html|(application|text)/javascript|application/vnd\.jupyter\.widget")
URL = re.compile(r"https?://", re.IGNORECASE)
IFRAME_SRC = re.compile(r"<iframe\b[^>]*?\bsrc=[\"']([^\"']*)[\"']", re.IGNORECASE | re.DOTALL)


def _kernel_specs() -> KernelSpecManager:
    """Kernel specs of this interpreter only: its environment's kernels folder, else ipykernel's built-in
    ``python3`` spec. Either starts ``sys.executable`` (jupyter_client swaps a bare ``python`` for it),
    whatever kernels a user-wide Jupyter folder holds."""
    return KernelSpecManager(kernel_dirs=[str(Path(sys.prefix) / "share" / "jupyter" / "kernels")])


def _stream_text(cell) -> str:
    return "".join(o.get("text", "") for o in cell.get("outputs", []) if o.get("output_type") == "stream")


def _rich_outputs(nb):
    """``(cell index, mime bundle)`` of every display_data / execute_result output."""
    for k, cell in enumerate(nb.cells):
        for output in cell.get("outputs", []):
            if output.get("output_type") in ("display_data", "execute_result"):
                yield k, output.get("data", {})


def _check_saved_outputs(name: str, nb, folder: Path) -> None:
    """The executed notebook, as it would be saved, is small and shows offline (module docstring)."""
    size = len(nbformat.writes(nb).encode("utf-8"))
    assert size < MAX_EXECUTED_BYTES, f"{name}: the executed notebook is {size / 1e6:.2f} MB (> 2 MB)"
    assert not nb.metadata.get("widgets"), (
        f"{name}: the run left widget state in the notebook's metadata (its saved view needs a widget "
        f"manager from a CDN); keep widgets behind a flag that is off by default"
    )
    frames = []
    for k, bundle in _rich_outputs(nb):
        images = [mime for mime in bundle if mime.startswith("image/")]
        assert len(images) <= 1, f"{name}: cell {k} stores one picture as {images}: keep one representation"
        for mime, value in bundle.items():
            if not SCRIPTED_MIME.match(mime):
                continue
            assert not mime.startswith("application/vnd.jupyter.widget"), (
                f"{name}: cell {k} displays a widget ({mime}), blank in the saved notebook offline"
            )
            text = value if isinstance(value, str) else "".join(value)
            assert not URL.search(text), f"{name}: cell {k}'s {mime} output references a URL: {text[:300]}"
            frames += [(k, src) for src in IFRAME_SRC.findall(text)]
    for k, src in frames:
        assert src and not src.startswith("/") and ":" not in src, (
            f"{name}: cell {k}'s <iframe src={src!r}> is not relative to the notebook"
        )
        assert (folder / src).is_file(), f"{name}: cell {k}'s <iframe src={src!r}>: no such file beside the notebook"
    if name in VIEWER_NOTEBOOKS and viewer_available():
        pages = [folder / src for _, src in frames if src.endswith(VIEWER_FILE)]
        assert pages, f"{name}: the 3D view shows no {VIEWER_FILE} in an <iframe> (outputs of cells {frames})"
        for page in pages:
            assert read_viewer_data(page)["channels"], f"{page} holds no joint channels"


def test_notebooks_exist():
    assert NOTEBOOKS, f"no notebooks in {NOTEBOOK_DIR}"


# the photo-fit notebook fits a photo (10 s of the fast suite's 6 minutes): CI's make test-slow runs it
SLOW_NOTEBOOKS = {"explore_photo_fit.ipynb"}


@pytest.mark.parametrize(
    "path",
    [pytest.param(p, marks=pytest.mark.slow) if p.name in SLOW_NOTEBOOKS else p for p in NOTEBOOKS],
    ids=[p.name for p in NOTEBOOKS],
)
def test_notebook_runs(path: Path, tmp_path: Path):
    specs = _kernel_specs()
    try:
        specs.get_kernel_spec(KERNEL_NAME)
    except NoSuchKernel:
        pytest.skip(f"no Jupyter kernel {KERNEL_NAME!r} for {sys.executable}: pip install ipykernel")

    nb = nbformat.read(path, as_version=4)
    nb.cells.append(nbformat.v4.new_code_cell(PREFIX_PROBE))  # which interpreter ran the notebook
    km = KernelManager(kernel_name=KERNEL_NAME, kernel_spec_manager=specs)
    client = NotebookClient(
        nb, km=km, timeout=CELL_TIMEOUT_S, kernel_name=KERNEL_NAME, resources={"metadata": {"path": str(tmp_path)}}
    )
    try:
        # the notebook as saved by default: its optional widgets (plotly, ipywidgets) off
        client.execute(env={**os.environ, "JNR_NOTEBOOK_FAST": "1", "JNR_NOTEBOOK_SLIDERS": "0"})
    except CellExecutionError as exc:
        pytest.fail(f"{path.name}: a cell failed:\n{ANSI_ESCAPE.sub('', str(exc))}", pytrace=False)
    finally:
        # nbclient leaves a kernel it was handed running
        if client.kc is not None:
            client.kc.stop_channels()
        if km.has_kernel:
            km.shutdown_kernel(now=True)

    probe = nb.cells.pop()
    reported = PREFIX_LINE.search(_stream_text(probe))
    assert reported, f"{path.name}: the interpreter probe printed nothing: {probe.get('outputs')}"
    assert Path(reported.group(1).strip()).resolve() == Path(sys.prefix).resolve(), (
        f"{path.name} ran on another interpreter ({reported.group(1)}) than the tests ({sys.prefix})"
    )
    nbformat.write(nb, tmp_path / path.name)  # the executed notebook, beside what it wrote (for a look)
    _check_saved_outputs(path.name, nb, tmp_path)
