"""The rig's parameter file: a JSON object of named channel values (deg, mm, factor).

A file is ``{"joints": {"nose_tip.translate_y": 2.0, "neck.scale": 1.1, ...}}`` (optionally with a
``"units"`` entry), or just the inner object of names to values. Channels not named stay at rest; names
and limits are those of :data:`rig.parameters.CHANNELS`. The fits' own ``params.json`` files (joints,
latent Z and expressions, and the fit around them) follow :mod:`pipeline.head.params`.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from rig.errors import InputError
from rig.io.atomic import write_bytes_atomic
from rig.io.inputs import loads_json_strict, regular_file
from rig.parameters import ParameterError, params_to_theta, theta_to_params

__all__ = ["PARAMS_UNITS", "check_units", "load_params_json", "save_params_json"]

PARAMS_UNITS = {"rotate": "deg", "translate": "mm", "scale": "factor"}
"""The ``"units"`` entry :func:`save_params_json` writes."""
MAX_PARAMS_JSON_BYTES = 64 << 20
"""The largest parameter file read (64 MiB)."""


def check_units(units: object, source: str | Path) -> None:
    """A file's ``"units"`` entry must state the rig's units where it states any: ``rotate`` in ``deg``,
    ``translate`` in ``mm``, ``scale`` a ``factor`` (other keys, e.g. a photo fit's pixel convention, are the
    file's own). A file in other units is refused rather than read as if it were in these.

    Raises:
        ParameterError: ``units`` is not an object, or states another unit (one line naming it).
    """
    if units is None:
        return
    if not isinstance(units, dict):
        raise ParameterError(f"{source}: 'units' must be an object like {PARAMS_UNITS}, got {units!r}")
    wrong = {k: units[k] for k in PARAMS_UNITS if k in units and units[k] != PARAMS_UNITS[k]}
    if wrong:
        raise ParameterError(
            f"{source}: units {wrong} are not the rig's; jnr reads {PARAMS_UNITS} only (convert the values and "
            "the 'units' entry)"
        )


def load_params_json(path: str | Path, *, clamp: bool = False) -> torch.Tensor:
    """Read a parameter file: a JSON object of ``name: value``, or ``{"joints": {name: value}}``.

    Args:
        path: the JSON file.
        clamp: clamp out-of-limit values to the limits with a warning instead of raising.

    Returns:
        ``(P,)`` float32 flat parameters (:func:`rig.parameters.params_to_theta`).

    Raises:
        FileNotFoundError: the file does not exist.
        ParameterError: the file is not valid JSON of that shape, or a name/value is bad.
    """
    path = Path(path)
    try:
        regular_file(path, "parameter file", MAX_PARAMS_JSON_BYTES)  # a device or FIFO is refused, not "missing"
    except InputError as exc:
        raise ParameterError(str(exc)) from None
    try:
        data = loads_json_strict(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ParameterError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise ParameterError(f"{path}: nested too deeply to be a parameter file") from None
    except ValueError as exc:  # a duplicate key
        raise ParameterError(f"{path}: {exc}") from None
    if isinstance(data, dict) and isinstance(data.get("joints"), dict):
        check_units(data.get("units"), path)
        data = data["joints"]
    if not isinstance(data, dict):
        raise ParameterError(f"{path}: expected a JSON object of parameter names to values")
    return params_to_theta(data, clamp=clamp)


def save_params_json(theta: torch.Tensor, path: str | Path, *, include_rest: bool = False) -> None:
    """Write ``{"units": ..., "joints": {name: value}}`` (deg, mm, factor) to ``path``, atomically.

    Args:
        theta: ``(P,)`` flat parameters.
        path: the destination file; its folder must exist.
        include_rest: also write the channels at rest (by default only the ones that moved).
    """
    payload = {"units": dict(PARAMS_UNITS), "joints": theta_to_params(theta, include_rest=include_rest)}
    write_bytes_atomic(path, (json.dumps(payload, indent=2, sort_keys=False) + "\n").encode("utf-8"))
