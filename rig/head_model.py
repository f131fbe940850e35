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
UV-space Gaussian-mixture weights on the same template, the same ARKit shapes). A new model is one class
with these methods plus ``register_head_model(kind, cls)``.

Example:
    >>> model = create("jnr")
    >>> head = model.forward(model.initial())
    >>> head.vertices.shape
    (4874, 3)
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np
import torch

from rig.asset import RigAsset, load_asset
from rig.errors import InputError, is_number
from rig.expressions import EXPRESSION_NAMES, ExpressionModel, coefficients_from_dict, expression_limits
from rig.lbs import skin_vertices, skin_vertices_shared_weights
from rig.model import JointRig
from rig.parameters import CHANNELS, params_to_theta, theta_limits, theta_to_params
from rig.skinning.asm import (
    DEFAULT_COMPONENTS,
    AdaptiveSkinning,
    AsmParameters,
    asm_params_from_dict,
    asm_params_to_dict,
)
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
]


class HeadModelError(InputError):
    """An unknown head model, or parameters that do not belong to the model (exit status 2 on the CLI)."""


@dataclass(frozen=True)
class ParameterGroup:
    """A named group of a model's parameters.

    Attributes:
        name: the group (``joints``, ``latent``, ``expressions``, ``asm``).
        names: ``(n,)`` the name of each float (``nose_tip.translate_y``, ``jawOpen``, ``z_0``).
        low, high: ``(n,)`` float64 limits (``-inf`` / ``inf`` where there is none).
        units: what the values are in.
    """

    name: str
    names: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray
    units: str

    @property
    def size(self) -> int:
        return len(self.names)


@dataclass(frozen=True)
class HeadParams:
    """One head's parameters.

    Attributes:
        kind: the model they belong to.
        values: each group's float64 array by group name (``joints (P,)``, ``latent (50,)``,
            ``expressions (E,)``; ASM: ``asm``, a dict of its :class:`rig.skinning.asm.AsmParameters`
            fields as arrays of batch 1, and ``expressions``).
    """

    kind: str
    values: Mapping[str, Any]

    def __getitem__(self, group: str):
        return self.values[group]

    def replace(self, **groups) -> HeadParams:
        """A copy with some groups replaced."""
        return HeadParams(self.kind, {**self.values, **groups})


@dataclass(frozen=True, eq=False)
class HeadPose:
    """A head made by :meth:`HeadModel.forward` (float64, rig space, mm).

    Attributes:
        vertices: ``(V, 3)`` the posed head.
        rest: ``(V, 3)`` the template with the expressions applied (the bind shape the joints skin).
        weights: ``(V, J)`` skinning weights, or None for a model a skinned glTF cannot carry.
        joint_transforms: ``(J, 4, 4)`` each joint's channel transform (the glTF joints' pose), or None.
        expressions: ``(E,)`` the ARKit coefficients (:data:`rig.expressions.EXPRESSION_NAMES`).
    """

    vertices: np.ndarray
    rest: np.ndarray
    weights: np.ndarray | None
    joint_transforms: np.ndarray | None
    expressions: np.ndarray


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


def _expression_group() -> ParameterGroup:
    low, high = (t.numpy() for t in expression_limits(torch.float64))
    return ParameterGroup("expressions", tuple(EXPRESSION_NAMES), low, high, "ARKit coefficient")


def _vector(values, size: int, what: str) -> np.ndarray:
    v = np.asarray(values, np.float64)
    if v.shape != (size,):
        raise HeadModelError(f"{what} must have {size} values, got shape {v.shape}")
    return v


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


def _require(data: Mapping, keys: tuple[str, ...]) -> None:
    missing = [k for k in keys if k not in data]
    if missing:
        raise HeadModelError(f"parameter file lacks {missing}")


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
            _expression_group(),
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
                "joints": _vector(theta, len(CHANNELS), "joints"),
                "latent": _vector(z, LATENT, "latent_z"),
                "expressions": _vector(expressions, len(EXPRESSION_NAMES), "expressions"),
            },
        )

    def weights(self, z) -> np.ndarray:
        """``(V, J)`` skinning weights decoded from the latent ``z (50,)``."""
        with torch.no_grad():
            return self.neural(torch.as_tensor(_vector(z, LATENT, "latent_z"))[None])[0].numpy()

    def rest(self, expressions) -> np.ndarray:
        """``(V, 3)`` the template with the ARKit coefficients ``expressions (E,)`` applied, mm."""
        c = torch.as_tensor(_vector(expressions, len(EXPRESSION_NAMES), "expressions"))
        with torch.no_grad():
            return self.expression_model.vertices(c[None])[0].numpy()

    def pose(self, theta, rest: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """``(V, 3)`` the rest shape ``rest (V, 3)`` skinned with ``weights (V, J)`` by ``theta (P,)``."""
        t = torch.as_tensor(_vector(theta, len(CHANNELS), "joints"))[None]
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
        c = torch.as_tensor(_vector(params["expressions"], len(EXPRESSION_NAMES), "expressions"))[None]
        theta = torch.as_tensor(_vector(params["joints"], len(CHANNELS), "joints"))[None]
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
        _require(data, ("joints", "expressions", "latent_z"))
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


class AsmHead:
    """The Adaptive Skinning Model (ASM, ICCV 2023; :mod:`rig.skinning.asm`) on the rig's template: 9-DoF
    bones with dynamic binding and Gaussian-mixture weights in UV space, plus the 52 ARKit shapes. Its
    weights and bind positions change per head, so it is not :attr:`posable` by the rig's joints.

    Args:
        asset: the rig asset. components: Gaussians per bone.
    """

    kind: ClassVar[str] = "asm"
    posable: ClassVar[bool] = False
    entries: ClassVar[tuple[str, ...]] = ("asm", "expressions")
    """The keys of a ``params.json`` this model reads (:meth:`to_dict`)."""

    def __init__(self, asset: RigAsset | None = None, *, components: int | None = None, rig=None) -> None:
        if rig is None or rig.template.dtype != torch.float64:
            rig = JointRig(rig.asset if rig is not None else asset or load_asset(), dtype=torch.float64)
        self.rig = rig
        self.asset = rig.asset
        self.model = AdaptiveSkinning(rig, components=components or DEFAULT_COMPONENTS)
        self._expressions = ExpressionModel(self.asset, dtype=torch.float64)

    def groups(self) -> tuple[ParameterGroup, ...]:
        p = self.model.initial(1)
        names, low, high = [], [], []
        for field, tensor in p.as_dict().items():
            n = tensor[0].numel()
            names += [f"{field}[{i}]" for i in range(n)]
            low.append(np.full(n, -np.inf))
            high.append(np.full(n, np.inf))
        group = ParameterGroup("asm", tuple(names), np.concatenate(low), np.concatenate(high), "ASM units")
        return (group, _expression_group())

    def initial(self) -> HeadParams:
        p = self.model.initial(1)
        values = {k: v.detach().numpy() for k, v in p.as_dict().items()}
        return HeadParams(self.kind, {"asm": values, "expressions": np.zeros(len(EXPRESSION_NAMES))})

    def _parameters(self, params: HeadParams):
        return AsmParameters(**{k: torch.as_tensor(np.asarray(v, np.float64)) for k, v in params["asm"].items()})

    def vertices(self, values: Mapping, vertex_ids: torch.Tensor | None = None) -> torch.Tensor:
        """The differentiable, batched forward: ``values`` ``{"asm": AsmParameters of batch B, "expressions":
        (B, E)}`` -> ``(B, U, 3)`` posed vertices, mm, float64 (``U``: ``vertex_ids`` or every vertex;
        gradients flow to every ASM parameter and coefficient)."""
        rest = self._expressions.vertices(values["expressions"].to(torch.float64))
        posed = self.model(values["asm"], vertices=rest).vertices
        return posed if vertex_ids is None else posed[:, vertex_ids]

    def forward(self, params: HeadParams) -> HeadPose:
        self._check(params)
        c = torch.as_tensor(_vector(params["expressions"], len(EXPRESSION_NAMES), "expressions"))
        with torch.no_grad():
            posed = self.vertices({"asm": self._parameters(params), "expressions": c[None]})[0].numpy()
            rest = self._expressions.vertices(c[None])[0]
        return HeadPose(posed, rest.numpy(), None, None, c.numpy())

    def to_dict(self, params: HeadParams) -> dict:
        self._check(params)
        return {
            "asm": asm_params_to_dict(self._parameters(params), self.asset.joint_names),
            "expressions": {n: float(c) for n, c in zip(EXPRESSION_NAMES, params["expressions"])},
        }

    def from_dict(self, data: Mapping) -> HeadParams:
        _require(data, ("asm", "expressions"))
        try:
            p = asm_params_from_dict(data["asm"], self.model)
        except ValueError as exc:
            raise HeadModelError(str(exc)) from None
        c = coefficients_from_dict(data["expressions"], dtype=torch.float64).numpy()
        return HeadParams(self.kind, {"asm": {k: v.detach().numpy() for k, v in p.as_dict().items()}, "expressions": c})

    @staticmethod
    def options_from_params(params: HeadParams) -> dict:
        return {"components": int(np.asarray(params["asm"]["log_pi"]).shape[-1])}

    @staticmethod
    def options_from_dict(data: Mapping) -> dict:
        block = data.get("asm")
        components = block.get("components", DEFAULT_COMPONENTS) if isinstance(block, Mapping) else None
        return {"components": int(components)} if isinstance(components, int | float) else {}

    def _check(self, params: HeadParams) -> None:
        if params.kind != self.kind:
            raise HeadModelError(f"{self.kind} head model given {params.kind} parameters")


register_head_model("jnr", JnrHead)
register_head_model("asm", AsmHead)
