"""ICT's 53 expression shapes on the template: their names, facial areas and limits, the offsets of a
coefficient vector, and how much of each offset lies outside the span of the rig's own 52 ARKit shapes.

The narrative (what is independent of the rig's basis, the features, the mirror asymmetry, the sampling and
the limits) is :mod:`pipeline.synthetic.expressive`'s docstring; that module samples the expressions, makes
the expressive splits and re-exports every public name here.

Coordinates: millimetres, right-handed, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import numpy as np

from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.errors import InputError, SetupError
from rig.expressions import EXPRESSION_NAMES, ExpressionModel
from rig.ict.modes import expression_shapes

EXPRESSION_BASIS = "ict"
"""The expression basis of every head: ICT's 53 expression shapes (:func:`rig.ict.modes.expression_shapes`)."""

EXPRESSIVE_FEATURE_NAMES: tuple[str, ...] = (
    "browDown_L",
    "browDown_R",
    "browInnerUp_L",
    "browInnerUp_R",
    "browOuterUp_L",
    "browOuterUp_R",
    "cheekPuff_L",
    "cheekPuff_R",
    "cheekSquint_L",
    "cheekSquint_R",
    "eyeBlink_L",
    "eyeBlink_R",
    "eyeLookDown_L",
    "eyeLookDown_R",
    "eyeLookIn_L",
    "eyeLookIn_R",
    "eyeLookOut_L",
    "eyeLookOut_R",
    "eyeLookUp_L",
    "eyeLookUp_R",
    "eyeSquint_L",
    "eyeSquint_R",
    "eyeWide_L",
    "eyeWide_R",
    "jawForward",
    "jawLeft",
    "jawOpen",
    "jawRight",
    "mouthClose",
    "mouthDimple_L",
    "mouthDimple_R",
    "mouthFrown_L",
    "mouthFrown_R",
    "mouthFunnel",
    "mouthLeft",
    "mouthLowerDown_L",
    "mouthLowerDown_R",
    "mouthPress_L",
    "mouthPress_R",
    "mouthPucker",
    "mouthRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthSmile_L",
    "mouthSmile_R",
    "mouthStretch_L",
    "mouthStretch_R",
    "mouthUpperUp_L",
    "mouthUpperUp_R",
    "noseSneer_L",
    "noseSneer_R",
)
"""ICT's 53 expression names (its spelling, its order: :attr:`rig.ict.data.IctModel.expression_names`): the
coefficient order."""

EXPRESSIVE_LIMITS: dict[str, tuple[float, float]] = {n: (0.0, 1.0) for n in EXPRESSIVE_FEATURE_NAMES}
"""Coefficient limits per feature: all ``[0, 1]``."""

COMPANIONS: dict[str, str] = {"mouthClose": "jawOpen"}
"""Correctives and the shape they correct: the sampler never draws ``mouthClose`` without as much
``jawOpen`` (:mod:`pipeline.synthetic.expressive`'s docstring, Sampling)."""

_SIDE_TWINS = {"jawLeft": "jawRight", "mouthLeft": "mouthRight"}


def _twin(name: str) -> str:
    if name.endswith("_L"):
        return name[:-2] + "_R"
    if name.endswith("_R"):
        return name[:-2] + "_L"
    for left, right in _SIDE_TWINS.items():
        if name == left:
            return right
        if name == right:
            return left
    return name


EXPRESSIVE_PAIRS: tuple[tuple[str, str], ...] = tuple(
    (n, _twin(n)) for n in EXPRESSIVE_FEATURE_NAMES if n.endswith("_L") or n in _SIDE_TWINS
)
"""The 22 ``(left, right)`` pairs (``X_L``/``X_R``, ``jawLeft``/``jawRight``, ``mouthLeft``/``mouthRight``;
``left`` = the subject's left, +X): mirror images of each other to within 0.6 mm, kept as captured
(:mod:`pipeline.synthetic.expressive`'s docstring, Mirror); the other 9 shapes are midline shapes."""


def _group(name: str) -> str:
    if name.startswith(("mouth", "jaw")):
        return "mouth"
    if name.startswith("nose"):
        return "nose"
    if name.startswith("cheek"):
        return "cheeks"
    side = name[-1]  # eye... and brow... end in _L / _R
    return ("eye_" if name.startswith("eye") else "brow_") + side


EXPRESSIVE_GROUPS: dict[str, str] = {n: _group(n) for n in EXPRESSIVE_FEATURE_NAMES}
"""Facial area of each shape: ``eye_L``, ``eye_R`` (blink, look, squint, wide), ``brow_L``, ``brow_R``,
``nose`` (sneer), ``cheeks`` (puff, squint), ``mouth`` (the mouth and jaw shapes): the sampler keeps the
drawn strengths of one area's active shapes summing to at most 1."""

SPAN_EXCLUDED_REGIONS: tuple[str, ...] = ("teeth", "tongue")
"""Regions :func:`span_residuals` leaves out: the mouth's rigid insides, which a scan or photo does not see
and which the two bases move differently (the rig's ``jawOpen`` carries them with the jaw, 31 mm; ICT's
data has no teeth or tongue, :mod:`rig.ict.transfer` moves them rigidly with the nearest skin, up to 23 mm).
Counted in, ``jawOpen`` would be 39 % outside the span instead of 36 %; the median over shapes stays
54 %."""


# ----------------------------------------------------------------------------------------------------
# The shapes
# ----------------------------------------------------------------------------------------------------


def expressive_units(asset: RigAsset | None = None) -> np.ndarray:
    """ICT's 53 expression shapes at weight 1 on the template's vertices: ``(53, V, 3)`` float64 mm,
    read-only, in :data:`EXPRESSIVE_FEATURE_NAMES` order; transferred once per asset
    (:func:`rig.ict.modes.expression_shapes`).

    Raises:
        rig.errors.SetupError: the ICT data is missing or its names are not :data:`EXPRESSIVE_FEATURE_NAMES`.
    """
    names, shapes = expression_shapes(load_asset() if asset is None else asset)
    if tuple(names) != EXPRESSIVE_FEATURE_NAMES:
        raise SetupError(
            f"ICT's expression shapes are {list(names)}; this code expects {list(EXPRESSIVE_FEATURE_NAMES)} "
            "(rig/assets/ict/ changed?)"
        )
    return shapes


def _check_coefficients(coefficients) -> tuple[np.ndarray, bool]:
    c = np.asarray(coefficients, dtype=float)
    single = c.ndim == 1
    c = c[None] if single else c
    n_feat = len(EXPRESSIVE_FEATURE_NAMES)
    if c.ndim != 2 or c.shape[1] != n_feat:
        raise InputError(
            f"expressive_offsets: coefficients must have shape (n, {n_feat}) or ({n_feat},), "
            f"got {np.shape(coefficients)}"
        )
    if not np.isfinite(c).all():
        raise InputError("expressive_offsets: coefficients must be finite")
    bad = (c < -1e-9) | (c > 1.0 + 1e-9)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise InputError(
            f"expressive_offsets: coefficient {EXPRESSIVE_FEATURE_NAMES[j]!r} = {c[i, j]} of head {i} "
            f"is outside its limits {EXPRESSIVE_LIMITS[EXPRESSIVE_FEATURE_NAMES[j]]}"
        )
    return c, single


def expressive_offsets(coefficients: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """Expression displacements on the template: ``einsum("nf,fvk->nvk", c, expressive_units(asset))``.

    Args:
        coefficients: ``(n, 53)`` or ``(53,)`` in :data:`EXPRESSIVE_FEATURE_NAMES` order, within ``[0, 1]``.
        asset: the template (default: :func:`rig.asset.load_asset`).

    Returns:
        ``(n, V, 3)`` or ``(V, 3)`` float64 offsets in mm (linear in the coefficients; 0 at 0).

    Raises:
        ValueError: wrong shape, non-finite values or coefficients outside ``[0, 1]``.

    Example:
        >>> c = np.zeros(len(EXPRESSIVE_FEATURE_NAMES)); c[EXPRESSIVE_FEATURE_NAMES.index("jawOpen")] = 0.5
        >>> expressive_offsets(c).shape
        (4874, 3)
    """
    c, single = _check_coefficients(coefficients)
    out = np.einsum("nf,fvk->nvk", c, expressive_units(asset))
    return out[0] if single else out


def expressive_peaks(asset: RigAsset | None = None) -> dict[str, float]:
    """Peak displacement (mm) of each shape alone at coefficient 1."""
    return {
        n: float(np.linalg.norm(u, axis=1).max()) for n, u in zip(EXPRESSIVE_FEATURE_NAMES, expressive_units(asset))
    }


# ----------------------------------------------------------------------------------------------------
# Outside the rig's span
# ----------------------------------------------------------------------------------------------------


@cached_per_asset
def _arkit_span(asset: RigAsset) -> tuple[np.ndarray, np.ndarray]:
    """``(kept (V,) bool, Q (3 K, r))``: an orthonormal basis of the span of the rig's 52 shapes on the kept
    vertices (an SVD, rank ``r``: ``tongueOut`` moves only the tongue, so it is 0 there and ``r = 51``)."""
    import torch

    eye = torch.eye(len(EXPRESSION_NAMES), dtype=torch.float64)
    with torch.no_grad():
        shapes = ExpressionModel(asset, torch.float64)(eye).numpy()  # jawOpen: its displacement at c = 1
    kept = ~asset.region_mask(*SPAN_EXCLUDED_REGIONS)
    u, sv, _ = np.linalg.svd(shapes[:, kept].reshape(len(shapes), -1).T, full_matrices=False)
    return kept, u[:, sv > 1e-9 * sv[0]]


def span_residuals(offsets: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """Fraction of each offset outside the span of the rig's 52 ARKit shapes.

    For an offset ``o`` (``(V, 3)`` mm) this is ``||o - B x*|| / ||o||``, where ``B x*`` is the
    least-squares combination (any real coefficients) of the rig's shapes (the rows of
    :class:`rig.expressions.ExpressionModel`'s basis; ``jawOpen`` linearised as its displacement at
    ``c = 1``) and both norms run over all vertices except :data:`SPAN_EXCLUDED_REGIONS` (``||o||`` is then
    the norm over the vertices it moves). 0: the rig's linear span holds it; 1: orthogonal to every shape.
    A lower bound on what the rig misses (its coefficients are limited to ``[0, 1]``).

    Args:
        offsets: ``(V, 3)`` or ``(n, V, 3)`` mm on the template's vertices.
        asset: the template (default: :func:`rig.asset.load_asset`).

    Returns:
        ``float`` or ``(n,)`` float64 in ``[0, 1]`` (0 for an all-zero offset).
    """
    asset = load_asset() if asset is None else asset
    o = np.asarray(offsets, dtype=float)
    single = o.ndim == 2
    o = o[None] if single else o
    if o.ndim != 3 or o.shape[1:] != asset.vertices.shape:
        raise InputError(
            f"span_residuals: offsets must have shape {asset.vertices.shape} or "
            f"(n, {len(asset.vertices)}, 3), got {np.shape(offsets)}"
        )
    kept, q = _arkit_span(asset)
    x = o[:, kept].reshape(len(o), -1)
    norm = np.linalg.norm(x, axis=1)
    resid = np.linalg.norm(x - (x @ q) @ q.T, axis=1)
    out = np.divide(resid, norm, out=np.zeros_like(norm), where=norm > 0)
    return float(out[0]) if single else out


def unit_span_residuals(asset: RigAsset | None = None) -> dict[str, float]:
    """:func:`span_residuals` of every shape at coefficient 1, by name (median 0.54, least ``jawLeft`` and
    ``jawRight`` 0.34, most ``eyeLookOut_*`` 0.96)."""
    res = span_residuals(expressive_units(asset), asset)
    return dict(zip(EXPRESSIVE_FEATURE_NAMES, (float(r) for r in res)))
