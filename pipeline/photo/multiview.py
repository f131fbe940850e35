"""Multi-view uncalibrated reconstruction: several photos of one person, no calibration (issue 15, ASM 4.2, App. D).

Unknowns: one shared **identity** (the rig's 105 joint channels ``theta``, as the single-photo fit uses them;
the neural skinning at ``Z = 0``, which the landmark fit does not move either), and per view ``k`` a head
pose ``(R_k, t_k)`` (``x_cam = RIG_TO_OPENCV @ R_k @ x_rig + t_k``, :mod:`pipeline.photo.camera`), the 52
ARKit expression coefficients ``c_k`` and the focal length ``f_k = f0_k exp(s_k)`` (``f0_k``: ``--focal`` or
:func:`pipeline.photo.camera.default_focal`; principal point at the image centre).

1. **Single-view fits** (ASM App. D.1): :func:`pipeline.photo.landmark_fit.fit_landmarks` on each view; the
   shared identity starts from their **average** ``theta`` (over ``theta / span``), each view from its own
   pose and expressions, ``s_k = 0``.
2. **Joint landmark refinement** (ASM eq. 18 with our priors): Levenberg-Marquardt
   (:mod:`pipeline.fitting.least_squares`) on ``x = [theta / span | per view: pose (6), c_k (52), s_k]``,
   minimising

       sum_k 0.5 |r_k|^2 + 0.5 lambda_identity |M (theta / span - mu)|^2 + sum_k lambda_expressions |c_k|^2
       + sum_k 0.5 lambda_focal s_k^2

   where ``r_k`` are view ``k``'s weighted landmark residuals exactly as in the single-photo fit
   (:class:`pipeline.photo.landmark_fit._LandmarkLeastSquares`: detector weights, Huber by IRLS, the jaw
   contour re-picked from view ``k``'s camera centre). The landmark terms are **summed** over views, the
   identity prior counted once: each view is more evidence about the one identity.
3. **Photometric consistency** (optional, ASM eqs. 21-22, :class:`PhotoConsistencyConfig`): Adam on the
   shared identity and the per-view poses, minimising the step-2 cost plus
   ``lambda_pc * (1 - mean over view pairs of LNCC)``.

The identity is an interchangeable *identity model*: ``skinning="jnr"`` (the rig's joints, above) or
``skinning="asm"`` (:mod:`rig.skinning.asm`, when installed: registered to the averaged single-view mesh by
``fit_asm`` as ASM App. D.1 does, then refined by Adam on the landmarks of every view + ASM's eq. 19
regulariser).
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix

from pipeline.fitting.engine import StageLog
from pipeline.fitting.least_squares import LMSettings, levenberg_marquardt
from pipeline.fitting.priors import cached_identity_prior
from pipeline.fitting.state import PhotoState
from pipeline.photo.camera import check_focal, default_focal, make_camera
from pipeline.photo.fit import PHOTO_PRIOR
from pipeline.photo.landmark_fit import (
    LandmarkFit,
    LandmarkFitConfig,
    LandmarkTerm,
    _expressions64,
    _LandmarkLeastSquares,
    check_landmarks_2d_shape,
    fit_landmarks,
)
from rig.errors import InputError
from rig.expressions import ExpressionModel
from rig.lbs import ShapeError, joint_world_transforms, skin_vertices, skin_vertices_shared_weights
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS
from rig.skinning.neural import LATENT, NeuralSkinning, load_neural
from rig.template import FACE_REGIONS

SKINNING_MODELS = ("jnr", "asm")
PATCHES = ("1-ring",)


# ----------------------------------------------------------------------------------------------------
# LNCC: pure tensor functions
# ----------------------------------------------------------------------------------------------------

def ncc(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor | None = None, eps: float = 1e-6) -> torch.Tensor:
    """Normalised cross-correlation of patches along the last axis.

    Args:
        a, b: ``(*, P)`` intensities of corresponding patches (any units; NCC is invariant to ``a -> g a + o``
            with ``g > 0`` per patch).
        mask: ``(*, P)`` 0/1 (or weights) of the entries that count (default: all).
        eps: added to the product of the variances (a flat patch gives ~0, not NaN).

    Returns:
        ``(*)`` NCC in [-1, 1]: ``sum m a' b' / sqrt(sum m a'^2 sum m b'^2 + eps)``, ``a' = a - mean_m(a)``.

    Example:
        >>> a = torch.tensor([[0.1, 0.5, 0.2]])
        >>> round(float(ncc(a, 3.0 * a + 1.0)[0]), 4)
        1.0
    """
    if a.shape != b.shape:
        raise ShapeError(f"ncc: a and b must have the same shape, got {tuple(a.shape)} and {tuple(b.shape)}")
    m = torch.ones_like(a) if mask is None else mask.to(a.dtype).expand_as(a)
    count = m.sum(-1, keepdim=True).clamp_min(1e-12)
    da = (a - (m * a).sum(-1, keepdim=True) / count) * m
    db = (b - (m * b).sum(-1, keepdim=True) / count) * m
    return (da * db).sum(-1) / ((da * da).sum(-1) * (db * db).sum(-1) + eps).sqrt()


def lncc(a: torch.Tensor, b: torch.Tensor, patches: torch.Tensor, patch_mask: torch.Tensor,
         visible_a: torch.Tensor, visible_b: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Local NCC of two views' per-vertex intensities (ASM eq. 21, with mesh patches).

    Args:
        a, b: ``(S,)`` intensity sampled at each of ``S`` vertices in view i and view j.
        patches: ``(X, P)`` int64, the patch of each of the ``X`` scored vertices (indices into ``S``; entry 0 the
            vertex itself, then its 1-ring; padded).
        patch_mask: ``(X, P)`` bool, the real (not padded) entries.
        visible_a, visible_b: ``(S,)`` bool or 0/1 visibility of each vertex in view i / j (z-buffer + facing).
        eps: as :func:`ncc`.

    Returns:
        Scalar: the mean of ``NCC(patch_i(x), patch_j(x))`` over the scored vertices ``x`` visible in both
        views (ASM's ``V(S_x^i) V(S_x^j)``); inside a patch only entries visible in both views count. 0 when
        no vertex is visible in both.
    """
    if a.shape != b.shape or a.dim() != 1:
        raise ShapeError(f"lncc: a and b must be (S,), got {tuple(a.shape)} and {tuple(b.shape)}")
    if patches.shape != patch_mask.shape or patches.dim() != 2:
        raise ShapeError(f"lncc: patches and patch_mask must be (X, P), got {tuple(patches.shape)} and "
                         f"{tuple(patch_mask.shape)}")
    both = visible_a.to(a.dtype) * visible_b.to(a.dtype)  # (S,)
    m = patch_mask.to(a.dtype) * both[patches]  # (X, P)
    centre = both[patches[:, 0]] * (m.sum(-1) >= 3).to(a.dtype)  # the vertex itself seen, and >= 3 entries
    scores = ncc(a[patches], b[patches], m, eps)
    n = centre.sum()
    if float(n) == 0:
        return a.new_zeros(())
    return (scores * centre).sum() / n


def one_ring_patches(faces: np.ndarray, vertex_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 1-ring patch of each vertex of ``vertex_ids``.

    Returns:
        ``(sampled (S,) int64 vertex ids: vertex_ids and their neighbours, patches (X, P) int64 indices into
        sampled (column 0: the vertex itself), mask (X, P) bool)``, ``P = 1 + max degree``.
    """
    from rig.geometry import mesh_edges

    edges = mesh_edges(np.asarray(faces))
    ids = np.asarray(vertex_ids, np.int64)
    chosen = np.zeros(int(edges.max()) + 1, bool)
    chosen[ids] = True
    keep = chosen[edges[:, 0]] | chosen[edges[:, 1]]
    e = edges[keep]
    both = np.concatenate([e, e[:, ::-1]])
    neighbours: dict[int, list[int]] = {int(i): [] for i in ids}
    for u, w in both:
        if int(u) in neighbours:
            neighbours[int(u)].append(int(w))
    sampled = np.unique(np.concatenate([ids, e.ravel()]))
    where = {int(v): k for k, v in enumerate(sampled)}
    width = 1 + max(len(n) for n in neighbours.values())
    patches = np.zeros((len(ids), width), np.int64)
    mask = np.zeros((len(ids), width), bool)
    for row, i in enumerate(ids):
        entries = [int(i)] + neighbours[int(i)]
        patches[row, :len(entries)] = [where[v] for v in entries]
        mask[row, :len(entries)] = True
    return sampled, patches, mask


def sample_image(image: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of an image at pixel positions (differentiable in ``pixels``).

    Args:
        image: ``(C, H, W)``.
        pixels: ``(N, 2)`` x right, y down, pixel centres at integer coordinates (OpenCV).

    Returns:
        ``(N, C)``; positions outside the image take the border value.
    """
    c, h, w = image.shape
    grid = torch.stack([2.0 * pixels[:, 0] / max(w - 1, 1) - 1.0, 2.0 * pixels[:, 1] / max(h - 1, 1) - 1.0], -1)
    out = torch.nn.functional.grid_sample(image[None].to(pixels.dtype), grid[None, None], mode="bilinear",
                                          padding_mode="border", align_corners=True)
    return out[0, :, 0].T


# ----------------------------------------------------------------------------------------------------
# Configuration and results
# ----------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PhotoConsistencyConfig:
    """Photometric consistency between views (ASM eqs. 21-22; ``photometric:`` in the multi-view config).

    Each view's photo (luminance of linear RGB) is sampled bilinearly (``grid_sample``) at the projected
    vertices of the face regions and their 1-ring neighbours. **Patches**: the mesh 1-ring of each vertex (the
    vertex and its 5-8 neighbours, about 3 x 3 samples on the surface; ASM uses 3 x 3 UV patches); a patch
    counts in a pair of views when its vertex is visible in both (z-buffer of the whole head,
    :func:`pipeline.photo.texture.zbuffer`, within ``depth_tolerance_mm``, and facing the camera by
    ``visible_cos``, re-tested every ``visibility_every`` steps) and has >= 3 co-visible entries. The term is
    ``lambda_pc * (1 - mean over the N (N - 1) / 2 view pairs of LNCC)``, added to the landmark refinement's
    cost (sum over views of ``0.5 |r_k|^2`` in px^2-scale units, plus the priors). Adam on the shared
    identity (``theta / span``) and the per-view poses; expressions and focals stay where the landmark
    refinement put them.

    Off by default (docs/multiview.md, ``benchmarks/bench_multiview_photometric.py``): on rendered synthetic
    views of held-out heads 20-22 it changed the identity's s2m median by -0.015, -0.029, +0.018 mm with 3
    views (mean -0.009) and by +0.001, -0.033 mm with 5 views (heads 20, 21), for 1.5-3 minutes of Adam
    on this 2-core machine: a small gain, not on every head, at many times the cost of the landmark fit.
    """

    enabled: bool = False
    """Run it (``jnr fit --views --photometric``)."""
    iterations: int = 60
    """Adam steps."""
    lambda_pc: float = 5.0
    """Weight of ``1 - LNCC`` against the landmark cost."""
    patch: str = "1-ring"
    """The patch around each vertex: ``1-ring`` (the only one)."""
    regions: tuple[str, ...] = FACE_REGIONS
    """Rig regions whose vertices are scored."""
    visible_cos: float = 0.3
    """Facing test: cosine between the vertex normal and the direction to the camera at least this."""
    depth_tolerance_mm: float = 2.0
    """A vertex is hidden when the z-buffer holds a surface more than this much in front of it."""
    visibility_every: int = 20
    """Re-test visibility every this many steps."""
    lr_rotation: float = 0.001
    """Adam step of the poses' rotation vectors, radians."""
    lr_translation: float = 0.2
    """Adam step of the poses' translations, mm."""
    lr_joints: float = 0.002
    """Adam step of the identity's joint channels, fraction of each channel's range."""

    def __post_init__(self) -> None:
        if self.patch not in PATCHES:
            raise ValueError(f"photometric.patch must be one of {list(PATCHES)}, got {self.patch!r}")
        if self.iterations < 0 or self.visibility_every < 1:
            raise ValueError("photometric.iterations must be >= 0 and visibility_every >= 1")
        if self.lambda_pc < 0:
            raise ValueError(f"photometric.lambda_pc must be >= 0, got {self.lambda_pc}")
        from rig.asset import REGION_NAMES

        bad = [r for r in self.regions if r not in REGION_NAMES]
        if bad or not self.regions:
            raise ValueError(f"photometric.regions must be a non-empty subset of {list(REGION_NAMES)}, got "
                             f"{list(self.regions)}")


@dataclass(frozen=True)
class AsmConfig:
    """The ASM identity model (``skinning: asm``; ``asm:`` in YAML; :mod:`rig.skinning.asm`)."""

    components: int = 2
    """GMM components per joint (ASM-K2, the paper's default)."""
    register_iterations: int = 100
    """``fit_asm`` steps registering ASM to the averaged single-view mesh (ASM App. D.1: 300; 100 here for CPU
    time: vertex RMSE 0.46 mm against 0.33 mm at 300 on a test head)."""
    iterations: int = 60
    """Adam steps of the refinement on every view's landmarks + eq. 19."""
    lr: float = 0.003
    """Adam step of the ASM parameters."""
    lr_rotation: float = 0.002
    """Adam step of the poses' rotation vectors, radians."""
    lr_translation: float = 0.5
    """Adam step of the poses' translations, mm."""
    lambda_regularizer: float = 0.1
    """Weight of ASM's eq. 19 regulariser (the paper's per-term weights 1, 0.1, 0.1, 0.1, 0.1 in
    :class:`rig.skinning.asm.AsmRegularizer`'s units) against the landmark cost summed over views (on held-out
    head 22, 3 views: s2m median 0.515 mm at 0.01, 0.497 at 0.1; 0.620 at 0.001, which lets ASM's capacity
    chase the landmark noise)."""
    register_to: str = "averaged"
    """``averaged``: register to the averaged single-view JNR head (ASM App. D.1); ``refined``: to the JNR
    multi-view head after the joint landmark refinement."""
    lambda_smooth: float = 100.0
    """Weight of the squared uniform Laplacian of the identity's offset from the template (mm^2, mean over
    vertices) in the refinement, against the folds that the landmarks alone let the mixtures make (0: off).
    On held-out head 20: 0 gave 0.655 / 0.604 mm with 3 / 10 views and visible folds at the eyes, nose and
    lips; 100 gave 0.651 / 0.600 mm and a smooth head; 1000 over-smoothed (0.709 / 0.706 mm)."""

    def __post_init__(self) -> None:
        if self.register_to not in ("averaged", "refined"):
            raise ValueError(f"asm.register_to must be 'averaged' or 'refined', got {self.register_to!r}")


@dataclass(frozen=True)
class MultiViewConfig:
    """Settings of :func:`fit_multiview` (``jnr fit --views``; ``--set KEY=VALUE``)."""

    landmarks: LandmarkFitConfig = field(default_factory=lambda: LandmarkFitConfig(prior=PHOTO_PRIOR))
    """The single-view fits (as ``jnr fit`` on one photo)."""
    refine_iterations: int = 20
    """Levenberg-Marquardt iterations of the joint refinement (0: only the averaged single-view fits)."""
    lm: LMSettings = field(default_factory=LMSettings)
    """Damping and stopping of the joint refinement (``max_iterations`` comes from ``refine_iterations``)."""
    lambda_identity: float = 0.03
    """Weight of the identity prior, counted once against the landmark terms summed over the views."""
    fit_focal: bool = True
    """Fit each view's focal length (``s_k``); False: keep ``f0_k``."""
    lambda_focal: float = 10.0
    """Prior ``0.5 lambda_focal s_k^2`` on the log focal change of each view."""
    photometric: PhotoConsistencyConfig = field(default_factory=PhotoConsistencyConfig)
    """Photometric consistency between views (off by default)."""
    skinning: str = "jnr"
    """The identity model: ``jnr`` (the rig's joints) or ``asm`` (:mod:`rig.skinning.asm`)."""
    asm: AsmConfig = field(default_factory=AsmConfig)
    """The ASM identity model's settings."""

    def __post_init__(self) -> None:
        if self.skinning not in SKINNING_MODELS:
            raise ValueError(f"skinning must be one of {list(SKINNING_MODELS)}, got {self.skinning!r}")
        if self.refine_iterations < 0:
            raise ValueError(f"refine_iterations must be >= 0, got {self.refine_iterations}")
        if self.lambda_identity < 0 or self.lambda_focal < 0:
            raise ValueError("lambda_identity and lambda_focal must be >= 0")


@dataclass(frozen=True)
class ViewFit:
    """One view of a :class:`MultiViewFit`.

    Attributes:
        rotation, translation: head pose, ``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation`` (mm).
        focal: fitted focal length, pixels; focal_start: ``f0`` it started from.
        width, height: image size, pixels.
        expressions: ``(E,)`` ARKit coefficients of this view.
        rig_vertices: ``(V, 3)`` the head with this view's expression, rig space, mm.
        landmarks2d: ``(68, 2)`` input landmarks; landmarks_px ``(68, 2)`` fitted, px; error_px ``(68,)``;
            nme: mean error / outer-eye-corner distance.
    """

    rotation: np.ndarray
    translation: np.ndarray
    focal: float
    focal_start: float
    width: int
    height: int
    expressions: np.ndarray
    rig_vertices: np.ndarray
    landmarks2d: np.ndarray
    landmarks_px: np.ndarray
    error_px: np.ndarray
    nme: float

    @property
    def camera(self):
        """The view's ``PinholeCamera`` (world = rig space)."""
        return make_camera(self.width, self.height, self.focal, rotation=self.rotation, translation=self.translation)


@dataclass(frozen=True)
class MultiViewFit:
    """Result of :func:`fit_multiview`.

    Attributes:
        theta: ``(P,)`` the shared joint channels (deg, mm, ``scale - 1``); with ``skinning="asm"`` the JNR
            identity ASM was registered to.
        z: ``(50,)`` latent of the neural skinning (zeros).
        identity_vertices: ``(V, 3)`` the shared identity without expression, rig space, mm.
        views: one :class:`ViewFit` per photo, in input order.
        single_view_fits: the single-view landmark fits it started from.
        skinning: ``jnr`` or ``asm``.
        asm_parameters: with ``skinning="asm"``, the fitted ASM parameters as float64 arrays by field name.
        stages: one :class:`~pipeline.fitting.engine.StageLog` per stage (``average``, ``refine``, and
            ``photometric`` / ``asm register`` / ``asm refine`` when run).
        timings: seconds per phase.
    """

    theta: np.ndarray
    z: np.ndarray
    identity_vertices: np.ndarray
    views: tuple[ViewFit, ...]
    single_view_fits: tuple[LandmarkFit, ...]
    skinning: str
    stages: tuple[StageLog, ...]
    timings: dict
    asm_parameters: dict | None = None

    @property
    def mean_error_px(self) -> float:
        """Mean landmark error over all views, px."""
        return float(np.mean([v.error_px.mean() for v in self.views]))


# ----------------------------------------------------------------------------------------------------
# The joint least-squares problem
# ----------------------------------------------------------------------------------------------------

class _ViewResiduals(_LandmarkLeastSquares):
    """One view's landmark residuals (and expression prior rows) for ``x = [pose (6) | theta_n (P) | c (E) | s]``:
    the single-photo fit's residuals with the focal scaled by ``exp(s)``."""

    def _project(self, x: torch.Tensor) -> torch.Tensor:
        pixels = super()._project(x[:, :-1])
        return (pixels - self.centre) * x[:, -1:, None].exp() + self.centre


class MultiViewProblem:
    """The joint refinement as batched residuals of ``x = [theta_n (P) | per view: pose (6), c (E), s (1)]``
    (module docstring, step 2). ``views[k]`` holds view ``k``'s :class:`PhotoState` and residuals.

    A batch row that leaves view ``k``'s unknowns and the identity as in row 0 gives view ``k`` row 0's
    residuals: only the rows that differ are evaluated, so a forward-difference Jacobian costs about ``N``
    single-view Jacobians, not ``N^2``.
    """

    def __init__(self, states: list[PhotoState], terms: list[LandmarkTerm], focal_scale: np.ndarray,
                 config: MultiViewConfig, weights: torch.Tensor) -> None:
        f64 = torch.float64
        view_config = replace(config.landmarks, prior=replace(config.landmarks.prior, lambda_identity=0.0,
                                                              lambda_m=0.0, lambda_symmetry=0.0))
        expressions64 = _expressions64(states[0].rig.asset)
        self.views = [_ViewResiduals(s, t, view_config, ("pose", "joints", "expressions"), None, weights, expressions64)
                      for s, t in zip(states, terms)]
        self.states, self.config = states, config
        self.P = NUM_PARAMETERS
        self.E = states[0].c.numel()
        self.block = 6 + self.E + 1
        identity = cached_identity_prior()
        self.whiten = torch.as_tensor(identity.whitening_matrix, dtype=f64)
        self.mu = torch.as_tensor(identity.mean, dtype=f64)
        s0 = states[0]
        self.span = s0.span.double()
        with torch.no_grad():
            parts = [s0.theta_n.double()]
            for s, scale in zip(states, focal_scale):
                parts += [s.rotvec.double(), s.translation.double(), s.c.double(),
                          torch.tensor([math.log(scale)], dtype=f64)]
        self.x0 = torch.cat(parts)

    def view_slice(self, k: int) -> slice:
        start = self.P + k * self.block
        return slice(start, start + self.block)

    def view_x(self, x: torch.Tensor, k: int) -> torch.Tensor:
        """``(B, n)`` -> view ``k``'s ``(B, 6 + P + E + 1)``."""
        own = x[:, self.view_slice(k)]
        return torch.cat([own[:, :6], x[:, :self.P], own[:, 6:]], 1)

    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        s = self.states[0]
        inf = torch.full((6,), float("inf"), dtype=torch.float64)
        limit = 0.7 if self.config.fit_focal else 0.0
        low = [(s.low / s.span).double()]
        high = [(s.high / s.span).double()]
        for _ in self.states:
            low += [-inf, s.c_low.double(), torch.tensor([-limit], dtype=torch.float64)]
            high += [inf, s.c_high.double(), torch.tensor([limit], dtype=torch.float64)]
        return torch.cat(low), torch.cat(high)

    def prepare(self, x: torch.Tensor) -> None:
        for k, view in enumerate(self.views):
            view.prepare(self.view_x(x[None], k)[0])

    def write(self, x: torch.Tensor) -> None:
        for k, view in enumerate(self.views):
            view.write(self.view_x(x[None], k)[0])
            view.state._basis = None

    def focal_scales(self, x: torch.Tensor) -> np.ndarray:
        return np.array([math.exp(float(x[self.view_slice(k)][-1])) for k in range(len(self.views))])

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """``x (B, n)`` -> residuals ``(B, m)``."""
        batch = x.shape[0]
        rows = []
        for k, view in enumerate(self.views):
            xk = self.view_x(x, k)
            if batch > 2:
                moved = (xk != xk[:1]).any(1)
                moved[0] = True
                idx = torch.nonzero(moved)[:, 0]
                sub = view(xk[idx])
                rk = sub[:1].expand(batch, -1).clone()
                rk[idx] = sub
            else:
                rk = view(xk)
            rows.append(rk)
        w = self.config
        theta_n = x[:, :self.P]
        if w.lambda_identity:
            rows.append(math.sqrt(w.lambda_identity) * (theta_n - self.mu) @ self.whiten.T)
        if w.lambda_focal:
            s = torch.stack([x[:, self.view_slice(k)][:, -1] for k in range(len(self.views))], 1)
            rows.append(math.sqrt(w.lambda_focal) * s)
        return torch.cat(rows, 1)

    # -- full meshes ---------------------------------------------------------------------------------
    def camera_vertices(self, x: torch.Tensor, k: int, ids: torch.Tensor, weights: torch.Tensor
                        ) -> tuple[torch.Tensor, torch.Tensor]:
        """View ``k``'s vertices ``ids`` at ``x (n,)``: ``(camera frame (U, 3) mm, pixels (U, 2))``,
        differentiable in ``x``."""
        view = self.views[k]
        xk = self.view_x(x[None], k)[0]
        pose, theta_n, c, s = xk[:6], xk[6:6 + self.P], xk[6 + self.P:-1], xk[-1]
        rest = view.expressions.template[ids] + view.expressions(c[None], ids)[0]
        _, skinning = view.state.rig.joint_transforms((theta_n * self.span)[None])
        posed = skin_vertices_shared_weights(rest, weights[ids], skinning.double())[0]
        rotation = axis_angle_to_rotation_matrix(pose[None, :3])[0]
        cam = posed @ (view.flip @ rotation).T + pose[3:]
        pixels = cam[:, :2] / cam[:, 2:] * (view.focal * s.exp()) + view.centre
        return cam, pixels


# ----------------------------------------------------------------------------------------------------
# The fit
# ----------------------------------------------------------------------------------------------------

def _check_inputs(images, landmarks, focals, min_views: int = 2) -> list[np.ndarray]:
    n = len(landmarks)
    if n < min_views:
        raise InputError(f"fit_multiview: needs at least {min_views} views, got {n}")
    if images is not None and len(images) != n:
        raise InputError(f"fit_multiview: {len(images)} images but {n} landmark sets")
    if focals is not None and len(focals) != n:
        raise InputError(f"fit_multiview: {len(focals)} focal lengths but {n} views")
    lms = [check_landmarks_2d_shape(lm, "fit_multiview") for lm in landmarks]
    return lms


def fit_multiview(landmarks, sizes, *, images=None, focals=None, config: MultiViewConfig | None = None,
                  rig: JointRig | None = None, neural: NeuralSkinning | None = None,
                  single_view_fits: tuple[LandmarkFit, ...] | None = None, min_views: int = 2) -> MultiViewFit:
    """Reconstruct one head from ``N >= 2`` uncalibrated photos of it (module docstring).

    Args:
        landmarks: ``N`` arrays ``(68, 2)``, pixels (OpenCV, 0-based), iBUG-68 order, one per view.
        sizes: ``N`` ``(width, height)`` image sizes, pixels.
        images: ``N`` ``(H, W, 3)`` uint8 sRGB photos; needed only for the photometric consistency.
        focals: ``N`` focal lengths in pixels to start from (None or a None entry: 1.4 x the longer side).
        config: :class:`MultiViewConfig`.
        rig, neural: the models (default: the committed rig, float32, and its learned skinning).
        single_view_fits: the views' single-view fits, if already made (with the same focals and
            ``config.landmarks``; the benchmark reuses them for nested sets of views).
        min_views: the fewest views accepted (2; the benchmark runs the pipeline on 1 view to compare).

    Returns:
        :class:`MultiViewFit`.

    Raises:
        rig.errors.InputError: fewer than 2 views, mismatched lists, photometric consistency without images.
        ShapeError / ValueError: bad landmarks or sizes.
    """
    t_start = time.perf_counter()
    config = config or MultiViewConfig()
    lms = _check_inputs(images, landmarks, focals, min_views)
    n = len(lms)
    if len(sizes) != n:
        raise InputError(f"fit_multiview: {len(sizes)} image sizes but {n} views")
    if config.photometric.enabled and images is None:
        raise InputError("fit_multiview: photometric consistency needs the images")
    rig = rig or JointRig()
    if neural is None:
        neural, _ = load_neural(rig)
    dtype = rig.template.dtype
    f0 = []
    for k, (w, h) in enumerate(sizes):
        given = None if focals is None else focals[k]
        f0.append(default_focal(w, h) if given is None else check_focal(given, w, h))

    # 1. single-view fits, averaged
    t0 = time.perf_counter()
    if single_view_fits is not None and len(single_view_fits) != n:
        raise InputError(f"fit_multiview: {len(single_view_fits)} single-view fits but {n} views")
    singles = tuple(single_view_fits) if single_view_fits is not None else tuple(
        fit_landmarks(lm, w, h, focal=f, config=config.landmarks, rig=rig, neural=neural)
        for lm, (w, h), f in zip(lms, sizes, f0))
    t_single = time.perf_counter() - t0
    states, terms = [], []
    theta_mean = np.mean([s.theta for s in singles], 0)
    for lm, (w, h), f, single in zip(lms, sizes, f0, singles):
        state = PhotoState(rig, neural, ExpressionModel(rig.asset, dtype=dtype), single.rotation, single.translation)
        state.load(theta_mean, np.zeros(LATENT), single.expressions)
        states.append(state)
        terms.append(LandmarkTerm(rig.asset, lm, make_camera(w, h, f, dtype=dtype, pose=False),
                                  config.landmarks.huber_delta_px, config.landmarks.contour_weight,
                                  config.landmarks.landmark_weighting))
    with torch.no_grad():
        weights = neural(torch.zeros(1, LATENT, dtype=dtype))[0].double()
    problem = MultiViewProblem(states, terms, np.ones(n), config, weights)
    average = _vertices(rig, weights, torch.as_tensor(theta_mean), None)
    stages = []
    x = problem.x0.clone()
    problem.prepare(x)
    with torch.no_grad():
        cost0 = 0.5 * float(problem(x[None]).square().sum())
    stages.append(StageLog("average", ("joints",), 0, cost0, cost0, metrics={"views": n}, seconds=t_single))

    # 2. the joint landmark refinement
    if config.refine_iterations > 0:
        t0 = time.perf_counter()
        low, high = problem.bounds()
        settings = replace(config.lm, max_iterations=config.refine_iterations)
        result = levenberg_marquardt(problem, x, lower=low, upper=high, settings=settings, prepare=problem.prepare)
        x = result.x
        problem.write(x)
        stages.append(StageLog("refine", ("pose", "joints", "expressions", "focal"), result.iterations, cost0,
                               result.cost, metrics={"lm_converged": result.converged,
                                                     "lm_costs": [round(c, 4) for c in result.costs]},
                               seconds=time.perf_counter() - t0))

    # 3. photometric consistency
    if config.photometric.enabled and config.photometric.iterations > 0 and config.skinning == "jnr":
        x, log = _photo_consistency(problem, x, images, weights, config.photometric)
        problem.write(x)
        stages.append(log)

    asm_parameters = None
    identity = _vertices(rig, weights, torch.as_tensor(problem.span * x[:problem.P]), None)
    view_vertices = [_vertices(rig, weights, torch.as_tensor(problem.span * x[:problem.P]),
                               problem.view_x(x[None], k)[0, 6 + problem.P:-1]) for k in range(n)]
    if config.skinning == "asm":
        source = average if config.asm.register_to == "averaged" else identity
        identity, view_vertices, asm_parameters, asm_logs, x = _fit_asm_identity(problem, x, source, config)
        stages.extend(asm_logs)

    views = []
    scales = problem.focal_scales(x)
    for k in range(n):
        xk = problem.view_x(x[None], k)[0]
        rotation = axis_angle_to_rotation_matrix(xk[None, :3])[0].numpy()
        translation = xk[3:6].numpy().copy()
        focal = f0[k] * scales[k]
        (w, h) = sizes[k]
        px = _project_landmarks(view_vertices[k], rotation, translation, focal, w, h, rig.asset, terms[k])
        from pipeline.evaluation.metrics import landmark_errors

        error, nme = landmark_errors(px, lms[k])
        views.append(ViewFit(rotation=rotation, translation=translation, focal=float(focal), focal_start=float(f0[k]),
                             width=int(w), height=int(h), expressions=xk[6 + problem.P:-1].numpy().copy(),
                             rig_vertices=view_vertices[k], landmarks2d=lms[k], landmarks_px=px, error_px=error,
                             nme=nme))
    theta = (problem.span * x[:problem.P]).numpy().copy()
    return MultiViewFit(theta=theta, z=np.zeros(LATENT), identity_vertices=identity, views=tuple(views),
                        single_view_fits=singles, skinning=config.skinning, stages=tuple(stages),
                        timings={"single_view": t_single, "total": time.perf_counter() - t_start},
                        asm_parameters=asm_parameters)


def _vertices(rig: JointRig, weights: torch.Tensor, theta: torch.Tensor, c: torch.Tensor | None) -> np.ndarray:
    """``(V, 3)`` float64 rig-space head of joint channels ``theta (P,)`` and expressions ``c (E,)`` (None: 0)."""
    expr = _expressions64(rig.asset)
    with torch.no_grad():
        rest = expr.template if c is None else expr.template + expr(c.double()[None])[0]
        _, skinning = rig.joint_transforms(theta.double()[None])
        return skin_vertices_shared_weights(rest, weights, skinning.double())[0].numpy()


def _project_landmarks(vertices: np.ndarray, rotation, translation, focal, width, height, asset,
                       term: LandmarkTerm) -> np.ndarray:
    """``(68, 2)`` the landmarks of a rig-space head as a view's camera sees them (jaw contour dynamic)."""
    from landmarks.ibug68 import contour_landmarks, landmark_positions
    from landmarks.loss import project_points
    from pipeline.photo.camera import camera_center_in_rig
    from rig.geometry import RIG_TO_OPENCV

    v = torch.as_tensor(vertices)
    static = landmark_positions(v, term.embedding, asset.faces)[0]
    contour = contour_landmarks(v, asset.faces, camera_center_in_rig(rotation, translation), asset)
    points = torch.cat([contour, static[17:]]).double()
    cam = points @ torch.as_tensor(RIG_TO_OPENCV @ rotation).T + torch.as_tensor(translation)
    camera = make_camera(width, height, focal, dtype=torch.float64, pose=False)
    return project_points(cam[None], camera)[0].numpy()


# ----------------------------------------------------------------------------------------------------
# Photometric consistency
# ----------------------------------------------------------------------------------------------------

def luminance(image: np.ndarray) -> np.ndarray:
    """``(H, W)`` float64 luminance (Rec. 709) of a uint8 sRGB photo, in linear RGB."""
    from pipeline.photo.colour import srgb_to_linear

    lin = srgb_to_linear(np.asarray(image, np.float32) / 255.0).astype(np.float64)
    return lin @ np.array([0.2126, 0.7152, 0.0722])


def vertex_visibility(camera_vertices: np.ndarray, faces: np.ndarray, width: int, height: int,
                      pixels: np.ndarray, ids: np.ndarray, visible_cos: float, tolerance_mm: float) -> np.ndarray:
    """``(U,)`` bool: vertices ``ids`` of a head (``camera_vertices (V, 3)``, OpenCV camera frame, mm; their
    ``pixels (V, 2)``) seen by the camera: inside the image, facing it (``cos >= visible_cos``) and not behind
    another part of the head (:func:`pipeline.photo.texture.zbuffer` within ``tolerance_mm``)."""
    from pipeline.photo.texture import zbuffer
    from rig.geometry import vertex_normals

    depth = camera_vertices[:, 2]
    buffer = zbuffer(pixels, depth, faces, width, height)
    p = pixels[ids]
    col = np.clip(np.round(p[:, 0]).astype(np.int64), 0, width - 1)
    row = np.clip(np.round(p[:, 1]).astype(np.int64), 0, height - 1)
    inside = (p[:, 0] >= 0) & (p[:, 0] <= width - 1) & (p[:, 1] >= 0) & (p[:, 1] <= height - 1)
    unoccluded = depth[ids] <= buffer[row, col] + tolerance_mm
    normals = vertex_normals(camera_vertices, faces)[ids]
    to_camera = -camera_vertices[ids]
    cos = (normals * to_camera).sum(1) / np.linalg.norm(to_camera, axis=1).clip(1e-12)
    return inside & unoccluded & (cos >= visible_cos)


def _photo_consistency(problem: MultiViewProblem, x: torch.Tensor, images, weights: torch.Tensor,
                       settings: PhotoConsistencyConfig) -> tuple[torch.Tensor, StageLog]:
    """Adam on the identity and the poses: landmark cost + ``lambda_pc (1 - mean pair LNCC)``."""
    t0 = time.perf_counter()
    asset = problem.states[0].rig.asset
    faces = np.asarray(asset.faces, np.int64)
    scored = np.flatnonzero(asset.region_mask(*settings.regions))
    sampled, patches_np, mask_np = one_ring_patches(faces, scored)
    patches, patch_mask = torch.as_tensor(patches_np), torch.as_tensor(mask_np)
    ids = torch.as_tensor(sampled)
    everything = torch.arange(len(asset.vertices))
    grey = [torch.as_tensor(luminance(img))[None] for img in images]
    n = len(problem.views)
    pairs = list(itertools.combinations(range(n), 2))

    theta = x[:problem.P].clone().requires_grad_(True)
    rotations = [x[problem.view_slice(k)][:3].clone().requires_grad_(True) for k in range(n)]
    translations = [x[problem.view_slice(k)][3:6].clone().requires_grad_(True) for k in range(n)]
    fixed = x.clone()
    low, high = problem.bounds()

    def assemble() -> torch.Tensor:
        parts = [theta]
        for k in range(n):
            parts += [rotations[k], translations[k], fixed[problem.view_slice(k)][6:]]
        return torch.cat(parts)

    optimiser = torch.optim.Adam([{"params": [theta], "lr": settings.lr_joints},
                                  {"params": rotations, "lr": settings.lr_rotation},
                                  {"params": translations, "lr": settings.lr_translation}])
    visible: list[torch.Tensor] = []
    start = end = None
    pc_value = float("nan")
    for it in range(settings.iterations):
        xi = assemble()
        if it % settings.visibility_every == 0:  # visibility and the jaw contour at the current estimate
            with torch.no_grad():
                problem.prepare(xi.detach())
                visible = []
                for k in range(n):
                    cam, px = problem.camera_vertices(xi.detach(), k, everything, weights)
                    h, w = grey[k].shape[1:]
                    visible.append(torch.as_tensor(vertex_visibility(
                        cam.numpy(), faces, w, h, px.numpy(), sampled, settings.visible_cos,
                        settings.depth_tolerance_mm)))
        # forward: the landmark cost of every view, the intensities at the projected vertices, LNCC per pair
        lm_cost = 0.5 * problem(xi[None]).square().sum()
        samples = [sample_image(grey[k], problem.camera_vertices(xi, k, ids, weights)[1])[:, 0] for k in range(n)]
        scores = [lncc(samples[i], samples[j], patches, patch_mask, visible[i], visible[j]) for i, j in pairs]
        pc = 1.0 - torch.stack(scores).mean()
        loss = lm_cost + settings.lambda_pc * pc
        if not torch.isfinite(loss):
            raise FloatingPointError("fit_multiview: the photometric consistency stage diverged")
        if start is None:
            start = float(loss.detach())
        end, pc_value = float(loss.detach()), float(pc.detach())
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        with torch.no_grad():  # back into the joints' limits
            theta.copy_(torch.maximum(torch.minimum(theta, high[:problem.P]), low[:problem.P]))
    out = assemble().detach()
    with torch.no_grad():
        final_lm = float(0.5 * problem(out[None]).square().sum())
    return out, StageLog("photometric", ("pose", "joints"), settings.iterations, start or 0.0, end or 0.0,
                         terms={"landmarks": final_lm, "one_minus_lncc": pc_value},
                         metrics={"pairs": len(pairs), "scored_vertices": int(len(scored))},
                         seconds=time.perf_counter() - t0)


# ----------------------------------------------------------------------------------------------------
# The ASM identity model
# ----------------------------------------------------------------------------------------------------

def _fit_asm_identity(problem: MultiViewProblem, x: torch.Tensor, singles_mean_vertices: np.ndarray,
                      config: MultiViewConfig):
    """The ASM identity model (module docstring): ``fit_asm`` registers ASM to ``singles_mean_vertices`` (the
    averaged single-view JNR head, ASM App. D.1), then Adam on the ASM parameters and the per-view poses
    minimises the landmark cost of every view (the step-2 residuals, the jaw contour as picked there) plus
    ``lambda_regularizer`` times ASM's eq. 19; expressions and focals stay at the joint refinement's.

    Returns:
        ``(identity (V, 3), per-view vertices [(V, 3)], ASM parameters as arrays, stage logs, x)``.
    """
    try:
        from rig.skinning.asm import (
            TAU_UNITS,
            UV_UNIT,
            AdaptiveSkinning,
            AsmParameters,
            AsmVariant,
            bone_local_transforms,
            fit_asm,
        )
    except ImportError:
        raise InputError("skinning=asm needs rig.skinning.asm, which this installation does not have") from None
    settings = config.asm
    n = len(problem.views)
    rig = problem.states[0].rig
    model = AdaptiveSkinning(rig, components=settings.components)
    dtype = rig.template.dtype
    t0 = time.perf_counter()
    target = torch.as_tensor(singles_mean_vertices, dtype=dtype)[None]
    registered = fit_asm(model, target, variant=AsmVariant(True, True), iterations=settings.register_iterations)
    logs = [StageLog("asm register", ("asm",), settings.register_iterations, float(registered.losses[0]),
                     float(registered.losses[-1]), metrics={"rmse_mm": float(registered.rmse[0])},
                     seconds=time.perf_counter() - t0)]
    t0 = time.perf_counter()
    units = {"tau": torch.tensor(TAU_UNITS, dtype=dtype), "zeta": UV_UNIT, "log_pi": 1.0, "mu": UV_UNIT, "chol": 1.0}
    start = registered.params
    scaled = {k: (v.detach() / units[k]).clone().requires_grad_(True) for k, v in start.as_dict().items()}
    rotations = [x[problem.view_slice(k)][:3].clone().requires_grad_(True) for k in range(n)]
    translations = [x[problem.view_slice(k)][3:6].clone().requires_grad_(True) for k in range(n)]
    optimiser = torch.optim.Adam([{"params": list(scaled.values()), "lr": settings.lr},
                                  {"params": rotations, "lr": settings.lr_rotation},
                                  {"params": translations, "lr": settings.lr_translation}])
    expr = _expressions64(rig.asset)
    rests = []
    for k in range(n):
        c = problem.view_x(x[None], k)[0, 6 + problem.P:-1]
        with torch.no_grad():
            rests.append((expr.template + expr(c[None])[0]).to(dtype))
    with torch.no_grad():
        problem.prepare(x)

    def params() -> AsmParameters:
        return AsmParameters(**{k: v * units[k] for k, v in scaled.items()})

    def landmark_rows(k: int, vertices: torch.Tensor, rotvec: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
        view = problem.views[k]
        points = (vertices.double()[view.vertex_ids][view.local_ids] * view.bary[..., None]).sum(1)  # (68, 3)
        rotation = axis_angle_to_rotation_matrix(rotvec[None])[0]
        cam = points @ (view.flip @ rotation).T + translation
        s = x[problem.view_slice(k)][-1]
        pixels = cam[:, :2] / cam[:, 2:] * (view.focal * s.exp()) + view.centre
        return ((pixels - view.target) * (view.base_w * view.robust).sqrt()[:, None]).reshape(-1)

    # only the vertices the landmarks sit on (the contours as picked by the joint refinement) are skinned
    used = torch.unique(torch.cat([view.vertex_ids for view in problem.views]))
    where = torch.full((len(rig.asset.vertices),), -1, dtype=torch.long)
    where[used] = torch.arange(len(used))
    local = [where[view.vertex_ids] for view in problem.views]
    rest_used = torch.stack([r[used] for r in rests])  # (N, U, 3)

    def posed_views(p: AsmParameters) -> torch.Tensor:
        """``(N, U, 3)``: the ASM head with each view's expression (one skinning of the shared bones)."""
        weights = model.weights(p)[0][used]  # (U, J)
        bind = model.bone_positions(p)
        _, skinning = joint_world_transforms(bone_local_transforms(p.tau), bind, rig.parents, model.levels)
        return skin_vertices(rest_used, weights, skinning.expand(n, -1, -1, -1))

    laplacian = model.rig.laplacian.to(dtype) if settings.lambda_smooth else None
    first = last = None
    for it in range(settings.iterations):
        p = params()
        cost = 0.0
        posed = posed_views(p)
        for k in range(n):
            v = torch.zeros(len(rig.asset.vertices), 3, dtype=posed.dtype).index_copy(0, problem.views[k].vertex_ids,
                                                                                   posed[k][local[k]])
            cost = cost + 0.5 * landmark_rows(k, v, rotations[k], translations[k]).square().sum()
        reg = settings.lambda_regularizer * model.regularizer(p)[0]
        loss = cost + reg
        if settings.lambda_smooth:
            offset = model(p).vertices[0] - model.rig.template
            loss = loss + settings.lambda_smooth * torch.sparse.mm(laplacian, offset).square().sum(-1).mean()
        if not torch.isfinite(loss):
            raise FloatingPointError("fit_multiview: the ASM refinement diverged")
        first = float(loss.detach()) if first is None else first
        last = float(loss.detach())
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    out = x.clone()
    with torch.no_grad():
        for k in range(n):
            sl = problem.view_slice(k)
            out[sl.start:sl.start + 3] = rotations[k].detach()
            out[sl.start + 3:sl.start + 6] = translations[k].detach()
        p = params().map(torch.Tensor.detach)
        identity = model(p).vertices[0].double().numpy()
        per_view = [model(p, vertices=rests[k][None]).vertices[0].double().numpy() for k in range(n)]
        reg_end = float(model.regularizer(p)[0])
    logs.append(StageLog("asm refine", ("asm", "pose"), settings.iterations, first or 0.0, last or 0.0,
                         terms={"regularizer_eq19": reg_end}, seconds=time.perf_counter() - t0))
    arrays = {k: v[0].double().numpy() for k, v in p.as_dict().items()}
    return identity, per_view, arrays, logs, out
