"""The free parameters of a rig fit in rig space, as an ``nn.Module`` with named parameter groups.

:class:`GroupedParameters` is what the engine needs of any fit state (parameters named by group, their
learning rates, limits and projection); :class:`FitState` holds the joints, the neural-skinning latent Z, the
expression coefficients and a head rotation, and maps them to rig-space vertices; :func:`head_vertices`
evaluates fitted values without a state. The states that also place the head (in a photo or a point
cloud) are in :mod:`pipeline.fitting.state`, which re-exports every name here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from scipy.spatial.transform import Rotation
from torch import nn

from pipeline.fitting.identity import IdentityPrior
from pipeline.fitting.priors import PriorWeights, jnr_prior_terms
from pipeline.fitting.terms import Inputs, Term
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES, ExpressionModel, expression_limits
from rig.head_model import HeadParams, jnr_vertices
from rig.lbs import skin_with_basis, skinning_basis
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS, theta_limits
from rig.skinning.neural import LATENT, LATENT_LIMIT, NeuralSkinning

FREE_GROUPS = ("pose", "joints", "latent", "expressions")
"""The groups of the geometry: head pose, joint channels, latent Z, expression coefficients."""
JOINT_GROUPS = ("joints", "identity")
"""The groups that move the joint channels: all of them (``joints``), or along the identity prior's main directions
(``identity``, :meth:`FitState.set_identity_subspace`)."""
GEOMETRY_GROUPS = FREE_GROUPS + ("identity",)
"""Every group that moves or places the head's vertices."""


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
        # the identity subspace (:meth:`set_identity_subspace`): none until a fit asks for it
        self.register_buffer("identity_basis", torch.zeros(NUM_PARAMETERS, 0, dtype=dtype))
        self.identity_c = nn.Parameter(torch.zeros(0, dtype=dtype))
        self._basis: tuple[tuple[int, int], torch.Tensor] | None = None
        self.identity_prior: IdentityPrior | None = None
        """The identity prior of :meth:`prior_terms` when none is passed (None: the committed population prior);
        a photo fit sets the conditional one read from the detector's 3D points
        (:meth:`pipeline.fitting.identity_regression.IdentityRegressor.prior`)."""

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

    @property
    def asset(self):
        """The rig's asset (template, faces, regions)."""
        return self.models.rig.asset

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
        if "identity" in free:
            self._fold_identity()
        if any(g in free for g in JOINT_GROUPS) and self.hard_joint_limits:
            self.clamp_joints()

    def set_identity_subspace(self, prior: IdentityPrior, k: int) -> None:
        """Let the group ``identity`` move the joint channels along the ``k`` main directions of the identity prior,
        each step in units of that direction's standard deviation: ``theta_n + B c``, ``B (P, k)`` = the
        principal directions times the square roots of their variances, ``c (k,)`` the parameter
        ``identity_c``. After each step :meth:`project` folds ``B c`` into ``theta_n`` and sets ``c`` back to 0
        (Adam's step does not depend on the parameter's value, so this is the same optimisation)."""
        k = min(int(k), prior.rank)
        if k < 1:
            raise InputError(f"set_identity_subspace: need at least one direction, got k={k}")
        basis = prior.components[:k].T * np.sqrt(prior.variances[:k])
        self.identity_basis = torch.as_tensor(basis, dtype=self.dtype)
        self.identity_c = nn.Parameter(torch.zeros(k, dtype=self.dtype))

    def _fold_identity(self) -> None:
        with torch.no_grad():
            self.theta_n.add_(self.identity_basis @ self.identity_c)
            self.identity_c.zero_()

    # -- the head -----------------------------------------------------------------------------------
    def joints_n(self) -> torch.Tensor:
        """``(P,)`` joint channels over their span: ``theta_n`` plus the identity subspace's step (live)."""
        if self.identity_c.numel() == 0:
            return self.theta_n
        return self.theta_n + self.identity_basis @ self.identity_c

    @property
    def theta(self) -> torch.Tensor:
        """``(P,)`` joint channels (deg, mm, ``scale - 1``)."""
        return self.joints_n() * self.span

    def weights(self) -> torch.Tensor:
        """``(V, K)`` skinning weights: neural of ``z``, or the rig's own."""
        return self.rig.dense_weights() if self.neural is None else self.neural(self.z[None])[0]

    def rotation(self) -> torch.Tensor:
        """``(3, 3)`` head rotation from ``rotvec``."""
        return axis_angle_to_rotation_matrix(self.rotvec[None])[0]

    def rig_vertices(self, free: tuple[str, ...] = ()) -> torch.Tensor:
        """``(V, 3)`` rig-space vertices, mm; only the groups in ``free`` carry gradients."""
        theta = self.theta if any(g in free for g in JOINT_GROUPS) else self.theta.detach()
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
        return jnr_vertices(self.rig, expr, theta[None], w if "latent" in free else w.detach(), c[None])[0]

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
            theta_n=lambda: self.joints_n()[None],
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
        identity = identity or self.identity_prior
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


def head_vertices(rig: JointRig, neural: NeuralSkinning | None, theta, z, expressions) -> np.ndarray:
    """``(V, 3)`` float64 rig-space head (mm) of fitted parameters: joint channels ``theta (P,)``, latent
    ``z (50,)`` (ignored without ``neural``: the rig's own weights) and expression coefficients ``(E,)``."""
    dtype = rig.template.dtype
    with torch.no_grad():
        c = torch.as_tensor(np.asarray(expressions, np.float64), dtype=dtype)[None]
        weights = (
            rig.dense_weights()
            if neural is None
            else neural(torch.as_tensor(np.asarray(z, np.float64), dtype=dtype)[None])[0]
        )
        theta = torch.as_tensor(np.asarray(theta, np.float64), dtype=dtype)[None]
        expressions_model = ExpressionModel(rig.asset, dtype=dtype)
        return jnr_vertices(rig, expressions_model, theta, weights, c)[0].double().numpy()
