"""Learning the identity regressor (``jnr train --identity-regressor``, :mod:`pipeline.fitting.identity_regression`).

No face data set is used: the training faces are ICT identities drawn afresh from the ICT model's own
distribution (seeds of their own stream, never a ``train``/``val``/``test``/``heldout`` split's), half of
them with a random sparse expression (:func:`pipeline.synthetic.expressive.sample_expression_coefficients`: the
map must read the identity through the expression), each photographed once by
:func:`pipeline.synthetic.photos.simulate.simulate_photo` (random pose, skin, light, background; the focal
length cycled over :data:`FOCAL_FACTORS` with the distance scaled so the face keeps its size in the frame) and
read by MediaPipe (its 478 3D points). Faces MediaPipe misses are left out.

The targets are the heads' joint channels. Fitting the rig to every head would take most of the time, so
the rig is fitted to the first ``map_heads`` heads only (:func:`pipeline.train.fit_population_joints`, as the
population prior is made) and a ridge map from the 100 ICT coefficients to the channels, learned on those
fits, gives every head's target; its own residuals (the rig's fits against the map) are added to the
regression's uncertainty.

Real people are not drawn from ICT's N(0, I): the training heads can include a second set drawn from a wider
distribution (``wide_heads`` heads, every mode's standard deviation ``wide_spread`` times ICT's, seeds of stream
``seed + 1``), so the map does not pull an unusual face towards the ICT population's middle.

The rendered points are kept in ``cache`` (one ``.npz`` per chunk of photos), so an interrupted run resumes.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from pipeline.fitting.identity import clip_to_limits
from pipeline.fitting.identity_regression import (
    IdentityRegressor,
    default_identity_regressor_path,
    fit_identity_regressor,
)
from pipeline.synthetic.expressive import sample_expression_coefficients
from pipeline.synthetic.expressive_shapes import expressive_offsets
from pipeline.synthetic.photos.settings import focal_settings
from pipeline.synthetic.photos.simulate import simulate_photo
from pipeline.synthetic.population import ict_coefficients, ict_heads, split_seeds
from rig.asset import load_asset, write_npz_atomic
from rig.errors import InputError
from rig.optim import Progress
from rig.parameters import mirror_theta
from rig.skinning.joint_fit import parameter_span

FOCAL_FACTORS = (1.0, 1.4, 2.0, 3.0)
"""The training photos' focal lengths over the image side, cycled over the heads (wide phone to tele)."""
WIDE_SPREAD = 1.5
"""The wide training heads' ICT coefficients' spread over ICT's own (set, not tuned; the held-out split's fine
modes have this spread too: ``docs/fit_photo.md`` says what that means for its figures)."""
CHUNK = 20
"""Photos per cache file."""
_STREAM = zlib.crc32(b"identity-regressor")


def training_seeds(n: int, seed: int = 0) -> np.ndarray:
    """``(n,)`` head seeds of the regressor's stream ``seed``, none of them a split's (of split seed 0, the
    benchmarks', or ``seed``)."""
    used = set().union(
        *(set(split_seeds(s, k).tolist()) for s in ("train", "val", "test", "heldout") for k in {0, int(seed)})
    )
    ss = np.random.SeedSequence([int(seed), _STREAM])
    seeds = [int(s) for s in ss.generate_state(n + 64, dtype=np.uint32) if int(s) not in used]
    return np.asarray(seeds[:n], dtype=np.int64)


def render_chunk(seeds: np.ndarray, first: int, seed: int, spp: int, spread: float = 1.0) -> dict[str, np.ndarray]:
    """Photograph heads ``first..first + len(seeds) - 1`` (head ``i`` of seed ``seeds[i - first]``, its ICT
    coefficients' spread ``spread`` times ICT's) and read them.

    Returns:
        ``coefficients (n, 100)``, ``expressive (n,)`` bool, ``found (n,)`` bool, ``points (n, 478, 3)``
        MediaPipe's dense points (NaN where no face was found), ``seconds (n,)`` each photo's render and
        detection wall time.
    """
    from landmarks.detect import detect_landmarks
    from landmarks.detector import NoFaceError

    asset = load_asset()
    n = len(seeds)
    coefficients = np.stack([ict_coefficients(int(s), asset=asset, spread=spread) for s in seeds])
    neutral = ict_heads(coefficients, asset)
    expressive = (np.arange(first, first + n) % 2) == 1
    points = np.full((n, 478, 3), np.nan)
    found = np.zeros(n, bool)
    seconds = np.zeros(n)
    for j in range(n):
        t0 = time.perf_counter()
        i = first + j
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), _STREAM, i]))
        vertices = neutral[j]
        if expressive[j]:
            vertices = vertices + expressive_offsets(sample_expression_coefficients(rng, 1), asset)[0]
        settings = replace(focal_settings(FOCAL_FACTORS[i % len(FOCAL_FACTORS)]), spp=int(spp))
        photo = simulate_photo(vertices, rng, settings, asset)
        try:
            face = detect_landmarks(photo.image, detector="mediapipe")
            points[j] = face.dense
            found[j] = True
        except NoFaceError:
            pass
        seconds[j] = time.perf_counter() - t0
    return {
        "coefficients": coefficients,
        "expressive": expressive,
        "found": found,
        "points": points,
        "seconds": seconds,
    }


def training_photos(
    heads: int,
    cache: str | Path,
    *,
    seed: int = 0,
    spp: int = 64,
    spread: float = 1.0,
    progress: Progress | None = None,
) -> dict[str, np.ndarray]:
    """The training photos' points, rendered chunk by chunk into ``cache`` (chunks already there are read).

    Args:
        heads: how many (one photo each). cache: folder of the chunks. seed: the heads' and photos' stream.
        spp: samples per pixel. spread: the heads' ICT coefficients' spread over ICT's own (1: N(0, I)).
        progress: reports.

    Returns:
        The concatenated arrays of :func:`render_chunk` over ``heads`` heads (``seconds`` NaN for photos of
        a cache written before their times were kept).
    """
    if not (np.isfinite(spread) and spread > 0):
        raise InputError(f"training_photos: spread must be a positive number, got {spread}")
    cache = Path(cache)
    if cache.exists() and not cache.is_dir():
        raise InputError(f"the photos' cache {cache} is a file, not a folder")
    cache.mkdir(parents=True, exist_ok=True)
    seeds = training_seeds(heads, seed)
    tag = "" if spread == 1.0 else f"_sd{spread:g}"  # the N(0, I) chunks keep their first names
    parts = []
    for first in range(0, heads, CHUNK):
        path = cache / f"photos_s{seed}{tag}_spp{spp}_{first:06d}.npz"
        chunk_seeds = seeds[first : first + CHUNK]
        part = None
        if path.is_file():
            with np.load(path) as data:
                part = {k: data[k] for k in data.files}
            if len(part["coefficients"]) != len(chunk_seeds):
                part = None
            elif "seconds" not in part:
                part["seconds"] = np.full(len(chunk_seeds), np.nan)
        if part is None:
            part = render_chunk(chunk_seeds, first, seed, spp, spread)
            write_npz_atomic(path, part)
        parts.append(part)
        if progress is not None:
            progress("identity regressor: photos", min(first + CHUNK, heads), heads)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def coefficient_map(coefficients: np.ndarray, theta: np.ndarray, alpha: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Ridge map ``theta ~ coefficients @ a + b`` (``a (100, P)``, ``b (P,)``) from fitted heads ``theta (n, P)``."""
    c = np.asarray(coefficients, np.float64)
    cm, tm = c.mean(0), theta.mean(0)
    x = c - cm
    a = np.linalg.solve(x.T @ x + alpha * len(c) * np.eye(c.shape[1]), x.T @ (theta - tm))
    return a, tm - cm @ a


def coefficient_map_residuals(coefficients: np.ndarray, theta: np.ndarray, folds: int = 5) -> np.ndarray:
    """``(n, P)`` cross-validated residuals ``theta - (c @ a + b)`` of :func:`coefficient_map` (each head
    predicted by the map learned without its fold)."""
    out = np.zeros_like(theta)
    for f in range(folds):
        test = np.arange(f, len(theta), folds)
        train = np.setdiff1d(np.arange(len(theta)), test)
        a, b = coefficient_map(coefficients[train], theta[train])
        out[test] = theta[test] - (coefficients[test] @ a + b)
    return out


def train_identity_regressor(
    out_path: str | Path | None = None,
    *,
    heads: int = 10000,
    map_heads: int = 300,
    seed: int = 0,
    spp: int = 64,
    iterations: int = 400,
    cache: str | Path | None = None,
    mirror: bool = True,
    wide_heads: int | None = None,
    wide_spread: float = WIDE_SPREAD,
    yaw_interaction: bool = True,
    progress: Progress | None = None,
) -> IdentityRegressor:
    """Render, read and fit the identity regressor; write it (default: the committed asset path).

    Args:
        out_path: where to write the map. heads: training photos (one per head). map_heads: heads whose rig fit
            teaches the coefficient-to-channel map (the first ones). seed: of the heads and photos. spp: the
            photos' samples per pixel. iterations: Adam steps of each rig fit. cache: folder of the rendered
            points (default ``.cache/identity_regressor`` in the working directory). mirror: learn from every
            photo's mirror image too (:func:`~pipeline.fitting.identity_regression.fit_identity_regressor`).
            wide_heads: more training photos of heads from a wider distribution (default: as many as ``heads``;
            0: none; stream ``seed + 1``, every ICT mode's spread ``wide_spread`` times ICT's; module docstring).
            yaw_interaction: the map's weights change linearly with the face's yaw
            (:func:`~pipeline.fitting.identity_regression.regression_features`). progress: reports.
    """
    from pipeline.train import fit_population_joints

    wide_heads = heads if wide_heads is None else wide_heads
    if heads < 50 or map_heads < 20 or map_heads > heads or wide_heads < 0:
        raise InputError(
            "train_identity_regressor: need heads >= 50, 20 <= map_heads <= heads and wide_heads >= 0, got "
            f"{heads}, {map_heads}, {wide_heads}"
        )
    if wide_heads and not (np.isfinite(wide_spread) and wide_spread > 0):  # before hours of the first set's renders
        raise InputError(f"train_identity_regressor: wide_spread must be a positive number, got {wide_spread}")
    t0 = time.perf_counter()
    cache = cache or Path(".cache") / "identity_regressor"
    data = training_photos(heads, cache, seed=seed, spp=spp, progress=progress)
    if wide_heads:
        wide = training_photos(wide_heads, cache, seed=seed + 1, spp=spp, spread=wide_spread, progress=progress)
        data = {k: np.concatenate([data[k], wide[k]]) for k in data}
    fitted = clip_to_limits(
        fit_population_joints(ict_heads(data["coefficients"][:map_heads]), iterations=iterations, progress=progress)
    )
    a, b = coefficient_map(data["coefficients"][:map_heads], fitted)
    span = parameter_span(torch.float64).numpy()
    map_residual = coefficient_map_residuals(data["coefficients"][:map_heads], fitted) / span
    theta = data["coefficients"] @ a + b
    found = data["found"]
    regressor = fit_identity_regressor(
        data["points"][found],
        theta[found],
        span,
        seed=seed,
        extra_residuals=map_residual,
        mirror=(lambda t: mirror_theta(torch.from_numpy(t)).numpy()) if mirror else None,
        yaw_interaction=yaw_interaction,
        meta={
            "seed": seed,
            "heads": int(heads),
            "wide_heads": int(wide_heads),
            "wide_spread": float(wide_spread) if wide_heads else None,
            "faces_found": int(found.sum()),
            "expressive": int(data["expressive"][found].sum()),
            "map_heads": int(map_heads),
            "map_residual_u_rms": float(np.sqrt((map_residual**2).sum(-1).mean())),
            "focal_factors": list(FOCAL_FACTORS),
            "spp": int(spp),
            "layout": "mediapipe",
        },
    )
    regressor = replace(
        regressor,
        meta={
            **regressor.meta,
            "seconds": {
                # the photos' own render + detection times, kept in the cache (not this run's reading of it)
                "photos": round(float(np.nansum(data["seconds"])), 1),
                "photos_untimed": int(np.isnan(data["seconds"]).sum()),
                "total": round(time.perf_counter() - t0, 1),
            },
        },
    )
    regressor.save(out_path or default_identity_regressor_path())
    return regressor
