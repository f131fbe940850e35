"""The free parameters of a rig fit as an ``nn.Module`` with named parameter groups.

:class:`FitState` holds the joints, the neural-skinning latent Z, the expression coefficients and a head
rotation, and maps them to rig-space vertices; :class:`PhotoState` (one photo: a pose into the camera
frame) and :class:`ScanState` (a point cloud: a similarity into the cloud's frame) add where the head
is. Joint channels are optimised as ``theta / span`` (each channel's range), so degrees, millimetres
and scale factors take comparable steps.

A *group* is what a stage frees (``pose``, ``joints``, ``latent``, ``expressions`` and, for the photo
fit, ``albedo``, ``light``); :meth:`FitState.parameter_groups` turns a stage's groups and a
learning-rate config into the optimiser's parameter groups, one per tensor, by name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from scipy.spatial.transform import Rotation
from torch import nn

from pipeline.camera import camera_center_in_rig
from pipeline.fitting.identity import IdentityPrior
from pipeline.fitting.priors import PriorWeights, asm_prior_terms, jnr_prior_terms
from pipeline.fitting.terms import Inputs, Term
from rig.expressions import EXPRESSION_NAMES, ExpressionModel, expression_limits
from rig.geometry import RIG_TO_OPENCV
from rig.head_model import HeadParams
from rig.lbs import skin_vertices, skin_with_basis, skinning_basis
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS, theta_limits
from rig.skinning.asm import TAU_UNITS, UV_UNIT, AdaptiveSkinning, AsmParameters
from rig.skinning.neural import LATENT, LATENT_LIMIT, NeuralSkinning

FREE_GROUPS = ("pose", "joints", "latent", "expressions")
"""The groups of the geometry: head pose, joint channels, latent Z, expression coefficients."""


@dataclass(frozen=True)
class RigModels:
    """The fixed models a fit evaluates (not parameters of the fit).

    Attributes:
        rig: the joint rig. neural: its neural skinning (None: the rig's own weights, no latent).
        expressions: the expression blendshapes.
    """

    rig: JointRig
    neural: NeuralSkinning | None
    expressions: ExpressionModel


class GroupedParameters(nn.Module):
    """Parameters named by group (what a stage frees): what the engine (:func:`pipeline.fitting.engine.
    run_schedule`) and the LM stages (:class:`pipeline.fitting.least_squares.StateVector`) need of a fit state.

    Subclasses set :attr:`GROUPS` and may narrow :meth:`available`, add box limits (:meth:`limits`) and a
    projection after each step (:meth:`project`).
    """

    GROUPS: ClassVar[dict[str, tuple[tuple[str, str], ...]]] = {}
    """group -> ``(parameter name, learning-rate field)`` pairs, in the optimiser's order."""

    neural: NeuralSkinning | None = None
    """Neural skinning whose decoder the engine freezes while it runs (None: nothing to freeze)."""

    def available(self, free: tuple[str, ...]) -> tuple[str, ...]:
        """``free`` without the groups this state cannot move."""
        return free

    def parameter_groups(self, free: tuple[str, ...], lr) -> list[dict]:
        """The optimiser's parameter groups for the groups ``free``: one ``{"params": [p], "lr": ...}`` per
        parameter, its step read from the field of ``lr`` that :attr:`GROUPS` names."""
        groups = self.GROUPS
        return [
            {"params": [getattr(self, name)], "lr": float(getattr(lr, field))}
            for g in free
            for name, field in groups[g]
        ]

    def limits(self, name: str) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The box limits of parameter ``name`` (what a least-squares solver keeps it in); None: unbounded."""
        return None

    def project(self, free: tuple[str, ...]) -> None:
        """After a step: project what ``free`` moved back into its limits (nothing here)."""


class FitState(GroupedParameters):
    """Joints ``theta (P,)``, latent ``z (50,)``, expressions ``c (E,)`` and a head rotation, as parameters.

    Args:
        rig, neural, expressions: the models (``neural=None``: the rig's own weights, no latent).
        rotation: initial ``(3, 3)`` head rotation (kept as a rotation vector ``rotvec``).
        hard_joint_limits: project the joints back into their limits after each step (else only the
            soft penalty L_x keeps them there).

    Parameters (``named_parameters()``): ``rotvec (3,)`` radians, ``theta_n (P,)`` joint channels over
    their span, ``z (50,)``, ``c (E,)``; subclasses add theirs. :attr:`GROUPS` names them by group, each
    with the field of the learning-rate config that gives its step.
    """

    GROUPS: ClassVar[dict[str, tuple[tuple[str, str], ...]]] = {
        "pose": (("rotvec", "rotation"),),
        "joints": (("theta_n", "joints"),),
        "latent": (("z", "latent"),),
        "expressions": (("c", "expressions"),),
    }
    """group -> ``(parameter name, learning-rate field)`` pairs, in the optimiser's order."""

    def __init__(
        self,
        rig: JointRig,
        neural: NeuralSkinning | None,
        expressions: ExpressionModel,
        rotation: np.ndarray,
        *,
        hard_joint_limits: bool = True,
    ) -> None:
        super().__init__()
        self.models = RigModels(rig, neural, expressions)
        self.hard_joint_limits = hard_joint_limits
        dtype = rig.template.dtype
        low, high = theta_limits(dtype)
        self.register_buffer("low", low)
        self.register_buffer("high", high)
        self.register_buffer("span", (high - low).clamp_min(1e-3))
        c_low, c_high = expression_limits(dtype)
        self.register_buffer("c_low", c_low)
        self.register_buffer("c_high", c_high)
        self.rotvec = nn.Parameter(torch.tensor(Rotation.from_matrix(rotation).as_rotvec(), dtype=dtype))
        self.theta_n = nn.Parameter(torch.zeros(NUM_PARAMETERS, dtype=dtype))
        self.z = nn.Parameter(torch.zeros(LATENT, dtype=dtype))
        self.c = nn.Parameter(torch.zeros(len(EXPRESSION_NAMES), dtype=dtype))
        self._basis: tuple[tuple[int, int], torch.Tensor] | None = None

    # -- the models ---------------------------------------------------------------------------------
    @property
    def rig(self) -> JointRig:
        return self.models.rig

    @property
    def neural(self) -> NeuralSkinning | None:
        return self.models.neural

    @property
    def dtype(self) -> torch.dtype:
        return self.models.rig.template.dtype

    # -- groups -------------------------------------------------------------------------------------
    def available(self, free: tuple[str, ...]) -> tuple[str, ...]:
        """``free`` without the groups this state cannot move (``latent`` without neural skinning)."""
        return tuple(g for g in free if not (g == "latent" and self.neural is None))

    def limits(self, name: str) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The box limits of parameter ``name`` (what a least-squares solver keeps it in): the joint channels
        ``theta_n`` within their limits over their span, the expression coefficients ``c`` within theirs, the
        latent ``z`` within ±LATENT_LIMIT;
        None for the others."""
        if name == "theta_n":
            return self.low / self.span, self.high / self.span
        if name == "c":
            return self.c_low, self.c_high
        if name == "z":
            limit = torch.full_like(self.z, LATENT_LIMIT)
            return -limit, limit
        return None

    def project(self, free: tuple[str, ...]) -> None:
        """After a step: project what ``free`` moved back into its limits (expressions and the latent Z,
        within ±:data:`rig.skinning.neural.LATENT_LIMIT`, always; joints with ``hard_joint_limits``). Only
        freed groups are written: a write to ``c`` or ``z`` invalidates the cached skinning basis."""
        if "expressions" in free:
            self.clamp_expressions()
        if "latent" in free and self.neural is not None:
            with torch.no_grad():
                self.z.clamp_(-LATENT_LIMIT, LATENT_LIMIT)
        if "joints" in free and self.hard_joint_limits:
            self.clamp_joints()

    # -- the head -----------------------------------------------------------------------------------
    @property
    def theta(self) -> torch.Tensor:
        """``(P,)`` joint channels (deg, mm, ``scale - 1``)."""
        return self.theta_n * self.span

    def weights(self) -> torch.Tensor:
        """``(V, K)`` skinning weights: neural of ``z``, or the rig's own."""
        return self.rig.dense_weights() if self.neural is None else self.neural(self.z[None])[0]

    def rotation(self) -> torch.Tensor:
        """``(3, 3)`` head rotation from ``rotvec``."""
        return axis_angle_to_rotation_matrix(self.rotvec[None])[0]

    def rig_vertices(self, free: tuple[str, ...] = ()) -> torch.Tensor:
        """``(V, 3)`` rig-space vertices, mm; only the groups in ``free`` carry gradients."""
        theta = self.theta if "joints" in free else self.theta.detach()
        c = self.c if "expressions" in free else self.c.detach()
        expr = self.models.expressions
        _, skinning = self.rig.joint_transforms(theta[None])
        if "latent" not in free and "expressions" not in free:
            # Rest shape and weights are fixed: reuse their skinning basis (one GEMM per step).
            key = (self.z._version, self.c._version)
            if self._basis is None or self._basis[0] != key:
                with torch.no_grad():
                    rest = expr.template + expr(self.c[None])[0]
                    self._basis = (key, skinning_basis(rest, self.weights()))
            return skin_with_basis(self._basis[1], skinning)[0]
        with torch.set_grad_enabled("latent" in free):
            w = self.weights()
        rest = expr.template + expr(c[None])[0]
        return skin_vertices(rest, w if "latent" in free else w.detach(), skinning)[0]

    def clamp_joints(self) -> None:
        """Project the joint channels back into their limits (in place), so every fit is a valid rig pose."""
        with torch.no_grad():
            self.theta_n.copy_(torch.maximum(torch.minimum(self.theta_n, self.high / self.span), self.low / self.span))

    def clamp_expressions(self) -> None:
        """Project the expression coefficients back into their limits (in place)."""
        with torch.no_grad():
            self.c.copy_(torch.maximum(torch.minimum(self.c, self.c_high), self.c_low))

    def load(self, theta, z, expressions) -> None:
        """Start from fitted values: joint channels ``theta (P,)`` (deg, mm, ``scale - 1``), ``z (50,)``,
        expression coefficients ``(E,)``."""
        with torch.no_grad():
            self.theta_n.copy_(torch.as_tensor(theta, dtype=self.dtype) / self.span)
            self.z.copy_(torch.as_tensor(z, dtype=self.dtype))
            self.c.copy_(torch.as_tensor(expressions, dtype=self.dtype))

    # -- the loss terms -----------------------------------------------------------------------------
    def term_inputs(self) -> Inputs:
        """The parameters as batch-1 tensors by the names the terms read (:mod:`pipeline.fitting.terms`):
        ``theta_n``, ``theta`` (joint units), ``z``, ``c``; live, so gradients flow to every parameter."""
        return Inputs(
            theta_n=lambda: self.theta_n[None],
            theta=lambda: self.theta[None],
            z=lambda: self.z[None],
            c=lambda: self.c[None],
        )

    def prior_terms(
        self,
        weights: PriorWeights,
        *,
        lambda_m: float | None = None,
        identity: IdentityPrior | None = None,
        gaze: bool = False,
    ) -> tuple[Term, ...]:
        """The priors of this head model with ``weights`` (:func:`pipeline.fitting.priors.jnr_prior_terms`:
        L_m, L_x, latent, expressions, identity, symmetry); ``lambda_m`` overrides L_m's weight; ``gaze``: the
        data sees the irises (the eyeLook* coefficients get ``lambda_gaze``)."""
        return jnr_prior_terms(weights, self.low, self.high, lambda_m=lambda_m, identity=identity, gaze=gaze)

    def head_params(self) -> HeadParams:
        """The fitted head as its head model's parameters (:class:`rig.head_model.HeadParams`, kind ``jnr``:
        joints, latent, expressions; float64)."""
        values = self.arrays()
        return HeadParams(
            "jnr", {"joints": values["theta"], "latent": values["z"], "expressions": values["expressions"]}
        )

    def arrays(self) -> dict[str, np.ndarray]:
        """The fitted values as float64 arrays: ``theta (P,)``, ``z (50,)``, ``expressions (E,)``,
        ``rotation (3, 3)``."""
        with torch.no_grad():
            return {
                "theta": self.theta.double().numpy(),
                "z": self.z.double().numpy(),
                "expressions": self.c.double().numpy(),
                "rotation": self.rotation().double().numpy(),
            }


class PhotoState(FitState):
    """A head in one photo: ``x_cam = RIG_TO_OPENCV @ R @ x_rig + t`` (OpenCV camera frame, mm), and for
    the photometric fit a per-vertex albedo and the light's ambient and irradiance.

    Args:
        rig, neural, expressions, rotation: as :class:`FitState`.
        translation: ``(3,)`` head position in the camera frame, mm.

    Extra parameters: ``translation (3,)`` mm (group ``pose``); ``albedo (V, 3)`` linear RGB (group
    ``albedo``), ``ambient (3,)``, ``irradiance (3,)`` and ``sh (9, 3)`` (group ``light``), set by
    :meth:`add_appearance`.
    """

    GROUPS: ClassVar[dict[str, tuple[tuple[str, str], ...]]] = {
        **FitState.GROUPS,
        "pose": (("rotvec", "rotation"), ("translation", "translation")),
        "albedo": (("albedo", "albedo"),),
        "light": (("ambient", "light"), ("irradiance", "light"), ("sh", "light")),
    }

    def __init__(
        self,
        rig: JointRig,
        neural: NeuralSkinning | None,
        expressions: ExpressionModel,
        rotation: np.ndarray,
        translation: np.ndarray,
    ) -> None:
        super().__init__(rig, neural, expressions, rotation)
        self.register_buffer("flip", torch.tensor(RIG_TO_OPENCV, dtype=self.dtype))
        self.translation = nn.Parameter(torch.tensor(translation, dtype=self.dtype))

    def add_appearance(
        self, albedo: torch.Tensor, ambient: torch.Tensor, irradiance: torch.Tensor, sh: torch.Tensor | None = None
    ) -> None:
        """The photometric parameters: ``albedo (V, 3)``, ``ambient (3,)``, ``irradiance (3,)``, linear RGB, and
        the spherical-harmonic light ``sh (9, 3)`` (zeros by default; used by the ``sh`` light model only)."""
        self.albedo = nn.Parameter(albedo.detach().clone())
        self.ambient = nn.Parameter(ambient.detach().clone())
        self.irradiance = nn.Parameter(irradiance.detach().clone())
        self.sh = nn.Parameter(torch.zeros(9, 3, dtype=albedo.dtype) if sh is None else sh.detach().clone())

    def project(self, free: tuple[str, ...]) -> None:
        """Albedo into [0, 1] and the light non-negative, then :meth:`FitState.project`."""
        if hasattr(self, "albedo"):
            with torch.no_grad():
                self.albedo.clamp_(0.0, 1.0)
                self.ambient.clamp_(min=0.0)
                self.irradiance.clamp_(min=0.0)
        super().project(free)

    def to_camera(self, points: torch.Tensor, free: tuple[str, ...] = ()) -> torch.Tensor:
        """``(N, 3)`` rig space -> OpenCV camera space, mm; the pose carries gradients if ``pose`` is free."""
        rot, t = (
            (self.rotation(), self.translation)
            if "pose" in free
            else (self.rotation().detach(), self.translation.detach())
        )
        return points @ (self.flip @ rot).T + t

    def camera_center(self) -> np.ndarray:
        """``(3,)`` float64 camera centre in rig space, mm."""
        return camera_center_in_rig(
            self.rotation().detach().double().numpy(), self.translation.detach().double().numpy()
        )


class ScanState(FitState):
    """A head in a point cloud's frame: ``x = s R x_rig + t`` (mm), ``s = exp(log_scale)``.

    Args:
        rig, neural, expressions: as :class:`FitState`.
        rotation, translation, scale: the start (a rigid pre-alignment): ``(3, 3)``, ``(3,)`` mm, scalar.
        fit_scale: optimise the global scale with the pose.

    Joints are kept in their limits by the soft penalty L_x only (JNR's point-cloud fit).
    """

    def __init__(
        self,
        rig: JointRig,
        neural: NeuralSkinning | None,
        expressions: ExpressionModel,
        rotation: np.ndarray,
        translation: np.ndarray,
        scale: float,
        *,
        fit_scale: bool = True,
    ) -> None:
        super().__init__(rig, neural, expressions, rotation, hard_joint_limits=False)
        self.log_scale = nn.Parameter(torch.tensor(math.log(scale), dtype=self.dtype))
        self.translation = nn.Parameter(torch.tensor(translation, dtype=self.dtype))
        pose = (("rotvec", "rotation"), ("translation", "translation"))
        self.GROUPS = {**FitState.GROUPS, "pose": pose + ((("log_scale", "log_scale"),) if fit_scale else ())}

    def to_cloud(self, v: torch.Tensor) -> torch.Tensor:
        """``(V, 3)`` rig space -> the cloud's frame, mm."""
        return self.log_scale.exp() * v @ self.rotation().T + self.translation

    @property
    def scale(self) -> float:
        return float(self.log_scale.detach().exp())


def head_vertices(rig: JointRig, neural: NeuralSkinning | None, theta, z, expressions) -> np.ndarray:
    """``(V, 3)`` float64 rig-space head (mm) of fitted parameters: joint channels ``theta (P,)``, latent
    ``z (50,)`` (ignored without ``neural``: the rig's own weights) and expression coefficients ``(E,)``."""
    dtype = rig.template.dtype
    with torch.no_grad():
        c = torch.as_tensor(np.asarray(expressions, np.float64), dtype=dtype)[None]
        rest = ExpressionModel(rig.asset, dtype=dtype).vertices(c)[0]
        weights = (
            rig.dense_weights()
            if neural is None
            else neural(torch.as_tensor(np.asarray(z, np.float64), dtype=dtype)[None])[0]
        )
        theta = torch.as_tensor(np.asarray(theta, np.float64), dtype=dtype)[None]
        return rig(theta, weights=weights, vertices=rest).vertices[0].double().numpy()


class AsmScanState(ScanState):
    """A point-cloud fit whose head is ASM (:mod:`rig.skinning.asm`) instead of the JNR joints and Z.

    The groups keep their roles: ``joints`` frees ASM's bone transforms ``tau`` (9 per bone), ``latent``
    its skinning parameters (the binding ``zeta`` and the mixtures ``log_pi``, ``mu``, ``chol``), so
    JNR's schedule (joints, then skinning, then expressions) applies unchanged; ``pose`` and
    ``expressions`` are as :class:`ScanState`. Parameters are stored in the units of
    :data:`rig.skinning.asm.TAU_UNITS` and :data:`rig.skinning.asm.UV_UNIT`, so one step size fits each
    group (``lr.asm_bones``, ``lr.asm_skinning``). ``theta`` and ``z`` stay at zero and unused.

    Args:
        model: the :class:`rig.skinning.asm.AdaptiveSkinning` (its rig is the state's rig).
        expressions, rotation, translation, scale, fit_scale: as :class:`ScanState`.
    """

    def __init__(
        self,
        model: AdaptiveSkinning,
        expressions: ExpressionModel,
        rotation: np.ndarray,
        translation: np.ndarray,
        scale: float,
        *,
        fit_scale: bool = True,
    ) -> None:
        super().__init__(model.rig, None, expressions, rotation, translation, scale, fit_scale=fit_scale)
        self.asm = model
        init = model.initial(1)
        self.register_buffer("tau_unit", torch.tensor(TAU_UNITS, dtype=self.dtype))
        self.uv_unit = UV_UNIT
        self.tau_n = nn.Parameter(torch.zeros_like(init.tau[0]))
        self.zeta_n = nn.Parameter(init.zeta[0] / UV_UNIT)
        self.log_pi = nn.Parameter(init.log_pi[0].clone())
        self.mu_n = nn.Parameter(init.mu[0] / UV_UNIT)
        self.chol = nn.Parameter(init.chol[0].clone())
        self.GROUPS = {
            **self.GROUPS,
            "joints": (("tau_n", "asm_bones"),),
            "latent": (
                ("zeta_n", "asm_skinning"),
                ("log_pi", "asm_skinning"),
                ("mu_n", "asm_skinning"),
                ("chol", "asm_skinning"),
            ),
        }

    def available(self, free: tuple[str, ...]) -> tuple[str, ...]:
        return free

    def project(self, free: tuple[str, ...]) -> None:
        if "expressions" in free:
            self.clamp_expressions()

    def asm_parameters(self, free: tuple[str, ...] = ("joints", "latent")) -> AsmParameters:
        """The current :class:`rig.skinning.asm.AsmParameters` (batch 1); groups not in ``free`` detached."""

        def grad(t: torch.Tensor, group: str) -> torch.Tensor:
            return t if group in free else t.detach()

        return AsmParameters(
            tau=grad(self.tau_n * self.tau_unit, "joints")[None],
            zeta=grad(self.zeta_n * self.uv_unit, "latent")[None],
            log_pi=grad(self.log_pi, "latent")[None],
            mu=grad(self.mu_n * self.uv_unit, "latent")[None],
            chol=grad(self.chol, "latent")[None],
        )

    def rig_vertices(self, free: tuple[str, ...] = ()) -> torch.Tensor:
        """``(V, 3)`` rig-space vertices of the ASM head, mm; only the groups in ``free`` carry gradients."""
        c = self.c if "expressions" in free else self.c.detach()
        expr = self.models.expressions
        rest = expr.template + expr(c[None])[0]
        return self.asm(self.asm_parameters(free), vertices=rest).vertices[0]

    def term_inputs(self) -> Inputs:
        """:meth:`FitState.term_inputs` and ``asm`` (:meth:`asm_parameters`, both groups live)."""
        return super().term_inputs().add(asm=self.asm_parameters)

    def prior_terms(
        self,
        weights: PriorWeights,
        *,
        lambda_m: float | None = None,
        identity: IdentityPrior | None = None,
        gaze: bool = False,
    ) -> tuple[Term, ...]:
        """ASM's priors instead of the joints' (:func:`pipeline.fitting.priors.asm_prior_terms`: eq. 19
        following L_m's schedule, expressions, smoothness); ``identity`` does not apply."""
        return asm_prior_terms(weights, self.asm, lambda_m=lambda_m)

    def head_params(self) -> HeadParams:
        """The fitted head as ASM's parameters (:class:`rig.head_model.HeadParams`, kind ``asm``: its
        :class:`rig.skinning.asm.AsmParameters` fields as float64 arrays of batch 1, expressions)."""
        with torch.no_grad():
            asm = {k: v.detach().double().numpy() for k, v in self.asm_parameters(()).as_dict().items()}
            return HeadParams("asm", {"asm": asm, "expressions": self.c.double().numpy()})

    def load_asm(self, params: AsmParameters) -> None:
        """Start from fitted :class:`rig.skinning.asm.AsmParameters` (batch 1)."""
        with torch.no_grad():
            self.tau_n.copy_(params.tau[0] / self.tau_unit)
            self.zeta_n.copy_(params.zeta[0] / self.uv_unit)
            self.log_pi.copy_(params.log_pi[0])
            self.mu_n.copy_(params.mu[0] / self.uv_unit)
            self.chol.copy_(params.chol[0])
