"""The free parameters of a rig fit as an ``nn.Module`` with named parameter groups.

:class:`FitState` holds the joints, the neural-skinning latent Z, the expression coefficients and a head
rotation, and maps them to rig-space vertices; :class:`PhotoState` (one photo: a pose into the camera
frame) and :class:`ScanState` (a point cloud: a similarity into the cloud's frame) add where the head
is, and :class:`AsmScanState` fits ASM's head to a point cloud instead. Joint channels are optimised as
``theta / span`` (each channel's range), so degrees, millimetres and scale factors take comparable steps.

A *group* is what a stage frees (``pose``, ``joints``, ``latent``, ``expressions`` and, for the photo
fit, ``albedo``, ``light``); :meth:`FitState.parameter_groups` turns a stage's groups and a
learning-rate config into the optimiser's parameter groups, one per tensor, by name.

The rig-space part (:data:`FREE_GROUPS`, :data:`GEOMETRY_GROUPS`, :data:`JOINT_GROUPS`, :class:`RigModels`,
:class:`GroupedParameters`, :class:`FitState`, :func:`head_vertices`) is in :mod:`pipeline.fitting.rig_state`
and re-exported here; this module holds the states that place the head.
"""

from __future__ import annotations

import logging
import math
from typing import ClassVar

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from torch import nn

from pipeline.camera import camera_center_in_rig
from pipeline.fitting.identity import IdentityPrior
from pipeline.fitting.model_state import ModelScanState
from pipeline.fitting.priors import PriorWeights, asm_prior_terms
from pipeline.fitting.rig_state import FREE_GROUPS as FREE_GROUPS
from pipeline.fitting.rig_state import GEOMETRY_GROUPS as GEOMETRY_GROUPS
from pipeline.fitting.rig_state import JOINT_GROUPS as JOINT_GROUPS
from pipeline.fitting.rig_state import FitState as FitState
from pipeline.fitting.rig_state import GroupedParameters as GroupedParameters
from pipeline.fitting.rig_state import RigModels as RigModels
from pipeline.fitting.rig_state import head_vertices as head_vertices
from pipeline.fitting.terms import Inputs, Term
from rig.errors import InputError
from rig.expressions import ExpressionModel
from rig.geometry import RIG_TO_OPENCV
from rig.head_model import HeadParams, head_model_kinds
from rig.model import JointRig
from rig.skinning.asm import TAU_UNITS, UV_UNIT, AdaptiveSkinning, AsmParameters, asm_params_to_dict
from rig.skinning.neural import NeuralSkinning, load_neural

_log = logging.getLogger(__name__)


class PhotoState(FitState):
    """A head in one photo: ``x_cam = RIG_TO_OPENCV @ R @ x_rig + t`` (OpenCV camera frame, mm), and for
    the photometric fit a per-vertex albedo and the light's ambient and irradiance.

    Args:
        rig, neural, expressions, rotation: as :class:`FitState`.
        translation: ``(3,)`` head position in the camera frame, mm.

    Extra parameters: ``translation (3,)`` mm (group ``pose``); ``identity_c (k,)`` (group ``identity``: the
    joint channels along the identity prior's main directions, :meth:`~FitState.set_identity_subspace`);
    ``albedo (V, 3)`` linear RGB (group
    ``albedo``), ``ambient (3,)``, ``irradiance (3,)`` and ``sh (9, 3)`` (group ``light``), set by
    :meth:`add_appearance`.
    """

    GROUPS: ClassVar[dict[str, tuple[tuple[str, str], ...]]] = {
        **FitState.GROUPS,
        "pose": (("rotvec", "rotation"), ("translation", "translation")),
        "identity": (("identity_c", "identity"),),
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

    kind: ClassVar[str] = "jnr"
    """The head model (:mod:`rig.head_model`) this state fits: the ``skinning`` of a scan fit's config."""

    @classmethod
    def for_scan(
        cls, rig: JointRig, neural: NeuralSkinning | None, expressions: ExpressionModel, config, *, fit_scale: bool
    ) -> ScanState:
        """The state at the identity pose for a scan fit's ``config`` (:class:`pipeline.scan.fit_config.FitScanConfig`):
        the learned skinning ``neural`` (loaded when ``config.use_neural`` and not given; the rig's own weights
        without it)."""
        if config.use_neural and neural is None:
            neural = load_neural(rig)[0]
        return cls(
            rig, neural if config.use_neural else None, expressions, np.eye(3), np.zeros(3), 1.0, fit_scale=fit_scale
        )

    @staticmethod
    def label(config) -> str:
        """The head model's name in the evaluation's records (``jnr``; ASM's with its components)."""
        return "jnr"

    def set_pose(self, rotation: np.ndarray, translation: np.ndarray, scale: float) -> None:
        """Place the head in the cloud's frame: ``(3, 3)``, ``(3,)`` mm, scalar (a rigid pre-alignment)."""
        with torch.no_grad():
            self.rotvec.copy_(torch.as_tensor(Rotation.from_matrix(rotation).as_rotvec(), dtype=self.dtype))
            self.translation.copy_(torch.as_tensor(translation, dtype=self.dtype))
            self.log_scale.fill_(math.log(scale))

    def finish(self) -> dict:
        """After the fit: project the joint channels the soft limit penalty left outside their limits onto
        them (in place), so the written head is one its readers accept: ``{name: [fitted, written]}`` in the
        channel's unit (the scales as factors), logged."""
        from rig.parameters import CHANNELS

        before = self.theta.detach().double().numpy().copy()
        self.clamp_joints()
        after = self.theta.detach().double().numpy()
        moved = np.flatnonzero(np.abs(after - before) > 1e-9)
        clamped = {
            CHANNELS[i].name: [CHANNELS[i].from_theta(before[i]), CHANNELS[i].from_theta(after[i])] for i in moved
        }
        if clamped:
            _log.info("fit-scan: %d joint channel(s) clamped to their limits: %s", len(clamped), ", ".join(clamped))
        return clamped

    def model_entry(self) -> dict | None:
        """The head model's own entry of the result beyond ``theta``, ``z`` and the expressions (None here)."""
        return None

    def to_cloud(self, v: torch.Tensor) -> torch.Tensor:
        """``(V, 3)`` rig space -> the cloud's frame, mm."""
        return self.log_scale.exp() * v @ self.rotation().T + self.translation

    @property
    def scale(self) -> float:
        return float(self.log_scale.detach().exp())


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

    kind: ClassVar[str] = "asm"

    @classmethod
    def for_scan(
        cls, rig: JointRig, neural: NeuralSkinning | None, expressions: ExpressionModel, config, *, fit_scale: bool
    ) -> AsmScanState:
        """The state at the identity pose for a scan fit's ``config``: ASM with ``config.asm_components``
        Gaussians per bone on ``rig`` (``neural`` does not apply)."""
        model = AdaptiveSkinning(rig, components=config.asm_components)
        return cls(model, expressions, np.eye(3), np.zeros(3), 1.0, fit_scale=fit_scale)

    @staticmethod
    def label(config) -> str:
        return f"asm_k{config.asm_components}"

    def finish(self) -> dict:
        """ASM's parameters have no limits to project onto: nothing clamped."""
        return {}

    def model_entry(self) -> dict:
        """The fitted ASM parameters by bone (:func:`rig.skinning.asm.asm_params_to_dict`)."""
        return asm_params_to_dict(self.asm_parameters(()), self.rig.asset.joint_names)

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


SCAN_STATES: dict[str, type[ScanState]] = {}
"""The state of a scan fit by head model kind (:func:`register_scan_state`)."""


def register_scan_state(state: type[ScanState]) -> None:
    """Make ``jnr fit-scan`` fit the head model ``state.kind`` with ``state`` (a :class:`ScanState` with
    :meth:`ScanState.for_scan`, :meth:`ScanState.finish`, :meth:`ScanState.model_entry` and
    :meth:`ScanState.label`)."""
    SCAN_STATES[state.kind] = state


def scan_kinds() -> tuple[str, ...]:
    """The head models a scan fit takes: those with a registered state, then every other registered head model
    (:func:`rig.head_model.head_model_kinds`, fitted by :class:`pipeline.fitting.model_state.ModelScanState`)."""
    return (*SCAN_STATES, *(k for k in head_model_kinds() if k not in SCAN_STATES))


def scan_state_class(kind: str) -> type[ScanState] | type[ModelScanState]:
    """The scan-fit state of head model ``kind``: its registered state, else the generic state over the registered
    head model's groups.

    Raises:
        InputError: ``kind`` is neither.
    """
    if kind in SCAN_STATES:
        return SCAN_STATES[kind]
    if kind in head_model_kinds():
        return ModelScanState.for_kind(kind)
    raise InputError(f"fit-scan: no fit for the head model {kind!r}; known: {', '.join(scan_kinds())}")


register_scan_state(ScanState)
register_scan_state(AsmScanState)
