"""Synthetic multi-view photo sets of one held-out head, with known truth (issue 15).

Several uncalibrated photos of one person: the same held-out head (never seen in training) and the same
albedo in every view (:func:`pipeline.synthetic.photos.albedo.synthesize_albedo`, drawn once), each view with its
own random head pose (yaw within ``yaw_deg_range``, default ±60°; pitch and roll as
:class:`~pipeline.synthetic.photos.settings.PhotoSettings`), its own focal length (``focal_factor_range``), light,
background and landmark noise, and a small expression of its own: ICT's 53 expression shapes
(:mod:`pipeline.synthetic.expressive`, not the rig's ARKit shapes), sampled as for the expressive heads and
scaled by ``expression_scale`` (default 0.25: strengths 0.1-0.25 of ICT's full expression). Each view is
path-traced by :func:`render.reference.render_reference` through
:func:`~pipeline.synthetic.photos.simulate.simulate_photo`
(a renderer and light model unlike the fitting ones).

The truth of the identity is :attr:`SyntheticViews.neutral_vertices` (the head without expression, rig
space, mm); each view's own mesh (with its expression) is ``photos[k].gt_vertices``.

Deterministic given ``(seed, index)``: view ``k`` of a set of ``n`` views is the same for every ``n > k``,
so the 3-view set of a head is the first three views of its 10-view set.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field, replace

import numpy as np

from pipeline.synthetic.expressive import expressive_offsets, sample_expression_coefficients
from pipeline.synthetic.photos.albedo import synthesize_albedo
from pipeline.synthetic.photos.settings import PhotoSettings, SyntheticPhoto
from pipeline.synthetic.photos.simulate import simulate_photo
from pipeline.synthetic.population import SPLIT_SIZES, population_split
from rig.asset import RigAsset, load_asset
from rig.errors import InputError

__all__ = ["MultiViewSettings", "SyntheticViews", "simulate_views", "synthetic_views"]

_VIEWS_STREAM = zlib.crc32(b"synthetic-multiview")


@dataclass(frozen=True)
class MultiViewSettings:
    """How :func:`simulate_views` varies the views.

    Attributes:
        photo: the camera, light and albedo distributions of each view
            (:class:`~pipeline.synthetic.photos.settings.PhotoSettings`); its ``yaw_deg_range`` is replaced by
            :attr:`yaw_deg_range`.
        yaw_deg_range: head yaw of each view, degrees (uniform).
        expression_scale: factor on the sampled ICT expression coefficients of each view (0: the
            neutral head in every view).
    """

    photo: PhotoSettings = field(default_factory=PhotoSettings)
    yaw_deg_range: tuple[float, float] = (-60.0, 60.0)
    expression_scale: float = 0.25

    def __post_init__(self) -> None:
        if not isinstance(self.photo, PhotoSettings):
            raise TypeError(f"MultiViewSettings: photo must be a PhotoSettings, got {type(self.photo).__name__}")
        lo, hi = (float(x) for x in self.yaw_deg_range)
        if not (-90.0 <= lo <= hi <= 90.0):
            raise InputError(
                f"MultiViewSettings: yaw_deg_range must be (low, high) within [-90, 90], got {self.yaw_deg_range!r}"
            )
        if not (np.isfinite(self.expression_scale) and 0.0 <= self.expression_scale <= 1.0):
            raise InputError(f"MultiViewSettings: expression_scale must be in [0, 1], got {self.expression_scale!r}")


@dataclass(frozen=True)
class SyntheticViews:
    """``N`` synthetic photos of one head (``V`` vertices).

    Attributes:
        photos: ``N`` :class:`~pipeline.synthetic.photos.settings.SyntheticPhoto`, each with its pose, focal, landmarks
            and its own expressive mesh ``gt_vertices`` (rig space, mm).
        neutral_vertices: ``(V, 3)`` float64 the head without expression, rig space, mm: the identity.
        expression_coefficients: ``(N, 53)`` the ICT expression coefficients of each view
            (:data:`pipeline.synthetic.expressive.EXPRESSIVE_FEATURE_NAMES`).
        albedo: ``(V, 3)`` linear RGB, the same in every view.
        name: e.g. ``heldout_020``.
    """

    photos: tuple[SyntheticPhoto, ...]
    neutral_vertices: np.ndarray
    expression_coefficients: np.ndarray
    albedo: np.ndarray
    name: str

    @property
    def yaw_deg(self) -> np.ndarray:
        """``(N,)`` each view's head yaw, degrees."""
        return np.array([p.yaw_deg for p in self.photos])

    def subset(self, n: int) -> SyntheticViews:
        """The first ``n`` views."""
        if not 1 <= n <= len(self.photos):
            raise InputError(f"SyntheticViews.subset: n must be in [1, {len(self.photos)}], got {n}")
        return replace(self, photos=self.photos[:n], expression_coefficients=self.expression_coefficients[:n])


def simulate_views(
    neutral_vertices,
    n_views: int,
    rng: np.random.Generator | int,
    settings: MultiViewSettings = MultiViewSettings(),
    asset: RigAsset | None = None,
    *,
    name: str = "",
    render: bool = True,
) -> SyntheticViews:
    """Photograph one head ``n_views`` times (module docstring).

    Args:
        neutral_vertices: ``(V, 3)`` the head without expression, rig space, mm (template topology).
        n_views: number of photos, >= 1.
        rng: ``np.random.Generator`` or integer seed. The albedo is drawn first, then each view from its own
            child stream (view ``k`` does not depend on ``n_views``).
        settings: :class:`MultiViewSettings`.
        asset: the template (default :func:`rig.asset.load_asset`).
        name: the set's name; view ``k`` is named ``{name}_view{k:02d}``.
        render: False: no path tracing (poses, cameras and landmarks only; black images).

    Returns:
        :class:`SyntheticViews`.

    Raises:
        ValueError: bad ``n_views`` or vertices, or :func:`~pipeline.synthetic.photos.simulate.simulate_photo`'s errors.
    """
    if isinstance(n_views, bool) or not isinstance(n_views, (int, np.integer)) or n_views < 1:
        raise InputError(f"simulate_views: n_views must be an integer >= 1, got {n_views!r}")
    asset = load_asset() if asset is None else asset
    v = np.asarray(neutral_vertices, np.float64)
    if v.shape != asset.vertices.shape or not np.isfinite(v).all():
        raise InputError(f"simulate_views: neutral_vertices must be finite {asset.vertices.shape}, got {v.shape}")
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    photo_settings = replace(settings.photo, yaw_deg_range=tuple(settings.yaw_deg_range))
    albedo = synthesize_albedo(rng, asset, settings=photo_settings)
    children = rng.bit_generator.seed_seq.spawn(n_views) if hasattr(rng.bit_generator, "seed_seq") else None
    photos, coefficients = [], []
    for k in range(int(n_views)):
        view_rng = np.random.default_rng(children[k] if children is not None else rng.integers(2**63))
        c = sample_expression_coefficients(view_rng, 1)[0] * settings.expression_scale
        coefficients.append(c)
        expressive = v + expressive_offsets(c, asset)
        photos.append(
            simulate_photo(
                expressive, view_rng, photo_settings, asset, name=f"{name}_view{k:02d}", albedo=albedo, render=render
            )
        )
    return SyntheticViews(
        photos=tuple(photos),
        neutral_vertices=v,
        expression_coefficients=np.array(coefficients),
        albedo=albedo,
        name=str(name),
    )


def synthetic_views(
    index: int, n_views: int, *, seed: int = 0, settings: MultiViewSettings = MultiViewSettings(), render: bool = True
) -> SyntheticViews:
    """``n_views`` photos of held-out head ``index`` (``population_split("heldout", 0)``, 0..99).

    The generator is seeded from ``(seed, index)``: the first ``k`` views are the same for any ``n_views >= k``.

    Example:
        >>> views = synthetic_views(20, 3, render=False)
        >>> len(views.photos), views.photos[0].landmarks2d.shape
        (3, (68, 2))
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"synthetic_views: seed must be a non-negative integer, got {seed!r}")
    n_heads = SPLIT_SIZES["heldout"]
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < n_heads:
        raise InputError(f"synthetic_views: index must be an integer in [0, {n_heads - 1}], got {index!r}")
    population = population_split("heldout", 0, first=int(index) + 1)  # the same heads, without making all 100
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index), _VIEWS_STREAM]))
    return simulate_views(
        population.vertices[int(index)], n_views, rng, settings, name=population.names[int(index)], render=render
    )
