"""The fitted head: one type that every fit result and every reader of a fit folder becomes.

A :class:`FittedHead` is a head model (:mod:`rig.head_model`), its parameters, and the arrays of its
forward pass (posed and rest vertices, skinning weights, joint transforms, ARKit coefficients), with what
its ``params.json`` says about the fit around it (camera, pose, input frame) and, from a folder, the
photo texture. The outputs, ``jnr rig edit``, ``jnr animate``/``retarget``, ``jnr accessory``, the
notebook and the viewer all take one.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.head.params import PARAMS_FILE, FitParams, ParamsFileError, load_params_file, read_params
from rig.errors import InputError, check_shape
from rig.expressions import ExpressionError
from rig.head_model import (
    HeadModel,
    HeadModelError,
    HeadParams,
    HeadPose,
    JnrHead,
    create_for,
    create_from_dict,
    is_posable,
)
from rig.io.gltf.encoding import is_png
from rig.parameters import ParameterError

TEXTURE_FILE = "texture.png"


class NotPosableError(InputError):
    """A head whose model cannot be re-posed by the rig's joints (an ASM fit) given to a task that needs it."""


@dataclass(frozen=True, eq=False)
class FittedHead:
    """A fitted head (module docstring).

    Attributes:
        model: its head model (float64). params: its parameters.
        arrays: :meth:`HeadModel.forward` of them (``vertices``, ``rest``, ``weights``, ``joint_transforms``,
            ``expressions``; float64, rig space, mm).
        fit: the ``params.json`` it was read from (:class:`~pipeline.head.params.FitParams`: its fit's entries,
            camera, pose, input), or None for a head made from arrays.
        folder: the fit folder it was read from, or None.
        texture: the bytes of the folder's ``texture.png`` (a photo fit), or None.
        colours: ``(V, 3)`` sRGB in [0, 1] per vertex (a photo fit's albedo), or None.
    """

    model: HeadModel
    params: HeadParams
    arrays: HeadPose
    fit: FitParams | None = None
    folder: Path | None = None
    texture: bytes | None = None
    colours: np.ndarray | None = None

    @property
    def vertices(self) -> np.ndarray:
        """``(V, 3)`` the fitted head, rig space, mm."""
        return self.arrays.vertices

    @property
    def rest(self) -> np.ndarray:
        """``(V, 3)`` the template with the fitted expressions, mm."""
        return self.arrays.rest

    @property
    def weights(self) -> np.ndarray | None:
        """``(V, J)`` skinning weights (None for a model that is not posable)."""
        return self.arrays.weights

    @property
    def tau(self) -> np.ndarray | None:
        """``(J, 4, 4)`` the joints' channel transforms (None for a model that is not posable)."""
        return self.arrays.joint_transforms

    @property
    def expressions(self) -> np.ndarray:
        """``(E,)`` the ARKit coefficients (:data:`rig.expressions.EXPRESSION_NAMES`)."""
        return self.arrays.expressions

    @property
    def theta(self) -> np.ndarray:
        """``(P,)`` the joint channels (deg, mm, ``scale - 1``) of a posable head."""
        self.require_posable("joint channels")
        return np.asarray(self.params["joints"], np.float64)

    @property
    def faces(self) -> np.ndarray:
        """``(F, 3)`` the template's triangles."""
        return np.asarray(self.model.asset.faces)

    @property
    def asset(self):
        return self.model.asset

    def require_posable(self, task: str) -> None:
        """Raise :class:`NotPosableError` naming ``task`` unless the model is posable by the joints."""
        if not self.model.posable:
            raise NotPosableError(_not_posable(self.source, self.model.kind, task))

    @property
    def source(self) -> str:
        return str(self.folder) if self.folder is not None else "this head"

    def rest_with(self, expressions) -> np.ndarray:
        """``(V, 3)`` float64 the template with the ARKit coefficients ``expressions (E,)`` applied, mm."""
        c = _vector(expressions, len(self.expressions), "FittedHead.rest_with", "expressions", "(E,)")
        return self.model.rest(c)

    def pose(self, theta, expressions) -> np.ndarray:
        """The head re-posed: the rest shape of ARKit coefficients ``expressions (E,)`` skinned with the fit's
        weights by joint channels ``theta (P,)`` (deg, mm, ``scale - 1``): ``(V, 3)`` float64, rig space, mm."""
        self.require_posable("re-posing")
        t = _vector(theta, len(self.params["joints"]), "FittedHead.pose", "theta", "(P,)")
        return self.model.pose(t, self.rest_with(expressions), self.weights)

    def with_params(self, params: HeadParams) -> FittedHead:
        """The same fit (folder, texture, colours) with other parameters of the same model."""
        return FittedHead(
            self.model, params, self.model.forward(params), self.fit, self.folder, self.texture, self.colours
        )


def _vector(values, size: int, function: str, name: str, shape: str) -> np.ndarray:
    v = np.asarray(values.detach().cpu() if hasattr(values, "detach") else values, np.float64)
    check_shape(v.shape == (size,), function, name, shape, v.shape)
    return v


def _not_posable(source: str | Path, kind: str, task: str) -> str:
    return f"{source}: an {kind.upper()} fit has no joint rig for {task} (fit with the jnr model)"


def fitted_head(
    data: Mapping | FitParams,
    *,
    model: HeadModel | None = None,
    folder: Path | None = None,
    texture: bytes | None = None,
    source: str | Path = PARAMS_FILE,
    posable_for: str | None = None,
) -> FittedHead:
    """The :class:`FittedHead` of a ``params.json`` (its parsed object or :class:`FitParams`).

    Args:
        model: a head model of the file's kind to reuse (default: a new one).
        posable_for: a task that needs a head posable by the joints (``"animation"``): a head of another
            model is refused before its parameters are read.

    Raises:
        ParamsFileError: not a jnr fit's parameters, unknown names, values outside limits, missing keys.
        NotPosableError: ``posable_for`` and a model that is not posable.
    """
    fit = data if isinstance(data, FitParams) else read_params(data, source)
    try:
        posable = is_posable(fit.model)
    except HeadModelError as exc:
        raise ParamsFileError(f"{source}: {exc}") from None
    if posable_for is not None and not posable:
        raise NotPosableError(_not_posable(folder or source, fit.model, posable_for))
    try:
        if model is not None and model.kind == fit.model:
            params = model.from_dict(fit.data)
        else:
            model, params = create_from_dict(fit.data, kind=fit.model)
        arrays = model.forward(params)
    except (HeadModelError, ParameterError, ExpressionError, ValueError, TypeError) as exc:
        raise ParamsFileError(f"{source}: {exc}") from None
    return FittedHead(model, params, arrays, fit, folder, texture)


def fitted_head_from_arrays(
    theta, z, expressions, *, model: JnrHead | None = None, colours: np.ndarray | None = None
) -> FittedHead:
    """The :class:`FittedHead` of a JNR fit's arrays ``theta (P,)``, ``z (50,)``, ``expressions (E,)``.

    Args:
        model: the :class:`rig.head_model.JnrHead` to use (default: a new one on the committed rig).
        colours: ``(V, 3)`` sRGB in [0, 1] per vertex, or None.
    """
    model = model or JnrHead()
    return fitted_head_from_params(model.params(theta, z, expressions), model=model, colours=colours)


def fitted_head_from_params(
    params: HeadParams, *, model: HeadModel | None = None, colours: np.ndarray | None = None
) -> FittedHead:
    """The :class:`FittedHead` of a fit's :class:`rig.head_model.HeadParams` (what its fit state says it
    fitted, :meth:`pipeline.fitting.state.FitState.head_params`), with ``model`` when it is of their kind
    (default: :func:`rig.head_model.create_for`). Values are taken as fitted (no limit checks: a fit may
    hold joints a little outside by a soft penalty)."""
    if model is None or model.kind != params.kind:
        model = create_for(params)
    return FittedHead(model, params, model.forward(params), colours=colours)


def _decodable_png(data: bytes) -> bool:
    """A PNG's signature and a file Pillow decodes (a signature followed by garbage is not a texture)."""
    if not is_png(data):
        return False
    import io

    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as image:
            image.load()
    except (OSError, ValueError, Image.DecompressionBombError):
        return False
    return True


def read_fit_folder(
    folder: str | Path, *, model: HeadModel | None = None, posable_for: str | None = None
) -> FittedHead:
    """The head of a ``jnr fit`` / ``jnr fit --views`` / ``jnr fit-scan`` output folder: its ``params.json``
    and, where there is one, its ``texture.png``.

    Args:
        model, posable_for: as :func:`fitted_head`.

    Raises:
        ParamsFileError: not a folder, no ``params.json``, unreadable, not a jnr fit's, bad parameters.
        NotPosableError: as :func:`fitted_head`.
    """
    folder = Path(folder)
    if not folder.is_dir():
        why = "not found" if not folder.exists() else "not a folder"
        raise ParamsFileError(f"{folder} is not a fit folder: {why} (give the --out folder of jnr fit or jnr fit-scan)")
    path = folder / PARAMS_FILE
    if not path.is_file():
        raise ParamsFileError(f"{folder} has no {PARAMS_FILE}: not a jnr fit folder")
    fit = load_params_file(path)
    texture_path = folder / TEXTURE_FILE
    texture = texture_path.read_bytes() if texture_path.is_file() else None
    if texture is not None and not _decodable_png(texture):
        warnings.warn(f"{texture_path} is not a PNG file; the head's files are written untextured", stacklevel=2)
        texture = None
    return fitted_head(fit, model=model, folder=folder, texture=texture, source=path, posable_for=posable_for)
