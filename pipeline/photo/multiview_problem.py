"""The unknowns and the terms of the multi-view fit (:func:`pipeline.photo.multiview.fit_multiview`).

:class:`MultiViewState` holds one identity (the joint channels ``theta_n``) and, per view ``k``, a head pose, the
expression coefficients ``c_k`` and the log focal change ``s_k``, as float64 parameters named by group
(``joints``, ``pose``, ``expressions``, ``focal``), so the engine's Adam stages and the LM stages both run on
it. :class:`MultiViewProblem` gives what the terms read at a batch of its parameters
(:class:`~pipeline.fitting.terms.Inputs`): every view's landmark pixels (``landmarks_px_<k>``, by
:class:`~pipeline.fitting.landmark_term.BatchedLandmarks` with the focal scaled by ``exp(s_k)``), all views'
expression coefficients (``c (B, N * E)``), ``theta``, ``theta_n`` and ``log_focal (B, N)``. Its terms
(:meth:`MultiViewProblem.terms`) are each view's landmark term, the state's priors (the identity prior counted
once, every view's expressions) and :func:`focal_term`.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import ClassVar

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from scipy.spatial.transform import Rotation
from torch import nn

from pipeline.camera import camera_center_in_rig, camera_points_to_pixels
from pipeline.fitting.engine import Stage
from pipeline.fitting.identity import IdentityPrior
from pipeline.fitting.landmark_term import BatchedLandmarks, LandmarkTerm, expressions64
from pipeline.fitting.least_squares import StateVector
from pipeline.fitting.priors import PriorWeights, jnr_prior_terms
from pipeline.fitting.state import FREE_GROUPS, GroupedParameters
from pipeline.fitting.terms import L2, Inputs, Term
from pipeline.photo.landmark_fit import LandmarkFit
from pipeline.photo.multiview_config import MultiViewConfig
from rig.expressions import expression_limits
from rig.geometry import RIG_TO_OPENCV, head_angles
from rig.head_model import jnr_vertices
from rig.model import JointRig
from rig.parameters import theta_limits

FOCAL_LIMIT = 0.7
"""Box limit of each view's log focal change ``s_k`` (a factor of 2 either way)."""


class MultiViewStage(Stage):
    """A stage of the multi-view fit: ``free`` may also name ``focal`` (the views' focal lengths) and ``asm``
    (the ASM identity's parameters)."""

    groups: ClassVar[tuple[str, ...]] = FREE_GROUPS + ("focal", "asm")


def focal_term(weight: float) -> Term:
    """``0.5 weight sum_k s_k^2``: the prior on each view's log focal change (input ``log_focal (B, N)``)."""
    return Term("focal", 0.5 * weight, lambda p: p["log_focal"], L2())


def view_weights(yaw_deg: np.ndarray, correlation: float, yaw_scale_deg: float) -> np.ndarray:
    """``(N,)`` the weights of ``N`` views' landmark terms (:class:`~pipeline.photo.multiview_config.MultiViewConfig`'s
    ``view_correlation`` and ``view_yaw_deg``).

    Each view ``k`` gets ``u_k / max(u) / (1 + (N - 1) correlation)``, ``u_k = 1 / (1 + (|yaw_k| / yaw_scale_deg)^4)``
    (``u = 1`` when ``yaw_scale_deg`` is 0): a turned face's points count less than a frontal one's, and errors
    the views share (``correlation`` 1) are counted once, not ``N`` times.

    Args:
        yaw_deg: ``(N,)`` the head's yaw in each view, degrees. correlation: in [0, 1]. yaw_scale_deg: >= 0.

    Example:
        >>> view_weights(np.array([0.0, 30.0, -60.0]), 1.0, 30.0).round(4).tolist()
        [0.3333, 0.1667, 0.0196]
        >>> view_weights(np.array([0.0, 30.0]), 0.0, 0.0).tolist()
        [1.0, 1.0]
    """
    yaw = np.abs(np.asarray(yaw_deg, np.float64))
    u = 1.0 / (1.0 + (yaw / yaw_scale_deg) ** 4) if yaw_scale_deg > 0 else np.ones_like(yaw)
    return u / u.max() / (1.0 + (len(yaw) - 1) * correlation)


class MultiViewState(GroupedParameters):
    """One identity in ``N`` views, float64 parameters (module docstring).

    Args:
        rig: the rig (its dtype rounds the poses the jaw contour is picked from, as a single-view fit's).
        theta_n: ``(P,)`` the identity's joint channels over their span.
        rotvec, translation: ``(N, 3)`` each view's head pose (radians; mm), ``x_cam = RIG_TO_OPENCV @ R_k
            @ x_rig + t_k``.
        c: ``(N, E)`` each view's expression coefficients. log_focal: ``(N,)`` each view's ``s_k``.
        fit_focal: False keeps ``s_k`` at 0 (its box is then empty).
    """

    GROUPS: ClassVar[dict[str, tuple[tuple[str, str], ...]]] = {
        "joints": (("theta_n", "joints"),),
        "pose": (("rotvec", "rotation"), ("translation", "translation")),
        "expressions": (("c", "expressions"),),
        "focal": (("log_focal", "focal"),),
    }

    def __init__(
        self,
        rig: JointRig,
        theta_n: np.ndarray,
        rotvec: np.ndarray,
        translation: np.ndarray,
        c: np.ndarray,
        log_focal: np.ndarray,
        *,
        fit_focal: bool = True,
    ) -> None:
        super().__init__()
        f64 = torch.float64
        self.rig, self.fit_focal = rig, fit_focal
        low, high = theta_limits(rig.template.dtype)
        span = (high - low).clamp_min(1e-3)
        self.register_buffer("low", low.double())
        self.register_buffer("high", high.double())
        self.register_buffer("span", span.double())
        self.register_buffer("theta_low", (low / span).double())
        self.register_buffer("theta_high", (high / span).double())
        c_low, c_high = expression_limits(rig.template.dtype)
        self.register_buffer("c_low", c_low.double())
        self.register_buffer("c_high", c_high.double())
        self.theta_n = nn.Parameter(torch.as_tensor(theta_n, dtype=f64).clone())
        self.rotvec = nn.Parameter(torch.as_tensor(rotvec, dtype=f64).clone())
        self.translation = nn.Parameter(torch.as_tensor(translation, dtype=f64).clone())
        self.c = nn.Parameter(torch.as_tensor(c, dtype=f64).clone())
        self.log_focal = nn.Parameter(torch.as_tensor(log_focal, dtype=f64).clone())

    @property
    def views(self) -> int:
        return int(self.rotvec.shape[0])

    def limits(self, name: str) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Joint channels and expression coefficients within their limits, ``|s_k| <= 0.7`` (0 without
        ``fit_focal``); the poses unbounded."""
        if name == "theta_n":
            return self.theta_low, self.theta_high
        if name == "c":
            return self.c_low.expand_as(self.c), self.c_high.expand_as(self.c)
        if name == "log_focal":
            limit = torch.full_like(self.log_focal, FOCAL_LIMIT if self.fit_focal else 0.0)
            return -limit, limit
        return None

    def project(self, free: tuple[str, ...]) -> None:
        """After an Adam step: the joint channels (and expression coefficients) back into their limits."""
        with torch.no_grad():
            if "joints" in free:
                self.theta_n.copy_(torch.maximum(torch.minimum(self.theta_n, self.theta_high), self.theta_low))
            if "expressions" in free:
                self.c.copy_(torch.maximum(torch.minimum(self.c, self.c_high), self.c_low))

    def prior_terms(self, weights: PriorWeights, identity: IdentityPrior | None = None) -> tuple[Term, ...]:
        """The identity's priors (:func:`pipeline.fitting.priors.jnr_prior_terms` without a latent: the neural
        skinning stays at ``Z = 0``; ``identity``: the identity prior, default the population's), every view's
        expressions in one ``expressions`` term."""
        return jnr_prior_terms(weights, self.low, self.high, latent=False, identity=identity)

    def camera_center(self, k: int) -> np.ndarray:
        """``(3,)`` view ``k``'s camera centre in rig space, mm, from its pose rounded to the rig's dtype (where
        a single-view fit picks its jaw contour from)."""
        dtype = self.rig.template.dtype
        with torch.no_grad():
            rotation = axis_angle_to_rotation_matrix(self.rotvec[k].to(dtype)[None])[0]
            return camera_center_in_rig(rotation.double().numpy(), self.translation[k].to(dtype).double().numpy())


def initial_state(singles: tuple[LandmarkFit, ...], theta_mean: np.ndarray, rig: JointRig, fit_focal: bool):
    """The state the joint refinement starts from (ASM App. D.1): the single-view fits' average joint channels
    ``theta_mean (P,)``, each view's own pose and expressions, ``s_k = 0``; each value rounded to the rig's dtype,
    as a single-view state holds it."""
    dtype = rig.template.dtype
    low, high = theta_limits(dtype)
    span = (high - low).clamp_min(1e-3)

    def rounded(values) -> np.ndarray:
        return torch.as_tensor(np.asarray(values, np.float64), dtype=dtype).double().numpy()

    return MultiViewState(
        rig,
        (torch.as_tensor(theta_mean, dtype=dtype) / span).double().numpy(),
        np.stack([rounded(Rotation.from_matrix(s.rotation).as_rotvec()) for s in singles]),
        np.stack([rounded(s.translation) for s in singles]),
        np.stack([rounded(s.expressions) for s in singles]),
        np.zeros(len(singles)),
        fit_focal=fit_focal,
    )


class MultiViewProblem:
    """The terms' inputs of a :class:`MultiViewState`, at the state itself (Adam, :meth:`state_inputs`) or at
    a batch of its packed parameters (the LM stage: :meth:`inputs`, a
    :class:`~pipeline.fitting.least_squares.LeastSquaresProblem`).

    A batch row that leaves view ``k``'s unknowns and the identity as in row 0 gives view ``k`` row 0's
    landmarks: only the rows that differ are evaluated, so a forward-difference Jacobian costs about ``N``
    single-view Jacobians, not ``N^2``.

    Args:
        state: the unknowns. terms: each view's :class:`~pipeline.fitting.landmark_term.LandmarkTerm`.
        weights: ``(V, K)`` skinning weights (the neural skinning at ``Z = 0``).
        config: the fit's settings (the priors' weights).
        identity: the conditional identity prior of the views' 3D points (their regressed heads' mean,
            :func:`pipeline.photo.multiview.views_identity_prior`), or None for the population prior.
    """

    FREE = ("joints", "pose", "expressions", "focal")

    def __init__(
        self,
        state: MultiViewState,
        terms: list[LandmarkTerm],
        weights: torch.Tensor,
        config: MultiViewConfig,
        identity: IdentityPrior | None = None,
    ) -> None:
        self.state, self.landmark_terms, self.config = state, terms, config
        with torch.no_grad():
            rotations = axis_angle_to_rotation_matrix(state.rotvec.detach())
        yaws = np.array([head_angles(r.numpy())[0] for r in rotations])
        self.view_weights = view_weights(yaws, config.view_correlation, config.view_yaw_deg)
        self.weights = weights.double()
        self.vector = StateVector(state, self.FREE)
        self.views = [BatchedLandmarks(t, state.rig, self.weights, ("pose", "joints", "expressions")) for t in terms]
        self.expressions = expressions64(state.rig.asset)
        self.flip = torch.tensor(RIG_TO_OPENCV, dtype=torch.float64)
        self.identity = identity
        """The conditional identity prior of the views' 3D points (their regressed heads' mean), or None."""

    def terms(self) -> tuple[Term, ...]:
        """Each view's landmark term (``landmarks_<k>``, weighed by :attr:`view_weights`: averaged over the views
        and a turned view's less by default), the state's priors with the identity prior's weight
        ``lambda_identity`` (counted once), and the focal prior."""
        config = self.config
        conditional = self.identity is not None
        lambda_identity = config.landmarks.regression.lambda_identity if conditional else config.lambda_identity
        weights = replace(config.landmarks.prior, lambda_identity=lambda_identity, lambda_m=0.0, lambda_symmetry=0.0)
        # each view over its points' error squared, as in the single-view fit, and by view_weights
        landmarks = tuple(
            t.term(w / config.landmarks.noise_for(t.layout.name) ** 2, name=f"landmarks_{k}", key=f"landmarks_px_{k}")
            for k, (t, w) in enumerate(zip(self.landmark_terms, self.view_weights))
        )
        return (*landmarks, *self.state.prior_terms(weights, self.identity), focal_term(config.lambda_focal))

    # -- the LM problem ------------------------------------------------------------------------------
    def pack(self) -> torch.Tensor:
        return self.vector.pack()

    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self.vector.bounds()

    def inputs(self, x: torch.Tensor) -> Inputs:
        """The terms' inputs at ``x (B, n)`` (the packed parameters)."""
        return self._inputs(self.vector.unpack(x))

    def prepare(self, x: torch.Tensor) -> None:
        """Write ``x (n,)`` into the state and re-pick every view's jaw contour there."""
        self.vector.write(x)
        self.repick()

    def write(self, x: torch.Tensor) -> None:
        self.vector.write(x)

    # -- the state ----------------------------------------------------------------------------------
    def state_inputs(self) -> Inputs:
        """The terms' inputs at the state (batch 1; gradients flow to its parameters)."""
        names = ("theta_n", "rotvec", "translation", "c", "log_focal")
        return self._inputs({name: getattr(self.state, name)[None] for name in names})

    def repick(self) -> None:
        """Re-pick every view's jaw contour at the state (:meth:`BatchedLandmarks.prepare`)."""
        with torch.no_grad():
            p = self.state_inputs()
            for k, view in enumerate(self.views):
                view.prepare({"theta": p["theta"], "c": p["c_views"][:, k]}, self.state.camera_center(k))

    def _inputs(self, v: dict[str, torch.Tensor]) -> Inputs:
        n = self.state.views
        lazy = {f"landmarks_px_{k}": (lambda k=k: self._view_pixels(k, v, p["theta"])) for k in range(n)}
        p = Inputs(
            {"theta_n": v["theta_n"], "c_views": v["c"], "c": v["c"].reshape(v["c"].shape[0], -1)},
            log_focal=lambda: v["log_focal"].reshape(v["log_focal"].shape[0], n),
            theta=lambda: v["theta_n"] * self.state.span,
            **lazy,
        )
        return p

    def scale_focal(self, pixels: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        """``(B, L, 2)`` pixels of a view's camera with its focal scaled by ``exp(s (B,))``."""
        centre = self.views[0].centre
        return (pixels - centre) * s.exp()[:, None, None] + centre

    def _view_pixels(self, k: int, v: dict[str, torch.Tensor], theta: torch.Tensor) -> torch.Tensor:
        """``(B, 68, 2)`` view ``k``'s landmark pixels; rows where nothing of view ``k`` moved are row 0's."""
        own = {"rotvec": v["rotvec"][:, k], "translation": v["translation"][:, k], "theta": theta, "c": v["c"][:, k]}
        s = v["log_focal"][:, k]
        batch = theta.shape[0]
        if batch <= 2:
            return self.scale_focal(self.views[k].pixels(own), s)
        key = torch.cat([v["theta_n"], own["rotvec"], own["translation"], own["c"], s[:, None]], 1)
        moved = (key != key[:1]).any(1)
        moved[0] = True
        idx = torch.nonzero(moved)[:, 0]
        sub = self.scale_focal(self.views[k].pixels({name: t[idx] for name, t in own.items()}), s[idx])
        out = sub[:1].expand(batch, -1, -1).clone()
        out[idx] = sub
        return out

    # -- full meshes ---------------------------------------------------------------------------------
    def camera_vertices(self, k: int, ids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """View ``k``'s vertices ``ids`` at the state: ``(camera frame (U, 3) mm, pixels (U, 2))``,
        differentiable in its parameters."""
        s, view = self.state, self.views[k]
        posed = jnr_vertices(s.rig, self.expressions, (s.theta_n * s.span)[None], self.weights, s.c[k][None], ids)[0]
        rotation = axis_angle_to_rotation_matrix(s.rotvec[k][None])[0]
        cam = posed @ (self.flip @ rotation).T + s.translation[k]
        pixels = camera_points_to_pixels(cam, view.focal * s.log_focal[k].exp(), view.centre)
        return cam, pixels

    def focal_scales(self) -> np.ndarray:
        """``(N,)`` each view's ``exp(s_k)``."""
        return np.array([math.exp(float(s)) for s in self.state.log_focal.detach()])
