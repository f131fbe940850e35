"""The landmark fit of any registered head model (:mod:`pipeline.fitting.model_state`): what
:func:`pipeline.photo.landmark_fit.fit_landmarks` does for JNR's head, on the model's own groups.

The same steps and terms: the camera, solvePnP's pose on the model's initial head, then the configured stages
(``landmarks.lm_stages`` with the default solver, ``landmarks.stages`` with Adam), each freeing the groups of its
list that the model has (``pose`` is the head's pose; a model with a ``joints`` group is fitted by the
``joints`` stages). The landmark term (:class:`~pipeline.fitting.landmark_term.LandmarkTerm`, in the units of
``face_scale``, over the detector's error squared) and the model's own priors, if it has any; the points are
computed by the model's batched :meth:`~rig.head_model.HeadModel.vertices` on the vertices they read
(:class:`~pipeline.fitting.landmark_term.ModelLandmarks`).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import torch

from landmarks.ibug68.positions import landmark_positions
from landmarks.layout import LandmarkLayout, ibug68_layout
from pipeline.camera import default_focal, make_camera, solve_pose
from pipeline.fitting.engine import Loss, StageLog, run_schedule
from pipeline.fitting.landmark_term import LandmarkTerm, ModelLandmarks, face_scale
from pipeline.fitting.least_squares import StateVector
from pipeline.fitting.model_state import ModelPhotoState
from pipeline.fitting.terms import Inputs, Term, check_unique, term_values
from pipeline.photo.landmark_fit import (
    LandmarkFit,
    LandmarkFitConfig,
    LandmarkProblem,
    check_landmarks_2d_shape,
    landmark_result,
    run_lm_stages,
)
from rig.errors import InputError
from rig.head_model import HeadModel
from rig.optim import Progress


class ModelLandmarkProblem(LandmarkProblem):
    """One LM stage of a head model's landmark fit (:class:`~pipeline.fitting.least_squares.LeastSquaresProblem`):
    ``x`` = the stage's free groups of ``state`` (:class:`~pipeline.fitting.least_squares.StateVector`), the
    landmark pixels of a batch of ``x`` by :class:`~pipeline.fitting.landmark_term.ModelLandmarks` (the packing,
    the box and the contour's re-pick are :class:`~pipeline.photo.landmark_fit.LandmarkProblem`'s)."""

    def __init__(self, state: ModelPhotoState, term: LandmarkTerm, free: tuple[str, ...]) -> None:
        self.state = state
        self.vector = StateVector(state, free)
        self.landmarks = ModelLandmarks(term, state.model, state.group_names, free)

    def inputs(self, x: torch.Tensor) -> Inputs:
        v = self.vector.unpack(x)
        values = {"rotvec": v["rotvec"], "translation": v["translation"]}
        values.update({g: v[f"p_{g}"] for g in self.state.group_names})
        p = Inputs(values, landmarks_px=lambda: self.landmarks.pixels(p))
        return p


def _run_stages(
    state: ModelPhotoState, term: LandmarkTerm, terms: tuple[Term, ...], config: LandmarkFitConfig, objective, progress
) -> tuple[StageLog, ...]:
    if config.solver != "lm":
        stages = tuple(replace(s, free=state.available(s.free)) for s in config.stages)
        return run_schedule(state, stages, objective, config.lr, label="fit_landmarks", progress=progress)
    stages = [replace(s, free=state.available(s.free)) for s in config.lm_stages if state.available(s.free)]
    return run_lm_stages(
        stages, lambda stage: ModelLandmarkProblem(state, term, stage.free), terms, config, objective, progress
    )


def fit_model_landmarks(
    landmarks2d,
    width: int,
    height: int,
    model: HeadModel,
    *,
    focal: float | None = None,
    config: LandmarkFitConfig | None = None,
    progress: Progress | None = None,
    terms: tuple[Term, ...] = (),
    layout: LandmarkLayout | None = None,
) -> LandmarkFit:
    """Fit a head model's groups and the head pose to the landmarks of one photo (module docstring).

    Args:
        landmarks2d: ``(N, 2)`` pixels (OpenCV, 0-based), in the layout's order.
        width, height: image size, pixels. model: the head model (flat groups).
        focal: focal length, pixels (default :func:`pipeline.camera.default_focal`).
        config: the landmark fit's settings (:class:`~pipeline.photo.landmark_fit.LandmarkFitConfig`).
        progress: called after every step. terms: more loss terms (reading the groups by name and
            ``landmarks_px``). layout: the landmark scheme (default iBUG-68 on the model's asset).

    Returns:
        :class:`~pipeline.photo.landmark_fit.LandmarkFit` whose :attr:`~pipeline.photo.landmark_fit.LandmarkFit.head`
        is the fitted model's parameters (``theta`` and ``z`` are the template's zeros; ``expressions`` the
        model's ``expressions`` group when it has one of the rig's length, else zeros).

    Raises:
        rig.errors.InputError: bad landmarks, image size or focal; a model whose groups are not flat vectors.
    """
    t_start = time.perf_counter()
    asset = model.asset
    layout = ibug68_layout(asset) if layout is None else layout
    lm = check_landmarks_2d_shape(landmarks2d, count=layout.count)
    if not (width > 0 and height > 0):
        raise InputError(f"fit_landmarks: width and height must be > 0, got {width} x {height}")
    focal = default_focal(width, height) if focal is None else float(focal)
    config = config or LandmarkFitConfig()
    camera = make_camera(width, height, focal, dtype=torch.float64, pose=False)
    term = LandmarkTerm(
        asset, lm, camera, config.huber_delta_px, config.contour_weight, config.landmark_weighting, layout
    )
    state = ModelPhotoState(model, np.eye(3), np.zeros(3))
    with torch.no_grad():
        start = state.rig_vertices().numpy()
    model_points = landmark_positions(start, term.embedding, term.faces)[0]
    rotation0, translation0 = solve_pose(lm, model_points, width, height, focal, exclude=layout.pose_exclude)
    state.set_pose(rotation0, translation0)
    if config.face_scale:
        term.scale = face_scale(focal, float(translation0[2]), asset)
    noise = config.noise_for(layout.name)
    all_terms = (term.term(1.0 / noise**2), *state.prior_terms(config.prior), *terms)
    check_unique(all_terms)

    def objective(free: tuple[str, ...]) -> Loss:
        inputs = state.term_inputs().add(landmarks_px=lambda: term.pixels(state, state.rig_vertices(free), free))
        return Loss(term_values(all_terms, inputs))

    stages = _run_stages(state, term, all_terms, config, objective, progress)
    return landmark_result(state, term, lm, width, height, focal, stages, t_start)


__all__ = ["ModelLandmarkProblem", "fit_model_landmarks"]
