"""Validation of the photo fit on synthetic renders of held-out heads (NoW-style), ``jnr eval photos``.

Each photo (:func:`pipeline.synthetic.photos.simulate.synthetic_photo`) is a held-out synthetic head (neutral
or with a synthetic expression that is not one of the rig's blendshapes), rendered with a different
renderer and light model than the fitting one (path tracing, a point light and an environment, 64
samples per pixel) at yaw within +-30 deg; its landmarks are the projected true landmarks plus
1 px Gaussian noise. The fit is then scored like the NoW benchmark (Sanyal et al. 2019):

1. the fitted mesh is aligned to the true head by a similarity transform (rotation, translation,
   scale: from one photo the size of a head is not observable) on the 51 inner landmarks (17-67),
2. refined by similarity ICP of the true face-region points onto the fitted surface,
3. the **scan-to-mesh distance** of every true face-region vertex (forehead, brows, eyelids, nose,
   cheeks, lips, chin) to the fitted surface is reported (median, mean, std, mm;
   :func:`pipeline.metrics.distance_stats`).

The **pose error** is the angle of the rotation that best aligns (rigidly, face region) the fitted
head as the fit places it in the camera frame onto the true head in the camera frame
(:func:`pose_error_deg`): how far the fitted face is turned from the true one, whatever the rig-space
shape. The photo's landmarks are either the projected true ones plus 1 px Gaussian noise
(``landmarks="noisy"``) or dlib's own detections on the render (``landmarks="dlib"``; a photo where dlib
finds no face is left out and counted).

Because the true head has the template's topology, the **true vertex error** (same vertex, after
the same alignment) is reported too; it also measures sliding along the surface, which the
scan-to-mesh distance does not see. The template head, aligned the same way, is the reference that
any fit must beat. Summaries over photos (:mod:`pipeline.metrics`): mean ± sample std
(ddof=1) and median.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from landmarks.detect import detect_landmarks
from landmarks.detector import NoFaceError
from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.positions import landmark_positions
from landmarks.mediapipe.layout import mediapipe_layout
from pipeline.camera import solve_pose
from pipeline.evaluation.scans import scan_seed
from pipeline.fitting.state import head_vertices
from pipeline.metrics import (
    ALL,
    Column,
    Evaluation,
    Group,
    distance_stats,
    mean_vertex_error,
    scan_to_mesh_distances,
)
from pipeline.photo.fit import fit_photo
from pipeline.photo.fit_config import FitPhotoConfig
from pipeline.synthetic.photos.settings import PhotoSettings
from pipeline.synthetic.photos.simulate import synthetic_photo
from rig.asset import load_asset
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES
from rig.geometry import RIG_TO_OPENCV, Similarity, closest_surface_points, head_angles
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS
from rig.skinning.neural import LATENT, load_neural
from rig.template import FACE_REGIONS

INNER_LANDMARKS = tuple(range(17, 68))
"""Landmarks used for the initial alignment (the jaw contour's 3D points depend on the view)."""


KINDS: tuple[str, ...] = ("neutral", "expressive")
METHODS: tuple[str, ...] = ("jnr", "landmarks", "template")
#: Per-photo metrics summarised by :meth:`PhotoEvaluation.summary` (mean, std and median over photos).
METRICS: tuple[str, ...] = (
    "s2m_median_mm",
    "s2m_mean_mm",
    "s2m_std_mm",
    "vertex_mean_mm",
    "pose_error_deg",
    "landmark_error_px",
    "seconds",
)
LANDMARK_SOURCES: tuple[str, ...] = ("noisy", "dlib", "mediapipe", "mediapipe68")
"""Where the fit's landmarks come from: the true ones + 1 px noise; dlib's 68 detected on the render;
MediaPipe's 478 points (the dense layout, :mod:`landmarks.mediapipe.layout`); MediaPipe's 68 iBUG points
(mapped from its mesh) through the iBUG-68 fit."""


@dataclass(frozen=True)
class PhotoRecord:
    """One method on one fitted synthetic photo.

    Attributes:
        name: head name (``heldout_020``, ...).
        kind: ``neutral`` or ``expressive``.
        yaw_deg: the head's yaw in the photo, deg.
        method: ``jnr`` (full fit), ``landmarks`` (the landmark-only fit) or ``template`` (no fit).
        s2m_median_mm, s2m_mean_mm, s2m_std_mm: statistics of the distances from every true
            face-region vertex to the aligned fitted surface (std over the vertices, ddof=0), mm.
        vertex_mean_mm: true per-vertex error over the face region after the same alignment, mm.
        pose_error_deg: :func:`pose_error_deg` (``template``: the template placed by solvePnP).
        landmark_error_px: mean landmark error of the fit, px (NaN for ``template``).
        seconds: wall time of the fit, s (``landmarks``: that stage alone; ``template``: 0).
    """

    name: str
    kind: str
    yaw_deg: float
    method: str
    s2m_median_mm: float
    s2m_mean_mm: float
    s2m_std_mm: float
    vertex_mean_mm: float
    pose_error_deg: float
    landmark_error_px: float
    seconds: float


@dataclass(frozen=True)
class PhotoEvaluation(Evaluation):
    """All records and the settings of :func:`evaluate_photos` (:class:`pipeline.metrics.Evaluation`).

    :meth:`summary`: per kind (``neutral``, ``expressive``, and ``all`` photos) and method, ``n`` and for
    every name in :data:`METRICS` ``<metric>`` (mean over photos), ``<metric>_std`` (sample std over
    photos, ddof=1; NaN for one photo) and ``<metric>_median`` (``s2m_median_mm_median``: the median of
    the per-photo medians). :meth:`table_markdown`: the same, mean ± std over photos.
    """

    records: tuple[PhotoRecord, ...]
    settings: dict = field(default_factory=dict)

    GROUPS: ClassVar[tuple[Group, ...]] = (Group("kind", (*KINDS, ALL), title="photos"), Group("method", METHODS))
    METRICS: ClassVar[tuple[str, ...]] = METRICS
    COLUMNS: ClassVar[tuple[Column, ...]] = (
        Column("s2m median mm", "s2m_median_mm"),
        Column("s2m mean mm", "s2m_mean_mm"),
        Column("s2m std mm", "s2m_std_mm"),
        Column("vertex mean mm", "vertex_mean_mm"),
        Column("pose error deg", "pose_error_deg"),
        Column("landmarks px", "landmark_error_px"),
        Column("seconds", "seconds", digits=1),
    )


def now_style_error(
    fitted: np.ndarray,
    truth: np.ndarray,
    faces: np.ndarray,
    face_vertices: np.ndarray,
    fitted_landmarks: np.ndarray,
    true_landmarks: np.ndarray,
    icp_iterations: int = 10,
) -> dict:
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
    align = Similarity.fit(fitted_landmarks, true_landmarks, with_scale=True)
    points = truth[face_vertices]
    for _ in range(icp_iterations):
        aligned = align.apply(fitted)
        found = closest_surface_points(points, aligned, faces)
        d, closest = found.distance, found.closest
        keep = d <= max(3.0 * np.median(d), 1.0)
        # closest points expressed on the unaligned fitted mesh correspond to the true points
        source = ((closest - align.translation) / align.scale) @ align.rotation
        align = Similarity.fit(source[keep], points[keep], with_scale=True)
    aligned = align.apply(fitted)
    stats = distance_stats(scan_to_mesh_distances(points, aligned, faces))
    vertex = mean_vertex_error(aligned[face_vertices], truth[face_vertices])
    s = align.scale
    return {**stats.as_dict("s2m_"), "vertex_mean_mm": float(vertex), "scale": float(s)}


def pose_error_deg(
    fitted: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    truth: np.ndarray,
    true_rotation: np.ndarray,
    true_translation: np.ndarray,
    asset=None,
) -> float:
    """Angle (deg) of the best rigid rotation (Kabsch, face-region vertices) taking the fitted head, as its pose
    places it in the camera frame, onto the true head in the camera frame.

    Args:
        fitted, truth: ``(V, 3)`` rig-space heads, mm; rotation/translation and true_rotation/true_translation:
            their head poses (:mod:`pipeline.camera`).
    """
    return pose_error_angles(fitted, rotation, translation, truth, true_rotation, true_translation, asset)[0]


def pose_error_angles(
    fitted: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    truth: np.ndarray,
    true_rotation: np.ndarray,
    true_translation: np.ndarray,
    asset=None,
) -> tuple[float, float, float, float]:
    """:func:`pose_error_deg` and the signed ``(yaw, pitch, roll)`` (deg, :func:`rig.geometry.head_angles`'
    convention, in the camera's axes) of the rotation that corrects the fitted face: positive pitch means
    the true face is tipped further down than the fitted one."""
    asset = load_asset() if asset is None else asset
    face = asset.region_mask(*FACE_REGIONS)
    a = np.asarray(fitted, np.float64)[face] @ (RIG_TO_OPENCV @ rotation).T + translation
    b = np.asarray(truth, np.float64)[face] @ (RIG_TO_OPENCV @ true_rotation).T + true_translation
    a, b = a - a.mean(0), b - b.mean(0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(u @ vt))
    r = (u @ np.diag([1.0, 1.0, d]) @ vt).T
    angle = float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))
    return (angle, *head_angles(RIG_TO_OPENCV.T @ r @ RIG_TO_OPENCV))


def face_error(fitted: np.ndarray, truth: np.ndarray, asset=None) -> dict:
    """:func:`now_style_error` of a fitted head against the true head (both template topology, mm): aligned
    on the inner landmarks (:data:`INNER_LANDMARKS`), scored over the face regions
    (:data:`rig.template.FACE_REGIONS`)."""
    asset = load_asset() if asset is None else asset
    embedding = ibug68_embedding(asset)

    def inner(v: np.ndarray) -> np.ndarray:
        return landmark_positions(v, embedding, asset.faces)[0][list(INNER_LANDMARKS)]

    return now_style_error(fitted, truth, asset.faces, asset.region_mask(*FACE_REGIONS), inner(fitted), inner(truth))


def _check_selection(first, n_neutral, n_expressive, landmarks: str) -> None:
    """Reject counts or a first head outside the 100 held-out heads, and an unknown landmark source."""
    for name, value in (("first", first), ("n_neutral", n_neutral), ("n_expressive", n_expressive)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= 100:
            raise InputError(f"evaluate_photos: {name} must be an integer in [0, 100], got {value!r}")
    if first + max(n_neutral, n_expressive) > 100:
        raise InputError(
            f"evaluate_photos: heads {first}..{first + max(n_neutral, n_expressive) - 1} exceed the 100 held-out heads"
        )
    if landmarks not in LANDMARK_SOURCES:
        raise InputError(f"evaluate_photos: landmarks must be one of {list(LANDMARK_SOURCES)}, got {landmarks!r}")


def _photo_landmarks(photo, landmarks: str, asset) -> tuple[np.ndarray, tuple | None] | None:
    """The fit's ``(K, 2)`` px target and dense MediaPipe points from ``landmarks``' source; ``None``: no face seen."""
    target, dense = photo.landmarks2d, None
    if landmarks != "noisy":
        try:
            face = detect_landmarks(photo.image, detector="dlib" if landmarks == "dlib" else "mediapipe")
        except NoFaceError:
            return None
        target = face.landmarks
        if landmarks == "mediapipe":
            dense = (face.dense[:, :2], mediapipe_layout(asset))
    return target, dense


def _method_heads(fit, seconds: float, template: np.ndarray, template_pose: tuple, rig, neural) -> tuple:
    """Per method: name, ``(V, 3)`` rig-space head (mm), camera rotation and translation, landmark error (px), s."""
    lfit = fit.landmark_fit
    t_rot, t_trans = template_pose
    return (
        ("jnr", fit.rig_vertices, fit.rotation, fit.translation, float(fit.landmarks.error_px.mean()), seconds),
        (
            "landmarks",
            head_vertices(rig, neural, lfit.theta, lfit.z, lfit.expressions),
            lfit.rotation,
            lfit.translation,
            float(lfit.error_px.mean()),
            lfit.seconds,
        ),
        ("template", template, t_rot, t_trans, math.nan, 0.0),
    )


def _score_photo(photo, kind: str, heads: tuple, asset, add: Callable[..., None]) -> None:
    """Score each method's head against the photo's true head (face error, mm; pose error, deg) and ``add`` it."""
    truth = photo.gt_vertices
    common = {"name": photo.name, "kind": kind, "yaw_deg": float(photo.yaw_deg)}
    for method, vertices, rot, trans, lm_px, secs in heads:
        err = face_error(vertices, truth, asset)
        pose = pose_error_deg(vertices, rot, trans, truth, photo.rotation, photo.translation, asset)
        add(
            **common,
            method=method,
            s2m_median_mm=err["s2m_median_mm"],
            s2m_mean_mm=err["s2m_mean_mm"],
            s2m_std_mm=err["s2m_std_mm"],
            vertex_mean_mm=err["vertex_mean_mm"],
            pose_error_deg=pose,
            landmark_error_px=lm_px,
            seconds=secs,
        )


def evaluate_photos(
    n_neutral: int = 5,
    n_expressive: int = 5,
    *,
    first: int = 0,
    seed: int = 0,
    config: FitPhotoConfig | None = None,
    settings=None,
    landmarks: str = "noisy",
    progress: Callable[[PhotoRecord], None] | None = None,
) -> PhotoEvaluation:
    """Fit synthetic photos of the first held-out heads and score them (module docstring).

    Args:
        n_neutral, n_expressive: photos of held-out heads ``first .. first + n - 1`` without / with an
            expression.
        first: the first held-out head (the defaults of the photo fit were chosen on heads 0-5; the
            benchmark scores heads from 20 on).
        seed: seed of the photos (placement, light, albedo, landmark noise).
        config: fitting settings (default :class:`FitPhotoConfig`).
        settings: :class:`pipeline.synthetic.photos.settings.PhotoSettings` (default ones).
        landmarks: ``"noisy"`` (the true landmarks + 1 px noise), ``"dlib"`` (dlib's detection on the
            render, HOG then the CNN), ``"mediapipe"`` (MediaPipe's 478 points, fitted with the dense layout)
            or ``"mediapipe68"`` (its 68 iBUG points); photos without a detection are skipped and listed in
            the settings.
        progress: called with each record as it is made.

    Returns:
        :class:`PhotoEvaluation` with records for ``jnr``, ``landmarks`` and ``template`` per photo.
    """
    _check_selection(first, n_neutral, n_expressive, landmarks)

    config = config or FitPhotoConfig()
    settings = settings or PhotoSettings()
    missed: list[str] = []
    asset = load_asset()
    rig = JointRig()
    neural, _ = load_neural(rig)
    template = head_vertices(rig, neural, np.zeros(NUM_PARAMETERS), np.zeros(LATENT), np.zeros(len(EXPRESSION_NAMES)))

    template_landmarks = landmark_positions(template, ibug68_embedding(asset), asset.faces)[0]
    records: list[PhotoRecord] = []

    def add(**fields) -> None:
        record = PhotoRecord(**fields)
        records.append(record)
        if progress is not None:
            progress(record)

    for kind, count in (("neutral", n_neutral), ("expressive", n_expressive)):
        for index in range(first, first + count):
            photo = synthetic_photo(
                index, expressive=kind == "expressive", seed=scan_seed(seed, "photo-" + kind, index), settings=settings
            )
            found = _photo_landmarks(photo, landmarks, asset)
            if found is None:
                missed.append(photo.name)
                continue
            target, dense = found
            t0 = time.perf_counter()
            fit = fit_photo(photo.image, target, focal=photo.focal, config=config, rig=rig, neural=neural, dense=dense)
            seconds = time.perf_counter() - t0
            template_pose = solve_pose(target, template_landmarks, photo.width, photo.height, photo.focal)
            _score_photo(photo, kind, _method_heads(fit, seconds, template, template_pose, rig, neural), asset, add)
    return PhotoEvaluation(
        tuple(records),
        settings={
            "first": first,
            "n_neutral": n_neutral,
            "n_expressive": n_expressive,
            "seed": seed,
            "landmarks": landmarks,
            "missed_by_detector": missed,
            "photo_settings": dict(settings.__dict__),
        },
    )
