"""The drawing libraries of the notebook (the ``notebook`` extra), imported when a function draws."""

from __future__ import annotations

import importlib

from rig.errors import SetupError

NOTEBOOK_EXTRA = 'pip install -e ".[notebook]"'


def require(module: str):
    """Import one of the drawing libraries, or raise :class:`rig.errors.SetupError` naming the install."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise SetupError(f"pipeline.notebook needs {module.split('.')[0]} ({NOTEBOOK_EXTRA}): {exc}") from None


__all__ = ["NOTEBOOK_EXTRA", "require"]
