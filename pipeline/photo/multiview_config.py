"""The settings of the multi-view fit (:func:`pipeline.photo.multiview.fit_multiview`; ``jnr fit --views``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType

from pipeline.config import SIGNED
from pipeline.fitting.least_squares import LMSettings
from pipeline.photo.fit_config import PHOTO_PRIOR, OutputsConfig
from pipeline.photo.landmark_fit import LandmarkFitConfig
from rig.asset import REGION_NAMES
from rig.errors import InputError
from rig.head_model import head_model_kinds
from rig.template import FACE_REGIONS

PATCHES = ("1-ring",)


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

    Off by default: on rendered synthetic views of held-out heads its gain was small, not on every head, at
    many times the cost of the landmark fit (docs/multiview.md, ``benchmarks/bench_multiview_photometric.py``).
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
    visible_cos: float = field(default=0.3, metadata=SIGNED)  # a cosine: may be negative
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
            raise InputError(f"photometric.patch must be one of {list(PATCHES)}, got {self.patch!r}")
        if self.iterations < 0 or self.visibility_every < 1:
            raise InputError("photometric.iterations must be >= 0 and visibility_every >= 1")
        if self.lambda_pc < 0:
            raise InputError(f"photometric.lambda_pc must be >= 0, got {self.lambda_pc}")
        bad = [r for r in self.regions if r not in REGION_NAMES]
        if bad or not self.regions:
            raise InputError(
                f"photometric.regions must be a non-empty subset of {list(REGION_NAMES)}, got {list(self.regions)}"
            )


@dataclass(frozen=True)
class AsmConfig:
    """The ASM identity model (``skinning: asm``; ``asm:`` in YAML; :mod:`rig.skinning.asm`)."""

    components: int = 2
    """GMM components per joint (ASM-K2, the paper's default)."""
    register_iterations: int = 100
    """``fit_asm`` steps registering ASM to the averaged single-view mesh (ASM App. D.1: 300; 100 here for CPU
    time, docs/multiview.md "Settings")."""
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
    :class:`rig.skinning.asm.AsmRegularizer`'s units) against the views' weighted landmark cost (chosen when it was
    their sum, with true points); a smaller one lets ASM's capacity chase the landmark noise (docs/multiview.md
    "Settings")."""
    register_to: str = "averaged"
    """``averaged``: register to the averaged single-view JNR head (ASM App. D.1); ``refined``: to the JNR
    multi-view head after the joint landmark refinement."""
    lambda_smooth: float = 100.0
    """Weight of the squared uniform Laplacian of the identity's offset from the template (mm^2, mean over
    vertices) in the refinement, against the folds that the landmarks alone let the mixtures make (0: off);
    chosen on a held-out head (docs/multiview.md)."""

    def __post_init__(self) -> None:
        if self.register_to not in ("averaged", "refined"):
            raise InputError(f"asm.register_to must be 'averaged' or 'refined', got {self.register_to!r}")


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
    """Weight of the identity prior, counted once against the views' weighted landmark terms (``view_correlation``,
    ``view_yaw_deg``)."""
    view_correlation: float = 1.0
    """How much the detector's errors are shared between the views of one face, in [0, 1]: every view's landmark
    term is weighed by ``1 / (1 + (N - 1) view_correlation)``, so 0 counts the ``N`` views as independent evidence
    about the identity (their terms summed, as before issue 37) and 1 as one view's worth (their mean). 1: chosen
    on validation views with MediaPipe's points, whose errors the views share (docs/multiview.md)."""
    view_yaw_deg: float = 30.0
    """Each view's landmark term is also weighed by ``1 / (1 + (|yaw| / view_yaw_deg)^4)`` over the largest such
    weight of the set, ``yaw`` the head's yaw in the view's single fit: a detector's points on a face turned
    past ~30 degrees are worse (docs/multiview.md). 0: every view alike."""
    fit_focal: bool = True
    """Fit each view's focal length (``s_k``); False: keep ``f0_k``."""
    outputs: OutputsConfig = field(default_factory=OutputsConfig)
    """The output files (``outputs.units``: mesh.obj / mesh.ply in mm or m)."""
    lambda_focal: float = 10.0
    """Prior ``0.5 lambda_focal s_k^2`` on the log focal change of each view."""
    photometric: PhotoConsistencyConfig = field(default_factory=PhotoConsistencyConfig)
    """Photometric consistency between views (off by default)."""
    skinning: str = "jnr"
    """The identity model: ``jnr`` (the rig's joints), ``asm`` (:mod:`rig.skinning.asm`) or another registered head
    model with flat groups (:mod:`pipeline.photo.multiview_model`)."""
    asm: AsmConfig = field(default_factory=AsmConfig)
    """The ASM identity model's settings."""

    def __post_init__(self) -> None:
        if self.skinning not in head_model_kinds():
            raise InputError(f"skinning must be one of {list(head_model_kinds())}, got {self.skinning!r}")
        if self.refine_iterations < 0:
            raise InputError(f"refine_iterations must be >= 0, got {self.refine_iterations}")
        if self.lambda_identity < 0 or self.lambda_focal < 0:
            raise InputError("lambda_identity and lambda_focal must be >= 0")
        if self.view_yaw_deg < 0:
            raise InputError(f"view_yaw_deg must be >= 0, got {self.view_yaw_deg}")
        if not 0.0 <= self.view_correlation <= 1.0:
            raise InputError(f"view_correlation must be within [0, 1], got {self.view_correlation}")


INDEPENDENT_VIEWS = MappingProxyType({"view_correlation": 0.0, "view_yaw_deg": 0.0})
"""The :class:`MultiViewConfig` settings for points whose errors are independent between the views (the true
points + noise, points placed by hand, a tracker's keyframes): every view's landmark term counted in full, as before
issue 37 (``MultiViewConfig(**INDEPENDENT_VIEWS)``; ``--set view_correlation=0 --set view_yaw_deg=0``)."""
