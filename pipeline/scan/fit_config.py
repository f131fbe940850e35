"""The settings of a point-cloud fit (``jnr fit-scan``): the schedule, learning rates, priors,
correspondences and pre-alignment (``configs/fit_scan.yaml`` overrides them)."""

from __future__ import annotations

from dataclasses import dataclass, field

from pipeline.config import SIGNED
from pipeline.fitting.engine import LearningRates, Stage
from pipeline.fitting.priors import PriorWeights
from rig.errors import InputError


def jnr_schedule(
    joint_iterations: int = 25,
    latent_iterations: int = 5,
    expression_iterations: int = 25,
    identity_cycles: int = 1,
    outer_cycles: int = 2,
    coarse_iterations: int = 25,
) -> tuple[Stage, ...]:
    """JNR 4.3's schedule: (joints, then Z) x ``identity_cycles``, then expressions; all x ``outer_cycles``.

    Before it, a coarse stage (pose and expressions, ``coarse_iterations``; 0 leaves it out) lets the
    expressions take up large deformations such as an open jaw: started with the joints, the fit
    explains an open mouth with joint motion and stays in that local minimum (measured on the rig's own
    posed, expressive vertices fitted as a cloud: ``docs/fit_scan.md``). JNR runs 500 iterations per
    stage on a GPU; the defaults are scaled to a 2-core CPU: 135 steps, chosen on simulated scans of the
    ``test`` split's ICT identities (4 neutral, 3 expressive; not the benchmark's held-out heads) against the
    earlier 260 steps and shorter schedules: the lowest face error of those tried, in about half the earlier
    time (the table: ``docs/fit_scan.md``, "Speed").
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
    min_facing: float = field(default=0.2, metadata=SIGNED)  # a cosine: may be negative
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
        from pipeline.fitting.state import scan_kinds  # the head models a scan fit takes

        if self.skinning not in scan_kinds():
            known = " or ".join(repr(k) for k in scan_kinds())
            raise InputError(f"skinning must be {known}, got {self.skinning!r}")
        if not isinstance(self.asm_components, int) or not 1 <= self.asm_components <= 8:
            raise InputError(f"asm_components must be an int in [1, 8], got {self.asm_components!r}")
