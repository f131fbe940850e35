"""The ASM identity model of the multi-view fit (``skinning: asm``; :mod:`rig.skinning.asm`).

``fit_asm`` registers ASM to a JNR head (the averaged single-view fits, ASM App. D.1, or the refined multi-view
head); then an Adam stage of :func:`pipeline.fitting.engine.run_schedule` on ASM's parameters and every view's
pose (:class:`MultiViewAsmState`) minimises the landmark cost of every view (the joint refinement's landmark
terms at their last IRLS weights, the jaw contours as picked there) plus the ASM head's priors (ASM's eq. 19
and the smoothness term, :func:`pipeline.fitting.priors.asm_prior_terms`); expressions and focals stay at the
joint refinement's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from torch import nn

from pipeline.fitting.engine import Loss, StageLog, run_schedule
from pipeline.fitting.priors import PriorWeights, asm_prior_terms
from pipeline.fitting.state import GroupedParameters
from pipeline.fitting.terms import Inputs, LeastSquaresTerms, term_values
from pipeline.photo.multiview_config import AsmConfig
from pipeline.photo.multiview_problem import MultiViewProblem, MultiViewStage
from rig.lbs import joint_world_transforms, skin_vertices
from rig.skinning.asm import (
    TAU_UNITS,
    UV_UNIT,
    AdaptiveSkinning,
    AsmParameters,
    AsmVariant,
    bone_local_transforms,
    fit_asm,
)


@dataclass(frozen=True)
class AsmLearningRates:
    """Adam steps of the ASM refinement (from :class:`~pipeline.photo.multiview_config.AsmConfig`)."""

    asm: float
    rotation: float
    translation: float


class MultiViewAsmState(GroupedParameters):
    """ASM's parameters (group ``asm``, in the units of :data:`rig.skinning.asm.TAU_UNITS` and
    :data:`rig.skinning.asm.UV_UNIT`) and every view's head pose (group ``pose``, float64).

    Args:
        model: the :class:`rig.skinning.asm.AdaptiveSkinning`. start: its parameters (batch 1).
        rotvec, translation: ``(N, 3)`` the views' poses to start from.
    """

    GROUPS: ClassVar[dict[str, tuple[tuple[str, str], ...]]] = {
        "asm": (("tau_n", "asm"), ("zeta_n", "asm"), ("log_pi_n", "asm"), ("mu_n", "asm"), ("chol_n", "asm")),
        "pose": (("rotvec", "rotation"), ("translation", "translation")),
    }

    def __init__(
        self, model: AdaptiveSkinning, start: AsmParameters, rotvec: torch.Tensor, translation: torch.Tensor
    ) -> None:
        super().__init__()
        self.model = model
        self.units = {
            "tau": torch.tensor(TAU_UNITS, dtype=start.tau.dtype),
            "zeta": UV_UNIT,
            "log_pi": 1.0,
            "mu": UV_UNIT,
            "chol": 1.0,
        }
        for name, value in start.as_dict().items():
            setattr(self, f"{name}_n", nn.Parameter((value.detach() / self.units[name]).clone()))
        self.rotvec = nn.Parameter(rotvec.detach().clone())
        self.translation = nn.Parameter(translation.detach().clone())

    def asm_parameters(self) -> AsmParameters:
        """The current :class:`rig.skinning.asm.AsmParameters` (batch 1)."""
        return AsmParameters(**{name: getattr(self, f"{name}_n") * unit for name, unit in self.units.items()})


class AsmRefinement:
    """The objective of the ASM refinement (module docstring).

    Args:
        state: the ASM state. problem: the joint refinement (its views' contours and landmark terms).
        rows: the joint refinement's terms as least-squares rows, re-weighted at its solution.
        settings: :class:`~pipeline.photo.multiview_config.AsmConfig`.
    """

    def __init__(
        self, state: MultiViewAsmState, problem: MultiViewProblem, rows: LeastSquaresTerms, settings: AsmConfig
    ) -> None:
        self.state, self.problem = state, problem
        model, n = state.model, problem.state.views
        self.landmarks = rows.subset([f"landmarks_{k}" for k in range(n)])
        self.priors = asm_prior_terms(
            PriorWeights(lambda_asm=settings.lambda_regularizer, lambda_asm_smooth=settings.lambda_smooth),
            model,
            expressions=False,
        )
        dtype = model.rig.template.dtype
        expr = problem.expressions
        with torch.no_grad():
            self.rests = [(expr.template + expr(c[None])[0]).to(dtype) for c in problem.state.c.detach()]
        # only the vertices the landmarks sit on (the contours as picked by the joint refinement) are skinned
        views = problem.views
        self.used = torch.unique(torch.cat([view.vertex_ids for view in views]))
        where = torch.full((len(model.rig.asset.vertices),), -1, dtype=torch.long)
        where[self.used] = torch.arange(len(self.used))
        self.local = [where[view.vertex_ids] for view in views]
        self.rest_used = torch.stack([r[self.used] for r in self.rests])  # (N, U, 3)

    def posed_views(self, p: AsmParameters) -> torch.Tensor:
        """``(N, U, 3)``: the ASM head with each view's expression (one skinning of the shared bones)."""
        model = self.state.model
        weights = model.weights(p)[0][self.used]  # (U, J)
        bind = model.bone_positions(p)
        _, skinning = joint_world_transforms(bone_local_transforms(p.tau), bind, model.rig.parents, model.levels)
        return skin_vertices(self.rest_used, weights, skinning.expand(len(self.rests), -1, -1, -1))

    def inputs(self, p: AsmParameters) -> Inputs:
        """``landmarks_px_<k> (1, 68, 2)`` of every view, ``asm`` and (lazily) ``rig_vertices (1, V, 3)``, the
        neutral ASM head."""
        s, problem = self.state, self.problem
        posed = self.posed_views(p)
        pixels = {}
        for k, view in enumerate(problem.views):
            points = (posed[k][self.local[k]].double()[view.local_ids] * view.bary[..., None]).sum(1)
            px = view.to_pixels(points[None], s.rotvec[k][None], s.translation[k][None])
            pixels[f"landmarks_px_{k}"] = problem.scale_focal(px, problem.state.log_focal.detach()[k][None])
        return Inputs({**pixels, "asm": p}, rig_vertices=lambda: s.model(p).vertices)

    def __call__(self, free: tuple[str, ...]) -> Loss:
        inputs = self.inputs(self.state.asm_parameters())
        return Loss({"landmarks": self.landmarks.cost(inputs)[0], **term_values(self.priors, inputs)})


def fit_asm_identity(
    problem: MultiViewProblem, rows: LeastSquaresTerms, target_vertices: np.ndarray, settings: AsmConfig
) -> tuple[np.ndarray, list[np.ndarray], dict[str, np.ndarray], list[StageLog], MultiViewAsmState]:
    """The ASM identity model (module docstring): ``fit_asm`` registers ASM to ``target_vertices (V, 3)``, then
    the refinement on every view's landmarks.

    Returns:
        ``(identity (V, 3), per-view vertices [(V, 3)], ASM parameters as float64 arrays, stage logs, the
        refined state)``; the problem's state is left as it was (the refined poses are the ASM state's).
    """
    rig = problem.state.rig
    model = AdaptiveSkinning(rig, components=settings.components)
    dtype = rig.template.dtype
    t0 = time.perf_counter()
    target = torch.as_tensor(target_vertices, dtype=dtype)[None]
    registered = fit_asm(model, target, variant=AsmVariant(True, True), iterations=settings.register_iterations)
    logs = [
        StageLog(
            "asm register",
            ("asm",),
            settings.register_iterations,
            float(registered.losses[0]),
            float(registered.losses[-1]),
            metrics={"rmse_mm": float(registered.rmse[0])},
            seconds=time.perf_counter() - t0,
        )
    ]
    mv = problem.state
    state = MultiViewAsmState(model, registered.params, mv.rotvec, mv.translation)
    with torch.no_grad():
        problem.repick()
        rows.reweight(problem.state_inputs())
    objective = AsmRefinement(state, problem, rows, settings)
    lr = AsmLearningRates(settings.lr, settings.lr_rotation, settings.lr_translation)
    stage = MultiViewStage("asm refine", ("asm", "pose"), settings.iterations)
    logs.extend(run_schedule(state, (stage,), objective, lr, label="fit_multiview (ASM refinement)"))
    with torch.no_grad():
        p = state.asm_parameters().map(torch.Tensor.detach)
        identity = model(p).vertices[0].double().numpy()
        per_view = [model(p, vertices=rest[None]).vertices[0].double().numpy() for rest in objective.rests]
    arrays = {k: v[0].double().numpy() for k, v in p.as_dict().items()}
    return identity, per_view, arrays, logs, state


def asm_views_identity(
    problem: MultiViewProblem,
    rows: LeastSquaresTerms,
    averaged: np.ndarray,
    refined: np.ndarray,
    config,
) -> tuple[np.ndarray, list[np.ndarray], dict[str, np.ndarray], list[StageLog], MultiViewAsmState]:
    """:func:`fit_asm_identity` as the views fit's identity model ``asm``: registered to the averaged JNR head
    ``averaged (V, 3)`` or the refined one ``refined (V, 3)`` (``config.asm.register_to``), with
    ``config.asm``'s settings."""
    source = averaged if config.asm.register_to == "averaged" else refined
    return fit_asm_identity(problem, rows, source, config.asm)


VIEWS_IDENTITY_MODELS = {"jnr": None, "asm": asm_views_identity}
"""The head models with a views identity of their own, by kind: None for the joints' (``jnr``: the views fit
itself), else the identity model the views fit puts on top of the joints', ``(problem, rows, averaged, refined,
config) -> (identity, per-view vertices, parameters, logs, state)``; any other registered model takes the generic
one (:mod:`pipeline.photo.multiview_model`).
"""
