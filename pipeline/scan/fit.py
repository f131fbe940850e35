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
   frame), ``joints`` (the 107 channels), ``latent`` (Z) and ``expressions`` (the 52 ARKit coefficients) with
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

import dataclasses
import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import torch

from landmarks.points3d import LandmarkError, check_landmarks_3d, match_landmarks
from pipeline.fitting.engine import StageLog, run_schedule
from pipeline.fitting.state import scan_state_class
from pipeline.scan.fit_config import FitScanConfig
from pipeline.scan.objective import ScanObjective
from pipeline.scan.pointcloud.cloud import CloudError, PointCloud
from pipeline.scan.pointcloud.normals import boundary_mask, estimate_normals
from pipeline.scan.pointcloud.units import UNIT_NAMES, UNIT_SCALE_TO_MM, cloud_extent, plausible_units
from pipeline.scan.registration import (
    INLIER_MM,
    SCALE_BOUNDS,
    RigidAlignment,
    face_coverage,
    rigid_prealign,
    view_direction,
)
from rig.expressions import ExpressionModel
from rig.geometry import Similarity
from rig.head_model import HeadParams
from rig.model import JointRig
from rig.optim import Progress, torch_threads
from rig.skinning.neural import NeuralSkinning
from rig.template import FACE_REGIONS

_log = logging.getLogger(__name__)


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
            (:func:`rig.skinning.asm.parameters.asm_params_to_dict`); ``theta`` and ``z`` are then zeros.
        head: the fitted head as its head model's parameters (:meth:`pipeline.fitting.state.FitState.head_params`:
            the model's kind and values), what the outputs and readers build the fitted head from.
        clamped: the joint channels the fit's soft limit penalty left outside their limits, projected onto
            them at the end (every fit writes values its own readers accept): ``{name: [fitted, written]}``
            in the channel's unit.
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
    head: HeadParams | None = None
    clamped: dict = field(default_factory=dict)

    @property
    def transform(self) -> Similarity:
        """Rig space -> the cloud's frame as a :class:`rig.geometry.Similarity`."""
        return Similarity(self.rotation, self.translation, self.scale)


def _cloud_normals(cloud: PointCloud, config: FitScanConfig) -> np.ndarray:
    """``(N, 3)`` unit normals of the cloud: its own, or estimated (PCA over ``normals_k`` neighbours)."""
    return (
        cloud.normals
        if cloud.normals is not None
        else estimate_normals(cloud.points, k=config.correspondences.normals_k)
    )


FIT_THREADS = 1
"""Torch threads while :func:`fit_scan` runs (the caller's count is restored after). One head is small (4,874
vertices, batch 1): a second intra-op thread adds a synchronisation to every small operation, which on a
shared 2-core machine stalls the steps (``docs/fit_scan.md``, "Speed", has the measurement)."""


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
    with torch_threads(FIT_THREADS):
        return _fit_scan(
            cloud, config or FitScanConfig(), landmarks, rig, neural, expressions, progress, landmarks_source
        )


def _fit_scan(
    cloud: PointCloud,
    config: FitScanConfig,
    landmarks: Mapping[str, np.ndarray] | None,
    rig: JointRig | None,
    neural: NeuralSkinning | None,
    expressions: ExpressionModel | None,
    progress: Progress | None,
    landmarks_source: str,
) -> ScanFit:
    """:func:`fit_scan` with its arguments, ``config`` given. The fit runs on the cloud moved to the origin
    (float32 keeps 24 bits: a georeferenced cloud 1e8 mm away would be an 8 mm grid); the result is moved
    back in float64."""
    t_start = time.perf_counter()
    origin = 0.5 * (cloud.points.min(0) + cloud.points.max(0))
    cloud = dataclasses.replace(cloud, points=cloud.points - origin)
    if landmarks:
        landmarks = {name: np.asarray(xyz, np.float64) - origin for name, xyz in landmarks.items()}
    rig = rig or JointRig()
    expressions = expressions or ExpressionModel(rig.asset, dtype=rig.template.dtype)
    state = scan_state_class(config.skinning).for_scan(rig, neural, expressions, config, fit_scale=config.fit_scale)
    rng = np.random.default_rng(config.seed)
    normals = _cloud_normals(cloud, config)
    # Model -> cloud pairs only come from vertices facing the sensor (None: a cloud all around the head).
    view_dir = view_direction(normals)
    with torch.no_grad():
        start_vertices = state.rig_vertices().double().numpy()  # the head the fit starts from, rig space
    align, marks = _prealign(cloud, normals, view_dir, config, start_vertices, landmarks, landmarks_source, rig.asset)
    border = boundary_mask(cloud.points, k=config.correspondences.boundary_k)
    t_prealign = time.perf_counter() - t_start

    state.set_pose(align.rotation, align.translation, align.scale)
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
    clamped = state.finish()
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
        translation=state.translation.detach().double().numpy() + origin,
        scale=state.scale,
        vertices=v_cloud.double().numpy() + origin,
        rig_vertices=v_rig.double().numpy(),
        prealign=dataclasses.replace(align, translation=align.translation + origin),
        stages=stages,
        timings={"prealign": t_prealign, "fit": t_end - t_fit, "total": t_end - t_start},
        asm=state.model_entry(),
        head=state.head_params(),
        clamped=clamped,
    )


def _prealign(
    cloud: PointCloud,
    normals: np.ndarray,
    view_dir: np.ndarray | None,
    config: FitScanConfig,
    start_vertices: np.ndarray,
    landmarks: Mapping[str, np.ndarray] | None,
    landmarks_source: str,
    asset,
) -> tuple[RigidAlignment, tuple[np.ndarray, np.ndarray] | None]:
    """Check the landmarks, align the start head ``start_vertices (V, 3)`` (rig space, mm) rigidly and reject a
    cloud that is not a head. Returns the alignment and the matched landmarks ``(vertex ids, positions)``
    (None without landmarks)."""
    points = cloud.points
    marks = None
    if landmarks:
        try:
            lm_ids, lm_pos, lm_names = match_landmarks(landmarks, asset)
        except LandmarkError as exc:
            raise LandmarkError(f"{landmarks_source}: {exc}") from None
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
    pairs = None if marks is None else (start_vertices[marks[0]], marks[1])
    align = _align(points, normals, start_vertices, asset, config, pairs)
    where = f"{cloud.path}: " if cloud.path else ""
    if align.inlier_fraction < config.prealign.min_inlier_fraction:
        sampled = f" (a random {len(points)} of its {cloud.input_points})" if cloud.input_points > len(points) else ""
        raise CloudError(
            f"{where}the cloud does not look like a head: after the best rigid alignment only "
            f"{100 * align.inlier_fraction:.0f} % of its points{sampled} lie within {INLIER_MM:g} mm of the head "
            f"model (need {100 * config.prealign.min_inlier_fraction:.0f} %)"
        )
    if marks is None:
        _check_frame_and_units(cloud, normals, view_dir, align, config, start_vertices, asset, where)
    return align, marks


FRAME_CHECK_INLIERS = 0.9
"""A cloud whose pre-alignment puts fewer of its points near the head than this is also tried turned over
(:func:`_check_frame_and_units`); right-side-up synthetic scans score 0.93-0.98, turned over 0.67-0.79."""
UNITS_CHECK_COVERAGE = 0.6
"""A cloud with detected units that covers less of the aligned head's face than this (or needs a bound of
:data:`pipeline.scan.registration.SCALE_BOUNDS`) is also tried in its other plausible units; synthetic scans
cover 0.81-0.99, the same scans shrunk by inches read as cm 0.07-0.53."""


def _align(
    points: np.ndarray,
    normals: np.ndarray,
    model_vertices: np.ndarray,
    asset,
    config: FitScanConfig,
    landmarks: tuple[np.ndarray, np.ndarray] | None = None,
) -> RigidAlignment:
    """:func:`pipeline.scan.registration.rigid_prealign` of the head model ``model_vertices`` onto ``points``
    with the config's search (or the similarity of ``landmarks``: model points, cloud points)."""
    return rigid_prealign(
        points,
        normals,
        model_vertices,
        asset.faces,
        face_mask=asset.region_mask(*FACE_REGIONS),
        seed=config.seed,
        yaw_step_deg=config.prealign.yaw_step_deg,
        with_scale=config.prealign.scale,
        landmarks=landmarks,
    )


def _check_frame_and_units(
    cloud: PointCloud,
    normals: np.ndarray,
    view_dir: np.ndarray | None,
    align: RigidAlignment,
    config: FitScanConfig,
    model_vertices: np.ndarray,
    asset,
    where: str,
) -> None:
    """Refuse, with the evidence, a cloud the head fits far better turned over (a wrong ``--frame``) or in
    other units (inches detected as cm). Only doubtful alignments are checked (:data:`FRAME_CHECK_INLIERS`,
    :data:`UNITS_CHECK_COVERAGE`): a good scan costs nothing; a doubtful one one more pre-alignment per
    alternative (timed in ``docs/fit_scan.md``). The thresholds were chosen on synthetic scans
    (``docs/fit_scan.md``)."""
    from scipy.spatial import cKDTree

    def covered(points: np.ndarray, fit: RigidAlignment, direction: np.ndarray | None) -> float:
        mask = asset.region_mask(*FACE_REGIONS)
        return face_coverage(cKDTree(points), fit, model_vertices, asset.faces, mask, direction)

    def aligned(points: np.ndarray, point_normals: np.ndarray) -> tuple[RigidAlignment, float]:
        fit = _align(points, point_normals, model_vertices, asset, config)
        return fit, covered(points, fit, view_direction(point_normals))

    def pinned(fit: RigidAlignment) -> bool:
        return config.prealign.scale and min(abs(fit.scale - b) for b in SCALE_BOUNDS) < 0.01

    if align.inlier_fraction >= FRAME_CHECK_INLIERS and not cloud.units_detected:
        return  # a good alignment in the units the user gave: nothing to check
    coverage = covered(cloud.points, align, view_dir)
    _log.info(
        "fit-scan: pre-alignment inliers %.2f, face covered %.2f, scale %.3f",
        align.inlier_fraction,
        coverage,
        align.scale,
    )
    if align.inlier_fraction < FRAME_CHECK_INLIERS:
        turn = np.array([1.0, -1.0, -1.0])
        other, other_coverage = aligned(cloud.points * turn, normals * turn)
        if other.inlier_fraction >= align.inlier_fraction + 0.1 and other_coverage > coverage:
            raise CloudError(
                f"{where}the cloud looks upside down in the frame given: turned over (y and z negated), "
                f"{100 * other.inlier_fraction:.0f} % of its points lie within {INLIER_MM:g} mm of the head "
                f"against {100 * align.inlier_fraction:.0f} % as given; check --frame (y-up: +Y up, +Z out of "
                f"the face; opencv: x right, y down, z forward)"
            )
    if not cloud.units_detected or not (pinned(align) or coverage < UNITS_CHECK_COVERAGE):
        return
    extent = cloud_extent(cloud.points)  # mm
    for unit in plausible_units(extent / cloud.scale_to_mm):
        if unit == cloud.units:
            continue
        factor = UNIT_SCALE_TO_MM[unit] / cloud.scale_to_mm
        other, other_coverage = aligned(cloud.points * factor, normals)
        if other_coverage >= coverage + 0.2 and not pinned(other):
            raise CloudError(
                f"{where}read as {UNIT_NAMES[cloud.units]} (detected) the cloud is a head {extent:.0f} mm across: "
                f"the head model fits it at scale {align.scale:.2f} and covers {100 * coverage:.0f} % of its "
                f"face; read as {UNIT_NAMES[unit]} ({extent * factor:.0f} mm) it covers "
                f"{100 * other_coverage:.0f} %: pass --units {unit} (or --units {cloud.units} to fit it as it is)"
            )
