"""The rig posed by a parameter file, written as a mesh: what ``jnr rig export`` / ``jnr rig edit`` do.

A parameter file is either joint parameters (``{"joints": {"nose_tip.translate_z": 5.0, ...}}`` or the
bare mapping, :func:`rig.io.params.load_params_json`) or the ``params.json`` of a fit (``jnr fit`` /
``jnr fit-scan``: joints, latent Z and expressions, all used). OBJ and PLY hold the posed mesh; glTF
(``.glb``/``.gltf``) the rest mesh with posable joints, skin weights and the pose as node transforms.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

MESH_FORMATS = {"obj": ".obj", "ply": ".ply", "gltf": ".glb"}
"""Each mesh format and the suffix it is written with by default."""
MESH_SUFFIXES = {"obj": (".obj",), "ply": (".ply",), "gltf": (".glb", ".gltf")}
"""The suffixes each mesh format may be written with."""
FIT_PARAMS_KEYS = {"joints", "latent_z", "expressions"}
"""The keys of a fit's ``params.json`` that make the head."""
PARAMS_FILE_KEYS = {"joints", "units", "format"}
"""The keys a joint parameter file may hold."""


def load_edit_params(params: str | Path | None, clamp: bool = False) -> tuple[object, tuple | None]:
    """Read a parameter file: ``(theta (P,) float64 tensor, None)`` for joint parameters (zeros for
    None: the rest pose), or ``(None, arrays)`` for the ``params.json`` of a fit, whose joints, latent Z
    and expressions are all used (``arrays``: :func:`pipeline.scan.outputs.head_arrays_from_params`).

    Args:
        clamp: clamp joint parameters outside their limits (with a warning) instead of refusing them.

    Raises:
        ParameterError: unreadable file, unknown keys or names, values outside limits, a fit's file
            with ``clamp``.
    """
    import torch

    from rig.io.params import load_params_json
    from rig.parameters import NUM_PARAMETERS, ParameterError

    if params is None:
        return torch.zeros(NUM_PARAMETERS, dtype=torch.float64), None
    path = Path(params)
    try:
        data = json.loads(path.read_text()) if path.is_file() else None
    except (json.JSONDecodeError, UnicodeDecodeError):
        data = None  # load_params_json reports it
    if isinstance(data, dict) and data.get("skinning") == "asm":
        raise ParameterError(f"{path} is the parameter file of an ASM fit (skinning: asm); joint edits and the "
                             f"skinned export take JNR fits only (the ASM fit's mesh is its mesh.ply / mesh.obj)")
    if isinstance(data, dict) and (FIT_PARAMS_KEYS - {"joints"}) & set(data):
        missing = sorted(FIT_PARAMS_KEYS - set(data))
        if missing:
            raise ParameterError(f"{path}: a fit's parameter file needs {sorted(FIT_PARAMS_KEYS)}; {missing} missing")
        if clamp:
            raise ParameterError(f"{path} is the parameter file of a fit; --clamp applies to joint parameters only")
        from pipeline.scan.outputs import head_arrays_from_params

        try:
            return None, head_arrays_from_params(data)
        except (ValueError, TypeError) as exc:
            raise ParameterError(f"{path}: {exc}") from None
    if isinstance(data, dict) and isinstance(data.get("joints"), dict):
        unknown = sorted(set(data) - PARAMS_FILE_KEYS)
        if unknown:
            raise ParameterError(f"{path}: unknown key(s) {unknown}; a parameter file holds {sorted(PARAMS_FILE_KEYS)} "
                                 f"(or a fit's {sorted(FIT_PARAMS_KEYS)})")
    return load_params_json(path, clamp=clamp).double(), None


def write_head(path: str | Path, fmt: str, theta, rig=None, fit_arrays: tuple | None = None) -> None:
    """Write the rig posed by ``theta (P,)`` (deg, mm, factors) as OBJ/PLY (posed vertices, mm) or
    skinned glTF (rest mesh, posable joints); with ``fit_arrays`` (of a fit's ``params.json``,
    :func:`load_edit_params`) the fitted head instead.

    Args:
        fmt: ``"obj"``, ``"ply"`` or ``"gltf"`` (:data:`MESH_FORMATS`), whatever ``path``'s suffix.
        rig: the float64 :class:`rig.model.JointRig` (default: the committed one).
    """
    import torch

    from rig.io.mesh import export_mesh
    from rig.model import JointRig

    rig = rig or JointRig(dtype=torch.float64)
    asset = rig.asset
    if fit_arrays is not None:
        posed, _, weights, tau, coefficients = fit_arrays
    else:
        with torch.no_grad():
            posed = rig(theta[None]).vertices[0].numpy()
            tau = rig.channel_transforms(theta[None])[0].numpy()
        weights, coefficients = asset.weights, None
    if fmt == "gltf":
        write_skinned_head(path, asset, weights, tau, coefficients)
    else:
        export_mesh(path, posed, asset.faces, face_uvs=asset.face_uvs if fmt == "obj" else None,
                    file_format=fmt)


def write_skinned_head(path: str | Path, asset, weights: np.ndarray, tau: np.ndarray,
                       coefficients: np.ndarray | None = None, vertex_colors: np.ndarray | None = None,
                       base_color_texture: bytes | None = None, attachments=(), animation=None) -> None:
    """The skinned glTF of a head: the template as the bind mesh, the 52 ARKit shapes as morph targets named
    by ARKit (:func:`rig.expressions.morph_targets`) with ``coefficients (E,)`` as their weights (zeros when
    None), ``weights (V, J)``, the joint channel transforms ``tau (J, 4, 4)`` as the joints' pose,
    ``vertex_colors (V, 3)`` linear RGB in [0, 1] (glTF's ``COLOR_0`` is linear) and ``base_color_texture``
    the bytes of a PNG in the asset's UVs as the material's base colour (glTF multiplies it with
    ``COLOR_0``, so a textured head takes no vertex colours: ValueError); ``attachments``
    (:class:`rig.io.gltf.GltfAttachment`: accessories skinned to the same joints, their morph targets under the
    52 ARKit names) and ``animation`` (:class:`rig.io.gltf.GltfAnimation`) as :func:`rig.io.gltf.export_skinned_gltf`."""
    from rig.expressions import EXPRESSION_NAMES, morph_targets
    from rig.io.gltf import export_skinned_gltf

    if base_color_texture is not None and vertex_colors is not None:
        raise ValueError("write_skinned_head: a textured head takes no vertex colours (glTF would multiply them)")
    export_skinned_gltf(path, asset.vertices, asset.faces, joint_names=list(asset.joint_names),
                        parents=asset.parents, joint_positions=asset.joint_positions, weights=weights,
                        face_uvs=asset.face_uvs, vertex_colors=vertex_colors, joint_transforms=tau,
                        morph_targets=morph_targets(asset), morph_names=EXPRESSION_NAMES,
                        morph_weights=coefficients, base_color_texture=base_color_texture,
                        attachments=attachments, animation=animation)


def write_edited_head(params: str | Path | None, out: str | Path, fmt: str, *, clamp: bool = False,
                      force: bool = False) -> bool:
    """Write the head posed by the parameter file ``params`` (None: the rest pose) to ``out``
    atomically (:func:`load_edit_params`, :func:`write_head`).

    Returns:
        Whether ``params`` was a fit's ``params.json`` (the fitted head: joints, latent Z, expressions).

    Raises:
        ParameterError: as :func:`load_edit_params`; pipeline.files.OutputError: ``out`` is refused.
    """
    from pipeline.files import check_output, staged_file

    inputs = [params] if params else []
    check_output(out, force=force, inputs=inputs, kind="file")
    theta, fit_arrays = load_edit_params(params, clamp)
    with staged_file(out, force, inputs=inputs) as tmp:
        write_head(tmp, fmt, theta, fit_arrays=fit_arrays)
    return fit_arrays is not None


__all__ = ["FIT_PARAMS_KEYS", "MESH_FORMATS", "MESH_SUFFIXES", "PARAMS_FILE_KEYS", "load_edit_params",
           "write_edited_head", "write_head"]
