"""Fitting the rig to a point cloud: JNR's non-rigid ICP with alternating identity / expression stages.

JNR (sections 3.1, 3.3, 4.3) fits depth data with the losses of eq. 7, the correspondences built by
NICP, and a regulariser L_m (eq. 4) that diminishes while the correspondences converge; identity
(joints, then the neural-skinning latent Z, 2 cycles) and expressions alternate (2 cycles). Here:

1. **Rigid pre-alignment** (:func:`pipeline.scan.registration.rigid_prealign`): a multi-hypothesis trimmed
   ICP (every yaw, a few pitches) or the similarity of the 3D landmarks, with a scale. Landmarks are
   first checked (:func:`landmarks.points3d.check_landmarks_3d`); a cloud of which less than
   ``min_inlier_fraction`` lies near the aligned head is rejected as not a head before the per-point
   work of the fit (the scan border). Large clouds arrive subsampled (:func:`pipeline.scan.pointcloud.validate_points`).
2. **Stages** (:class:`Stage`): each optimises some of ``pose`` (rotation + translation in the cloud
   frame), ``joints`` (the 105 channels), ``latent`` (Z) and ``expressions`` (24 coefficients) with
   Adam, rebuilding correspondences every ``correspondence_every`` iterations:

   - cloud -> model: each (subsampled) cloud point and the closest point on the model's surface
     (searched around its nearest vertex; a barycentric combination of three vertices), residual
     point-to-plane plus ``tangential_weight`` times the tangential part;
   - model -> cloud: each model vertex facing the sensor and its nearest cloud point, residual
     point-to-plane on the cloud normal;

   both found with KD-trees and rejected when farther than an adaptive distance, when the normals
   disagree by more than ``normal_angle_deg``, or (model -> cloud) when the cloud point lies on the
   scan's border (a vertex outside the scanned area would otherwise be pulled to the border), under
   a Geman-McClure robust loss whose scale is a high quantile of the residuals. Regions the scan misses (holes, the back of the head) get no data
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
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch
from scipy.spatial import cKDTree

from pipeline.fitting.state import FREE_GROUPS, RigState
from pipeline.scan.pointcloud import (
    CloudError,
    PointCloud,
    boundary_mask,
    estimate_normals,
)
from pipeline.scan.registration import (
    MeshDistance,
    RigidAlignment,
    closest_on_one_ring,
    incident_faces,
    rigid_prealign,
    vertex_normals,
)
from rig.expressions import ExpressionModel
from rig.losses import limit_loss, regularizer
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS
from rig.skinning.neural import LATENT, NeuralSkinning, load_neural

FACE_REGIONS = ("forehead", "brows", "eyelids", "nose", "cheeks", "lips", "chin")


@dataclass(frozen=True)
class Stage:
    """One stage of the schedule."""

    name: str
    """Label in reports and progress bars."""
    free: tuple[str, ...]
    """What is optimised: a subset of ``pose``, ``joints``, ``latent``, ``expressions``."""
    iterations: int
    """Adam steps."""

    groups: ClassVar[tuple[str, ...]] = FREE_GROUPS
    """What ``free`` may name (a subclass may allow more)."""

    def __post_init__(self) -> None:
        bad = [f for f in self.free if f not in self.groups]
        if bad or not self.free:
            raise ValueError(f"stage {self.name!r}: free must be a non-empty subset of {list(self.groups)}, "
                             f"got {list(self.free)}")
        if self.iterations < 0:
            raise ValueError(f"stage {self.name!r}: iterations must be >= 0, got {self.iterations}")


def jnr_schedule(joint_iterations: int = 30, latent_iterations: int = 15, expression_iterations: int = 30,
                 identity_cycles: int = 2, outer_cycles: int = 2, coarse_iterations: int = 20) -> tuple[Stage, ...]:
    """JNR 4.3's schedule: (joints, then Z) x ``identity_cycles``, then expressions; all x ``outer_cycles``.

    Before it, a coarse stage (pose and expressions, ``coarse_iterations``; 0 leaves it out) lets the
    expressions take up large deformations such as an open jaw: started with the joints, the fit
    explains an open mouth with joint motion and stays in that local minimum (measured: lips 4 mm
    off when fitting the rig's own posed, expressive vertices as a cloud; 0.7 mm with the coarse
    stage). JNR runs 500 iterations per
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
class FitScanConfig:
    """Settings of ``jnr fit-scan`` (``configs/fit_scan.yaml`` overrides them)."""

    stages: tuple[Stage, ...] = field(default_factory=jnr_schedule)
    """The schedule (JNR 4.3); in YAML a list of ``{name, free, iterations}``."""
    seed: int = 0
    """Seed of the cloud subsampling."""
    lr_rotation: float = 0.002
    """Adam step of the pose rotation vector, radians."""
    lr_translation: float = 0.3
    """Adam step of the pose translation, mm."""
    lr_log_scale: float = 0.001
    """Adam step of the log of the global scale."""
    fit_scale: bool = True
    """Optimise a global scale with the pose (heads differ in size; the joints' scales are local)."""
    lr_joints: float = 0.01
    """Adam step of the joint channels, as a fraction of each channel's range."""
    lr_latent: float = 0.03
    lr_expressions: float = 0.03
    correspondence_every: int = 5
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
    Measured on noisy simulated scans of 5 held-out heads: 1.0 gives 2.5 mm true vertex error, 0.1
    1.05 mm, 0 1.04 mm (noise pulls a point-to-point fit sideways); a little keeps sliding in check."""
    model_to_cloud_weight: float = 1.0
    """Weight of the model -> cloud pairs relative to the cloud -> model pairs."""
    lambda_m_start: float = 0.3
    lambda_m_end: float = 0.03
    """L_m (eq. 4) weight at the start and once the correspondences have settled (JNR's 0.03)."""
    settle_mm: float = 1.0
    """Median vertex motion between rebuilds at which L_m has reached ``lambda_m_end``."""
    lambda_x: float = 0.3
    """L_x (eq. 5), the joint-limit penalty (JNR's 0.3)."""
    lambda_z: float = 1e-3
    """|Z|^2 keeps the latent where the decoder was trained."""
    lambda_expressions: float = 0.02
    """|c|^2 on the expression coefficients."""
    lambda_landmarks: float = 0.5
    """Weight of the 3D landmark RMSE (mm) when landmarks are given."""
    boundary_k: int = 16
    """Neighbours for the scan-border test."""
    normals_k: int = 16
    """Neighbours for normal estimation when the cloud has no normals."""
    use_neural: bool = True
    """Use the neural skinning (learned linear + decoded residual); else the learned linear weights only."""
    prealign_yaw_step_deg: float = 20.0
    prealign_scale: bool = True
    """Estimate a global scale in the pre-alignment (clamped to [0.85, 1.2])."""
    min_inlier_fraction: float = 0.6
    """After pre-alignment at least this fraction of the cloud must lie within 8 mm of the head, else the
    cloud is rejected as not a head."""


@dataclass(frozen=True)
class StageReport:
    """What one stage did: losses at its start and end, the data RMS (mm), L_m's weight, pair counts."""

    name: str
    free: tuple[str, ...]
    iterations: int
    loss_start: float
    loss_end: float
    data_rms_mm: float
    lambda_m: float
    pairs_cloud_to_model: int
    pairs_model_to_cloud: int
    seconds: float


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
        stages: one :class:`StageReport` per stage.
        timings: seconds per phase (``prealign``, ``fit``, ``total``).
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
    stages: tuple[StageReport, ...]
    timings: dict


class _Pairs:
    """Correspondences of one rebuild (index tensors and the fixed normals of the residuals)."""

    def __init__(self, cloud_idx, tri_idx, bary, normals_c2m, vert_idx_m2c, cloud_idx_m2c, normals_m2c, sigma):
        self.c_i = torch.as_tensor(cloud_idx, dtype=torch.long)
        self.c_tri = torch.as_tensor(tri_idx, dtype=torch.long)  # (M, 3) vertex ids of the matched triangle
        self.c_bary = torch.as_tensor(bary)  # (M, 3) barycentric coordinates of the closest surface point
        self.c_n = torch.as_tensor(normals_c2m)
        self.m_j = torch.as_tensor(vert_idx_m2c, dtype=torch.long)
        self.m_k = torch.as_tensor(cloud_idx_m2c, dtype=torch.long)
        self.m_n = torch.as_tensor(normals_m2c)
        self.sigma = float(sigma)


def _residual(d: torch.Tensor, n: torch.Tensor, tangential: float) -> torch.Tensor:
    """Squared point-to-plane distance plus a weighted tangential part, ``(M, 3) -> (M,)`` mm^2."""
    normal = (d * n).sum(-1)
    tangent = d - normal[:, None] * n
    return normal ** 2 + tangential * (tangent ** 2).sum(-1)


def _geman_mcclure(e: torch.Tensor, sigma: float) -> torch.Tensor:
    s2 = sigma * sigma
    return s2 * e / (s2 + e)


class _Model(RigState):
    """The differentiable map (pose, joints, Z, expressions) -> vertices in the cloud frame."""

    def __init__(self, rig: JointRig, neural: NeuralSkinning | None, expressions: ExpressionModel,
                 prealign: RigidAlignment) -> None:
        super().__init__(rig, neural, expressions, prealign.rotation)
        dtype = rig.template.dtype
        self.log_scale = torch.tensor(math.log(prealign.scale), dtype=dtype, requires_grad=True)
        self.translation = torch.tensor(prealign.translation, dtype=dtype, requires_grad=True)

    def to_cloud(self, v: torch.Tensor) -> torch.Tensor:
        return self.log_scale.exp() * v @ self.rotation().T + self.translation

    @property
    def scale(self) -> float:
        return float(self.log_scale.detach().exp())


def _cloud_normals(cloud: PointCloud, config: FitScanConfig) -> np.ndarray:
    """``(N, 3)`` unit normals of the cloud: its own, or estimated (PCA over ``normals_k`` neighbours)."""
    return cloud.normals if cloud.normals is not None else estimate_normals(cloud.points, k=config.normals_k)


def fit_scan(cloud: PointCloud, config: FitScanConfig | None = None, *,
             landmarks: Mapping[str, np.ndarray] | None = None, rig: JointRig | None = None,
             neural: NeuralSkinning | None = None, expressions: ExpressionModel | None = None,
             progress: Callable[[str, int, int], None] | None = None,
             landmarks_source: str = "--landmarks") -> ScanFit:
    """Fit the rig (pose, joints, Z, expressions) to a point cloud.

    Args:
        cloud: the validated cloud (:func:`pipeline.scan.pointcloud.read_point_cloud`), mm, rig frame.
        config: settings and schedule (default :class:`FitScanConfig`).
        landmarks: optional ``{name: (3,) mm}`` 3D landmarks in the cloud's frame
            (:data:`landmarks.points3d.LANDMARK_NAMES_3D`); they replace the rigid search and add a term.
        rig, neural, expressions: the models (default: the committed rig and learned skinning, float32).
        progress: called as ``progress(stage_name, iteration, iterations)``.
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
    if config.use_neural and neural is None:
        neural, _ = load_neural(rig)
    if not config.use_neural:
        neural = None
    expressions = expressions or ExpressionModel(rig.asset, dtype=rig.template.dtype)
    dtype = rig.template.dtype
    asset = rig.asset
    faces = asset.faces
    rng = np.random.default_rng(config.seed)

    points = cloud.points
    face_mask = asset.region_mask(*FACE_REGIONS)
    with torch.no_grad():
        start_vertices = (neural.rig(torch.zeros(1, NUM_PARAMETERS, dtype=dtype), weights=neural(
            torch.zeros(1, LATENT, dtype=dtype))[0]).vertices[0].numpy() if neural is not None else asset.vertices)
    lm_ids = lm_pos = None
    if landmarks:
        from landmarks.points3d import check_landmarks_3d, match_landmarks

        lm_ids, lm_pos, lm_names = match_landmarks(landmarks, asset)
    # The not-a-head test (the pre-alignment's inlier fraction) comes before the per-point work only
    # the fit needs (the scan border); the pre-alignment needs the normals.
    normals = _cloud_normals(cloud, config)
    # A single-view scan's normals face its sensor: their mean is the viewing direction (None for a
    # cloud all around the head). Model -> cloud pairs only come from vertices facing the sensor.
    mean_normal = normals.mean(0)
    view_dir = mean_normal / np.linalg.norm(mean_normal) if np.linalg.norm(mean_normal) > 0.3 else None
    if lm_ids is not None:
        check_landmarks_3d(lm_pos, lm_names, reference=start_vertices[lm_ids], cloud=points, view_direction=view_dir,
                           source=landmarks_source)
    align = rigid_prealign(points, normals, start_vertices, faces, face_mask=face_mask, seed=config.seed,
                           yaw_step_deg=config.prealign_yaw_step_deg, with_scale=config.prealign_scale,
                           landmarks=None if lm_ids is None else (start_vertices[lm_ids], lm_pos),
                           )
    if align.inlier_fraction < config.min_inlier_fraction:
        sampled = (f" (a random {len(points)} of its {cloud.input_points})"
                   if cloud.input_points > len(points) else "")
        raise CloudError(f"the cloud does not look like a head: after the best rigid alignment only "
                         f"{100 * align.inlier_fraction:.0f} % of its points{sampled} lie within 8 mm of the head "
                         f"model (need {100 * config.min_inlier_fraction:.0f} %)")
    border = boundary_mask(points, k=config.boundary_k)
    t_prealign = time.perf_counter() - t_start

    sub = np.sort(rng.choice(len(points), size=config.max_cloud_points, replace=False)) \
        if len(points) > config.max_cloud_points else np.arange(len(points))
    p_sub, n_sub = points[sub], normals[sub]
    cloud_tree = cKDTree(points)
    P_sub = torch.as_tensor(p_sub, dtype=dtype)
    P_all = torch.as_tensor(points, dtype=dtype)
    model = _Model(rig, neural, expressions, align)
    cos_max = math.cos(math.radians(config.normal_angle_deg))
    lm_ids_t = None if lm_ids is None else torch.as_tensor(lm_ids)
    lm_pos_t = None if lm_pos is None else torch.as_tensor(lm_pos, dtype=dtype)

    incident = incident_faces(faces, len(asset.vertices))
    state = {"max_d": config.max_distance_mm, "lambda_m": config.lambda_m_start, "prev": None}

    def rebuild(v_cloud: np.ndarray) -> _Pairs:
        vn = vertex_normals(v_cloud, faces)
        tree = cKDTree(v_cloud)
        _, j1 = tree.query(p_sub)
        # cloud -> model: the closest point on the model's surface (around the nearest vertex).
        f1, b1, q1 = closest_on_one_ring(p_sub, v_cloud, faces, incident, j1)
        n1 = (b1[:, :, None] * vn[faces[f1]]).sum(1)
        n1 /= np.linalg.norm(n1, axis=1, keepdims=True).clip(1e-12)
        d1 = np.linalg.norm(p_sub - q1, axis=1)
        ok1 = (d1 <= state["max_d"]) & ((n_sub * n1).sum(1) >= cos_max)
        d2, k2 = cloud_tree.query(v_cloud)
        ok2 = (d2 <= state["max_d"]) & ~border[k2] & ((vn * normals[k2]).sum(1) >= cos_max)
        if view_dir is not None:
            ok2 &= vn @ view_dir > config.min_facing
        e1 = _residual(torch.from_numpy(p_sub[ok1] - q1[ok1]), torch.from_numpy(n1[ok1]),
                       config.tangential_weight).numpy()
        e2 = _residual(torch.from_numpy(v_cloud[ok2] - points[k2[ok2]]), torch.from_numpy(normals[k2[ok2]]),
                       0.0).numpy()
        r = np.sqrt(np.concatenate([e1, e2]))
        sigma = max(config.robust_sigma_min_mm, float(np.quantile(r, config.robust_sigma_quantile)))
        inlier_rms = float(np.sqrt(np.mean(np.minimum(r, sigma * 3) ** 2)))
        state["max_d"] = float(np.clip(3.0 * max(inlier_rms, sigma), config.min_distance_mm, config.max_distance_mm))
        if state["prev"] is not None:
            motion = float(np.median(np.linalg.norm(v_cloud - state["prev"], axis=1)))
            target = config.lambda_m_end + (config.lambda_m_start - config.lambda_m_end) * min(
                1.0, motion / config.settle_mm)
            state["lambda_m"] = min(state["lambda_m"], target)
        state["prev"] = v_cloud.copy()
        return _Pairs(np.flatnonzero(ok1), faces[f1[ok1]], torch.as_tensor(b1[ok1], dtype=dtype),
                      torch.as_tensor(n1[ok1], dtype=dtype),
                      np.flatnonzero(ok2), k2[ok2], torch.as_tensor(normals[k2[ok2]], dtype=dtype), sigma)

    def objective(v_cloud: torch.Tensor, pairs: _Pairs, free: tuple[str, ...]) -> tuple[torch.Tensor, torch.Tensor]:
        on_surface = (pairs.c_bary[:, :, None] * v_cloud[pairs.c_tri]).sum(1)
        e1 = _residual(P_sub[pairs.c_i] - on_surface, pairs.c_n, config.tangential_weight)
        e2 = _residual(v_cloud[pairs.m_j] - P_all[pairs.m_k], pairs.m_n, 0.0)
        w2 = config.model_to_cloud_weight
        robust = (_geman_mcclure(e1, pairs.sigma).sum() + w2 * _geman_mcclure(e2, pairs.sigma).sum()) / (
            len(e1) + w2 * len(e2))
        data = (robust + 1e-12).sqrt()
        theta = model.theta
        loss = data + state["lambda_m"] * regularizer(theta[None])[0] \
            + config.lambda_x * limit_loss(theta[None], model.low, model.high)[0]
        loss = loss + config.lambda_z * model.z.square().sum() + config.lambda_expressions * model.c.square().sum()
        if lm_ids_t is not None:
            lm = ((v_cloud[lm_ids_t] - lm_pos_t) ** 2).sum(-1).mean().sqrt()
            loss = loss + config.lambda_landmarks * lm
        return loss, e1.detach().clamp_max((3 * pairs.sigma) ** 2).mean().sqrt()

    reports: list[StageReport] = []
    lrs = {"joints": [(model.theta_n, config.lr_joints)], "latent": [(model.z, config.lr_latent)],
           "expressions": [(model.c, config.lr_expressions)],
           "pose": [(model.rotvec, config.lr_rotation), (model.translation, config.lr_translation)]
           + ([(model.log_scale, config.lr_log_scale)] if config.fit_scale else [])}
    if neural is not None:
        for p in neural.decoder.parameters():
            p.requires_grad_(False)
    t_fit = time.perf_counter()
    try:
        for stage in config.stages:
            free = tuple(g for g in stage.free if not (g == "latent" and neural is None))
            if stage.iterations == 0 or not free:
                continue
            t0 = time.perf_counter()
            record = {"start": float("nan"), "loss": float("nan"), "data": float("nan"), "pairs": None}

            def step_loss(pairs: _Pairs) -> torch.Tensor:
                v_cloud = model.to_cloud(model.rig_vertices(free))
                loss, data_rms_t = objective(v_cloud, pairs, free)
                record["loss"], record["data"] = float(loss.detach()), float(data_rms_t)
                if record["start"] != record["start"]:
                    record["start"] = record["loss"]
                return loss

            opt = torch.optim.Adam([{"params": [t], "lr": lr} for g in free for t, lr in lrs[g]])
            for it in range(stage.iterations):  # rebuild -> forward -> loss -> backward -> step -> project
                if it % config.correspondence_every == 0:
                    with torch.no_grad():
                        record["pairs"] = rebuild(model.to_cloud(model.rig_vertices()).numpy().astype(np.float64))
                loss = step_loss(record["pairs"])
                if not torch.isfinite(loss):
                    raise FloatingPointError(f"fit-scan diverged in stage {stage.name!r} (non-finite loss); "
                                             f"try smaller learning rates in the config")
                opt.zero_grad()
                loss.backward()
                opt.step()
                model.clamp_expressions()
                if progress is not None:
                    progress(stage.name, it + 1, stage.iterations)
            pairs = record["pairs"]
            loss_start, loss_value, data_rms = record["start"], record["loss"], record["data"]
            reports.append(StageReport(stage.name, free, stage.iterations, loss_start, loss_value, data_rms,
                                       state["lambda_m"], len(pairs.c_i), len(pairs.m_j),
                                       time.perf_counter() - t0))
    finally:
        if neural is not None:
            for p in neural.decoder.parameters():
                p.requires_grad_(True)
    with torch.no_grad():
        v_rig = model.rig_vertices()
        v_cloud = model.to_cloud(v_rig)
        rot = model.rotation().numpy().astype(np.float64)
    t_end = time.perf_counter()
    return ScanFit(theta=model.theta.detach().numpy().astype(np.float64), z=model.z.detach().numpy().astype(np.float64),
                   expressions=model.c.detach().numpy().astype(np.float64), rotation=rot,
                   translation=model.translation.detach().numpy().astype(np.float64), scale=model.scale,
                   vertices=v_cloud.numpy().astype(np.float64), rig_vertices=v_rig.numpy().astype(np.float64),
                   prealign=align, stages=tuple(reports),
                   timings={"prealign": t_prealign, "fit": t_end - t_fit, "total": t_end - t_start})


def scan_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Exact distance (mm) from every point ``(N, 3)`` to the mesh surface, ``(N,)``."""
    return MeshDistance(vertices, faces).query(points)[0]
