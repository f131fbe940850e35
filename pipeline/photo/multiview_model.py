"""Any registered head model as the multi-view fit's identity (``skinning: KIND``; :mod:`pipeline.fitting.model_state`),
for a model that brings no identity step of its own (ASM's: :mod:`pipeline.photo.multiview_asm`).

As ASM's: the model is registered to the JNR head the views fit made (the refined one, or the averaged single-view
fits with ``asm.register_to: averaged``): Levenberg-Marquardt on its groups, the mean squared distance between
its vertices and that head's; then Levenberg-Marquardt on its groups and every view's pose against the joint
refinement's landmark terms (re-weighted as the solver goes, the contours as picked there), each view's expression
that of the refinement (the model's own ``expressions`` group set to it when it has one of the rig's length,
else the rig's expression shapes added to its head), focals held, plus the model's own priors if it has any.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from pipeline.fitting.engine import Stage, StageLog
from pipeline.fitting.least_squares import LMSettings, StateVector, run_lm_stage
from pipeline.fitting.model_state import ModelState
from pipeline.fitting.terms import L2, Inputs, LeastSquaresTerms, Term
from pipeline.photo.multiview_problem import MultiViewProblem
from rig.expressions import EXPRESSION_NAMES, expression_limits
from rig.head_model import HeadModel, HeadParams, create

LM_ITERATIONS = 25
"""Levenberg-Marquardt iterations at most of the registration and of the refinement (each stops earlier when it
converges)."""


def has_own_expressions(model: HeadModel) -> bool:
    """Whether ``model`` has an ``expressions`` group of the rig's 52 ARKit coefficients."""
    return any(g.name == "expressions" and g.size == len(EXPRESSION_NAMES) for g in model.groups())


class ViewsModelState(ModelState):
    """A head model's groups, every view's head pose (``rotvec``, ``translation``: ``(N, 3)``, group ``pose``) and,
    for a model without its own expressions, every view's rig expression coefficients (``c (N, E)``, group
    ``view_expressions``, in their limits)."""

    def __init__(self, model: HeadModel, rotvec: torch.Tensor, translation: torch.Tensor, c: torch.Tensor) -> None:
        super().__init__(model, np.eye(3), np.zeros(3))
        self.rotvec = nn.Parameter(rotvec.detach().double().clone())
        self.translation = nn.Parameter(translation.detach().double().clone())
        self.own_expressions = has_own_expressions(model)
        if not self.own_expressions:
            self.c = nn.Parameter(c.detach().double().clone())
            low, high = expression_limits(torch.float64)
            self.register_buffer("c_low", low.expand_as(self.c).clone())
            self.register_buffer("c_high", high.expand_as(self.c).clone())
            self.GROUPS = {**self.GROUPS, "view_expressions": (("c", "expressions"),)}

    def limits(self, name: str) -> tuple[torch.Tensor, torch.Tensor] | None:
        return (self.c_low, self.c_high) if name == "c" else super().limits(name)


def _stage(name: str, free: tuple[str, ...], iterations: int) -> Stage:
    """A stage freeing the model's own groups (whatever they are named), built from them."""
    kind = type("ModelStage", (Stage,), {"groups": free})
    return kind(name, free, iterations)


class _Problem:
    """A :class:`~pipeline.fitting.least_squares.LeastSquaresProblem` over ``free`` groups of the state, whose
    inputs ``make(values)`` builds from the unpacked parameters."""

    def __init__(self, state: ViewsModelState, free: tuple[str, ...], make) -> None:
        self.state, self.vector, self.make = state, StateVector(state, free), make

    def pack(self) -> torch.Tensor:
        return self.vector.pack()

    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self.vector.bounds()

    def inputs(self, x: torch.Tensor) -> Inputs:
        return self.make(self.vector.unpack(x))

    def prepare(self, x: torch.Tensor) -> None:
        self.vector.write(x)

    def write(self, x: torch.Tensor) -> None:
        self.vector.write(x)


class _Views:
    """Each view's landmark pixels of the model's head (module docstring)."""

    def __init__(self, state: ViewsModelState, problem: MultiViewProblem) -> None:
        self.state, self.problem = state, problem
        self.c = problem.state.c.detach().double()  # (N, E) the refinement's expressions
        self.log_focal = problem.state.log_focal.detach().double()
        self.own_expressions = state.own_expressions

    def values(self, v: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {g: v[f"p_{g}"] for g in self.state.group_names}

    def pixels(self, v: dict[str, torch.Tensor], k: int) -> torch.Tensor:
        view, model = self.problem.views[k], self.state.model
        values = self.values(v)
        batch = v["rotvec"].shape[0]
        if self.own_expressions:
            values["expressions"] = self.c[k][None].expand(batch, -1)
        vertices = model.vertices(values, view.vertex_ids).double()
        if not self.own_expressions:
            vertices = vertices + self.problem.expressions(v["c"][:, k], view.vertex_ids)
        px = view.to_pixels(view.interpolate(vertices), v["rotvec"][:, k], v["translation"][:, k])
        return self.problem.scale_focal(px, self.log_focal[k].expand(batch))

    def inputs(self, v: dict[str, torch.Tensor]) -> Inputs:
        lazy = {f"landmarks_px_{k}": (lambda k=k: self.pixels(v, k)) for k in range(len(self.problem.views))}
        values = self.values(v)
        if not self.own_expressions:  # the views' expressions as the refinement's prior reads them
            values["c"] = v["c"].reshape(v["c"].shape[0], -1)
        return Inputs(values, **lazy)


def fit_model_identity(
    kind: str, problem: MultiViewProblem, rows: LeastSquaresTerms, target: np.ndarray, iterations: tuple[int, int]
) -> tuple[np.ndarray, list[np.ndarray], HeadParams, list[StageLog], ViewsModelState]:
    """The registered head model ``kind`` as the views' identity (module docstring), registered to ``target
    (V, 3)`` (rig space, mm) in ``iterations[0]`` LM iterations, refined in ``iterations[1]``.

    Returns:
        ``(identity (V, 3), per-view vertices [(V, 3)], the fitted parameters, stage logs, the refined state)``.
    """
    mv = problem.state
    model = create(kind, asset=mv.rig.asset)
    state = ViewsModelState(model, mv.rotvec, mv.translation, mv.c)
    goal = torch.as_tensor(target, dtype=torch.float64)[None]
    groups = state.group_names

    def registered(v):
        values = {g: v[f"p_{g}"] for g in groups}
        return Inputs(values, rig_vertices=lambda: model.vertices(values).double())

    fit = Term("register_mm2", 1.0, lambda p: p["rig_vertices"] - goal, L2(), normaliser="mean")
    register = _stage(f"{kind} register", groups, iterations[0])
    logs = [run_lm_stage(_Problem(state, groups, registered), (fit,), register, LMSettings())]
    views = _Views(state, problem)
    with torch.no_grad():
        problem.repick()  # the contours where the joint refinement ended
    # the landmark terms; and the views' expressions, free with their prior, when the model has none of its own
    own = state.own_expressions
    landmarks = [t for t in rows.terms if t.name.startswith("landmarks_") or (t.name == "expressions" and not own)]
    free = (*groups, "pose", *(() if own else ("view_expressions",)))
    stage = _stage(f"{kind} refine", free, iterations[1])
    terms = (*landmarks, *state.prior_terms())
    logs.append(run_lm_stage(_Problem(state, free, views.inputs), terms, stage, LMSettings()))
    with torch.no_grad():
        values = state.values()
        identity = model.vertices(values)[0].double().numpy()
        per_view = []
        for k in range(mv.views):
            one = dict(values)
            if views.own_expressions:
                one["expressions"] = views.c[k][None]
                per_view.append(model.vertices(one)[0].double().numpy())
            else:
                per_view.append(identity + problem.expressions(state.c[k][None].detach())[0].numpy())
    return identity, per_view, state.head_params(), logs, state


def model_views_identity(kind: str):
    """The views fit's identity step for registered head model ``kind`` (the signature of
    :data:`pipeline.photo.multiview_asm.VIEWS_IDENTITY_MODELS`' entries): registered to the head
    ``config.asm.register_to`` names, :data:`LM_ITERATIONS` each."""

    def identity(problem: MultiViewProblem, rows: LeastSquaresTerms, averaged, refined, config):
        source = averaged if config.asm.register_to == "averaged" else refined
        return fit_model_identity(kind, problem, rows, source, (LM_ITERATIONS, LM_ITERATIONS))

    return identity


__all__ = ["LM_ITERATIONS", "ViewsModelState", "fit_model_identity", "model_views_identity"]
