"""The identity read from a face detector's 3D mesh by a map learned from many rendered heads (issue 37).

A landmark fit treats the detector's points as the person's surface; their errors lean towards the average
face (docs/fit_photo.md, "Where the photo fit loses the shape"), so the fitted identity moves only a little
of the way from the template. Here the detector's 3D mesh (MediaPipe's 478 points with its relative depth) is
instead mapped to the rig's joint channels by a ridge regression learned from photos of thousands of sampled
ICT heads (:mod:`pipeline.identity_training`, ``jnr train --identity-regressor``):

1. the points are similarity-normalised (:func:`normalise_points`: centred, unit RMS size, rotated onto the
   training set's Procrustes mean by Kabsch), so the camera's distance, the head's pose and the image's size
   drop out;
2. the ``3 N`` normalised coordinates (and, in a map learned with ``yaw_interaction``, their differences from the
   reference times the face's yaw: :func:`regression_features`) are mapped linearly to range-normalised joint
   channels ``u = theta / span``
   (the units of :class:`pipeline.fitting.identity.IdentityPrior`), the ridge penalty chosen by cross-validation;
   every training photo is also learned from as its mirror image, the mirrored head's channels its target
   (:func:`mirror_permutation`);
3. the regression's cross-validated residuals give a Gaussian of the truth around the prediction
   (probabilistic PCA like the population prior), so :meth:`IdentityRegressor.prior` is a **conditional
   identity prior** ``p(theta | the detector's mesh)``: the photo fit's identity term then pulls towards the
   regressed head, with the uncertainty the regression has in each direction, instead of towards the mean.

The committed map is ``rig/assets/jnr_identity_regressor_v<version>.npz``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.fitting.identity import (
    PRIOR_COMPONENTS,
    IdentityPrior,
    build_identity_prior,
    gaussian_arrays,
    read_asset_arrays,
)
from rig.asset import ASSET_DIR, TEMPLATE_VERSION, AssetError, write_npz_atomic
from rig.errors import InputError
from rig.lbs import ShapeError
from rig.parameters import NUM_PARAMETERS

RIDGE_ALPHAS = (1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 3e-3, 0.01, 0.03, 0.1, 0.3, 1.0)
"""The ridge penalties tried by :func:`fit_identity_regressor`'s cross-validation (on features of unit RMS
point size, so they are comparable between point sets)."""


def default_identity_regressor_path() -> Path:
    """The committed map (``rig/assets/jnr_identity_regressor_v<template version>.npz``)."""
    return ASSET_DIR / f"jnr_identity_regressor_v{TEMPLATE_VERSION}.npz"


def _check_points(points, count: int | None, function: str) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim not in (2, 3) or p.shape[-1] != 3 or (count is not None and p.shape[-2] != count):
        want = f"({count}, 3)" if count is not None else "(N, 3)"
        raise ShapeError(f"{function}: points must be {want} or (B, {want[1:]}, got {p.shape}")
    if not np.isfinite(p).all():
        raise InputError(f"{function}: the points must be finite (NaN or inf found)")
    return p


def normalise_points(points, reference: np.ndarray | None = None) -> np.ndarray:
    """Points without position, size and (given a ``reference``) rotation.

    Args:
        points: ``(N, 3)`` or ``(B, N, 3)``, any unit and frame (a detector's pixels and depth).
        reference: ``(N, 3)`` points of unit RMS radius about their centroid; None: only centre and scale.

    Returns:
        The same shape: centred on the centroid, scaled to unit RMS radius, and rotated (a proper rotation,
        Kabsch) onto ``reference`` when given.

    Raises:
        ShapeError: not ``(..., N, 3)``; InputError: not finite, or all points at one place.
    """
    return _normalised_and_rotation(points, reference)[0]


def _normalised_and_rotation(points, reference: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`normalise_points` and the ``(B, 3, 3)`` rotations it applied (``p @ R``; identity without a
    reference)."""
    p = _check_points(points, None if reference is None else len(reference), "normalise_points")
    one = p.ndim == 2
    p = p[None] if one else p
    p = p - p.mean(1, keepdims=True)
    size = np.sqrt((p * p).sum(-1).mean(-1))
    if (size <= 1e-12).any():
        raise InputError("normalise_points: the points have no extent (all at one place)")
    p = p / size[:, None, None]
    rotation = np.broadcast_to(np.eye(3), (len(p), 3, 3))
    if reference is not None:
        h = np.einsum("bni,nj->bij", p, reference)  # covariance of the points against the reference
        u, _, vt = np.linalg.svd(h)
        d = np.sign(np.linalg.det(u @ vt))
        u[:, :, -1] *= d[:, None]  # a proper rotation (no reflection)
        rotation = u @ vt
        p = p @ rotation
    return (p[0] if one else p), rotation


def regression_features(points, reference: np.ndarray, yaw_interaction: bool = False) -> np.ndarray:
    """The identity map's inputs: ``(B, 3 N)`` normalised coordinates of ``points (N, 3)`` or ``(B, N, 3)``
    (:func:`normalise_points` onto ``reference``), and with ``yaw_interaction`` ``(B, 6 N)``: followed by their
    difference from ``reference`` times the face's yaw (radians; the vertical component of the rotation vector
    that turned the points onto ``reference``), so the map's weights can change linearly with the turn of the
    face (MediaPipe's errors on a turned face are not those on a frontal one). The yaw is taken in ``reference``'s
    frame: a map learned from mirror images has a reference in its own plane of symmetry (:func:`symmetric_reference`),
    so a mirrored face's yaw is exactly the opposite."""
    p, rotation = _normalised_and_rotation(points, reference)
    x = p.reshape(-1, p.shape[-2] * 3)
    if not yaw_interaction:
        return x
    yaw = Rotation.from_matrix(rotation).as_rotvec()[:, 1]
    return np.concatenate([x, (x - reference.reshape(1, -1)) * yaw[:, None]], 1)


def procrustes_mean(points, iterations: int = 10) -> np.ndarray:
    """``(N, 3)`` generalised Procrustes mean of point sets ``(B, N, 3)`` (unit RMS radius, centred): each set
    rotated onto the current mean, the mean re-estimated; the first set is the start."""
    p = normalise_points(_check_points(points, None, "procrustes_mean"))
    if p.ndim != 3:
        raise ShapeError(f"procrustes_mean: points must be (B, N, 3), got {p.shape}")
    mean = p[0]
    for _ in range(iterations):
        mean = normalise_points(normalise_points(p, mean).mean(0))
    return mean


def mirror_permutation(reference: np.ndarray, iterations: int = 10) -> np.ndarray:
    """The left-right partner of every point of a mirror-symmetric point set (its own index on the midline).

    A symmetric shape's plane of symmetry is normal to one of its principal axes; for each axis the points
    are reflected in it and matched to themselves (a one-to-one assignment of the reflected points to the
    originals by least squared distance, Hungarian, alternated with the rotation that best aligns them,
    Kabsch, until the assignment stops changing); the axis whose pairs fit best wins.

    Args:
        reference: ``(N, 3)`` a left-right symmetric layout's points (e.g. the regressor's Procrustes mean), in
            any position, size and orientation.

    Returns:
        ``(N,)`` int ``perm``: point ``perm[i]`` is point ``i``'s mirror partner (``perm[perm]`` the identity).

    Raises:
        InputError: the points are not mirror symmetric (no one-to-one pairing, or the pairs more than 5 % of
            the points' RMS radius apart after the reflection).
    """
    from scipy.optimize import linear_sum_assignment

    r = normalise_points(reference)
    best = (np.inf, None)
    for axis in np.linalg.svd(r, full_matrices=False)[2]:
        reflected = r - 2.0 * np.outer(r @ axis, axis)
        moved, perm = reflected, None
        for _ in range(iterations):
            _, col = linear_sum_assignment(((moved[:, None] - r[None]) ** 2).sum(-1))
            new = np.empty_like(col)
            new[col] = np.arange(len(col))  # point j's partner is reflected point new[j]
            if perm is not None and (new == perm).all():
                break
            perm = new
            u, _, vt = np.linalg.svd(reflected[perm].T @ r)
            u[:, -1] *= np.sign(np.linalg.det(u @ vt))
            moved = reflected @ (u @ vt)
        error = float(np.sqrt(((moved[perm] - r) ** 2).sum(-1).mean()))
        if error < best[0]:
            best = (error, perm)
    error, perm = best
    if not (perm[perm] == np.arange(len(perm))).all() or error > 0.05:
        raise InputError(f"mirror_permutation: the points are not mirror symmetric (pairs {error:.3f} apart)")
    return perm


def symmetric_reference(reference: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """``(N, 3)`` a nearly symmetric point set made exactly mirror symmetric in its own plane of symmetry.

    The set is turned so that the normal of its plane of symmetry (the main direction of the differences between
    mirror partners ``perm``, :func:`mirror_permutation`) is +x (the sign nearest the set's own x), then averaged
    with its mirror image (:func:`mirror_points`) and normalised (centred, unit RMS radius). A face's mirror
    image then turns onto it by the mirrored rotation, so its yaw (:func:`regression_features`) is exactly the
    opposite of the face's: a map learned with mirror images and the yaw interaction is exactly left-right
    equivariant. (The Procrustes mean keeps a training photo's frame: the map of 16,000 photos' was 12 deg off.)

    Raises:
        ShapeError: ``reference`` not ``(N, 3)`` or ``perm`` not ``(N,)``.
    """
    r = _check_points(reference, None, "symmetric_reference")
    perm = np.asarray(perm)
    if r.ndim != 2 or perm.shape != (len(r),):
        raise ShapeError(f"symmetric_reference: reference (N, 3) and perm (N,); got {r.shape}, {perm.shape}")
    r = r - r.mean(0)
    normal = np.linalg.svd(r - r[perm], full_matrices=False)[2][0]
    normal = normal if normal[0] >= 0 else -normal
    turn, _ = Rotation.align_vectors([[1.0, 0.0, 0.0]], [normal])
    r = r @ turn.as_matrix().T
    return normalise_points((r + mirror_points(r, perm)) / 2)


def mirror_points(points, perm: np.ndarray) -> np.ndarray:
    """The mirror image of point sets ``(..., N, 3)``: x negated and every point swapped with its partner
    (``perm`` of :func:`mirror_permutation`), so point ``i`` is again point ``i`` of the layout."""
    return (np.asarray(points, np.float64) * np.array([-1.0, 1.0, 1.0]))[..., perm, :]


@dataclass(frozen=True)
class IdentityRegressor:
    """A linear map from a detector's normalised 3D points to the rig's joint channels (module docstring).

    Attributes:
        reference: ``(N, 3)`` the points' Procrustes mean (unit RMS radius), what every input is rotated onto.
        weights: ``(3 N, P)`` from normalised coordinates (minus ``feature_mean``) to ``u = theta / span``.
        feature_mean: ``(3 N,)`` the training features' mean.
        intercept: ``(P,)`` ``u`` at ``feature_mean``.
        residual: the Gaussian of the truth around a prediction (an
            :class:`~pipeline.fitting.identity.IdentityPrior` with zero mean; its ``span`` is the unit of ``u``).
        meta: how it was made (photos, the cross-validation tables, seconds).
        yaw_interaction: its features include the coordinates times the face's yaw
            (:func:`regression_features`; ``weights`` then ``(6 N, P)``).
    """

    reference: np.ndarray
    weights: np.ndarray
    feature_mean: np.ndarray
    intercept: np.ndarray
    residual: IdentityPrior
    meta: dict
    yaw_interaction: bool = False

    @property
    def count(self) -> int:
        """The number of points it reads."""
        return len(self.reference)

    def features(self, points) -> np.ndarray:
        """``(B, F)`` the map's inputs for ``points (N, 3)`` or ``(B, N, 3)`` (:func:`regression_features`)."""
        p = _check_points(points, self.count, "IdentityRegressor")
        return regression_features(p, self.reference, self.yaw_interaction)

    def predict_u(self, points) -> np.ndarray:
        """``(B, P)`` predicted range-normalised channels ``u = theta / span``."""
        return (self.features(points) - self.feature_mean) @ self.weights + self.intercept

    def predict(self, points) -> np.ndarray:
        """Joint channels ``(P,)`` for ``points (N, 3)``, ``(B, P)`` for ``(B, N, 3)`` (deg, mm, ``scale - 1``)."""
        theta = self.predict_u(points) * self.residual.span
        return theta[0] if np.ndim(points) == 2 else theta

    def prior(self, points) -> IdentityPrior:
        """The conditional identity prior given one point set ``(N, 3)``: the residual Gaussian centred on the
        prediction (an :class:`~pipeline.fitting.identity.IdentityPrior`, usable wherever the population's is)."""
        if np.ndim(points) != 2:
            raise ShapeError(f"IdentityRegressor.prior: one point set ({self.count}, 3), got {np.shape(points)}")
        return replace(self.residual, mean=self.predict_u(points)[0], meta={"conditional": True})

    def save(self, path: str | Path) -> None:
        """Write the map as one ``.npz`` of named arrays (atomic)."""
        r = self.residual
        write_npz_atomic(
            path,
            {
                "reference": self.reference,
                "weights": self.weights.astype(np.float32),
                "feature_mean": self.feature_mean,
                "intercept": self.intercept,
                "yaw_interaction": np.asarray(self.yaw_interaction),
                **gaussian_arrays(r.components, r.variances, r.noise, r.span, self.meta),
            },
        )


def load_identity_regressor(path: str | Path | None = None) -> IdentityRegressor:
    """Read a map written by :meth:`IdentityRegressor.save` (default: :func:`default_identity_regressor_path`).

    Raises:
        rig.asset.AssetError: the file is missing or does not match the rig's parameters.
    """
    path = Path(path) if path else default_identity_regressor_path()
    arrays = read_asset_arrays(path, "identity regressor", "jnr train --identity-regressor")
    residual = IdentityPrior(
        np.zeros_like(arrays["intercept"]), *(arrays[k] for k in ("components", "variances", "noise", "span")), {}
    )
    reg = IdentityRegressor(
        arrays["reference"],
        arrays["weights"].astype(np.float64),
        arrays["feature_mean"],
        arrays["intercept"],
        residual,
        arrays["meta"],
        bool(arrays.get("yaw_interaction", False)),  # maps written before it: the coordinates only
    )
    features = 3 * reg.count * (2 if reg.yaw_interaction else 1)
    if reg.intercept.shape != (NUM_PARAMETERS,) or reg.weights.shape != (features, NUM_PARAMETERS):
        raise AssetError(
            f"{path} maps {reg.weights.shape[0]} features to {reg.intercept.shape[0]} joint channels, the rig has "
            f"{NUM_PARAMETERS} and its points {features} features; rebuild it"
        )
    return reg


def _ridge_solutions(x: np.ndarray, y: np.ndarray, alphas) -> list[np.ndarray]:
    """Ridge weights ``(F, P)`` of centred ``x (n, F)``, ``y (n, P)`` for each alpha > 0: one SVD of ``x`` when
    there are fewer rows than features, else one eigendecomposition of the ``(F, F)`` Gram matrix (cheaper than the
    SVD when ``n`` is several times ``F``, as for the committed map)."""
    if x.shape[0] < x.shape[1]:
        u, s, vt = np.linalg.svd(x, full_matrices=False)
        uty = u.T @ y
        return [vt.T @ ((s / (s * s + a))[:, None] * uty) for a in alphas]
    ev, v = np.linalg.eigh(x.T @ x)
    vty = v.T @ (x.T @ y)
    ev = np.clip(ev, 0.0, None)  # round-off below zero
    return [v @ (vty / (ev + a)[:, None]) for a in alphas]


def fit_identity_regressor(
    points,
    theta: np.ndarray,
    span: np.ndarray,
    *,
    alphas: tuple[float, ...] = RIDGE_ALPHAS,
    components: tuple[int, ...] = PRIOR_COMPONENTS,
    folds: int = 5,
    seed: int = 0,
    noise_floor: float = 1e-4,
    extra_residuals: np.ndarray | None = None,
    mirror: Callable[[np.ndarray], np.ndarray] | None = None,
    yaw_interaction: bool = False,
    meta: dict | None = None,
) -> IdentityRegressor:
    """Learn the map from point sets to joint channels.

    Args:
        points: ``(n, N, 3)`` a detector's 3D points of ``n`` photos.
        theta: ``(n, P)`` the photographed heads' joint channels (deg, mm, ``scale - 1``).
        span: ``(P,)`` the channels' ranges (:func:`rig.skinning.joint_fit.parameter_span`).
        alphas: ridge penalties tried by ``folds``-fold cross-validation (mean squared error in ``u``).
        components: PPCA ranks tried for the residual Gaussian (cross-validated log-likelihood, as
            :func:`pipeline.fitting.identity.build_identity_prior`).
        seed: of the fold split. noise_floor: the residual Gaussian's least isotropic variance (``u^2``).
        extra_residuals: ``(m, P)`` more residuals in ``u`` (e.g. of the targets themselves against the rig's
            fits), added to the regression's as an independent error (each regression residual plus a random
            one of these rows).
        mirror: ``theta (n, P) -> (n, P)`` the channels of the mirror-image heads (e.g.
            :func:`rig.parameters.mirror_theta`); given, every photo is also learned from as its mirror image (the
            points by :func:`mirror_points`, the layout's pairs found by :func:`mirror_permutation`, the reference
            made symmetric), so the map is left-right equivariant (a mirrored photo reads as the mirrored head)
            and learns from twice the photos; a photo and its mirror image stay in one fold, and the residuals
            are the real photos'.
        yaw_interaction: the features include the coordinates times the face's yaw (:func:`regression_features`).
        meta: recorded with the map (the cross-validation tables are added).

    Returns:
        :class:`IdentityRegressor` fitted on all photos with the best penalty; its residual Gaussian is that
        of the cross-validated residuals.
    """
    theta = np.asarray(theta, np.float64)
    span = np.asarray(span, np.float64)
    p = _check_points(points, None, "fit_identity_regressor")
    if p.ndim != 3 or theta.shape != (len(p), len(span)):
        raise ShapeError(
            f"fit_identity_regressor: points (n, N, 3) and theta (n, {len(span)}); got {p.shape}, {theta.shape}"
        )
    if len(p) < 2 * folds:
        raise InputError(f"fit_identity_regressor: need at least {2 * folds} photos, got {len(p)}")
    reference = procrustes_mean(p)
    if mirror is not None:  # a symmetric reference: a mirrored photo's features are then its mirror image's
        perm = mirror_permutation(reference)
        reference = symmetric_reference(reference, perm)
    x = regression_features(p, reference, yaw_interaction)
    u = theta / span
    if mirror is not None:
        xm_all = regression_features(mirror_points(p, perm), reference, yaw_interaction)
        um_all = np.asarray(mirror(theta), np.float64) / span
        if um_all.shape != u.shape:
            raise ShapeError(f"fit_identity_regressor: mirror gave {um_all.shape}, expected {u.shape}")

    def learned(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The training features and targets of photos ``rows`` (with their mirror images)."""
        if mirror is None:
            return x[rows], u[rows]
        return np.concatenate([x[rows], xm_all[rows]]), np.concatenate([u[rows], um_all[rows]])

    order = np.random.default_rng(seed).permutation(len(p))
    cv_pred = np.zeros((len(alphas), *u.shape))
    for f in range(folds):
        test = order[f::folds]
        xt, ut = learned(np.setdiff1d(order, test))
        xm, um = xt.mean(0), ut.mean(0)
        for i, w in enumerate(_ridge_solutions(xt - xm, ut - um, alphas)):
            cv_pred[i, test] = (x[test] - xm) @ w + um
    mse = ((cv_pred - u) ** 2).sum(-1).mean(-1)
    best = int(np.argmin(mse))
    residual = u - cv_pred[best]
    if extra_residuals is not None:
        extra = np.asarray(extra_residuals, np.float64)
        residual = residual + extra[np.random.default_rng(seed + 1).integers(0, len(extra), len(residual))]
    # the residuals' Gaussian: the population prior's PPCA with its rank by cross-validated likelihood
    gauss = build_identity_prior(
        residual, np.ones(u.shape[1]), components=components, folds=folds, seed=seed + 2, noise_floor=noise_floor
    )
    xt, ut = learned(np.arange(len(p)))
    xm, um = xt.mean(0), ut.mean(0)
    (w,) = _ridge_solutions(xt - xm, ut - um, (alphas[best],))
    total = float(((u - u.mean(0)) ** 2).sum(-1).mean())
    return IdentityRegressor(
        reference=reference,
        weights=w,
        feature_mean=xm,
        intercept=um,
        residual=replace(gauss, mean=np.zeros(u.shape[1]), span=span, meta={}),
        yaw_interaction=bool(yaw_interaction),
        meta={
            **(meta or {}),
            "photos": int(len(p)),
            "alpha": float(alphas[best]),
            "cv_mse_u": {str(a): float(m) for a, m in zip(alphas, mse)},
            "cv_explained": float(1.0 - mse[best] / total),
            "mirror_augmented": mirror is not None,
            "yaw_interaction": bool(yaw_interaction),
            "residual_rank": gauss.rank,
            "residual_cv_log_likelihood": gauss.meta["cv_log_likelihood"],
        },
    )


_REGRESSOR: list[IdentityRegressor] = []


def cached_identity_regressor() -> IdentityRegressor:
    """The committed identity regressor, read once per process."""
    if not _REGRESSOR:
        _REGRESSOR.append(load_identity_regressor())
    return _REGRESSOR[0]


@dataclass(frozen=True)
class IdentityRegressionConfig:
    """The identity read from the detector's 3D points (:mod:`pipeline.fitting.identity_regression`): with
    ``enabled`` and a detector that gives them (MediaPipe's 478 points with their depth), the identity prior of the
    fit is the conditional one, centred on the regressed head with the regression's uncertainty, instead of the
    population's; photos without them (dlib's points, a landmarks file) keep the population prior."""

    enabled: bool = True
    """Use it (chosen on the validation photos of heldout heads 0-9 and 30-49: the fit's identity 0.878 x the
    template's against 0.966 x with the population prior; ``docs/fit_photo.md``)."""
    lambda_identity: float = 3.0
    """The conditional prior's weight (instead of ``prior.lambda_identity``). Chosen on the validation photos with
    the map of 20,000 photos (2026-12-08): 0.1 / 0.3 / 1 / 3 / 10 / 100 gave the fit's identity 0.866 / 0.863 /
    0.864 / 0.862 / 0.862 / 0.862 x the template (median), mean change -0.159 / -0.162 / -0.162 / -0.163 / -0.163
    / -0.163 mm, 4 photos worse by > 0.05 mm at every weight: the landmarks are the points the map already read,
    so letting them move the identity again counts them twice (0.1 was chosen with the first map of 3,000 photos,
    whose regressed head was less sure)."""
    start: bool = False
    """Start the joints at the regressed head (else at the template; the same fit on the validation photos)."""
    max_yaw_deg: float = 30.0
    """The regressor learned from photos of faces turned up to 30 deg; a face turned further (the yaw of the fit's
    first pose) keeps the population prior. On the views of validation heads 0-2 (yaw up to 60 deg) the conditional
    prior's fit was worse than the population prior's on 12 of the 17 views estimated past 30 deg (+0.18 mm on
    average) and better on 9 of the 13 within it (-0.07 mm) (``docs/fit_photo.md``)."""

    def __post_init__(self) -> None:
        for name in ("enabled", "start"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"landmarks.regression.{name} must be true or false, got {getattr(self, name)!r}")
        for name in ("lambda_identity", "max_yaw_deg"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0 <= value < float("inf")):
                raise InputError(f"landmarks.regression.{name} must be a finite number >= 0, got {value!r}")


def conditional_identity(
    config: IdentityRegressionConfig, points3d, yaw_deg: float | None = None
) -> IdentityPrior | None:
    """The conditional identity prior of the detector's 3D points ``points3d (478, 3)`` when ``config.enabled``,
    the points are MediaPipe's 478 (:func:`cached_identity_regressor`) and the face's yaw ``yaw_deg`` (degrees,
    None: not known) is within ``config.max_yaw_deg``; None otherwise (the fit keeps the population prior)."""
    if not config.enabled or points3d is None:
        return None
    if yaw_deg is not None and abs(yaw_deg) > config.max_yaw_deg:
        return None
    regressor = cached_identity_regressor()
    points = np.asarray(points3d, np.float64)
    if points.shape != (regressor.count, 3):
        return None
    return regressor.prior(points)
