"""Any registered head model as a fit state: the fits' path for a model that brings no state of its own.

A head model (:class:`rig.head_model.HeadModel`, registered by :func:`rig.head_model.register_head_model`) says
what it fits (:meth:`~rig.head_model.HeadModel.groups`: named flat groups with limits), where it starts
(:meth:`~rig.head_model.HeadModel.initial`) and how its parameters make a head
(:meth:`~rig.head_model.HeadModel.vertices`: differentiable, batched). :class:`ModelPhotoState` turns that into
what the fitting engine and the Levenberg-Marquardt stages need (:class:`~pipeline.fitting.rig_state.
GroupedParameters`): one parameter per group, named ``p_<group>``, held in the group's limits, plus the head's pose
in a photo. So ``jnr fit --set model=KIND`` fits a newly registered model with no other code
(``tests/pipeline/photo/test_photo_head_model.py``).

A model may add priors by a method ``prior_terms(weights) -> tuple[Term, ...]`` reading the groups by name from
the terms' inputs (each group ``(1, n)``); without one the fit has the data term only. JNR's own head keeps its
state (:class:`pipeline.fitting.state.PhotoState`): its fast paths and priors are tuned to it.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from scipy.spatial.transform import Rotation
from torch import nn

from pipeline.camera import camera_center_in_rig
from pipeline.fitting.rig_state import GroupedParameters
from pipeline.fitting.terms import Inputs, Term
from rig.expressions import EXPRESSION_NAMES
from rig.geometry import RIG_TO_OPENCV
from rig.head_model import HeadModel, HeadModelError, HeadParams, create
from rig.parameters import NUM_PARAMETERS
from rig.skinning.neural import LATENT

LR_FIELDS = ("joints", "latent", "expressions")
"""Groups whose Adam step has its own field in :class:`pipeline.fitting.engine.LearningRates`; other groups step
as the joints."""


def _flat_initial(model: HeadModel) -> dict[str, np.ndarray]:
    """Each group's initial values as a float64 vector; HeadModelError for a group that is not one."""
    initial = model.initial()
    out = {}
    for group in model.groups():
        try:
            values = np.asarray(initial[group.name], dtype=np.float64)
        except (TypeError, ValueError, KeyError):
            values = None
        if values is None or values.shape != (group.size,):
            raise HeadModelError(
                f"head model {model.kind!r}: group {group.name!r} is not a flat vector of {group.size} floats, and the "
                "generic fit (one photo) takes flat groups only; fit it from several views (jnr fit --views "
                f"--skinning {model.kind}) or a scan (jnr fit-scan --skinning {model.kind}) if it brings its own fits"
            )
        out[group.name] = values
    return out


def jnr_arrays(params: HeadParams) -> dict[str, np.ndarray]:
    """``theta (P,)`` (deg, mm, ``scale - 1``), ``z (50,)`` and ``expressions (E,)`` (ARKit) of a head's parameters:
    its ``joints``, ``latent`` and ``expressions`` groups where it has them at the rig's sizes (JNR's head), zeros
    where not (what a result record of another model holds in JNR's fields)."""
    values = params.values

    def group(name: str, size: int) -> np.ndarray:
        value = values.get(name)
        return np.asarray(value, np.float64) if np.shape(value) == (size,) else np.zeros(size)

    return {
        "theta": group("joints", NUM_PARAMETERS),
        "z": group("latent", LATENT),
        "expressions": group("expressions", len(EXPRESSION_NAMES)),
    }


class ModelState(GroupedParameters):
    """A head model's parameters and the head's rotation and translation (the states below say where to).

    Args:
        model: the head model (flat groups: :meth:`~rig.head_model.HeadModel.groups`).
        rotation: ``(3, 3)`` the head's start rotation; translation: ``(3,)`` mm.
        params: start values (default the model's :meth:`~rig.head_model.HeadModel.initial`).

    Parameters: ``rotvec (3,)`` radians and ``translation (3,)`` mm (group ``pose``), ``p_<group> (n,)`` for each
    of the model's groups (group ``<group>``), float64.

    Raises:
        rig.head_model.HeadModelError: a group that is not a flat vector.
    """

    def __init__(
        self, model: HeadModel, rotation: np.ndarray, translation: np.ndarray, params: HeadParams | None = None
    ) -> None:
        super().__init__()
        self.model = model
        start = _flat_initial(model)
        if params is not None:
            start = {name: np.asarray(params[name], np.float64) for name in start}
        self.group_names = tuple(start)
        self.rotvec = nn.Parameter(torch.tensor(Rotation.from_matrix(rotation).as_rotvec(), dtype=torch.float64))
        self.translation = nn.Parameter(torch.tensor(translation, dtype=torch.float64))
        self.register_buffer("flip", torch.tensor(RIG_TO_OPENCV, dtype=torch.float64))
        groups: dict[str, tuple[tuple[str, str], ...]] = {
            "pose": (("rotvec", "rotation"), ("translation", "translation"))
        }
        for group in model.groups():
            setattr(self, f"p_{group.name}", nn.Parameter(torch.tensor(start[group.name], dtype=torch.float64)))
            self.register_buffer(f"low_{group.name}", torch.as_tensor(group.low, dtype=torch.float64))
            self.register_buffer(f"high_{group.name}", torch.as_tensor(group.high, dtype=torch.float64))
            field = group.name if group.name in LR_FIELDS else "joints"
            groups[group.name] = ((f"p_{group.name}", field),)
        self.GROUPS = groups

    @property
    def dtype(self) -> torch.dtype:
        return torch.float64

    @property
    def asset(self):
        """The model's rig asset (template, faces, regions)."""
        return self.model.asset

    # -- groups -------------------------------------------------------------------------------------
    def available(self, free: tuple[str, ...]) -> tuple[str, ...]:
        """``free`` without the groups the model does not have."""
        return tuple(g for g in free if g in self.GROUPS)

    def limits(self, name: str) -> tuple[torch.Tensor, torch.Tensor] | None:
        """A group's limits (:class:`rig.head_model.ParameterGroup`); None for the pose."""
        if name.startswith("p_"):
            group = name[2:]
            return getattr(self, f"low_{group}"), getattr(self, f"high_{group}")
        return None

    def project(self, free: tuple[str, ...]) -> None:
        """After a step: each freed group back into its limits."""
        with torch.no_grad():
            for group in free:
                if group in self.group_names:
                    p = getattr(self, f"p_{group}")
                    p.copy_(
                        torch.maximum(torch.minimum(p, getattr(self, f"high_{group}")), getattr(self, f"low_{group}"))
                    )

    # -- the head -----------------------------------------------------------------------------------
    def values(self, free: tuple[str, ...] = ()) -> dict[str, torch.Tensor]:
        """Each group's ``(1, n)`` values by group name; only the groups in ``free`` carry gradients."""
        out = {}
        for group in self.group_names:
            p = getattr(self, f"p_{group}")
            out[group] = (p if group in free else p.detach())[None]
        return out

    def rig_vertices(self, free: tuple[str, ...] = ()) -> torch.Tensor:
        """``(V, 3)`` the model's head in rig space, mm (:meth:`~rig.head_model.HeadModel.vertices`)."""
        return self.model.vertices(self.values(free))[0].to(torch.float64)

    def set_pose(self, rotation: np.ndarray, translation: np.ndarray) -> None:
        """Place the head: ``(3, 3)``, ``(3,)`` mm."""
        with torch.no_grad():
            self.rotvec.copy_(torch.as_tensor(Rotation.from_matrix(rotation).as_rotvec()))
            self.translation.copy_(torch.as_tensor(translation, dtype=torch.float64))

    def rotation(self) -> torch.Tensor:
        """``(3, 3)`` head rotation from ``rotvec``."""
        return axis_angle_to_rotation_matrix(self.rotvec[None])[0]

    # -- the loss terms -----------------------------------------------------------------------------
    def term_inputs(self) -> Inputs:
        """Each group by name, ``(1, n)``, live (gradients flow)."""
        return Inputs({group: getattr(self, f"p_{group}")[None] for group in self.group_names})

    def prior_terms(self, weights=None, **_) -> tuple[Term, ...]:
        """The model's own priors (its ``prior_terms(weights)``, if it has one), else none."""
        own = getattr(self.model, "prior_terms", None)
        return tuple(own(weights)) if callable(own) else ()

    def arrays(self) -> dict[str, np.ndarray]:
        """JNR's arrays of a result record (:func:`jnr_arrays` of the head) and ``rotation (3, 3)``."""
        with torch.no_grad():
            rotation = self.rotation().numpy()
        return {**jnr_arrays(self.head_params()), "rotation": rotation}

    def head_params(self) -> HeadParams:
        """The fitted head as the model's :class:`~rig.head_model.HeadParams` (float64)."""
        with torch.no_grad():
            return HeadParams(
                self.model.kind,
                {group: getattr(self, f"p_{group}").double().numpy().copy() for group in self.group_names},
            )


class ModelPhotoState(ModelState):
    """A head model in one photo: ``x_cam = RIG_TO_OPENCV @ R @ x_rig + t`` (OpenCV camera frame, mm); arguments
    as :class:`ModelState`."""

    def to_camera(self, points: torch.Tensor, free: tuple[str, ...] = ()) -> torch.Tensor:
        """``(N, 3)`` rig space -> OpenCV camera space, mm; the pose carries gradients if ``pose`` is free."""
        rot, t = (
            (self.rotation(), self.translation)
            if "pose" in free
            else (self.rotation().detach(), self.translation.detach())
        )
        return points.to(torch.float64) @ (self.flip @ rot).T + t

    def camera_center(self) -> np.ndarray:
        """``(3,)`` float64 camera centre in rig space, mm."""
        with torch.no_grad():
            return camera_center_in_rig(self.rotation().numpy(), self.translation.numpy())


class ModelScanState(ModelState):
    """A head model in a point cloud's frame: ``x = s R x_rig + t`` (mm), ``s = exp(log_scale)`` (group ``pose``
    with ``fit_scale``); what :func:`pipeline.scan.fit.fit_scan` needs of a state
    (:class:`pipeline.fitting.state.ScanState`'s methods), for a model registered as a head model only
    (:func:`pipeline.fitting.state.scan_state_class`)."""

    model_kind: ClassVar[str] = ""

    def __init__(self, model: HeadModel, *, fit_scale: bool = True) -> None:
        super().__init__(model, np.eye(3), np.zeros(3))
        self.log_scale = nn.Parameter(torch.zeros((), dtype=torch.float64))
        if fit_scale:
            self.GROUPS = {**self.GROUPS, "pose": (*self.GROUPS["pose"], ("log_scale", "log_scale"))}

    @classmethod
    def for_kind(cls, kind: str) -> type[ModelScanState]:
        """The state class of registered head model ``kind`` (what ``for_scan`` builds)."""
        return type(f"ModelScanState_{kind}", (cls,), {"kind": kind})

    @classmethod
    def for_scan(cls, rig, neural, expressions, config, *, fit_scale: bool) -> ModelScanState:
        """The state at the identity pose: the model ``cls.kind`` on ``rig``'s asset."""
        return cls(create(cls.kind, asset=rig.asset), fit_scale=fit_scale)

    @staticmethod
    def label(config) -> str:
        """The head model's name in the evaluation's records."""
        return str(config.skinning)

    def set_pose(self, rotation: np.ndarray, translation: np.ndarray, scale: float = 1.0) -> None:
        """Place the head in the cloud's frame: ``(3, 3)``, ``(3,)`` mm, scalar."""
        super().set_pose(rotation, translation)
        with torch.no_grad():
            self.log_scale.fill_(math.log(scale))

    def finish(self) -> dict:
        """After the fit: the groups are already in their limits (projected after every step): ``{}``."""
        return {}

    def model_entry(self) -> dict | None:
        """The model's own entry of the result beyond its parameters: None."""
        return None

    def to_cloud(self, v: torch.Tensor) -> torch.Tensor:
        """``(V, 3)`` rig space -> the cloud's frame, mm."""
        return self.log_scale.exp() * v.to(torch.float64) @ self.rotation().T + self.translation

    @property
    def scale(self) -> float:
        return float(self.log_scale.detach().exp())


__all__ = ["LR_FIELDS", "ModelPhotoState", "ModelScanState", "ModelState", "jnr_arrays"]
