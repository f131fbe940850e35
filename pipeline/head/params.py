"""``params.json``: one schema for every fit (photo, views, scan), carrying its fit and its head model.

A file is one JSON object::

    {"format": "jnr-params/2",
     "fit": "photo" | "views" | "scan",          # what wrote it
     "model": "jnr" | "asm",                      # the head model (rig.head_model.create(model))
     "units": {"rotate": "deg", "translate": "mm", "scale": "factor", ...},
     ...the model's entries...                    # jnr: "joints" (by channel name), "latent_z", "expressions"
                                                  # asm: "asm" (bones by name), "expressions"
     ...the fit's entries...}                     # photo: camera, pose, light, albedo; views: views;
                                                  # scan: pose, input

A JNR fit's ``joints`` entry is also a ``jnr rig edit`` parameter file. The files of earlier versions
(``jnr-photo-params/1``, ``jnr-scan-params/1``, ``jnr-multiview-params/1``, whose model was the optional
``"skinning"`` key) are read as well.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from rig.errors import InputError
from rig.head_model import HeadModel, HeadModelError, HeadParams, model_entries
from rig.io.inputs import loads_json_strict, regular_file
from rig.io.params import check_units
from rig.parameters import ParameterError

PARAMS_FILE = "params.json"
MAX_PARAMS_BYTES = 64 << 20
"""The largest parameter file read (64 MiB; a fit's is a few kB, an ASM fit's < 1 MB)."""
PARAMS_FORMAT = "jnr-params/2"
FIT_KINDS = ("photo", "views", "scan", "track")
"""What may write a ``params.json``: ``jnr fit PHOTO``, ``jnr fit --views``, ``jnr fit-scan``, ``jnr track``."""
LEGACY_FORMATS = {"jnr-photo-params/1": "photo", "jnr-multiview-params/1": "views", "jnr-scan-params/1": "scan"}
"""The formats of earlier versions and the fit each was written by."""
UNITS = {"rotate": "deg", "translate": "mm", "scale": "factor"}
"""The ``units`` entry of every file (a photo fit adds its pixel convention)."""
SCHEMA_KEYS = ("format", "fit", "model", "skinning", "units", "retargeted_from")
"""The keys that are the schema's own, neither the model's nor the fit's (``retargeted_from``: what
``jnr retarget`` adds to the target fit's file)."""
FIT_ENTRIES = {
    "photo": ("camera", "pose", "light", "albedo"),
    "views": ("pose_description", "views"),
    "scan": ("pose", "input"),
    "track": ("track",),
    None: (),
}
"""The keys each fit adds to its ``params.json`` (a bare head, fit None, has the model's only); a file of this
format with any other key is refused (a misspelt key must not be silently ignored)."""


class ParamsFileError(InputError):
    """A ``params.json`` that is missing, unreadable or not a jnr fit's (exit status 2 on the CLI)."""


@dataclass(frozen=True)
class FitParams:
    """A fit's ``params.json``, read.

    Attributes:
        fit: the fit that wrote it (:data:`FIT_KINDS`), or None for a bare head (a dict of the model's entries
            only, as a notebook or a test makes).
        model: the head model's kind (``jnr``, ``asm``).
        data: the whole JSON object (the model's and the fit's entries by their keys).
    """

    fit: str | None
    model: str
    data: Mapping


def params_payload(model: HeadModel, params: HeadParams, *, fit: str, units: Mapping | None = None, **entries) -> dict:
    """The ``params.json`` object of a fit: the schema's keys, ``model.to_dict(params)``, then ``entries``
    (the fit's own: ``camera``, ``pose``, ``light``, ``input``, ``views``, ...).

    Raises:
        ValueError: an unknown ``fit``, an entry that would overwrite the schema's or the model's keys, or one
            :data:`FIT_ENTRIES` does not list for ``fit`` (its readers would refuse the file).
    """
    if fit not in FIT_KINDS:
        raise InputError(f"params_payload: fit must be one of {FIT_KINDS}, got {fit!r}")
    head = model.to_dict(params)
    clash = sorted(set(entries) & (set(head) | set(SCHEMA_KEYS)))
    if clash:
        raise InputError(f"params_payload: entries {clash} are the schema's or the model's")
    undeclared = sorted(set(entries) - set(FIT_ENTRIES[fit]))
    if undeclared:  # the readers refuse keys FIT_ENTRIES does not list: declare them there first
        raise InputError(f"params_payload: entries {undeclared} of a {fit} fit are not in FIT_ENTRIES")
    return {
        "format": PARAMS_FORMAT,
        "fit": fit,
        "model": model.kind,
        "units": dict(units or UNITS),
        **head,
        **entries,
    }


def read_params(data: object, source: str | Path = PARAMS_FILE) -> FitParams:
    """Check a parsed ``params.json`` (this schema or an earlier one) and say which fit and model wrote it.

    Raises:
        ParamsFileError: not a JSON object of a known jnr format.
    """
    if not isinstance(data, Mapping):
        raise ParamsFileError(f"{source} is not a jnr fit's parameter file (not a JSON object)")
    try:
        check_units(data.get("units"), source)  # cm or radians are refused, not read as mm and degrees
    except ParameterError as exc:
        raise ParamsFileError(str(exc)) from None
    fmt = data.get("format")
    if fmt == PARAMS_FORMAT:
        fit, model = data.get("fit"), data.get("model")
        if fit not in FIT_KINDS or not isinstance(model, str):
            raise ParamsFileError(f"{source}: format {PARAMS_FORMAT} needs 'fit' in {list(FIT_KINDS)} and 'model'")
        _check_keys(data, fit, model, source)
        return FitParams(fit, model, data)
    if fmt in LEGACY_FORMATS:
        return FitParams(LEGACY_FORMATS[fmt], str(data.get("skinning", "jnr")), data)
    if fmt is None and ("model" in data or "skinning" in data or {"joints", "latent_z", "expressions"} <= set(data)):
        # a bare head (a notebook's or a test's dict, or the viewer's "Save pose"; no fit around it)
        model = str(data.get("model", data.get("skinning", "jnr")))
        _check_keys(data, None, model, source)
        return FitParams(None, model, data)
    raise ParamsFileError(
        f"{source} is not a jnr fit's parameter file (format {fmt!r}; expected {PARAMS_FORMAT!r} "
        f"or one of {sorted(LEGACY_FORMATS)})"
    )


def _check_keys(data: Mapping, fit: str | None, model: str, source) -> None:
    """Refuse keys neither the schema, the head model nor the fit writes (:data:`FIT_ENTRIES`; a head model
    that does not declare its ``entries`` is not checked)."""
    try:
        entries = model_entries(model)
    except HeadModelError as exc:
        raise ParamsFileError(f"{source}: {exc}") from None
    if entries is None:
        return
    known = {*SCHEMA_KEYS, *entries, *FIT_ENTRIES[fit]}
    unknown = sorted(str(k) for k in set(data) - known)
    if unknown:
        raise ParamsFileError(
            f"{source}: unknown key(s) {unknown} in a {fit or 'head'} parameter file of model {model!r}; "
            f"known: {sorted(known)}"
        )


def load_params_file(path: str | Path) -> FitParams:
    """Read and check a ``params.json`` (:func:`read_params`).

    Raises:
        ParamsFileError: missing, unreadable, not JSON, or not a jnr fit's.
    """
    path = Path(path)
    try:
        regular_file(path, "parameter file", MAX_PARAMS_BYTES)
        data = loads_json_strict(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ParamsFileError(f"{path} not found") from None
    except InputError as exc:
        raise ParamsFileError(str(exc)) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ParamsFileError(f"{path} is not a readable JSON file ({exc})") from None
    except ValueError as exc:  # a key twice in one object
        raise ParamsFileError(f"{path}: {exc}") from None
    except RecursionError:
        raise ParamsFileError(f"{path} is nested too deeply to be a jnr parameter file") from None
    return read_params(data, path)
