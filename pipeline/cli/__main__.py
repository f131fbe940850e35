"""``python -m pipeline.cli ...``: the same as ``jnr ...``."""

from pipeline.cli import run

run()
