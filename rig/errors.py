"""The errors jnr raises on purpose, under one base, so callers (and the ``jnr`` command line) can tell
a user's bad input from a broken installation without listing every class.

=======================  =========================================================================
class                    meaning
=======================  =========================================================================
:class:`JnrError`        base of all of them
:class:`InputError`      the input is wrong: a file, an argument, a setting (also a ``ValueError``);
                         the command line ends with one line and exit status 2
:class:`SetupError`      the installation is wrong: a missing or corrupt asset, a missing library
                         (also a ``RuntimeError``); exit status 1
=======================  =========================================================================

Every package's own error class derives from one of these (``render`` imports nothing of jnr, so its
``LLVMError`` is a plain ``RuntimeError`` that the command line maps to exit status 1 by name).
"""

from __future__ import annotations


class JnrError(Exception):
    """Base of the errors jnr raises on purpose."""


class InputError(JnrError, ValueError):
    """Bad input (a file, an argument, a setting); the message says what and how to fix it."""


class SetupError(JnrError, RuntimeError):
    """A broken installation (asset, library); the message says what is missing."""


class ShapeError(InputError):
    """A tensor or array argument has the wrong shape (message: function, argument, expected, got)."""


def shape_error(func: str, arg: str, expected: str, got: object) -> ShapeError:
    """The one message for a wrong shape: ``"{func}: {arg} must have shape {expected}, got {got}"``.

    Example:
        >>> str(shape_error("skin_vertices", "weights", "(V, J)", (3, 2, 1)))
        'skin_vertices: weights must have shape (V, J), got (3, 2, 1)'
    """
    return ShapeError(f"{func}: {arg} must have shape {expected}, got {got}")


def check_shape(ok: bool, func: str, arg: str, expected: str, got: object) -> None:
    """Raise :func:`shape_error` unless ``ok`` (the caller's test of the shape, e.g. ``x.shape[-1] == 3``)."""
    if not ok:
        raise shape_error(func, arg, expected, got)


def check_faces(func: str, faces, num_vertices: int, error: type[InputError] = InputError):
    """``faces`` as an ``(F, 3)`` int64 array of a mesh of ``num_vertices`` vertices (``F > 0``), or
    :func:`shape_error` (another shape or dtype) / ``error`` (an index outside the vertices) naming ``func``."""
    import numpy as np

    f = np.asarray(faces)
    check_shape(
        f.ndim == 2 and f.shape[1] == 3 and len(f) > 0 and np.issubdtype(f.dtype, np.integer),
        func,
        "faces",
        "(F, 3) integer with F > 0",
        f.shape,
    )
    if f.min() < 0 or f.max() >= num_vertices:
        raise error(f"{func}: faces index outside the {num_vertices} vertices")
    return f.astype(np.int64)


__all__ = ["InputError", "JnrError", "SetupError", "ShapeError", "check_shape", "shape_error"]


def is_number(value: object) -> bool:
    """Whether a value read from a file is a real number: an int or float (Python's or NumPy's), never a
    boolean or a string (``true`` and ``"1.0"`` in a JSON parameter file are refused, not read as 1).

    Example:
        >>> is_number(1.5), is_number(2), is_number(True), is_number("1.0")
        (True, True, False, False)
    """
    import numbers

    return isinstance(value, numbers.Real) and not isinstance(value, bool)
