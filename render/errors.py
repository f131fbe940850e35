"""The error the render package raises on purpose for a malformed argument.

``render`` imports nothing of jnr (meshes come in as arrays), so it cannot use :class:`rig.errors.InputError`:
its own :class:`RenderArgumentError` is a ``ValueError``. The render functions only ever receive arrays the
pipeline made, so on the command line this error means a defect in jnr, not the user's input: ``jnr`` exits
with status 1 and names where it was raised.
"""

from __future__ import annotations


class RenderArgumentError(ValueError):
    """An argument of a render function is malformed (shape, dtype, non-finite or out-of-range values)."""


__all__ = ["RenderArgumentError"]
