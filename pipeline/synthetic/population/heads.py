"""Drawing and making one synthetic head: random feature coefficients (:func:`sample_coefficients`), the
redraw of heads whose skin folds (:func:`flipped_skin_faces`, :func:`sample_head`) and the head itself
(:func:`synthesize_heads`). See :mod:`pipeline.synthetic.population`; millimetres.
"""

from __future__ import annotations

import numpy as np

from pipeline.synthetic.population.features import _check_coefficients, _feature_table, feature_basis, feature_mask
from pipeline.synthetic.population.phenotypes import (
    _check_count,
    _check_phenotypes,
    _generator,
    phenotype_displacements,
    sample_phenotypes,
)
from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.errors import InputError
from rig.geometry import face_normals
from rig.template import HIDDEN_REGIONS

__all__ = [
    "ASYM_NOISE_SD",
    "ASYM_SLIDER_SD",
    "HEAD_SHAPE_SD",
    "LOCAL_SD",
    "MAX_DRAWS",
    "check_seed",
    "flipped_against",
    "flipped_skin_faces",
    "sample_coefficients",
    "sample_head",
    "synthesize_heads",
]


LOCAL_SD = 0.25
"""Standard deviation of a ``local`` feature (shared by the two sides of a pair)."""
ASYM_NOISE_SD = 0.05
"""Standard deviation of each side's own noise on a left/right pair, and of an antisymmetric target."""
ASYM_SLIDER_SD = 0.3
"""Standard deviation of an ``asym`` slider (held-out heads only)."""
HEAD_SHAPE_SD = 0.25
"""Scale of the half-normal a head shape is drawn from (held-out heads only)."""
MAX_DRAWS = 200
"""A head whose draws all fold the skin raises after this many (each is accepted with p ~ 0.4-0.5)."""


def sample_coefficients(rng: np.random.Generator | int, n: int, shifted: bool = False) -> np.ndarray:
    """Random feature coefficients for ``n`` heads (module docstring, "Distributions"): the proposal;
    :func:`sample_head` redraws the ones that fold the skin.

    Parameters
    ----------
    rng : numpy.random.Generator or int
        The random generator (or a seed for ``np.random.default_rng``).
    n : int
        Number of heads, >= 0.
    shifted : bool
        Also draw the ``asym`` sliders and head shapes (the held-out distribution); else they are 0.

    Returns
    -------
    numpy.ndarray
        ``(n, M)`` float64 slider values in :data:`FEATURE_NAMES` order, within each feature's range.
    """
    n = _check_count(n)
    rng = _generator(rng)
    table = _feature_table()
    index = {f.name: i for i, f in enumerate(table)}
    c = np.zeros((n, len(table)))
    local = [i for i, f in enumerate(table) if f.kind == "local" and f.symmetry != "right"]
    draws = rng.normal(0.0, 1.0, (n, len(local)))
    noise = rng.normal(0.0, ASYM_NOISE_SD, (n, len(local), 2))
    for j, i in enumerate(local):
        f = table[i]
        if f.symmetry == "symmetric":
            c[:, i] = LOCAL_SD * draws[:, j]
        elif f.symmetry == "antisymmetric":
            c[:, i] = ASYM_NOISE_SD * draws[:, j]
        else:  # a left feature and its right partner: one shared value, each side its own noise
            c[:, i] = LOCAL_SD * draws[:, j] + noise[:, j, 0]
            c[:, index[f.mirror]] = LOCAL_SD * draws[:, j] + noise[:, j, 1]
    if shifted:
        asym, shapes = feature_mask("asym"), feature_mask("head_shape")
        c[:, asym] = rng.normal(0.0, ASYM_SLIDER_SD, (n, int(asym.sum())))
        c[:, shapes] = np.abs(rng.normal(0.0, HEAD_SHAPE_SD, (n, int(shapes.sum()))))
    low = np.array([f.low for f in table])
    high = np.array([f.high for f in table])
    return np.clip(c, low, high)


def flipped_against(vertices: np.ndarray, reference: np.ndarray, asset: RigAsset) -> np.ndarray:
    """How many visible skin triangles (no vertex in :data:`rig.template.HIDDEN_REGIONS`) of each head
    ``(n, V, 3)`` (or ``(V, 3)``) are turned by 90 degrees or more from ``reference`` ``(V, 3)``'s."""
    faces = _skin_faces(asset)
    v = np.asarray(vertices, float)
    one = v.ndim == 2
    v = v[None] if one else v
    count = ((face_normals(v, faces) * face_normals(np.asarray(reference, float), faces)).sum(-1) <= 0.0).sum(1)
    return count.astype(np.int64)[0] if one else count.astype(np.int64)


@cached_per_asset
def _skin_faces(asset: RigAsset) -> np.ndarray:
    return asset.faces[~asset.region_mask(*HIDDEN_REGIONS)[asset.faces].any(1)]


@cached_per_asset
def _skin_face_normals(asset: RigAsset) -> tuple[np.ndarray, np.ndarray]:
    """The skin triangles (no vertex hidden) and their template normals (unnormalised)."""
    faces = asset.faces[~asset.region_mask(*HIDDEN_REGIONS)[asset.faces].any(1)]
    return faces, face_normals(feature_basis(asset).template, faces)


def flipped_skin_faces(vertices: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """How many skin triangles of each head are turned by 90 degrees or more from MakeHuman's average head
    (the MakeHuman population's template, :attr:`FeatureBasis.template`).

    Parameters
    ----------
    vertices : array_like
        ``(n, V, 3)`` (or ``(V, 3)``) heads in the template's vertex order, mm.
    asset : RigAsset, optional
        The template (default: :func:`rig.asset.load_asset`).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` int64 (a scalar for one head): triangles with no vertex in
        :data:`rig.template.HIDDEN_REGIONS` whose normal makes an angle >= 90 degrees with the template's.
    """
    asset = load_asset() if asset is None else asset
    v = np.asarray(vertices, float)
    one = v.ndim == 2
    v = v[None] if one else v
    faces, n0 = _skin_face_normals(asset)
    n = face_normals(v, faces)
    count = ((n * n0).sum(-1) <= 0.0).sum(1).astype(np.int64)
    return count[0] if one else count


def check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def _draw_head(seed: int, shifted: bool, asset: RigAsset) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(phenotype, coefficients, vertices, draws)`` of the head of ``seed`` (see :func:`sample_head`)."""
    rng = np.random.default_rng(check_seed(seed))
    for draws in range(1, MAX_DRAWS + 1):
        phenotype = sample_phenotypes(rng, 1)[0]
        coefficients = sample_coefficients(rng, 1, shifted)[0]
        vertices = synthesize_heads(coefficients, phenotype, asset)
        if flipped_skin_faces(vertices, asset) == 0:
            return phenotype, coefficients, vertices, draws
    raise RuntimeError(
        f"sample_head: {MAX_DRAWS} draws of seed {seed} all fold the skin (this should not happen: "
        f"each draw is accepted with a probability of ~0.4-0.5)"
    )


def sample_head(seed: int, shifted: bool = False, asset: RigAsset | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One head's ``(phenotype (P,), coefficients (M,))`` from its integer seed, as :func:`population_split`
    draws every head: with ``rng = np.random.default_rng(seed)``, ``sample_phenotypes(rng, 1)`` then
    ``sample_coefficients(rng, 1, shifted)``, repeated from the same ``rng`` until the head has no skin
    triangle turned by 90 degrees or more (:func:`flipped_skin_faces`; module docstring, "Folds")."""
    phenotype, coefficients, _, _ = _draw_head(seed, shifted, load_asset() if asset is None else asset)
    return phenotype, coefficients


def synthesize_heads(
    coefficients: np.ndarray, phenotypes: np.ndarray | None = None, asset: RigAsset | None = None
) -> np.ndarray:
    """Identity heads: template + phenotype part + feature displacements (module docstring).

    Parameters
    ----------
    coefficients : array_like
        ``(n, M)`` (or ``(M,)``) slider values in :data:`FEATURE_NAMES` order.
    phenotypes : array_like, optional
        ``(n, P)`` (or ``(P,)``, or ``(1, P)`` for all heads) in :data:`PHENOTYPE_NAMES` order; default: the
        template's adult average (no phenotype part).
    asset : RigAsset, optional
        The template (default: :func:`rig.asset.load_asset`); it must be the MakeHuman template.

    Returns
    -------
    numpy.ndarray
        ``(n, V, 3)`` float64 vertices in mm (``(V, 3)`` for a 1-D input), in the template's vertex order.
    """
    asset = load_asset() if asset is None else asset
    basis = feature_basis(asset)
    c = _check_coefficients(coefficients, len(basis.names))
    heads = basis.template + basis.displacements(c)
    if phenotypes is not None:
        p = _check_phenotypes(phenotypes)
        if len(p) not in (1, len(c)):
            raise InputError(f"phenotypes must have one row per head ({len(c)}) or one row; got {len(p)}")
        heads = heads + phenotype_displacements(p, asset)
    return heads[0] if np.ndim(coefficients) == 1 else heads
