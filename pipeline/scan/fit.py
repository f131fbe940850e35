"""Fitting the rig to a point cloud: JNR's non-rigid ICP with alternating identity / expression stages.

JNR (sections 3.1, 3.3, 4.3) fits depth data with the losses of eq. 7, the correspondences built by
NICP, and a regulariser L_m (eq. 4) that diminishes while the correspondences converge; identity
(joints, then the neural-skinning latent Z, 2 cycles) and expressions alternate (2 cycles). Here:

1. **Rigid pre-alignment** (:func:`pipeline.scan.registration.rigid_prealign`): a multi-hypothesis trimmed
   ICP (every yaw, a few pitches) or the similarity of the 3D landmarks, with a scale. Landmarks are
   first checked (:func:`landmarks.points3d.check_landmarks_3d`); a cloud of which less than
   ``min_inlier_fraction`` lies near the aligned head is rejected as not a head before the per-point
   work of the fit (the scan border). Large clouds arrive subsampled
   (:func:`pipeline.scan.pointcloud.validate.validate_points`).
2. **Stages** (:class:`pipeline.fitting.engine.Stage`, run by :func:`pipeline.fitting.engine.run_schedule`): each
   optimises some of ``pose`` (rotation + translation in the cloud
   frame), ``joints`` (the 105 channels), ``latent`` (Z) and ``expressions`` (the 52 ARKit coefficients) with
   Adam, rebuilding correspondences every ``correspondence_every`` iterations:

   - cloud -> model: each (subsampled) cloud point and the closest point on the model's surface
     (searched around its nearest vertex; a barycentric combination of three vertices), residual
     point-to-plane plus ``tangential_weight`` times the tangential part;
   - model -> cloud: each model vertex facing the sensor and its nearest cloud point, residual
     point-to-plane on the cloud normal;

   both found with KD-trees and rejected when farther than an adaptive distance, when the normals
   disagree by more than ``normal_angle_deg``, or (model -> cloud) when the cloud point lies on the
   scan's border (a vertex outside the scanned area would otherwise be pulled to the border), under
   a Geman-McClure robust loss whose scale is a high quantile of the residuals. Regions the scan misses (holes, the
   back of the head) get no data
   term and are filled by the rig's prior (joints, neural skinning, expression limits).
3. **Diminishing L_m**: its weight starts at ``lambda_m_start`` and shrinks towards ``lambda_m_end``
   as the correspondences settle (the median vertex motion between two rebuilds falls below
   ``settle_mm``); it never grows back.

The loss of an iteration: ``sqrt(mean robust residual) + lambda_m L_m + lambda_x L_x +
lambda_z |Z|^2 + lambda_e |c|^2 (+ lambda_landmarks * landmark RMSE)``; expression coefficients are
projected back into their limits after each step.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.spatial import cKDTree

from landmarks.points3d import check_landmarks_3d, match_landmarks
from pipeline.fitting.engine import LearningRates, Loss, Stage, StageLog, run_schedule
from pipeline.fitting.priors import PriorWeights
from pipeline.fitting.state import AsmScanState, ScanState
from pipeline.fitting.terms import Inputs, Term, Value, term_values
from pipeline.scan.pointcloud.cloud import CloudError, PointCloud
from pipeline.scan.pointcloud.normals import boundary_mask, estimate_normals
from pipeline.scan.registration import (
    RigidAlignment,
    closest_on_one_ring,
    incident_faces,
    rigid_prealign,
)
from rig.expressions import ExpressionModel
from rig.geometry import Similarity, vertex_normals
from rig.model import JointRig
from rig.optim import Progress
from rig.parameters import NUM_PARAMETERS
from rig.skinning.asm import AdaptiveSkinning, asm_params_to_dict
from rig.skinning.neural import LATENT, NeuralSkinning, load_neural
from rig.template import FACE_REGIONS


def jnr_schedule(
    joint_iterations: int = 30,
    latent_iterations: int = 15,
    expression_iterations: int = 30,
    identity_cycles: int = 2,
    outer_cycles: int = 2,
    coarse_iterations: int = 20,
) -> tuple[Stage, ...]:
    """JNR 4.3's schedule: (joints, then Z) x ``identity_cycles``, then expressions; all x ``outer_cycles``.

    Before it, a coarse stage (pose and expressions, ``coarse_iterations``; 0 leaves it out) lets the
    expressions take up large deformations such as an open jaw: started with the joints, the fit
    explains an open mouth with joint motion and stays in that local minimum (measured on the rig's own
    posed, expressive vertices fitted as a cloud: ``docs/fit_scan.md``). JNR runs 500 iterations per
    stage on a GPU; the defaults are scaled to a 2-core CPU.
    """
    stages: list[Stage] = []
    if coarse_iterations:
        stages.append(Stage("coarse", ("pose", "expressions"), coarse_iterations))
    for o in range(outer_cycles):
        for c in range(identity_cycles):
            stages.append(Stage(f"joints {o + 1}.{c + 1}", ("pose", "joints"), joint_iterations))
            stages.append(Stage(f"latent {o + 1}.{c + 1}", ("latent",), latent_iterations))
        stages.append(Stage(f"expressions {o + 1}", ("pose", "expressions"), expression_iterations))
    return tuple(stages)


@dataclass(frozen=True)
class ScanLearningRates(LearningRates):
    """Adam steps of the point-cloud fit (``lr:`` in YAML): the geometry's groups
    (:class:`pipeline.fitting.engine.LearningRates`) and the global scale."""

    log_scale: float = 0.001
    """Log of the global scale."""
    asm_bones: float = 0.03
    """``skinning: asm``: ASM's bone transforms, in units of 10 deg / 1 mm / 0.1 scale."""
    asm_skinning: float = 0.02
    """``skinning: asm``: ASM's binding and mixtures (UV in units of 0.01; log pi; Cholesky floats)."""


@dataclass(frozen=True)
class ScanPriorWeights(PriorWeights):
    """The rig priors of the point-cloud fit (``prior:`` in YAML): ``lambda_m`` is L_m's weight at the
    start; it diminishes towards ``lambda_m_end`` as the correspondences settle."""

    lambda_m_end: float = 0.03
    """L_m once the correspondences have settled (JNR's 0.03)."""
    settle_mm: float = 1.0
    """Median vertex motion between rebuilds at which L_m has reached ``lambda_m_end``."""


SCAN_LEARNING_RATES = ScanLearningRates(rotation=0.002, translation=0.3, joints=0.01, latent=0.03, expressions=0.03)
"""Steps of the point-cloud fit (radians, mm, fractions of the channels' ranges)."""
SCAN_PRIOR = ScanPriorWeights(lambda_m=0.3, lambda_x=0.3, lambda_z=1e-3, lambda_expressions=0.02)
"""JNR's weights for depth data: L_m 0.3 diminishing to 0.03, L_x 0.3; small latent and expression priors."""


@dataclass(frozen=True)
class CorrespondenceConfig:
    """How the non-rigid ICP pairs points with the model (``correspondences:`` in YAML)."""

    every: int = 5
    """Rebuild the correspondences every this many iterations."""
    max_cloud_points: int = 8000
    """Cloud points used by the fit (a seeded subsample of larger clouds)."""
    max_distance_mm: float = 15.0
    """Rejection distance at the start; it adapts to 3x the inlier RMS, within [min, max]."""
    min_distance_mm: float = 8.0
    normal_angle_deg: float = 60.0
    """Pairs whose normals differ by more are rejected."""
    min_facing: float = 0.2
    """Model -> cloud pairs need ``n_vertex . view_direction`` above this (the vertex faces the sensor;
    the view direction is the mean cloud normal of a single-view scan)."""
    robust_sigma_min_mm: float = 1.5
    """Floor of the Geman-McClure scale, mm."""
    robust_sigma_quantile: float = 0.9
    """The Geman-McClure scale is this quantile of the absolute residuals (so that regions still far
    from the cloud, e.g. an expression not fitted yet, keep pulling; only the worst tail is down-weighted)."""
    tangential_weight: float = 0.1
    """Weight of the tangential part of the cloud -> model residual (to the closest surface point):
    1 is point-to-point, 0 point-to-plane. Model -> cloud pairs are point-to-plane (the cloud is discrete).
    Noise pulls a point-to-point fit sideways; a little tangential weight keeps sliding in check (chosen
    on noisy simulated scans of held-out heads: ``docs/fit_scan.md``, "Settings")."""
    model_to_cloud_weight: float = 1.0
    """Weight of the model -> cloud pairs relative to the cloud -> model pairs."""
    boundary_k: int = 16
    """Neighbours for the scan-border test."""
    normals_k: int = 16
    """Neighbours for normal estimation when the cloud has no normals."""


@dataclass(frozen=True)
class PrealignConfig:
    """The rigid pre-alignment (``prealign:`` in YAML; :func:`pipeline.scan.registration.rigid_prealign`)."""

    yaw_step_deg: float = 20.0
    """Yaw hypotheses this far apart."""
    scale: bool = True
    """Estimate a global scale (clamped to [0.85, 1.2])."""
    min_inlier_fraction: float = 0.6
    """After pre-alignment at least this fraction of the cloud must lie within 8 mm of the head, else the
    cloud is rejected as not a head."""


@dataclass(frozen=True)
class FitScanConfig:
    """Settings of ``jnr fit-scan`` (``configs/fit_scan.yaml`` overrides them)."""

    stages: tuple[Stage, ...] = field(default_factory=jnr_schedule)
    """The schedule (JNR 4.3); in YAML a list of ``{name, free, iterations}``."""
    seed: int = 0
    """Seed of the cloud subsampling."""
    lr: ScanLearningRates = SCAN_LEARNING_RATES
    """Adam steps per parameter group."""
    fit_scale: bool = True
    """Optimise a global scale with the pose (heads differ in size; the joints' scales are local)."""
    prior: ScanPriorWeights = SCAN_PRIOR
    """The rig priors (:mod:`pipeline.fitting.priors`), L_m diminishing."""
    lambda_landmarks: float = 0.5
    """Weight of the 3D landmark RMSE (mm) when landmarks are given."""
    correspondences: CorrespondenceConfig = field(default_factory=CorrespondenceConfig)
    prealign: PrealignConfig = field(default_factory=PrealignConfig)
    use_neural: bool = True
    """Use the neural skinning (learned linear + decoded residual); else the learned linear weights only."""
    skinning: str = "jnr"
    """The head model: ``jnr`` (the 52 joints' channels with neural skinning) or ``asm`` (the Adaptive
    Skinning Model, :mod:`rig.skinning.asm`: 9-DoF bones, GMM skinning weights in UV space, dynamic
    binding; the ``joints`` stages free its bone transforms and the ``latent`` stages its skinning)."""
    asm_components: int = 2
    """``skinning: asm``: Gaussians per bone (K)."""

    def __post_init__(self) -> None:
        if self.skinning not in ("jnr", "asm"):
            raise ValueError(f"skinning must be 'jnr' or 'asm', got {self.skinning!r}")
        if not isinstance(self.asm_components, int) or not 1 <= self.asm_components <= 8:
            raise ValueError(f"asm_components must be an int in [1, 8], got {self.asm_components!r}")


@dataclass(frozen=True)
class ScanFit:
    """Result of :func:`fit_scan`.

    Attributes:
        theta: ``(P,)`` joint channels (deg, mm, ``scale - 1``).
        z: ``(50,)`` neural-skinning latent.
        expressions: ``(E,)`` expression coefficients (:data:`rig.expressions.EXPRESSION_NAMES`).
        rotation, translation, scale: rig space -> cloud frame, ``x = scale * R @ x_rig + t`` (mm).
        vertices: ``(V, 3)`` fitted mesh in the cloud frame, mm.
        rig_vertices: ``(V, 3)`` the same mesh in rig space, mm.
        prealign: the rigid pre-alignment.
        stages: one :class:`~pipeline.fitting.engine.StageLog` per stage: every loss term, and the metrics
            ``data_rms_mm`` (cloud -> model RMS of the inliers), ``lambda_m`` (L_m's weight at the end),
            ``pairs_cloud_to_model``, ``pairs_model_to_cloud``.
        timings: seconds per phase (``prealign``, ``fit``, ``total``).
        asm: with ``skinning: asm``, the fitted ASM parameters by bone
            (:func:`rig.skinning.asm.asm_params_to_dict`); ``theta`` and ``z`` are then zeros.
    """

    theta: np.ndarray
    z: np.ndarray
    expressions: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    scale: float
    vertices: np.ndarray
    rig_vertices: np.ndarray
    prealign: RigidAlignment
    stages: tuple[StageLog, ...]
    timings: dict
    asm: dict | None = None

    @property
    def transform(self) -> Similarity:
        """Rig space -> the cloud's frame as a :class:`rig.geometry.Similarity`."""
        return Similarity(self.rotation, self.translation, self.scale)


@dataclass(frozen=True)
class Pairs:
    """Correspondences of one rebuild: cloud -> model pairs (cloud point ``c_i``, triangle ``c_tri (M, 3)``,
    barycentric ``c_bary (M, 3)``, fixed normal ``c_n (M, 3)``), model -> cloud pairs (vertex ``m_j``,
    cloud point ``m_k``, cloud normal ``m_n``) and the Geman-McClure scale ``sigma`` (mm)."""

    c_i: torch.Tensor
    c_tri: torch.Tensor
    c_bary: torch.Tensor
    c_n: torch.Tensor
    m_j: torch.Tensor
    m_k: torch.Tensor
    m_n: torch.Tensor
    sigma: float


def plane_residual(d: torch.Tensor, n: torch.Tensor, tangential: float) -> torch.Tensor:
    """Squared point-to-plane distance plus a weighted tangential part: ``d, n (M, 3) -> (M,)`` mm^2."""
    normal = (d * n).sum(-1)
    tangent = d - normal[:, None] * n
    return normal**2 + tangential * (tangent**2).sum(-1)


def geman_mcclure(e: torch.Tensor, sigma: float) -> torch.Tensor:
    """Geman-McClure of squared residuals ``e`` (mm^2) at scale ``sigma`` (mm): ``s^2 e / (s^2 + e)``."""
    s2 = sigma * sigma
    return s2 * e / (s2 + e)


class ScanObjective:
    """The non-rigid ICP loss of one cloud: correspondences rebuilt every ``correspondences.every`` steps
    (:meth:`rebuild`, the engine's ``before_step``), the robust data term, the head model's priors
    (:meth:`~pipeline.fitting.state.FitState.prior_terms`) with L_m diminishing as the correspondences settle,
    and the optional 3D landmark term, as :class:`~pipeline.fitting.terms.Term` s (the data and landmark terms
    are given by their values: Adam only).

    Args:
        state: the fit state (:class:`~pipeline.fitting.state.ScanState`).
        points, normals: ``(N, 3)`` the cloud and its unit normals, mm. border: ``(N,)`` bool scan border.
        view_dir: ``(3,)`` unit viewing direction of a single-view scan, or None.
        config: the fit's settings. rng: subsampling generator.
        landmarks: ``(vertex ids (L,), positions (L, 3) mm)`` or None.
    """

    def __init__(
        self,
        state: ScanState,
        points: np.ndarray,
        normals: np.ndarray,
        border: np.ndarray,
        view_dir: np.ndarray | None,
        config: FitScanConfig,
        rng: np.random.Generator,
        landmarks: tuple[np.ndarray, np.ndarray] | None,
    ) -> None:
        c = config.correspondences
        dtype = state.dtype
        self.state, self.config, self.c = state, config, c
        self.points, self.normals, self.border, self.view_dir = points, normals, border, view_dir
        sub = (
            np.sort(rng.choice(len(points), size=c.max_cloud_points, replace=False))
            if len(points) > c.max_cloud_points
            else np.arange(len(points))
        )
        self.p_sub, self.n_sub = points[sub], normals[sub]
        self.cloud_tree = cKDTree(points)
        self.P_sub = torch.as_tensor(self.p_sub, dtype=dtype)
        self.P_all = torch.as_tensor(points, dtype=dtype)
        self.cos_max = math.cos(math.radians(c.normal_angle_deg))
        self.landmarks = (
            None if landmarks is None else (torch.as_tensor(landmarks[0]), torch.as_tensor(landmarks[1], dtype=dtype))
        )
        faces = state.rig.asset.faces
        self.incident = incident_faces(faces, len(state.rig.asset.vertices))
        self.max_d, self.lambda_m, self.previous = c.max_distance_mm, config.prior.lambda_m, None
        self.pairs: Pairs | None = None

    def before_step(self, stage: Stage, iteration: int) -> None:
        """Rebuild the correspondences at the stage's first step and every ``correspondences.every``."""
        if iteration % self.c.every == 0:
            with torch.no_grad():
                v = self.state.to_cloud(self.state.rig_vertices()).numpy().astype(np.float64)
            self.pairs = self.rebuild(v)

    def _candidates(self, v_cloud: np.ndarray):
        """Both pair directions, found and rejected (module docstring), with their residuals (mm^2)."""
        c, faces = self.c, self.state.rig.asset.faces
        vn = vertex_normals(v_cloud, faces)
        _, j1 = cKDTree(v_cloud).query(self.p_sub)
        # cloud -> model: the closest point on the model's surface (around the nearest vertex).
        f1, b1, q1 = closest_on_one_ring(self.p_sub, v_cloud, faces, self.incident, j1)
        n1 = (b1[:, :, None] * vn[faces[f1]]).sum(1)
        n1 /= np.linalg.norm(n1, axis=1, keepdims=True).clip(1e-12)
        d1 = np.linalg.norm(self.p_sub - q1, axis=1)
        ok1 = (d1 <= self.max_d) & ((self.n_sub * n1).sum(1) >= self.cos_max)
        d2, k2 = self.cloud_tree.query(v_cloud)
        ok2 = (d2 <= self.max_d) & ~self.border[k2] & ((vn * self.normals[k2]).sum(1) >= self.cos_max)
        if self.view_dir is not None:
            ok2 &= vn @ self.view_dir > c.min_facing
        e1 = plane_residual(
            torch.from_numpy(self.p_sub[ok1] - q1[ok1]), torch.from_numpy(n1[ok1]), c.tangential_weight
        ).numpy()
        e2 = plane_residual(
            torch.from_numpy(v_cloud[ok2] - self.points[k2[ok2]]), torch.from_numpy(self.normals[k2[ok2]]), 0.0
        ).numpy()
        return (f1, b1, n1, ok1), (k2, ok2), np.sqrt(np.concatenate([e1, e2]))

    def rebuild(self, v_cloud: np.ndarray) -> Pairs:
        """New pairs for the model at ``v_cloud (V, 3)`` (float64, mm); adapts the rejection distance and
        lowers L_m's weight by how far the model moved since the last rebuild."""
        c, p, faces, dtype = self.c, self.config.prior, self.state.rig.asset.faces, self.state.dtype
        (f1, b1, n1, ok1), (k2, ok2), r = self._candidates(v_cloud)
        sigma = max(c.robust_sigma_min_mm, float(np.quantile(r, c.robust_sigma_quantile)))
        inlier_rms = float(np.sqrt(np.mean(np.minimum(r, sigma * 3) ** 2)))
        self.max_d = float(np.clip(3.0 * max(inlier_rms, sigma), c.min_distance_mm, c.max_distance_mm))
        if self.previous is not None:
            motion = float(np.median(np.linalg.norm(v_cloud - self.previous, axis=1)))
            target = p.lambda_m_end + (p.lambda_m - p.lambda_m_end) * min(1.0, motion / p.settle_mm)
            self.lambda_m = min(self.lambda_m, target)
        self.previous = v_cloud.copy()
        return Pairs(
            c_i=torch.as_tensor(np.flatnonzero(ok1), dtype=torch.long),
            c_tri=torch.as_tensor(faces[f1[ok1]], dtype=torch.long),
            c_bary=torch.as_tensor(torch.as_tensor(b1[ok1], dtype=dtype)),
            c_n=torch.as_tensor(torch.as_tensor(n1[ok1], dtype=dtype)),
            m_j=torch.as_tensor(np.flatnonzero(ok2), dtype=torch.long),
            m_k=torch.as_tensor(k2[ok2], dtype=torch.long),
            m_n=torch.as_tensor(torch.as_tensor(self.normals[k2[ok2]], dtype=dtype)),
            sigma=float(sigma),
        )

    def __call__(self, free: tuple[str, ...]) -> Loss:
        """One step's loss: ``sqrt(mean robust residual)``, the head model's priors, the landmark RMSE."""
        pairs, c = self.pairs, self.c
        v_rig = self.state.rig_vertices(free)
        v_cloud = self.state.to_cloud(v_rig)
        on_surface = (pairs.c_bary[:, :, None] * v_cloud[pairs.c_tri]).sum(1)
        e1 = plane_residual(self.P_sub[pairs.c_i] - on_surface, pairs.c_n, c.tangential_weight)
        e2 = plane_residual(v_cloud[pairs.m_j] - self.P_all[pairs.m_k], pairs.m_n, 0.0)
        inputs = self.state.term_inputs().add({"rig_vertices": v_rig[None], "cloud_vertices": v_cloud[None]})
        terms = (
            self.data_term(e1, e2, pairs.sigma),
            *self.state.prior_terms(self.config.prior, lambda_m=self.lambda_m),
            *(() if self.landmarks is None else (self.landmark_term(),)),
        )
        data_rms = e1.detach().clamp_max((3 * pairs.sigma) ** 2).mean().sqrt()
        return Loss(
            term_values(terms, inputs),
            {
                "data_rms_mm": data_rms,
                "lambda_m": self.lambda_m,
                "pairs_cloud_to_model": len(pairs.c_i),
                "pairs_model_to_cloud": len(pairs.m_j),
            },
        )

    def data_term(self, e1: torch.Tensor, e2: torch.Tensor, sigma: float) -> Term:
        """``data``: ``sqrt(mean robust residual)`` of the squared residuals ``e1 (M,)`` (cloud -> model) and
        ``e2 (K,)`` (model -> cloud, weighted ``model_to_cloud_weight``), Geman-McClure at scale ``sigma``."""
        w2 = self.c.model_to_cloud_weight

        def root_mean_robust(p: Inputs) -> torch.Tensor:
            robust = (geman_mcclure(e1, sigma).sum() + w2 * geman_mcclure(e2, sigma).sum()) / (len(e1) + w2 * len(e2))
            return (robust + 1e-12).sqrt()[None, None]

        return Term(
            "data",
            1.0,
            root_mean_robust,
            Value(),
            lm="none",
            note="the root of a mean robust residual is not a sum of squares",
        )

    def landmark_term(self) -> Term:
        """``landmarks``: ``lambda_landmarks`` times the RMSE of the 3D landmarks (mm, cloud frame; the input
        ``cloud_vertices (B, V, 3)``)."""
        ids, positions = self.landmarks
        return Term(
            "landmarks",
            self.config.lambda_landmarks,
            lambda p: ((p["cloud_vertices"][:, ids] - positions) ** 2).sum(-1).mean(-1).sqrt()[:, None],
            Value(),
            lm="none",
            note="an RMSE (the root of a mean) is not a sum of squares",
        )


def _cloud_normals(cloud: PointCloud, config: FitScanConfig) -> np.ndarray:
    """``(N, 3)`` unit normals of the cloud: its own, or estimated (PCA over ``normals_k`` neighbours)."""
    return (
        cloud.normals
        if cloud.normals is not None
        else estimate_normals(cloud.points, k=config.correspondences.normals_k)
    )


def fit_scan(
    cloud: PointCloud,
    config: FitScanConfig | None = None,
    *,
    landmarks: Mapping[str, np.ndarray] | None = None,
    rig: JointRig | None = None,
    neural: NeuralSkinning | None = None,
    expressions: ExpressionModel | None = None,
    progress: Progress | None = None,
    landmarks_source: str = "--landmarks",
) -> ScanFit:
    """Fit the rig (pose, joints, Z, expressions) to a point cloud.

    Args:
        cloud: the validated cloud (:func:`pipeline.scan.pointcloud.read.read_point_cloud`), mm, rig frame.
        config: settings and schedule (default :class:`FitScanConfig`).
        landmarks: optional ``{name: (3,) mm}`` 3D landmarks in the cloud's frame
            (:data:`landmarks.points3d.LANDMARK_NAMES_3D`); they replace the rigid search and add a term.
        rig, neural, expressions: the models (default: the committed rig and learned skinning, float32).
        progress: :data:`rig.optim.Progress`, called after every step.
        landmarks_source: how error messages name the landmarks (e.g. their file).

    Returns:
        :class:`ScanFit`.

    Raises:
        CloudError: the cloud does not look like a head after the rigid pre-alignment (tested before
            the per-point work only the fit needs).
        LandmarkError: unknown or too few landmarks, or landmarks that fail
            :func:`landmarks.points3d.check_landmarks_3d` (coincident, not head-sized, not face-like or
            mirrored, turned away from the scanner, off the cloud); checked before the pre-alignment.
    """
    config = config or FitScanConfig()
    t_start = time.perf_counter()
    rig = rig or JointRig()
    asm_model, neural = _head_models(config, rig, neural)
    expressions = expressions or ExpressionModel(rig.asset, dtype=rig.template.dtype)
    rng = np.random.default_rng(config.seed)
    normals = _cloud_normals(cloud, config)
    # A single-view scan's normals face its sensor: their mean is the viewing direction (None for a
    # cloud all around the head). Model -> cloud pairs only come from vertices facing the sensor.
    mean_normal = normals.mean(0)
    view_dir = mean_normal / np.linalg.norm(mean_normal) if np.linalg.norm(mean_normal) > 0.3 else None
    align, marks = _prealign(cloud, normals, view_dir, config, rig, neural, landmarks, landmarks_source)
    border = boundary_mask(cloud.points, k=config.correspondences.boundary_k)
    t_prealign = time.perf_counter() - t_start

    pose = (align.rotation, align.translation, align.scale)
    if asm_model is not None:
        state = AsmScanState(asm_model, expressions, *pose, fit_scale=config.fit_scale)
    else:
        state = ScanState(rig, neural, expressions, *pose, fit_scale=config.fit_scale)
    objective = ScanObjective(state, cloud.points, normals, border, view_dir, config, rng, marks)
    t_fit = time.perf_counter()
    stages = run_schedule(
        state,
        config.stages,
        objective,
        config.lr,
        label="fit-scan",
        progress=progress,
        before_step=objective.before_step,
    )
    with torch.no_grad():
        v_rig = state.rig_vertices()
        v_cloud = state.to_cloud(v_rig)
    values = state.arrays()
    t_end = time.perf_counter()
    return ScanFit(
        theta=values["theta"],
        z=values["z"],
        expressions=values["expressions"],
        rotation=values["rotation"],
        translation=state.translation.detach().double().numpy(),
        scale=state.scale,
        vertices=v_cloud.double().numpy(),
        rig_vertices=v_rig.double().numpy(),
        prealign=align,
        stages=stages,
        timings={"prealign": t_prealign, "fit": t_end - t_fit, "total": t_end - t_start},
        asm=None if asm_model is None else asm_params_to_dict(state.asm_parameters(()), rig.asset.joint_names),
    )


def _head_models(
    config: FitScanConfig, rig: JointRig, neural: NeuralSkinning | None
) -> tuple[AdaptiveSkinning | None, NeuralSkinning | None]:
    """``(ASM model or None, neural skinning or None)`` of the head model ``config.skinning`` (the learned
    skinning loaded when needed and not given)."""
    if config.skinning == "asm":
        return AdaptiveSkinning(rig, components=config.asm_components), None
    if not config.use_neural:
        return None, None
    return None, neural if neural is not None else load_neural(rig)[0]


def _prealign(
    cloud: PointCloud,
    normals: np.ndarray,
    view_dir: np.ndarray | None,
    config: FitScanConfig,
    rig: JointRig,
    neural: NeuralSkinning | None,
    landmarks: Mapping[str, np.ndarray] | None,
    landmarks_source: str,
) -> tuple[RigidAlignment, tuple[np.ndarray, np.ndarray] | None]:
    """Check the landmarks, align the template rigidly and reject a cloud that is not a head. Returns the
    alignment and the matched landmarks ``(vertex ids, positions)`` (None without landmarks)."""
    asset, dtype, points = rig.asset, rig.template.dtype, cloud.points
    with torch.no_grad():
        start_vertices = (
            neural.rig(
                torch.zeros(1, NUM_PARAMETERS, dtype=dtype), weights=neural(torch.zeros(1, LATENT, dtype=dtype))[0]
            )
            .vertices[0]
            .numpy()
            if neural is not None
            else asset.vertices
        )
    marks = None
    if landmarks:
        lm_ids, lm_pos, lm_names = match_landmarks(landmarks, asset)
        check_landmarks_3d(
            lm_pos,
            lm_names,
            reference=start_vertices[lm_ids],
            cloud=points,
            view_direction=view_dir,
            source=landmarks_source,
        )
        marks = (lm_ids, lm_pos)
    # The not-a-head test (the pre-alignment's inlier fraction) comes before the per-point work only
    # the fit needs (the scan border).
    align = rigid_prealign(
        points,
        normals,
        start_vertices,
        asset.faces,
        face_mask=asset.region_mask(*FACE_REGIONS),
        seed=config.seed,
        yaw_step_deg=config.prealign.yaw_step_deg,
        with_scale=config.prealign.scale,
        landmarks=None if marks is None else (start_vertices[marks[0]], marks[1]),
    )
    if align.inlier_fraction < config.prealign.min_inlier_fraction:
        sampled = f" (a random {len(points)} of its {cloud.input_points})" if cloud.input_points > len(points) else ""
        raise CloudError(
            f"the cloud does not look like a head: after the best rigid alignment only "
            f"{100 * align.inlier_fraction:.0f} % of its points{sampled} lie within 8 mm of the head "
            f"model (need {100 * config.prealign.min_inlier_fraction:.0f} %)"
        )
    return align, marks
