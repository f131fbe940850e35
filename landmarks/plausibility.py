"""Is a set of 68 2D landmarks a plausible face in this image?

User-supplied landmark files (``jnr fit PHOTO --landmarks FILE``) can be garbage: points thousands of
pixels outside the photo, left/right labels swapped, all points on one spot, another point order.
:func:`check_landmarks_2d` rejects those with a one-line :class:`LandmarkPlausibilityError` before any
fitting starts, and returns a :class:`PlausibilityReport` for the accepted ones.

Points are ``(68, 2)`` float **0-based OpenCV pixel coordinates** (x right, y down) in iBUG-68 order
(:data:`landmarks.ibug68.names.IBUG68_NAMES`), as :mod:`landmarks.formats` reads and :mod:`landmarks.detect`
detects them. Messages name landmarks by their 0-based index.

The checks, in order (the first failing one raises):

1. **finite**: every coordinate is a finite number.
2. **inside the image**: at least :data:`MIN_FRACTION_INSIDE` of the 68 landmarks lie inside the image
   (the pixel rectangle ``[-0.5, width - 0.5] x [-0.5, height - 0.5]``), and none lies farther outside
   it than :data:`MAX_OUTSIDE_FACE_SIZES` times the bounding-box diagonal of the landmarks inside it.
   A face cut by the image border is legal (a detector extrapolates its hidden landmarks); points in
   another image's coordinates, or a stray point far away, are not.
3. **not degenerate**: the points are neither coincident nor (nearly) collinear: the minor principal
   spread of the 68 points is at least :data:`MIN_SPREAD_RATIO` of the major one.
4. **face-like**: the affine camera (:func:`fit_affine_camera`) that best maps the reference
   configuration (:func:`reference_landmarks`, the template's 68 embedded landmarks in the frontal
   view) onto the 51 inner landmarks (17-67) leaves an RMS residual of at most
   :data:`MAX_AFFINE_RESIDUAL` face sizes (:func:`face_affine_fit`). The jaw contour (0-16) is left
   out of this fit: it is the silhouette seen from the camera, which slides across the cheek as the
   head turns (only check 2 applies to it).
5. **large enough**: the outer eye corners (36, 45; the 300-W inter-ocular distance) are at least
   :data:`MIN_INTEROCULAR_PX` apart. (After check 4, so random points whose corners happen to be
   close are reported as not face-like.)
6. **not mirrored**: the fitted map keeps the orientation: the determinant of its ``(2, 2)`` part
   acting on the frontal plane (the 2D affine map of the frontal configuration) is positive. Every
   real view of a face from the front -- turned, tilted, rolled, even upside down, through any lens --
   keeps it; a negative determinant means the labels of the subject's left and right are swapped
   (the face would be seen from behind). dlib run on a mirrored photo still labels its points
   correctly, so only files made by swapping labels (or by flipping coordinates) fail here.

The *face size* is the diagonal of the 68 landmarks' bounding box, pixels (check 2 uses the landmarks
inside the image only, so that a stray point cannot widen its own allowance).

The affine camera is the 2D affine map of the frontal configuration plus a depth column (8 instead of
6 parameters): it absorbs how a turned or tilted head moves the nose and brows against the eyes, so
real poses fit about twice as tightly as with the 2D map alone (measured on the sample of
:data:`MAX_AFFINE_RESIDUAL`: worst pose 0.04 face sizes instead of 0.08, and 0.12 for the 2D map on
all 68 points), while shuffled or random points fit no better (0.20 at best either way).

Example:
    >>> import numpy as np
    >>> frontal = reference_landmarks()[:, :2]              # (68, 2) frontal view, unit RMS radius
    >>> points = 100.0 * frontal + np.array([320.0, 240.0])  # a face in a 640 x 480 photo
    >>> report = check_landmarks_2d(points, 640, 480)
    >>> report.determinant_sign, report.fraction_inside
    (1, 1.0)
    >>> from landmarks.ibug68.names import IBUG68_MIRROR
    >>> check_landmarks_2d(points[list(IBUG68_MIRROR)], 640, 480, source="face.pts")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    landmarks.plausibility.LandmarkPlausibilityError: face.pts: landmarks look mirrored left/right: ...
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from landmarks.ibug68.embedding import ibug68_embedding
from landmarks.ibug68.names import JAW_CONTOUR
from landmarks.ibug68.positions import landmark_positions
from rig.asset import load_asset
from rig.errors import InputError
from rig.geometry import RIG_TO_OPENCV

NUM_LANDMARKS = 68
RIGHT_EYE_OUTER = 36
"""Index of the subject's right outer eye corner (image left in a frontal photo)."""
LEFT_EYE_OUTER = 45
"""Index of the subject's left outer eye corner."""
INNER_LANDMARKS = tuple(i for i in range(NUM_LANDMARKS) if i not in JAW_CONTOUR)
"""The 51 landmarks (17-67: brows, nose, eyes, lips) used in the affine fit."""

MIN_FRACTION_INSIDE = 0.5
"""At least this fraction of the 68 landmarks must lie inside the image.

Set by rule, not fitted: a face may be cut by the image border (a detector then extrapolates the hidden
points), but if most of it is outside, the points belong to another image (another resolution or crop)
or to no image. All synthetic poses and both dlib detections of the astronaut have 1.0; a 5000 px shift
has 0.0."""

MAX_OUTSIDE_FACE_SIZES = 1.0
"""No landmark may lie farther outside the image than this many face sizes (landmark bounding-box
diagonals).

Set by rule: a landmark of a face cut by the border lies at most about one face size beyond it (when the
whole face would be outside); anything farther is not part of a face in the photo. The face size here
is that of the landmarks inside the image (at least half of them, by :data:`MIN_FRACTION_INSIDE`), which
a stray point cannot enlarge; for a face half outside it is still about 0.8 of the whole face's."""

MIN_INTEROCULAR_PX = 5.0
"""Smallest accepted distance between the outer eye corners (landmarks 36 and 45), pixels.

dlib's HOG detector finds faces down to about 40 px wide (``upsample=1``), whose outer corners are
about 18 px apart; the smallest distance in the synthetic poses (30 px frontal inter-ocular, yaw 60) is
about 20 px. Below 5 px the eye landmarks are sub-pixel detail: rejects a face-like configuration scaled
down to nothing (exactly coincident points are already rejected as degenerate)."""

MIN_SPREAD_RATIO = 0.1
"""Smallest accepted ratio of the points' minor to major principal spread (standard deviations along the
principal axes of the 68 points).

Measured on 3000 synthetic poses (yaw -60..60, pitch -30..30, any roll, expressions; see
:data:`MAX_AFFINE_RESIDUAL`): the smallest ratio is 0.42 (a face turned 60 degrees is narrow);
collinear and coincident points have 0. 0.1 is 4x below the narrowest real face."""

MAX_AFFINE_RESIDUAL = 0.10
"""Largest accepted RMS residual of the affine-camera fit of :func:`reference_landmarks` to the 51 inner
landmarks, in face sizes (the 68 landmarks' bounding-box diagonal).

Chosen on synthetic data (``tests/landmarks/test_plausibility.py`` repeats a smaller sample). Positives:
3000 views, half of the template and half of the 100 held-out population heads (:mod:`pipeline.synthetic.population`); a
third neutral, a third with ``jawOpen`` in 0..1, a third with random subsets of the 52 ARKit expressions
(:mod:`rig.expressions`) within their limits; yaw -60..60, pitch -30..30, roll -180..180 degrees;
orthographic or perspective at 250-2000 mm; jaw contour as the silhouette seen from the camera
(:func:`landmarks.ibug68.contour.contour_landmarks`); 2 px Gaussian noise per coordinate at 100 px frontal
inter-ocular distance. Their residual: median 0.015, 99th percentile 0.036, max 0.044 (large yaw and
pitch with an expression). dlib on ``skimage.data.astronaut()``: 0.024, and 0.023 on its mirror image.
Negatives, on 1000 of those faces: 68 uniform random points in the face's bounding box, min 0.23 (median
0.29); the landmark order shuffled, min 0.20 (median 0.25). 0.10 (about the geometric mean of 0.044 and
0.20) is 2.3x above the worst positive and 2x below the best negative. Mirrored labels fit as well as
their originals (a reflection is affine), which is why check 6 exists."""


class LandmarkPlausibilityError(InputError):
    """The 2D landmarks are not a plausible face in the image (one line, prefixed with the source)."""


@dataclass(frozen=True)
class PlausibilityReport:
    """What :func:`check_landmarks_2d` measured on accepted landmarks."""

    affine_residual: float
    """RMS distance of the 51 inner landmarks from the affine-camera fit of the reference, in face sizes."""
    determinant_sign: int
    """Sign of the determinant of the fitted map's frontal-plane part: ``+1`` (orientation kept; ``-1``,
    mirrored labels, is rejected)."""
    view_cosine: float
    """Cosine between the fitted affine camera's viewing axis and the face's forward axis, ``[-1, 1]``:
    1 frontal, about ``cos(yaw) cos(pitch)`` for a turned head, 0 profile, negative mirrored."""
    fraction_inside: float
    """Fraction of the 68 landmarks inside the image rectangle, ``[0, 1]``."""
    interocular_px: float
    """Distance between the outer eye corners (36, 45), pixels."""
    face_size_px: float
    """Diagonal of the 68 landmarks' bounding box, pixels."""
    spread_ratio: float
    """Minor over major principal spread of the 68 points, ``[0, 1]``."""


@functools.lru_cache(maxsize=1)
def _reference() -> np.ndarray:
    asset = load_asset()
    points3d = landmark_positions(asset.vertices, ibug68_embedding(asset), asset.faces)[0]  # (68, 3) rig, mm
    # Frontal view in camera axes: rig +X (subject's left) -> x right, +Y (up) -> y down, +Z -> towards the camera.
    ref = points3d @ RIG_TO_OPENCV.T
    ref -= ref.mean(axis=0)
    ref /= np.sqrt((ref[:, :2] ** 2).sum(axis=1).mean())
    ref.flags.writeable = False
    return ref


def reference_landmarks() -> np.ndarray:
    """The reference configuration: ``(68, 3)`` float64, read-only, unitless.

    The template's embedded iBUG-68 landmarks (rest pose, neutral, static jaw contour) in the axes of a
    camera looking at the face from the front: x = rig X (the subject's left is the image right),
    y = -rig Y (down), z = -rig Z (away from the camera); centred, and scaled so that the frontal
    orthographic view ``[:, :2]`` has unit RMS radius. Computed once from the committed asset.

    Example:
        >>> ref = reference_landmarks()
        >>> ref.shape, bool(ref[45, 0] > ref[36, 0]), bool(ref[8, 1] > ref[27, 1])  # left eye right, chin down
        ((68, 3), True, True)
    """
    return _reference()


def _face_size(points: np.ndarray) -> float:
    """Diagonal of the bounding box of ``(N, 2)`` points, pixels."""
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def fit_affine_camera(reference: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares affine camera ``points ~ reference @ A.T + t``.

    With ``(N, 2)`` references this is a 2D affine map; with ``(N, 3)`` references an affine camera
    (orthographic projection after any linear map, plus a 2D shift).

    Args:
        reference: ``(N, D)`` points, D = 2 or 3, not all in one (D-1)-dimensional plane.
        points: ``(N, 2)`` image points, pixels.

    Returns:
        ``(A, t, residuals)``: ``(2, D)`` matrix, ``(2,)`` translation and ``(N, 2)`` residuals
        ``points - (reference @ A.T + t)``, in the units of ``points``.

    Raises:
        ValueError: shapes do not match, or ``N <= D``.

    Example:
        >>> src = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
        >>> A, t, r = fit_affine_camera(src, src @ np.array([[2.0, 0.0], [0.0, -3.0]]).T + 5.0)
        >>> np.round(A, 6).tolist(), np.round(t, 6).tolist(), bool(np.abs(r).max() < 1e-9)
        ([[2.0, 0.0], [0.0, -3.0]], [5.0, 5.0], True)
    """
    reference = np.asarray(reference, np.float64)
    points = np.asarray(points, np.float64)
    if (
        reference.ndim != 2
        or reference.shape[1] not in (2, 3)
        or points.shape != (len(reference), 2)
        or len(reference) <= reference.shape[1]
    ):
        raise InputError(
            f"fit_affine_camera: reference must be (N, 2) or (N, 3) and points (N, 2) with "
            f"N > D, got {reference.shape} and {points.shape}"
        )
    design = np.concatenate([reference, np.ones((len(reference), 1))], axis=1)  # (N, D + 1)
    solution, *_ = np.linalg.lstsq(design, points, rcond=None)  # (D + 1, 2)
    return solution[:-1].T, solution[-1], points - design @ solution


def face_affine_fit(points: np.ndarray) -> tuple[float, float]:
    """How well an affine view of a face explains 68 landmarks (checks 4 and 5 of the module docstring).

    Fits :func:`fit_affine_camera` from :func:`reference_landmarks` to the 51 inner landmarks
    (:data:`INNER_LANDMARKS`); does not validate its input (:func:`check_landmarks_2d` does).

    Args:
        points: ``(68, 2)`` finite pixel coordinates (OpenCV, x right, y down), iBUG-68 order.

    Returns:
        ``(residual, view_cosine)``: the RMS residual of the inner landmarks in face sizes (the 68
        points' bounding-box diagonal), and the cosine between the fitted camera's viewing axis and the
        face's forward axis, whose sign is the sign of the determinant of the map's frontal-plane part
        (``[-1, 1]``; negative: mirrored labels).

    Example:
        >>> frontal = reference_landmarks()[:, :2]
        >>> residual, cosine = face_affine_fit(50.0 * frontal * [-1.0, 1.0] + 100.0)  # a reflection
        >>> bool(residual < 1e-9), round(cosine, 6)
        (True, -1.0)
    """
    pts = np.asarray(points, np.float64)
    inner = list(INNER_LANDMARKS)
    affine, _, residuals = fit_affine_camera(_reference()[inner], pts[inner])
    residual = float(np.sqrt((residuals**2).sum(axis=1).mean())) / max(_face_size(pts), np.finfo(float).tiny)
    det = float(np.linalg.det(affine[:, :2]))
    view_cosine = det / max(float(np.linalg.norm(np.cross(affine[0], affine[1]))), np.finfo(float).tiny)
    return residual, view_cosine


def check_landmarks_2d(
    points: np.ndarray, width: int, height: int, *, source: str = "landmarks", mapped_from: int | None = None
) -> PlausibilityReport:
    """Check that 68 2D landmarks are a plausible face in a ``width x height`` image (checks: module
    docstring).

    Args:
        points: ``(68, 2)`` float 0-based OpenCV pixel coordinates (x right, y down), iBUG-68 order.
        width, height: image size, pixels (positive integers).
        source: where the points came from (e.g. the file name); prefixes the error message.
        mapped_from: the count of MediaPipe points the 68 were mapped from (468 or 478), so that a message
            speaks of the file's points and their order, not of iBUG-68 indices the user never wrote.

    Returns:
        :class:`PlausibilityReport` of the accepted points.

    Raises:
        LandmarkPlausibilityError: one line, ``"{source}: ..."``, naming the first failed check; also
            for a wrong shape or dtype of ``points`` or a bad image size.

    Example:
        >>> pts = 80.0 * reference_landmarks()[:, :2] + 200.0
        >>> round(check_landmarks_2d(pts, 400, 400).view_cosine, 6)
        1.0
        >>> check_landmarks_2d(pts + 5000.0, 400, 400, source="a.pts")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        landmarks.plausibility.LandmarkPlausibilityError: a.pts: landmarks lie outside the 400x400 image: ...
    """

    def fail(message: str) -> LandmarkPlausibilityError:
        return LandmarkPlausibilityError(f"{source}: {message}")

    dense = f"the {mapped_from} MediaPipe points" if mapped_from else None

    pts = np.asarray(points)
    if pts.shape != (NUM_LANDMARKS, 2):
        raise fail(f"expected {NUM_LANDMARKS} landmarks of shape ({NUM_LANDMARKS}, 2), got shape {pts.shape}")
    if not (np.issubdtype(pts.dtype, np.integer) or np.issubdtype(pts.dtype, np.floating)):
        raise fail(f"landmarks must be real numbers, got dtype {pts.dtype}")
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
            raise fail(f"image {name} must be a positive integer, got {value!r}")
    pts = pts.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
    if len(bad):
        raise fail(
            f"{len(bad)} landmarks have non-finite coordinates (NaN or inf), the first is landmark {bad[0]} "
            f"(0-based; number {bad[0] + 1} counting from 1)"
        )

    # 2. inside the image
    low, high = np.array([-0.5, -0.5]), np.array([width - 0.5, height - 0.5])
    outside_px = np.linalg.norm(np.maximum(low - pts, 0.0) + np.maximum(pts - high, 0.0), axis=1)  # (68,)
    inside = outside_px == 0.0
    where = f"landmarks lie outside the {width}x{height} image"
    if np.all((pts >= -0.05) & (pts <= 1.05)) and min(width, height) > 20:
        raise fail(
            f"{dense or 'the landmarks'} all lie within [0, 1]: normalised coordinates (as MediaPipe's "
            f"NormalizedLandmark gives them)? jnr reads pixels: multiply x by the image width ({width}) and y by "
            f"its height ({height})"
        )
    if inside.sum() < MIN_FRACTION_INSIDE * NUM_LANDMARKS:
        if dense:
            raise fail(f"{where}: {dense} are not in this image's pixel coordinates (most of them lie outside it)")
        raise fail(
            f"{where}: only {inside.sum()} of {NUM_LANDMARKS} are inside it (need at least "
            f"{MIN_FRACTION_INSIDE:.0%}); are they in this image's pixel coordinates?"
        )
    inside_size = _face_size(pts[inside])
    worst = int(np.argmax(outside_px))
    if outside_px[worst] > MAX_OUTSIDE_FACE_SIZES * inside_size:
        raise fail(
            f"{where}: landmark {worst} (0-based) is {outside_px[worst]:.0f} px beyond its border, more than "
            f"{MAX_OUTSIDE_FACE_SIZES:g} face size ({inside_size:.0f} px, the bounding-box diagonal of "
            f"the landmarks inside the image)"
        )

    # 3. degenerate: coincident or collinear
    spread = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    spread_ratio = float(spread[1] / spread[0]) if spread[0] > 0.0 else 0.0
    if spread_ratio < MIN_SPREAD_RATIO:
        raise fail(
            f"landmarks are degenerate (coincident or collinear): their spread across their main axis is "
            f"{spread_ratio:.3f} of that along it (need at least {MIN_SPREAD_RATIO:g}; spread "
            f"{spread[0]:.2f} px along it)"
        )

    # 4. face-like: affine camera of the reference on the inner landmarks
    residual, view_cosine = face_affine_fit(pts)
    if residual > MAX_AFFINE_RESIDUAL:
        if dense:
            raise fail(
                f"{dense} do not look like a face in MediaPipe's Face Mesh order (the best affine view of a face "
                f"leaves an RMS residual of {residual:.3f} face sizes, at most {MAX_AFFINE_RESIDUAL:g}); check the "
                "point order (reversed or shuffled?) and that they are MediaPipe's"
            )
        raise fail(
            f"landmarks do not look like a face in iBUG-68 order: the best affine view of a face leaves "
            f"an RMS residual of {residual:.3f} face sizes (at most {MAX_AFFINE_RESIDUAL:g}); check the "
            f"point order and the file's convention"
        )

    # 5. size
    interocular = float(np.linalg.norm(pts[LEFT_EYE_OUTER] - pts[RIGHT_EYE_OUTER]))
    if interocular < MIN_INTEROCULAR_PX:
        raise fail(
            f"landmarks are too small: the outer eye corners ({RIGHT_EYE_OUTER}, {LEFT_EYE_OUTER}) are "
            f"{interocular:.2f} px apart (need at least {MIN_INTEROCULAR_PX:g} px)"
        )

    # 6. orientation: the frontal-plane part of the map must not be a reflection
    if view_cosine <= 0.0:
        if dense:
            raise fail(
                f"{dense} look mirrored left/right: matching them to a face needs a reflection (x flipped, or "
                "points from a mirrored image); detect them again on this photo"
            )
        raise fail(
            "landmarks look mirrored left/right: points 36-41 must be the subject's right eye (image "
            "left in a frontal photo), 42-47 the left, 0-7 the right jaw; matching them to a face needs a "
            "reflection. Swap the labels with landmarks.ibug68.names.IBUG68_MIRROR, or detect them again"
        )
    return PlausibilityReport(
        affine_residual=residual,
        determinant_sign=1,
        view_cosine=view_cosine,
        fraction_inside=float(inside.mean()),
        interocular_px=interocular,
        face_size_px=_face_size(pts),
        spread_ratio=spread_ratio,
    )
