"""Head models behind one interface: ``create(kind)`` (the shape of smplx's ``create(model_type)``).

A head model turns named, limited parameters into a head in rig space (mm, right-handed, +Y up, +Z out of
the face, +X the subject's left). Every model has:

* ``kind``: its name in files (``params.json``'s ``"model"``) and on the command line;
* :meth:`HeadModel.groups`: its parameter groups, each a :class:`ParameterGroup` of named floats with
  limits and units (the fits' priors and the sliders of the notebook and viewer read them);
* :meth:`HeadModel.forward`: :class:`HeadParams` -> :class:`HeadPose` (posed and rest vertices, and for a
  posable model the skinning weights and the joints' channel transforms that the skinned glTF carries);
* :meth:`HeadModel.to_dict` / :meth:`HeadModel.from_dict`: the model's entries of ``params.json``.

Two models are registered: ``jnr`` (:class:`JnrHead`: the 52-joint rig, 107 channels, neural skinning of a
50-d latent Z, the 52 ARKit shapes) and ``asm`` (:class:`AsmHead`: the Adaptive Skinning Model's bones and
UV-space Gaussian-mixture weights on the same template, the same ARKit shapes; in :mod:`rig.asm_head`). A new
model is one class with these methods plus ``register_head_model(kind, cls)``: its parameters then load and save,
its heads are written by every output, and a model whose groups are flat vectors is fitted to a photo by
``jnr fit --set model=KIND`` (:mod:`pipeline.fitting.model_state`). The shared types are in :mod:`rig.head_params`
(re-exported here).

Example:
    >>> model = create("jnr")
    >>> head = model.forward(model.initial())
    >>> head.vertices.shape
    (4874, 3)
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np
import torch

from rig.asm_head import AsmHead
from rig.asset import RigAsset, load_asset
from rig.errors import is_number
from rig.expressions import EXPRESSION_NAMES, ExpressionModel, coefficients_from_dict
from rig.head_params import (
    HeadModelError,
    HeadParams,
    HeadPose,
    ParameterGroup,
    expression_group,
    require_entries,
    vector_of,
)
from rig.lbs import skin_vertices, skin_vertices_shared_weights
from rig.model import JointRig
from rig.parameters import CHANNELS, params_to_theta, theta_limits, theta_to_params
from rig.skinning.neural import LATENT, LATENT_LIMIT, NeuralSkinning, load_neural

__all__ = [
    "AsmHead",
    "HeadModel",
    "HeadModelError",
    "HeadParams",
    "HeadPose",
    "JnrHead",
    "ParameterGroup",
    "create",
    "create_for",
    "create_from_dict",
    "head_model_kinds",
    "is_posable",
    "jnr_vertices",
    "model_entries",
    "register_head_model",
    "unregister_head_model",
]


@runtime_checkable
class HeadModel(Protocol):
    """What every head model provides (module docstring)."""

    kind: ClassVar[str]
    posable: ClassVar[bool]
    """Whether the head is the rig's joints with fixed skinning weights: it can be re-posed by joint
    channels, exported as a skinned glTF, animated and given accessories."""
    asset: RigAsset

    def groups(self) -> tuple[ParameterGroup, ...]: ...

    def initial(self) -> HeadParams: ...

    def forward(self, params: HeadParams) -> HeadPose: ...

    def vertices(self, values: Mapping[str, Any], vertex_ids: torch.Tensor | None = None) -> torch.Tensor:
        """The differentiable, batched forward every fit can call: each group's ``(B, n)`` tensor by group name
        (ASM: its :class:`rig.skinning.asm.AsmParameters` of batch ``B``) -> ``(B, U, 3)`` posed vertices, mm."""
        ...

    def to_dict(self, params: HeadParams) -> dict: ...

    def from_dict(self, data: Mapping) -> HeadParams: ...

    @staticmethod
    def options_from_dict(data: Mapping) -> dict:
        """The :func:`create` options a ``params.json`` of this model needs (e.g. ASM's components)."""
        ...


_REGISTRY: dict[str, Callable[..., HeadModel]] = {}


def register_head_model(kind: str, factory: Callable[..., HeadModel]) -> None:
    """Make ``create(kind)`` build ``factory(asset=..., **options)``."""
    _REGISTRY[kind] = factory


def unregister_head_model(kind: str) -> None:
    """Forget ``kind`` (a plug-in's or a test's model); the built-in ``jnr`` and ``asm`` cannot be removed."""
    if kind in ("jnr", "asm"):
        raise HeadModelError(f"the built-in head model {kind!r} cannot be unregistered")
    _REGISTRY.pop(kind, None)


def is_posable(kind: str) -> bool:
    """Whether heads of model ``kind`` are posable by the rig's joints (:attr:`HeadModel.posable`), without
    building the model.

    Raises:
        HeadModelError: an unknown kind.
    """
    if kind not in _REGISTRY:
        raise HeadModelError(f"unknown head model {kind!r}; known: {', '.join(_REGISTRY)}")
    return bool(getattr(_REGISTRY[kind], "posable", False))


def head_model_kinds() -> tuple[str, ...]:
    """The registered kinds, in registration order."""
    return tuple(_REGISTRY)


def create(kind: str = "jnr", *, asset: RigAsset | None = None, **options) -> HeadModel:
    """The head model ``kind`` (float64) on ``asset`` (default: the committed template).

    Raises:
        HeadModelError: an unknown kind.
    """
    if kind not in _REGISTRY:
        raise HeadModelError(f"unknown head model {kind!r}; known: {', '.join(_REGISTRY)}")
    return _REGISTRY[kind](asset=asset, **options)


def create_for(params: HeadParams, *, asset: RigAsset | None = None, **options) -> HeadModel:
    """The head model that ``params`` belong to (their kind; options such as ASM's components from their
    shapes), on ``asset``.

    Raises:
        HeadModelError: an unknown kind.
    """
    if params.kind not in _REGISTRY:
        raise HeadModelError(f"unknown head model {params.kind!r}; known: {', '.join(_REGISTRY)}")
    derived = getattr(_REGISTRY[params.kind], "options_from_params", lambda _params: {})(params)
    return create(params.kind, asset=asset, **{**derived, **options})


def create_from_dict(
    data: Mapping, *, kind: str = "jnr", asset: RigAsset | None = None
) -> tuple[HeadModel, HeadParams]:
    """The model and parameters of one head's entries of a ``params.json`` (``data``), for the model
    ``kind`` (the file's ``"model"``).

    Raises:
        HeadModelError: an unknown kind, missing keys; ParameterError / ExpressionError: bad names or values.
    """
    if kind not in _REGISTRY:
        raise HeadModelError(f"unknown head model {kind!r}; known: {', '.join(_REGISTRY)}")
    options = getattr(_REGISTRY[kind], "options_from_dict", lambda _data: {})(data)
    model = create(kind, asset=asset, **options)
    return model, model.from_dict(data)


def _latent(values) -> np.ndarray:
    """``(50,)`` float64 latent Z from a parameter file's list: numbers only, within
    :data:`rig.skinning.neural.LATENT_LIMIT` (the range the decoder was trained on)."""
    if not isinstance(values, list | tuple) or len(values) != LATENT:
        raise HeadModelError(f"latent_z must be a list of {LATENT} numbers, got {type(values).__name__}")
    for i, value in enumerate(values):
        if not is_number(value) or not np.isfinite(value):
            raise HeadModelError(f"latent_z[{i}] must be a finite number, got {value!r}")
        if abs(value) > LATENT_LIMIT:
            raise HeadModelError(
                f"latent_z[{i}] = {value:.6g} is outside [-{LATENT_LIMIT:g}, {LATENT_LIMIT:g}], the range the "
                f"skinning decoder was trained on (Z ~ N(0, I))"
            )
    return np.asarray(values, np.float64)


def model_entries(kind: str) -> tuple[str, ...] | None:
    """The ``params.json`` keys of head model ``kind`` (its optional ``entries``; None for a model that does
    not declare them), without building the model.

    Raises:
        HeadModelError: an unknown kind.
    """
    if kind not in _REGISTRY:
        raise HeadModelError(f"unknown head model {kind!r}; known: {', '.join(_REGISTRY)}")
    entries = getattr(_REGISTRY[kind], "entries", None)
    return None if entries is None else tuple(entries)


def jnr_vertices(
    rig: JointRig,
    expressions: ExpressionModel,
    theta: torch.Tensor,
    weights: torch.Tensor,
    coefficients: torch.Tensor,
    vertex_ids: torch.Tensor | None = None,
) -> torch.Tensor:
    """JNR's head, the one place it is computed: the template with the ARKit shapes, skinned by the joints
    (linear blend skinning, JNR eq. 2). Pure and differentiable in ``theta``, ``weights`` and ``coefficients``.

    Args:
        rig: the joint rig; expressions: its :class:`rig.expressions.ExpressionModel` (same dtype).
        theta: ``(B, P)`` joint channels (deg, mm, ``scale - 1``).
        weights: ``(V, K)`` or ``(B, V, K)`` skinning weights (the neural skinning's, or ``rig.dense_weights()``).
        coefficients: ``(B, E)`` the ARKit coefficients.
        vertex_ids: ``(U,)`` int64: only those vertices (a landmark or point subset), or None for all ``V``.

    Returns:
        ``(B, U, 3)`` the posed vertices, rig space, mm, in the expression model's dtype (the joints' transforms
        are computed in the rig's).
    """
    template = expressions.template if vertex_ids is None else expressions.template[vertex_ids]
    rest = template + expressions(coefficients, vertex_ids)  # (B, U, 3)
    _, skinning = rig.joint_transforms(theta.to(rig.template.dtype))
    skinning, weights = skinning.to(rest.dtype), weights.to(rest.dtype)
    if vertex_ids is not None:
        weights = weights[..., vertex_ids, :]
    if weights.dim() == 2:  # one set of weights for the batch: the blended transforms as one matrix product
        return skin_vertices_shared_weights(rest, weights, skinning)
    return skin_vertices(rest, weights, skinning)


class JnrHead:
    """JNR's head: 107 joint channels, the neural skinning's latent Z and the 52 ARKit shapes.

    Args:
        asset: the rig asset (default: the committed one).
        rig: the :class:`rig.model.JointRig` to use: a float64 one as it is, another one is rebuilt in float64
            on its asset (which then wins over ``asset``).
        neural: the learned skinning (default: the committed one, loaded on first use); one on another rig
            (a fit's float32 one) is converted onto the float64 rig.
    """

    kind: ClassVar[str] = "jnr"
    posable: ClassVar[bool] = True
    entries: ClassVar[tuple[str, ...]] = ("joints", "latent_z", "expressions")
    """The keys of a ``params.json`` this model reads (:meth:`to_dict`)."""

    def __init__(
        self, asset: RigAsset | None = None, *, rig: JointRig | None = None, neural: NeuralSkinning | None = None
    ) -> None:
        if rig is None or rig.template.dtype != torch.float64:
            rig = JointRig(rig.asset if rig is not None else asset or load_asset(), dtype=torch.float64)
        if neural is not None and neural.rig is not rig:
            # the fit's own learned skinning on the float64 rig: its linear weights (a float32 model's are
            # float32-rounded) and a float64 copy of its decoder
            neural = NeuralSkinning(rig, neural.linear_free.to(torch.float64), copy.deepcopy(neural.decoder))
        self.rig = rig
        self.asset = rig.asset
        self._neural = neural
        self._expressions: ExpressionModel | None = None

    @property
    def neural(self) -> NeuralSkinning:
        if self._neural is None:
            self._neural = load_neural(self.rig)[0]
        return self._neural

    @property
    def expression_model(self) -> ExpressionModel:
        if self._expressions is None:
            self._expressions = ExpressionModel(self.asset, dtype=torch.float64)
        return self._expressions

    def groups(self) -> tuple[ParameterGroup, ...]:
        low, high = (t.numpy() for t in theta_limits(torch.float64))
        inf = np.full(LATENT, np.inf)
        return (
            ParameterGroup("joints", tuple(c.name for c in CHANNELS), low, high, "deg / mm / scale - 1"),
            ParameterGroup("latent", tuple(f"z_{i}" for i in range(LATENT)), -inf, inf, "latent code"),
            expression_group(),
        )

    def initial(self) -> HeadParams:
        return HeadParams(
            self.kind,
            {
                "joints": np.zeros(len(CHANNELS)),
                "latent": np.zeros(LATENT),
                "expressions": np.zeros(len(EXPRESSION_NAMES)),
            },
        )

    def params(self, theta, z, expressions) -> HeadParams:
        """:class:`HeadParams` of arrays ``theta (P,)``, ``z (50,)``, ``expressions (E,)``."""
        return HeadParams(
            self.kind,
            {
                "joints": vector_of(theta, len(CHANNELS), "joints"),
                "latent": vector_of(z, LATENT, "latent_z"),
                "expressions": vector_of(expressions, len(EXPRESSION_NAMES), "expressions"),
            },
        )

    def weights(self, z) -> np.ndarray:
        """``(V, J)`` skinning weights decoded from the latent ``z (50,)``."""
        with torch.no_grad():
            return self.neural(torch.as_tensor(vector_of(z, LATENT, "latent_z"))[None])[0].numpy()

    def rest(self, expressions) -> np.ndarray:
        """``(V, 3)`` the template with the ARKit coefficients ``expressions (E,)`` applied, mm."""
        c = torch.as_tensor(vector_of(expressions, len(EXPRESSION_NAMES), "expressions"))
        with torch.no_grad():
            return self.expression_model.vertices(c[None])[0].numpy()

    def pose(self, theta, rest: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """``(V, 3)`` the rest shape ``rest (V, 3)`` skinned with ``weights (V, J)`` by ``theta (P,)``."""
        t = torch.as_tensor(vector_of(theta, len(CHANNELS), "joints"))[None]
        with torch.no_grad():
            out = self.rig(t, weights=torch.as_tensor(weights), vertices=torch.as_tensor(rest))
        return out.vertices[0].numpy()

    def vertices(self, values: Mapping[str, torch.Tensor], vertex_ids: torch.Tensor | None = None) -> torch.Tensor:
        """The differentiable, batched forward (:func:`jnr_vertices`): ``values`` ``{"joints": (B, P),
        "latent": (B, 50), "expressions": (B, E)}`` tensors (float32 or float64; gradients flow to each) ->
        ``(B, U, 3)`` posed vertices in their dtype, mm (``U``: ``vertex_ids`` or every vertex)."""
        theta = values["joints"]
        weights = self.neural(values["latent"].to(torch.float64))
        out = jnr_vertices(self.rig, self.expression_model, theta, weights, values["expressions"], vertex_ids)
        return out.to(theta.dtype)

    def forward(self, params: HeadParams) -> HeadPose:
        self._check(params)
        weights = self.weights(params["latent"])
        c = torch.as_tensor(vector_of(params["expressions"], len(EXPRESSION_NAMES), "expressions"))[None]
        theta = torch.as_tensor(vector_of(params["joints"], len(CHANNELS), "joints"))[None]
        with torch.no_grad():
            posed = jnr_vertices(self.rig, self.expression_model, theta, torch.as_tensor(weights), c)[0].numpy()
            tau = self.rig.channel_transforms(theta)[0].numpy()
        return HeadPose(posed, self.rest(params["expressions"]), weights, tau, c[0].numpy())

    def to_dict(self, params: HeadParams) -> dict:
        self._check(params)
        return {
            "joints": theta_to_params(torch.as_tensor(params["joints"]), include_rest=True),
            "latent_z": [float(x) for x in params["latent"]],
            "expressions": {n: float(c) for n, c in zip(EXPRESSION_NAMES, params["expressions"])},
        }

    def from_dict(self, data: Mapping) -> HeadParams:
        """Raises: HeadModelError (missing keys, a latent of the wrong length, with a value that is not a
        number or beyond :data:`rig.skinning.neural.LATENT_LIMIT`), ParameterError / ExpressionError
        (unknown names, values that are not numbers or outside limits)."""
        require_entries(data, ("joints", "expressions", "latent_z"))
        theta = params_to_theta(data["joints"], dtype=torch.float64).numpy()
        c = coefficients_from_dict(data["expressions"], dtype=torch.float64).numpy()
        return self.params(theta, _latent(data["latent_z"]), c)

    @staticmethod
    def options_from_dict(data: Mapping) -> dict:
        return {}

    @staticmethod
    def options_from_params(params: HeadParams) -> dict:
        return {}

    def _check(self, params: HeadParams) -> None:
        if params.kind != self.kind:
            raise HeadModelError(f"{self.kind} head model given {params.kind} parameters")


register_head_model("jnr", JnrHead)
register_head_model("asm", AsmHead)
