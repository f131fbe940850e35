"""Validation of the photo fit on synthetic renders of held-out heads (NoW-style), ``jnr eval photos``.

Each photo (:func:`pipeline.synthetic.photos.synthetic_photo`) is a held-out synthetic head (neutral
or with a synthetic expression that is not one of the rig's blendshapes), rendered with a different
renderer and light model than the fitting one (path tracing, a point light and an environment, 64
samples per pixel) at yaw within +-30 deg; its landmarks are the projected true landmarks plus
1 px Gaussian noise. The fit is then scored like the NoW benchmark (Sanyal et al. 2019):

1. the fitted mesh is aligned to the true head by a similarity transform (rotation, translation,
   scale: from one photo the size of a head is not observable) on the 51 inner landmarks (17-67),
2. refined by similarity ICP of the true face-region points onto the fitted surface,
3. the **scan-to-mesh distance** of every true face-region vertex (forehead, brows, eyelids, nose,
   cheeks, lips, chin) to the fitted surface is reported (median, mean, std, mm).

Because the true head has the template's topology, the **true vertex error** (same vertex, after
the same alignment) is reported too; it also measures sliding along the surface, which the
scan-to-mesh distance does not see. The template head, aligned the same way, is the reference that
any fit must beat.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from pipeline.evaluation.scans import scan_seed
from pipeline.photo.fit import FitPhotoConfig, fit_photo
from pipeline.scan.fit import FACE_REGIONS
from pipeline.scan.registration import MeshDistance, umeyama
from rig.asset import load_asset
from rig.expressions import EXPRESSION_NAMES

INNER_LANDMARKS = tuple(range(17, 68))
"""Landmarks used for the initial alignment (the jaw contour's 3D points depend on the view)."""


@dataclass(frozen=True)
class PhotoRecord:
    """One fitted synthetic photo."""

    name: str
    kind: str
    """``neutral`` or ``expressive``."""
    yaw_deg: float
    method: str
    """``jnr`` (full fit), ``landmarks`` (the landmark-only fit) or ``template`` (no fit)."""
    s2m_median_mm: float
    s2m_mean_mm: float
    s2m_std_mm: float
    vertex_mean_mm: float
    landmark_error_px: float
    seconds: float


@dataclass(frozen=True)
class PhotoEvaluation:
    """All records and the settings of :func:`evaluate_photos`."""

    records: list[PhotoRecord]
    settings: dict = field(default_factory=dict)

    def summary(self) -> list[dict]:
        """Per kind and method: median / mean / std over photos of each metric (the per-photo medians and
        means), and the pooled median of the per-photo scan-to-mesh medians."""
        rows = []
        for kind in ("neutral", "expressive", "all"):
            for method in ("jnr", "landmarks", "template"):
                rs = [r for r in self.records if r.method == method and (kind == "all" or r.kind == kind)]
                if not rs:
                    continue
                row = {"kind": kind, "method": method, "photos": len(rs)}
                for m in ("s2m_median_mm", "s2m_mean_mm", "s2m_std_mm", "vertex_mean_mm", "landmark_error_px",
                          "seconds"):
                    values = np.array([getattr(r, m) for r in rs], float)
                    row[m] = float(np.mean(values))
                    row[m + "_sd"] = float(np.std(values))
                row["s2m_median_of_medians_mm"] = float(np.median([r.s2m_median_mm for r in rs]))
                rows.append(row)
        return rows

    def table_markdown(self) -> str:
        """The summary as a Markdown table (mean +- sd over photos)."""
        lines = ["| photos | method | n | s2m median mm | s2m mean mm | s2m std mm | vertex mean mm | landmarks px | seconds |",
                 "|---|---|---|---|---|---|---|---|---|"]
        def pm(row: dict, m: str, digits: int = 2) -> str:
            return f"{row[m]:.{digits}f} ± {row[m + '_sd']:.{digits}f}"

        for r in self.summary():
            lines.append(f"| {r['kind']} | {r['method']} | {r['photos']} | {pm(r, 's2m_median_mm')} | "
                         f"{pm(r, 's2m_mean_mm')} | {pm(r, 's2m_std_mm')} | {pm(r, 'vertex_mean_mm')} | "
                         f"{pm(r, 'landmark_error_px')} | {pm(r, 'seconds', 1)} |")
        return "\n".join(lines)


def now_style_error(fitted: np.ndarray, truth: np.ndarray, faces: np.ndarray, face_vertices: np.ndarray,
                    fitted_landmarks: np.ndarray, true_landmarks: np.ndarray, icp_iterations: int = 10) -> dict:
    """NoW-style face-region error of a fitted head against the true head (module docstring).

    Args:
        fitted, truth: ``(V, 3)`` meshes (template topology), mm, any frames.
        faces: ``(F, 3)``; face_vertices: ``(V,)`` bool, the true face region's vertices.
        fitted_landmarks, true_landmarks: ``(L, 3)`` corresponding 3D landmarks for the initial alignment.
        icp_iterations: similarity-ICP refinements.

    Returns:
        ``{"s2m_median_mm", "s2m_mean_mm", "s2m_std_mm", "vertex_mean_mm", "scale"}``.
    """
    # align the fitted mesh onto the truth: x -> s R x + t
    rot, t, s = umeyama(fitted_landmarks, true_landmarks, with_scale=True)
    points = truth[face_vertices]
    for _ in range(icp_iterations):
        aligned = s * fitted @ rot.T + t
        d, closest, _ = MeshDistance(aligned, faces).query(points)
        keep = d <= max(3.0 * np.median(d), 1.0)
        # closest points expressed on the unaligned fitted mesh correspond to the true points
        source = ((closest - t) / s) @ rot
        rot, t, s = umeyama(source[keep], points[keep], with_scale=True)
    aligned = s * fitted @ rot.T + t
    d, _, _ = MeshDistance(aligned, faces).query(points)
    vertex = np.linalg.norm(aligned[face_vertices] - truth[face_vertices], axis=1)
    return {"s2m_median_mm": float(np.median(d)), "s2m_mean_mm": float(d.mean()), "s2m_std_mm": float(d.std()),
            "vertex_mean_mm": float(vertex.mean()), "scale": float(s)}


def face_error(fitted: np.ndarray, truth: np.ndarray, asset=None) -> dict:
    """:func:`now_style_error` of a fitted head against the true head (both template topology, mm): aligned
    on the inner landmarks (:data:`INNER_LANDMARKS`), scored over the face regions
    (:data:`pipeline.scan.fit.FACE_REGIONS`)."""
    from landmarks.ibug68 import ibug68_embedding, landmark_positions

    asset = load_asset() if asset is None else asset
    embedding = ibug68_embedding(asset)

    def inner(v: np.ndarray) -> np.ndarray:
        return landmark_positions(v, embedding, asset.faces)[0][list(INNER_LANDMARKS)]

    return now_style_error(fitted, truth, asset.faces, asset.region_mask(*FACE_REGIONS), inner(fitted), inner(truth))


def evaluate_photos(n_neutral: int = 5, n_expressive: int = 5, *, first: int = 0, seed: int = 0,
                    config: FitPhotoConfig | None = None, settings=None,
                    progress: Callable[[PhotoRecord], None] | None = None) -> PhotoEvaluation:
    """Fit synthetic photos of the first held-out heads and score them (module docstring).

    Args:
        n_neutral, n_expressive: photos of held-out heads ``first .. first + n - 1`` without / with an
            expression.
        first: the first held-out head (the defaults of the photo fit were chosen on heads 0-5; the
            benchmark scores heads from 20 on).
        seed: seed of the photos (placement, light, albedo, landmark noise).
        config: fitting settings (default :class:`FitPhotoConfig`).
        settings: :class:`pipeline.synthetic.photos.PhotoSettings` (default ones).
        progress: called with each record as it is made.

    Returns:
        :class:`PhotoEvaluation` with records for ``jnr``, ``landmarks`` and ``template`` per photo.
    """
    from pipeline.fitting.state import head_vertices
    from pipeline.synthetic.photos import PhotoSettings, synthetic_photo
    from rig.model import JointRig
    from rig.parameters import NUM_PARAMETERS
    from rig.skinning.neural import LATENT, load_neural

    for name, value in (("first", first), ("n_neutral", n_neutral), ("n_expressive", n_expressive)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= 100:
            raise ValueError(f"evaluate_photos: {name} must be an integer in [0, 100], got {value!r}")
    if first + max(n_neutral, n_expressive) > 100:
        raise ValueError(f"evaluate_photos: heads {first}..{first + max(n_neutral, n_expressive) - 1} exceed the "
                         "100 held-out heads")
    config = config or FitPhotoConfig()
    settings = settings or PhotoSettings()
    asset = load_asset()
    rig = JointRig()
    neural, _ = load_neural(rig)
    template = head_vertices(rig, neural, np.zeros(NUM_PARAMETERS), np.zeros(LATENT), np.zeros(len(EXPRESSION_NAMES)))
    records: list[PhotoRecord] = []

    def add(**fields) -> None:
        record = PhotoRecord(**fields)
        records.append(record)
        if progress is not None:
            progress(record)

    for kind, count in (("neutral", n_neutral), ("expressive", n_expressive)):
        for index in range(first, first + count):
            photo = synthetic_photo(index, expressive=kind == "expressive", seed=scan_seed(seed, "photo-" + kind, index),
                                    settings=settings)
            truth = photo.gt_vertices
            t0 = time.perf_counter()
            fit = fit_photo(photo.image, photo.landmarks2d, focal=photo.focal, config=config, rig=rig, neural=neural)
            seconds = time.perf_counter() - t0
            common = {"name": photo.name, "kind": kind, "yaw_deg": float(photo.yaw_deg)}
            lfit = fit.landmark_fit
            for method, vertices, lm_px, secs in (
                    ("jnr", fit.rig_vertices, float(fit.error_px.mean()), seconds),
                    ("landmarks", head_vertices(rig, neural, lfit.theta, lfit.z, lfit.expressions),
                     float(lfit.error_px.mean()), lfit.seconds),
                    ("template", template, math.nan, 0.0)):
                err = face_error(vertices, truth, asset)
                add(**common, method=method, s2m_median_mm=err["s2m_median_mm"], s2m_mean_mm=err["s2m_mean_mm"],
                    s2m_std_mm=err["s2m_std_mm"], vertex_mean_mm=err["vertex_mean_mm"], landmark_error_px=lm_px,
                    seconds=secs)
    return PhotoEvaluation(records, settings={"first": first, "n_neutral": n_neutral, "n_expressive": n_expressive, "seed": seed,
                                              "photo_settings": dict(settings.__dict__)})
