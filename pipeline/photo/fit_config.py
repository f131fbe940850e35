"""The settings of a photo fit (``jnr fit``): the photometric schedule, learning rates, the albedo prior,
:class:`PhotometricConfig` and :class:`FitPhotoConfig` (``configs/fit_photo.yaml`` overrides them)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from pipeline.fitting.engine import LearningRates, Stage
from pipeline.fitting.priors import PriorWeights
from pipeline.fitting.state import FREE_GROUPS
from pipeline.photo.landmark_fit import (
    LandmarkFitConfig,
)
from rig.asset import REGION_NAMES
from rig.errors import InputError
from rig.head_model import head_model_kinds
from rig.template import FACE_REGIONS

PHOTO_GROUPS = FREE_GROUPS + ("identity", "albedo", "light")
LIGHT_MODELS = ("directional", "sh")


PHOTO_LAMBDA_IDENTITY = 0.03
"""Weight of the learned identity prior (:mod:`pipeline.fitting.identity`) in the photo fit, against the
landmark term (mean over the fitted landmarks of half the squared pixel error, Huber); L_m is off.

Chosen on synthetic validation photos (held-out heads 0-5, neutral and expressive, 1 px landmark noise,
true focal; ``benchmarks/bench_fit_photo.py`` scores heads 20 on): NoW-style scan-to-mesh median,
mean over the 12 photos, LM landmark fit: see ``docs/fit_photo.md`` for the table and the previous prior
(L_m = 100 towards the template) it replaced."""

PHOTO_PRIOR = PriorWeights(lambda_m=0.0, lambda_identity=PHOTO_LAMBDA_IDENTITY)
"""The rig priors of the photo fit: the identity prior instead of L_m, the other weights as
:class:`~pipeline.fitting.priors.PriorWeights`."""


MAX_SPP = 1024
"""The most samples per pixel a render may take (the defaults take 2-32)."""


@dataclass(frozen=True)
class PhotoStage(Stage):
    """One stage of the photometric schedule: ``free`` is a subset of ``pose``, ``joints``, ``latent``,
    ``expressions``, ``identity`` (the joint channels along the identity prior's main directions,
    :attr:`PhotometricConfig.identity_components`), ``albedo``, ``light``."""

    groups: ClassVar[tuple[str, ...]] = PHOTO_GROUPS


def identity_schedule(iterations: int = 40) -> tuple[PhotoStage, ...]:
    """The default photometric schedule: one stage of ``iterations`` steps that moves the identity along the
    prior's main directions (``identity``), the albedo held at the face's median colour and the light
    re-fitted before it (``docs/fit_photo.md``: where the albedo is free it takes up the shading that tells the
    shape)."""
    return (PhotoStage("photo identity", ("identity",), iterations),) if iterations > 0 else ()


def photo_schedule(
    appearance_iterations: int = 25,
    joint_iterations: int = 30,
    latent_iterations: int = 15,
    expression_iterations: int = 25,
    final_joint_iterations: int = 25,
) -> tuple[PhotoStage, ...]:
    """JNR 4.3's photometric schedule (120 steps; the default before issue 37): albedo + light; then JNR 4.3's
    alternation (pose + joints, Z, pose + expressions, pose + joints), each with albedo and light. 0 leaves a stage
    out."""
    look = ("albedo", "light")
    stages = (
        PhotoStage("appearance", look, appearance_iterations),
        PhotoStage("photo joints", ("pose", "joints") + look, joint_iterations),
        PhotoStage("photo latent", ("latent",) + look, latent_iterations),
        PhotoStage("photo expressions", ("pose", "expressions") + look, expression_iterations),
        PhotoStage("photo joints 2", ("pose", "joints") + look, final_joint_iterations),
    )
    return tuple(s for s in stages if s.iterations > 0)


@dataclass(frozen=True)
class PhotoLearningRates(LearningRates):
    """Adam steps of the photometric stages (``photometric.lr:`` in YAML): the geometry's groups
    (:class:`pipeline.fitting.engine.LearningRates`) and the appearance."""

    albedo: float = 0.02
    """Per-vertex albedo, linear RGB."""
    light: float = 0.05
    """Ambient and irradiance of the light, linear RGB."""
    identity: float = 0.05
    """The identity subspace's coefficients, in standard deviations of the prior along each direction."""


PHOTO_LEARNING_RATES = PhotoLearningRates(rotation=0.003, translation=0.5, joints=0.004, latent=0.02, expressions=0.02)
"""The photometric stages' steps: smaller than the landmark fit's, which they refine."""


@dataclass(frozen=True)
class AlbedoPrior:
    """Weights of the albedo priors (``photometric.albedo_prior:`` in YAML), each a mean squared difference."""

    smooth: float = 20.0
    """Along mesh edges."""
    symmetry: float = 5.0
    """To the mirror vertex's albedo."""
    mean: float = 0.5
    """To the start colour (the median face colour)."""


@dataclass(frozen=True)
class PhotometricConfig:
    """The photometric stages of :func:`fit_photo` (``photometric:`` in YAML)."""

    enabled: bool = False
    """Run them (``jnr fit --photometric``). Off by default: on 100 synthetic photos the identity stage (a quarter of
    its step, :attr:`identity_step`) brings the fit about 1 % closer to the person, for 11-14 s a photo
    (``docs/fit_photo.md``)."""
    stages: tuple[PhotoStage, ...] = field(default_factory=identity_schedule)
    """The schedule: :func:`identity_schedule` (one stage of the identity along the prior's main directions);
    :func:`photo_schedule` is JNR 4.3's alternation with a per-vertex albedo."""
    render_size: int = 128
    """Side of the square face crop the photometric loss is computed on, pixels."""
    crop_margin: float = 0.25
    """Margin around the landmarks' bounding box (fraction of its size; the top gets twice as much, for
    the forehead)."""
    spp: int = 8
    """Renderer samples per pixel of the shading. 8, not 2: at 2 the loss's Monte Carlo noise from step to step is
    larger than what a step of the identity changes (``docs/fit_photo.md``)."""
    spp_silhouette: int = 1
    """Renderer samples per pixel of the silhouettes' gradients (Mitsuba's ``direct_projective`` ``sppp``). 1, not 8
    as the shading: on the 60 validation photos the stage's whole step changed the s2m by -0.020 mm at 1 and -0.025
    at 8 (the difference's standard error 0.003) in 7.6 s a photo instead of 12.7 (``docs/fit_photo.md``)."""
    lambda_photo: float = 60.0
    """Weight of the photometric term (linear RGB, Charbonnier); chosen on validation photos for the identity stage
    (``docs/fit_photo.md``: 6, 20, 60 and 200 tried against the landmark and identity terms)."""
    lambda_landmarks: float = 1.0
    """Weight of the landmark term during the photometric stages, in the landmark fit's units (px^2 of a face 100 px
    between the eye corners, over the detector's error squared: ``landmarks.noise_px`` / ``dense_noise_px``)."""
    charbonnier_eps: float = 0.01
    """``eps`` of the Charbonnier distance, linear RGB."""
    outlier_mads: float = 3.0
    """Residuals above ``median + outlier_mads * 1.4826 * MAD`` are outliers (re-selected every stage)."""
    face_regions: tuple[str, ...] = FACE_REGIONS
    """Rig regions whose pixels the photometric loss counts (default: no scalp/hair, ears, neck, eyes, mouth)."""
    albedo_prior: AlbedoPrior = field(default_factory=AlbedoPrior)
    lr: PhotoLearningRates = PHOTO_LEARNING_RATES
    prior: PriorWeights = PHOTO_PRIOR
    """The rig priors during the photometric stages (:data:`PHOTO_PRIOR`)."""
    light_model: str = "directional"
    """``directional``: ambient + one directional light (:mod:`render.lighting`), its direction re-picked
    before each stage; ``sh``: second-order spherical harmonics, 9 coefficients per channel on the
    vertex normals (:mod:`pipeline.photo.sh`), least squares before each stage, then optimised."""
    sh_ridge: float = 1e-3
    """Ridge weight of the SH least squares (relative to the design's mean diagonal)."""
    light_directions: int = 64
    """Candidate light directions re-picked before each stage."""
    identity_components: int = 40
    """How many of the identity prior's main directions the group ``identity`` moves the joint channels along
    (:meth:`~pipeline.fitting.rig_state.FitState.set_identity_subspace`)."""
    identity_step: float = 0.25
    """The fraction of the photometric stages' change of the joint channels that is kept: they end at the landmark
    fit's plus ``identity_step`` times that change (pose, expressions and appearance as the stages leave them). The
    stage's full step is closer to the person on average but farther on more photos; a quarter of it was the
    largest gain on validation photos that left no more photos worse than the template than the landmark fit did
    (``docs/fit_photo.md``: 0.25, 0.5, 0.75 and 1 on 60 photos). The stages' logs (``report.json``) are those of
    the stages as they ran, to their whole step."""
    seed: int = 0
    """Renderer sampling seed."""
    reproducible: bool = True
    """Bit-for-bit repeatable fits: the photometric stages run Dr.Jit (:func:`render.backend.reproducible`)
    and torch on one thread, whose gradient scatter-adds otherwise change order from run to run; it costs
    photometric time (``docs/fit_photo.md``). False: faster, not repeatable."""

    def __post_init__(self) -> None:
        if self.render_size < 16:
            raise InputError(f"render_size must be >= 16 pixels, got {self.render_size}")
        if not 1 <= self.spp <= MAX_SPP:
            raise InputError(f"spp must be within [1, {MAX_SPP}], got {self.spp}")
        if not 1 <= self.spp_silhouette <= MAX_SPP:
            raise InputError(f"spp_silhouette must be within [1, {MAX_SPP}], got {self.spp_silhouette}")
        if not self.crop_margin >= 0:
            raise InputError(f"crop_margin must be >= 0, got {self.crop_margin}")
        if self.light_model not in LIGHT_MODELS:
            raise InputError(f"light_model must be one of {list(LIGHT_MODELS)}, got {self.light_model!r}")
        if not 0.0 < self.identity_step <= 1.0:
            raise InputError(f"identity_step must be within (0, 1], got {self.identity_step}")
        if self.identity_components < 1:
            raise InputError(f"identity_components must be >= 1, got {self.identity_components}")
        if self.light_directions < 1:
            raise InputError(f"light_directions must be >= 1, got {self.light_directions}")
        bad = [r for r in self.face_regions if r not in REGION_NAMES]
        if bad or not self.face_regions:
            raise InputError(
                f"face_regions must be a non-empty subset of {list(REGION_NAMES)}, got {list(self.face_regions)}"
            )


OUTPUT_SET_NAMES = ("all", "mesh", "minimal")
"""``outputs.files`` (``jnr fit --outputs``): the named sets of :data:`pipeline.head.folders.PHOTO_OUTPUT_SETS`."""
MESH_UNITS = {"mm": 1.0, "m": 1e-3}
PLY_UP_AXES = ("y", "z")
"""``outputs.ply_up``: the up axis of ``mesh.ply``."""
"""``outputs.units`` (``jnr fit --units``): the unit of ``mesh.obj`` / ``mesh.ply`` and its factor from mm."""


@dataclass(frozen=True)
class OutputsConfig:
    """What the fit's files hold (``outputs.*``; ``jnr fit --units``)."""

    units: str = "mm"
    """The unit of ``mesh.obj`` and ``mesh.ply``: ``mm`` (rig space, the default; every other jnr file and
    ``params.json`` are in mm too) or ``m`` (what Blender and most DCC tools take an OBJ/PLY's numbers for;
    ``mesh.glb`` is in metres either way). Only those two files change."""

    files: str = "all"
    """Which files a photo fit writes (``jnr fit --outputs``): ``all`` (the default: every file of
    :data:`pipeline.head.folders.PHOTO_FOLDER`), ``mesh`` (the meshes, their texture, params, report and
    config) or ``minimal`` (params.json, report.json, config.yaml: ``jnr rig edit`` and the other commands
    rebuild the head from them); :data:`pipeline.head.folders.PHOTO_OUTPUT_SETS`. Fewer files, less time: the
    render and the texture are made only for the files that need them."""

    ply_up: str = "y"
    """The up axis of ``mesh.ply`` (``jnr fit --ply-up``): ``y`` (the default: rig space, as ``mesh.obj``;
    MeshLab, Open3D, CloudCompare and three.js show it upright) or ``z`` (rotated +90 degrees about x, the face
    towards -Y: what Blender's PLY importer takes as upright with its default axes, Forward Y / Up Z).
    ``mesh.obj`` stays Y-up either way (Blender's OBJ importer converts Y-up by default)."""

    def __post_init__(self) -> None:
        if self.ply_up not in PLY_UP_AXES:
            raise InputError(f"outputs.ply_up must be one of {list(PLY_UP_AXES)}, got {self.ply_up!r}")
        if self.units not in MESH_UNITS:
            raise InputError(f"outputs.units must be one of {list(MESH_UNITS)}, got {self.units!r}")
        if self.files not in OUTPUT_SET_NAMES:
            raise InputError(f"outputs.files must be one of {list(OUTPUT_SET_NAMES)}, got {self.files!r}")


@dataclass(frozen=True)
class FitPhotoConfig:
    """Settings of :func:`fit_photo` (``configs/fit_photo.yaml`` holds the defaults)."""

    model: str = "jnr"
    """The head model fitted (a kind registered with :func:`rig.head_model.register_head_model`; the name
    ``params.json`` records as ``model``): ``jnr`` (the joint rig, its priors and photometric stages) or any other
    registered model with flat parameter groups, fitted by the same landmark stages on its own groups
    (:mod:`pipeline.photo.model_fit`; no photometric stages)."""
    landmarks: LandmarkFitConfig = field(default_factory=lambda: LandmarkFitConfig(prior=PHOTO_PRIOR))
    """The landmark fit (Levenberg-Marquardt with the identity prior, :data:`PHOTO_PRIOR`)."""
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    """The photometric stages."""
    outputs: OutputsConfig = field(default_factory=OutputsConfig)
    """The output files (``outputs.units``)."""

    def __post_init__(self) -> None:
        if self.model not in head_model_kinds():
            raise InputError(f"model must be one of {list(head_model_kinds())}, got {self.model!r}")
