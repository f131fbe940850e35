"""Multi-view uncalibrated reconstruction: several photos of one person, no calibration (issue 15, ASM 4.2, App. D).

Unknowns (:class:`~pipeline.photo.multiview_problem.MultiViewState`): one shared **identity** (the rig's 107 joint
channels ``theta``, as the single-photo fit uses them; the neural skinning at ``Z = 0``, which the landmark fit
does not move either), and per view ``k`` a head pose ``(R_k, t_k)`` (``x_cam = RIG_TO_OPENCV @ R_k @ x_rig +
t_k``, :mod:`pipeline.camera`), the 52 ARKit expression coefficients ``c_k`` and the focal length
``f_k = f0_k exp(s_k)`` (``f0_k``: ``--focal`` or :func:`pipeline.camera.default_focal`; principal point at the
image centre).

1. **Single-view fits** (ASM App. D.1): :func:`pipeline.photo.landmark_fit.fit_landmarks` on each view; the
   shared identity starts from their **average** ``theta`` (over ``theta / span``), each view from its own
   pose and expressions, ``s_k = 0``.
2. **Joint landmark refinement** (ASM eq. 18 with our priors): a Levenberg-Marquardt stage
   (:func:`pipeline.fitting.least_squares.run_lm_stage`) on the identity and every view's pose, expressions and
   focal, minimising the terms of :meth:`~pipeline.photo.multiview_problem.MultiViewProblem.terms`

       sum_k w_k landmarks_k + 0.5 lambda_identity |M (theta / span - mu)|^2 + sum_k lambda_expressions |c_k|^2
       + sum_k 0.5 lambda_focal s_k^2

   where ``landmarks_k`` is view ``k``'s landmark term exactly as in the single-photo fit
   (:class:`~pipeline.fitting.landmark_term.LandmarkTerm`: detector weights, Huber by IRLS, the jaw contour
   re-picked from view ``k``'s camera centre) and ``w_k`` its weight
   (:func:`~pipeline.photo.multiview_problem.view_weights`): by default the views' terms are **averaged**, as a
   detector's errors are largely shared by the views of one face, and a view turned past ~30 degrees counts
   less (``view_correlation`` 0 and ``view_yaw_deg`` 0 sum them, for points with independent errors). The
   identity prior is counted once.
3. **Photometric consistency** (optional, ASM eqs. 21-22, :class:`PhotoConsistencyConfig`,
   :mod:`pipeline.photo.consistency`): an Adam stage on the shared identity and the per-view poses, minimising
   the step-2 cost plus ``lambda_pc * (1 - mean over view pairs of LNCC)``.

The identity is an interchangeable *identity model*: ``skinning="jnr"`` (the rig's joints, above) or
``skinning="asm"`` (:mod:`pipeline.photo.multiview_asm`: ASM registered to the averaged single-view mesh by
``fit_asm`` as ASM App. D.1 does, then refined by Adam on the landmarks of every view + ASM's priors).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix

from landmarks.ibug68.contour import contour_landmarks
from landmarks.ibug68.positions import landmark_positions
from landmarks.layout import LandmarkLayout, ibug68_layout
from landmarks.loss import project_points
from landmarks.mediapipe.ibug68_map import mesh_to_ibug68
from pipeline.camera import camera_center_in_rig, check_focal, default_focal, make_camera
from pipeline.fitting.engine import LearningRates, StageLog, run_schedule
from pipeline.fitting.identity import IdentityPrior
from pipeline.fitting.landmark_term import NUM_LANDMARKS, LandmarkTerm, expressions64, face_scale
from pipeline.fitting.least_squares import run_lm_stage
from pipeline.fitting.terms import LeastSquaresTerms
from pipeline.metrics import landmark_errors
from pipeline.photo.consistency import PhotoConsistency
from pipeline.photo.landmark_fit import LandmarkFit, check_landmarks_2d_shape, fit_landmarks
from pipeline.photo.multiview_asm import VIEWS_IDENTITY_MODELS
from pipeline.photo.multiview_config import AsmConfig, MultiViewConfig, PhotoConsistencyConfig
from pipeline.photo.multiview_model import model_views_identity
from pipeline.photo.multiview_problem import MultiViewProblem, MultiViewStage, initial_state
from rig.errors import InputError
from rig.geometry import RIG_TO_OPENCV
from rig.head_model import HeadParams, jnr_vertices
from rig.model import JointRig
from rig.skinning.neural import LATENT, NeuralSkinning, load_neural

__all__ = [
    "AsmConfig",
    "MultiViewConfig",
    "MultiViewFit",
    "PhotoConsistencyConfig",
    "ViewFit",
    "fit_multiview",
]


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
        weight: the weight of this view's landmark term in the joint refinement (before its points' error
            squared; :func:`~pipeline.photo.multiview_problem.view_weights`: the views' terms averaged, a turned
            view's weighed less).
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
    weight: float = 1.0

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
        head: with another registered head model as ``skinning``, its fitted parameters without expression
            (:mod:`pipeline.photo.multiview_model`).
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
    head: HeadParams | None = None

    @property
    def mean_error_px(self) -> float:
        """Mean landmark error over all views, px."""
        return float(np.mean([v.error_px.mean() for v in self.views]))

    @property
    def rig_identity(self) -> HeadParams:
        """The JNR rig's part of the fit without expression (joints and Z, kind ``jnr``): what the skinned
        glTF and the viewer pose."""
        zeros = np.zeros(len(self.views[0].expressions))
        return HeadParams("jnr", {"joints": np.asarray(self.theta, np.float64), "latent": self.z, "expressions": zeros})

    @property
    def identity(self) -> HeadParams:
        """The shared identity in the fit's identity model (``skinning``) without expression."""
        if self.head is not None:
            return self.head
        if self.asm_parameters is None:
            return self.rig_identity
        zeros = np.zeros(len(self.views[0].expressions))
        return HeadParams(self.skinning, {"asm": self.asm_parameters, "expressions": zeros})


# ----------------------------------------------------------------------------------------------------
# The fit
# ----------------------------------------------------------------------------------------------------


def _check_inputs(
    images, landmarks, sizes, focals, config: MultiViewConfig, single_view_fits, min_views: int = 2, layouts=None
) -> tuple[list[np.ndarray], list[float]]:
    """The landmarks as ``(N_k, 2)`` float64 arrays (68, or each view's layout's count) and each view's start
    focal ``f0_k``; raises InputError for too few views, lists of different lengths, or photometric consistency
    without images."""
    n = len(landmarks)
    if n < min_views:
        raise InputError(f"fit_multiview: needs at least {min_views} views, got {n}")
    if images is not None and len(images) != n:
        raise InputError(f"fit_multiview: {len(images)} images but {n} landmark sets")
    if focals is not None and len(focals) != n:
        raise InputError(f"fit_multiview: {len(focals)} focal lengths but {n} views")
    if layouts is not None and len(layouts) != n:
        raise InputError(f"fit_multiview: {len(layouts)} landmark layouts but {n} views")
    counts = [NUM_LANDMARKS if layouts is None or layouts[k] is None else layouts[k].count for k in range(n)]
    lms = [check_landmarks_2d_shape(lm, "fit_multiview", count) for lm, count in zip(landmarks, counts)]
    if len(sizes) != n:
        raise InputError(f"fit_multiview: {len(sizes)} image sizes but {n} views")
    if config.photometric.enabled and images is None:
        raise InputError("fit_multiview: photometric consistency needs the images")
    if single_view_fits is not None and len(single_view_fits) != n:
        raise InputError(f"fit_multiview: {len(single_view_fits)} single-view fits but {n} views")
    f0 = [
        default_focal(w, h) if focals is None or focals[k] is None else check_focal(focals[k], w, h)
        for k, (w, h) in enumerate(sizes)
    ]
    return lms, f0


def fit_multiview(
    landmarks,
    sizes,
    *,
    images=None,
    focals=None,
    config: MultiViewConfig | None = None,
    rig: JointRig | None = None,
    neural: NeuralSkinning | None = None,
    single_view_fits: tuple[LandmarkFit, ...] | None = None,
    min_views: int = 2,
    layouts: Sequence[LandmarkLayout | None] | None = None,
    progress=None,
    points3d: Sequence[np.ndarray | None] | None = None,
) -> MultiViewFit:
    """Reconstruct one head from ``N >= 2`` uncalibrated photos of it (module docstring).

    Args:
        landmarks: ``N`` arrays ``(68, 2)``, pixels (OpenCV, 0-based), iBUG-68 order, one per view; or, for a
            view with a ``layouts`` entry, ``(count, 2)`` points of that layout (e.g. MediaPipe's 478).
        sizes: ``N`` ``(width, height)`` image sizes, pixels.
        images: ``N`` ``(H, W, 3)`` uint8 sRGB photos; needed only for the photometric consistency.
        focals: ``N`` focal lengths in pixels to start from (None or a None entry: 1.4 x the longer side).
        config: :class:`MultiViewConfig`.
        rig, neural: the models (default: the committed rig, float32, and its learned skinning).
        single_view_fits: the views' single-view fits, if already made (with the same focals and
            ``config.landmarks``; the benchmark reuses them for nested sets of views).
        min_views: the fewest views accepted (2; the benchmark runs the pipeline on 1 view to compare).
        layouts: per view a :class:`landmarks.layout.LandmarkLayout` its landmarks follow, or None (iBUG-68);
            None: every view iBUG-68. The views' :class:`ViewFit` landmarks are iBUG-68 either way (a dense
            view's 68 mapped from its mesh, :func:`landmarks.mediapipe.ibug68_map.mesh_to_ibug68`).
        progress: ``progress("identity", done, N + 1)`` after each view's single fit and the joint refinement.
        points3d: per view the detector's ``(478, 3)`` points with their depth, or None: with
            ``config.landmarks.regression.enabled`` each single-view fit reads its identity from them
            (:mod:`pipeline.fitting.identity_regression`) and the joint refinement's identity prior is centred
            on the mean of the views' regressed heads.

    Returns:
        :class:`MultiViewFit`.

    Raises:
        rig.errors.InputError: fewer than 2 views, mismatched lists, photometric consistency without images.
        ShapeError / ValueError: bad landmarks or sizes.
    """
    t_start = time.perf_counter()
    config = config or MultiViewConfig()
    lms, f0 = _check_inputs(images, landmarks, sizes, focals, config, single_view_fits, min_views, layouts)
    n = len(lms)
    layouts = [None] * n if layouts is None else list(layouts)
    rig = rig or JointRig()
    if neural is None:
        neural, _ = load_neural(rig)

    # 1. single-view fits, averaged
    t0 = time.perf_counter()
    steps = n + 1  # progress: each view's single fit, then the joint refinement

    points3d = [None] * n if points3d is None else list(points3d)

    def single(k, lm, w, h, f, layout):
        fit = fit_landmarks(
            lm, w, h, focal=f, config=config.landmarks, rig=rig, neural=neural, layout=layout, points3d=points3d[k]
        )
        if progress is not None:
            progress("identity", k + 1, steps)
        return fit

    singles = single_view_fits or tuple(
        single(k, lm, w, h, f, layout) for k, (lm, (w, h), f, layout) in enumerate(zip(lms, sizes, f0, layouts))
    )
    singles = tuple(singles)
    t_single = time.perf_counter() - t0
    theta_mean = np.mean([s.theta for s in singles], 0)
    problem = _problem(lms, sizes, f0, singles, theta_mean, config, rig, neural, layouts, views_identity_prior(singles))
    rows = LeastSquaresTerms(problem.terms())
    cost0 = _start_cost(problem, rows)
    stages = [StageLog("average", ("joints",), 0, cost0, cost0, metrics={"views": n}, seconds=t_single)]

    # 2. the joint landmark refinement (LM); 3. photometric consistency (Adam)
    if config.refine_iterations > 0:
        refine = MultiViewStage("refine", ("pose", "joints", "expressions", "focal"), config.refine_iterations)
        stages.append(run_lm_stage(problem, rows, refine, config.lm, loss_start=cost0))
    identity_model = views_identity_model(config.skinning)  # None: the joints' own (jnr)
    # the photometric consistency refines the joints' identity, which another identity model replaces
    if config.photometric.enabled and config.photometric.iterations > 0 and identity_model is None:
        stages.extend(_photo_consistency(problem, rows, images, config.photometric))

    if progress is not None:
        progress("identity", steps, steps)
    state = problem.state
    with torch.no_grad():
        theta = (state.span * state.theta_n).clone()
    identity = _vertices(rig, problem.weights, theta, None)
    view_vertices = [_vertices(rig, problem.weights, theta, state.c[k].detach()) for k in range(n)]
    poses = (state.rotvec.detach(), state.translation.detach())
    asm_parameters = None
    if identity_model is not None:  # e.g. ASM, registered to the averaged (or refined) JNR head
        average = _vertices(rig, problem.weights, torch.as_tensor(theta_mean), None)
        identity, view_vertices, asm_parameters, model_logs, model_state = identity_model(
            problem, rows, average, identity, config
        )
        stages.extend(model_logs)
        poses = (model_state.rotvec.detach(), model_state.translation.detach())
    head = asm_parameters if isinstance(asm_parameters, HeadParams) else None
    return MultiViewFit(
        theta=theta.numpy().copy(),
        z=np.zeros(LATENT),
        identity_vertices=identity,
        views=tuple(_view_fits(problem, poses, view_vertices, lms, sizes, f0, layouts)),
        single_view_fits=singles,
        skinning=config.skinning,
        stages=tuple(stages),
        timings={"single_view": t_single, "total": time.perf_counter() - t_start},
        asm_parameters=None if head is not None else asm_parameters,
        head=head,
    )


def views_identity_prior(singles) -> IdentityPrior | None:
    """The conditional identity prior of several views: the views' own (:attr:`LandmarkFit.identity`, those that
    have one) with their means averaged; their errors are of one person's face, so not independent: the
    spread stays one view's. None when no view has one."""
    priors = [s.identity for s in singles if s.identity is not None]
    if not priors:
        return None
    return replace(priors[0], mean=np.mean([p.mean for p in priors], 0), meta={**priors[0].meta, "views": len(priors)})


def views_identity_model(kind: str):
    """The identity step of head model ``kind`` on top of the joints' fit: its own
    (:data:`~pipeline.photo.multiview_asm.VIEWS_IDENTITY_MODELS`), the generic one of a registered head model
    (:func:`~pipeline.photo.multiview_model.model_views_identity`), or None for ``jnr`` (the joints' own)."""
    return VIEWS_IDENTITY_MODELS[kind] if kind in VIEWS_IDENTITY_MODELS else model_views_identity(kind)


def _problem(
    lms, sizes, f0, singles, theta_mean, config: MultiViewConfig, rig: JointRig, neural, layouts, identity=None
) -> MultiViewProblem:
    """The joint refinement's problem, started from the single-view fits (module docstring, step 1), with the
    views' conditional identity prior ``identity`` (None: the population prior)."""
    dtype = rig.template.dtype
    landmark = config.landmarks
    terms = [
        LandmarkTerm(
            rig.asset,
            lm,
            make_camera(w, h, f, dtype=dtype, pose=False),
            landmark.huber_delta_px,
            landmark.contour_weight,
            landmark.landmark_weighting,
            layout,
            # each view's errors in pixels of a face 100 px between the eye corners, from its single-view pose
            face_scale(f, float(single.translation[2]), rig.asset) if landmark.face_scale else 1.0,
        )
        for lm, (w, h), f, layout, single in zip(lms, sizes, f0, layouts, singles)
    ]
    with torch.no_grad():
        weights = neural(torch.zeros(1, LATENT, dtype=dtype))[0].double()
    state = initial_state(singles, theta_mean, rig, config.fit_focal)
    return MultiViewProblem(state, terms, weights, config, identity)


def _start_cost(problem: MultiViewProblem, rows: LeastSquaresTerms) -> float:
    """The least-squares cost at the start, the jaw contours picked and the rows re-weighted there."""
    x0 = problem.pack()
    problem.prepare(x0)
    rows.reweight(problem.inputs(x0[None]))
    with torch.no_grad():
        return float(rows.cost(problem.inputs(x0[None]))[0])


def _photo_consistency(
    problem: MultiViewProblem, rows: LeastSquaresTerms, images, settings: PhotoConsistencyConfig
) -> tuple[StageLog, ...]:
    """The photometric consistency stage (:class:`pipeline.photo.consistency.PhotoConsistency`): Adam on the
    identity and the poses, the joint channels projected into their limits after each step."""
    consistency = PhotoConsistency(problem, rows, images, settings)
    lr = LearningRates(rotation=settings.lr_rotation, translation=settings.lr_translation, joints=settings.lr_joints)
    stage = MultiViewStage("photometric", ("pose", "joints"), settings.iterations)
    return run_schedule(
        problem.state,
        (stage,),
        consistency,
        lr,
        label="fit_multiview (photometric consistency)",
        before_step=consistency.before_step,
    )


def _view_fits(
    problem: MultiViewProblem, poses, view_vertices: list[np.ndarray], lms, sizes, f0, layouts
) -> list[ViewFit]:
    """One :class:`ViewFit` per view: its pose ``poses = (rotvec (N, 3), translation (N, 3))``, focal,
    expressions, head, and the 68 iBUG landmarks that head projects to (a dense view's input 68 mapped from
    its mesh)."""
    state = problem.state
    scales = problem.focal_scales()
    views = []
    for k, (w, h) in enumerate(sizes):
        with torch.no_grad():
            rotation = axis_angle_to_rotation_matrix(poses[0][k][None])[0].numpy()
        translation = poses[1][k].numpy().copy()
        focal = f0[k] * scales[k]
        px = _project_landmarks(view_vertices[k], rotation, translation, focal, w, h, problem.state.rig.asset)
        lm68 = lms[k] if layouts[k] is None else mesh_to_ibug68(lms[k])
        error, nme = landmark_errors(px, lm68)
        views.append(
            ViewFit(
                rotation=rotation,
                translation=translation,
                focal=float(focal),
                focal_start=float(f0[k]),
                width=int(w),
                height=int(h),
                expressions=state.c[k].detach().numpy().copy(),
                rig_vertices=view_vertices[k],
                landmarks2d=lm68,
                landmarks_px=px,
                error_px=error,
                nme=nme,
                weight=float(problem.view_weights[k]),
            )
        )
    return views


def _vertices(rig: JointRig, weights: torch.Tensor, theta: torch.Tensor, c: torch.Tensor | None) -> np.ndarray:
    """``(V, 3)`` float64 rig-space head of joint channels ``theta (P,)`` and expressions ``c (E,)`` (None: 0)."""
    expr = expressions64(rig.asset)
    c = torch.zeros(len(expr.names), dtype=torch.float64) if c is None else c.double()
    with torch.no_grad():
        return jnr_vertices(rig, expr, theta.double()[None], weights, c[None])[0].numpy()


def _project_landmarks(vertices: np.ndarray, rotation, translation, focal, width, height, asset):
    """``(68, 2)`` the iBUG landmarks of a rig-space head as a view's camera sees them (jaw contour dynamic)."""
    v = torch.as_tensor(vertices)
    static = landmark_positions(v, ibug68_layout(asset).embedding, asset.faces)[0]
    contour = contour_landmarks(v, asset.faces, camera_center_in_rig(rotation, translation), asset)
    points = torch.cat([contour, static[17:]]).double()
    cam = points @ torch.as_tensor(RIG_TO_OPENCV @ rotation).T + torch.as_tensor(translation)
    camera = make_camera(width, height, focal, dtype=torch.float64, pose=False)
    return project_points(cam[None], camera)[0].numpy()
