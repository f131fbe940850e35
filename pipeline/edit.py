"""The rig posed by a parameter file, written as a mesh: what ``jnr rig export`` / ``jnr rig edit`` do.

A parameter file is either joint parameters (``{"joints": {"nose_tip.translate_z": 5.0, ...}}`` or the
bare mapping, :func:`rig.io.params.load_params_json`) or the ``params.json`` of a fit (``jnr fit`` /
``jnr fit-scan``: joints, latent Z and expressions, all used). OBJ and PLY hold the posed mesh; glTF
(``.glb``/``.gltf``) the rest mesh with posable joints, skin weights and the pose as node transforms.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from pipeline.files import check_output, staged_file
from pipeline.formats import MESH_FORMATS, MESH_SUFFIXES
from pipeline.head.fitted import FittedHead, fitted_head
from pipeline.head.params import PARAMS_FORMAT, ParamsFileError
from pipeline.head.skinned import write_skinned_head
from rig.head_model import head_model_kinds, is_posable
from rig.io.mesh import export_mesh
from rig.io.params import load_params_json
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS, ParameterError, params_to_theta, theta_to_params

FIT_PARAMS_KEYS = {"joints", "latent_z", "expressions"}
"""The keys of a JNR fit's ``params.json`` that make the head."""
PARAMS_FILE_KEYS = {"joints", "units", "format"}
"""The keys a joint parameter file may hold."""


def _is_fit_params(data: object) -> bool:
    """Whether a parsed parameter file is a fit's ``params.json`` (rather than joint parameters)."""
    return isinstance(data, dict) and (
        data.get("format") == PARAMS_FORMAT
        or "skinning" in data
        or "model" in data
        or bool((FIT_PARAMS_KEYS - {"joints"}) & set(data))
    )


def load_edit_params(params: str | Path | None, clamp: bool = False) -> tuple[torch.Tensor | None, FittedHead | None]:
    """Read a parameter file: ``(theta (P,) float64 tensor, None)`` for joint parameters (zeros for
    None: the rest pose), or ``(None, head)`` for the ``params.json`` of a fit, whose head (joints, latent Z
    and expressions, all used) is a :class:`pipeline.head.fitted.FittedHead`.

    Args:
        clamp: clamp joint parameters outside their limits (with a warning) instead of refusing them.

    Raises:
        ParameterError: unreadable file, unknown keys or names, values outside limits, a fit's file
            with ``clamp``, a fit whose head model has no joints to export (ASM).
    """
    if params is None:
        return torch.zeros(NUM_PARAMETERS, dtype=torch.float64), None
    path = Path(params)
    try:
        data = json.loads(path.read_text()) if path.is_file() else None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
        data = None  # load_params_json reports it
    if _is_fit_params(data):
        kind = str(data.get("model", data.get("skinning", "jnr")))
        if kind not in head_model_kinds():
            raise ParameterError(f"{path}: unknown head model {kind!r}; known: {', '.join(head_model_kinds())}")
        if not is_posable(kind):
            raise ParameterError(
                f"{path} is the parameter file of an {kind.upper()} fit; joint edits and the skinned export take "
                f"fits posable by the rig's joints (the {kind.upper()} fit's mesh is its mesh.ply / mesh.obj)"
            )
        missing = sorted(FIT_PARAMS_KEYS - set(data))
        if missing:
            raise ParameterError(f"{path}: a fit's parameter file needs {sorted(FIT_PARAMS_KEYS)}; {missing} missing")
        if clamp and isinstance(data.get("joints"), dict):
            # the viewer's "Save pose" of a fit (joints with the fit's latent Z and expressions): its joints
            # clamped into their limits like a joint file's, with the same warning
            data = {**data, "joints": theta_to_params(params_to_theta(data["joints"], clamp=True, dtype=torch.float64))}
        try:
            return None, fitted_head(data, source=path)
        except ParamsFileError as exc:
            raise ParameterError(str(exc)) from None
    if isinstance(data, dict) and isinstance(data.get("joints"), dict):
        unknown = sorted(set(data) - PARAMS_FILE_KEYS)
        if unknown:
            raise ParameterError(
                f"{path}: unknown key(s) {unknown}; a parameter file holds {sorted(PARAMS_FILE_KEYS)} "
                f"(or a fit's {sorted(FIT_PARAMS_KEYS)})"
            )
    return load_params_json(path, clamp=clamp).double(), None


def write_head(path: str | Path, fmt: str, theta, rig=None, fit: FittedHead | None = None) -> None:
    """Write the rig posed by ``theta (P,)`` (deg, mm, factors) as OBJ/PLY (posed vertices, mm) or
    skinned glTF (rest mesh, posable joints); with ``fit`` (a fit's head, :func:`load_edit_params`) the
    fitted head instead.

    Args:
        fmt: ``"obj"``, ``"ply"`` or ``"gltf"`` (:data:`MESH_FORMATS`), whatever ``path``'s suffix.
        rig: the float64 :class:`rig.model.JointRig` (default: the committed one).
    """
    if fit is not None:
        asset, posed, weights, tau, coefficients = fit.asset, fit.vertices, fit.weights, fit.tau, fit.expressions
    else:
        rig = rig or JointRig(dtype=torch.float64)
        asset = rig.asset
        with torch.no_grad():
            posed = rig(theta[None]).vertices[0].numpy()
            tau = rig.channel_transforms(theta[None])[0].numpy()
        weights, coefficients = asset.weights, None
    if fmt == "gltf":
        write_skinned_head(path, asset, weights, tau, coefficients)
    else:
        export_mesh(path, posed, asset.faces, face_uvs=asset.face_uvs if fmt == "obj" else None, file_format=fmt)


def write_edited_head(
    params: str | Path | None, out: str | Path, fmt: str, *, clamp: bool = False, force: bool = False
) -> bool:
    """Write the head posed by the parameter file ``params`` (None: the rest pose) to ``out``
    atomically (:func:`load_edit_params`, :func:`write_head`).

    Returns:
        Whether ``params`` was a fit's ``params.json`` (the fitted head: joints, latent Z, expressions).

    Raises:
        ParameterError: as :func:`load_edit_params`; pipeline.files.OutputError: ``out`` is refused.
    """
    inputs = [params] if params else []
    check_output(out, force=force, inputs=inputs, kind="file")
    theta, fit = load_edit_params(params, clamp)
    with staged_file(out, force, inputs=inputs) as tmp:
        write_head(tmp, fmt, theta, fit=fit)
    return fit is not None


__all__ = [
    "FIT_PARAMS_KEYS",
    "MESH_FORMATS",
    "MESH_SUFFIXES",
    "PARAMS_FILE_KEYS",
    "load_edit_params",
    "write_edited_head",
    "write_head",
]
