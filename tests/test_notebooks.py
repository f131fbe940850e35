"""Run every ``notebooks/*.ipynb`` top to bottom, as CI does: short schedules (``JNR_NOTEBOOK_FAST=1``),
the notebooks folder as working directory, and the kernel on this test's own interpreter."""

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

NOTEBOOK_DIR = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
KERNEL_NAME = "python3"
CELL_TIMEOUT_S = 300
PREFIX_PROBE = "import sys\nprint('jnr-test kernel prefix:', sys.prefix)"
PREFIX_LINE = re.compile(r"^jnr-test kernel prefix: (.+)$", re.MULTILINE)
ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")  # IPython colours its tracebacks


def _kernel_specs() -> KernelSpecManager:
    """Kernel specs of this interpreter only: its environment's kernels folder, else ipykernel's built-in
    ``python3`` spec. Either starts ``sys.executable`` (jupyter_client swaps a bare ``python`` for it),
    whatever kernels a user-wide Jupyter folder holds."""
    return KernelSpecManager(kernel_dirs=[str(Path(sys.prefix) / "share" / "jupyter" / "kernels")])


def _stream_text(cell) -> str:
    return "".join(o.get("text", "") for o in cell.get("outputs", []) if o.get("output_type") == "stream")


def test_notebooks_exist():
    assert NOTEBOOKS, f"no notebooks in {NOTEBOOK_DIR}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path: Path):
    specs = _kernel_specs()
    try:
        specs.get_kernel_spec(KERNEL_NAME)
    except NoSuchKernel:
        pytest.skip(f"no Jupyter kernel {KERNEL_NAME!r} for {sys.executable}: pip install ipykernel")

    nb = nbformat.read(path, as_version=4)
    nb.cells.append(nbformat.v4.new_code_cell(PREFIX_PROBE))  # which interpreter ran the notebook
    km = KernelManager(kernel_name=KERNEL_NAME, kernel_spec_manager=specs)
    client = NotebookClient(
        nb, km=km, timeout=CELL_TIMEOUT_S, kernel_name=KERNEL_NAME, resources={"metadata": {"path": str(NOTEBOOK_DIR)}}
    )
    try:
        client.execute(env={**os.environ, "JNR_NOTEBOOK_FAST": "1"})
    except CellExecutionError as exc:
        pytest.fail(f"{path.name}: a cell failed:\n{ANSI_ESCAPE.sub('', str(exc))}", pytrace=False)
    finally:
        # nbclient leaves a kernel it was handed running
        if client.kc is not None:
            client.kc.stop_channels()
        if km.has_kernel:
            km.shutdown_kernel(now=True)

    reported = PREFIX_LINE.search(_stream_text(nb.cells[-1]))
    assert reported, f"{path.name}: the interpreter probe printed nothing: {nb.cells[-1].get('outputs')}"
    assert Path(reported.group(1).strip()).resolve() == Path(sys.prefix).resolve(), (
        f"{path.name} ran on another interpreter ({reported.group(1)}) than the tests ({sys.prefix})"
    )
