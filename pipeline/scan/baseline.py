"""The free-form baseline that jnr's rig fit is compared against: trimesh's non-rigid ICP.

:func:`nricp_baseline` wraps :func:`trimesh.registration.nricp_amberg` (Amberg et al. 2007,
"Optimal Step Nonrigid ICP Algorithms for Surface Registration"), the registration a user with
only trimesh would reach for. The rig template is first moved into the cloud's frame by the same
similarity jnr's own fit starts from (``x_cloud = scale * R @ x_rig + t``), so both methods get
the same rigid pre-alignment and differ only in the non-rigid model.

What ``nricp_amberg`` (trimesh 4.x/5.x) does with a point-cloud target, read from its source:

* The target may be an ``(N, 3)`` array or a ``trimesh.PointCloud``; it is wrapped in a
  ``PointCloud`` either way. With the default ``use_faces=True`` it crashes on a point cloud
  (``AttributeError: 'PointCloud' object has no attribute 'faces'``), so we pass
  ``use_faces=False``: correspondences are then the nearest cloud *point* (a cKDTree query), not
  the nearest surface point. ``use_vertex_normals`` only matters for mesh targets and is ignored.
* Target normals cannot be supplied. When a step's normal weight ``wn > 0`` it estimates them by
  a plane fit of the ``neighbors_count`` nearest cloud points and uses ``|cos|`` (the orientation
  is unknown), so back-facing matches are *not* rejected by the normal term.
* Everything (source, target, landmarks) is first normalised by the *source* mesh:
  ``(x - source.centroid) / source.scale`` where ``scale`` is the length of the source's
  bounding-box diagonal. Hence ``distance_threshold`` and ``eps`` are in units of that diagonal,
  not of the target (trimesh's default 0.1 is ~42 mm on our head template); this wrapper converts
  ``distance_threshold_mm``. For the same reason the stiffness weights are unit-free: scaling
  the whole problem (mm -> m) leaves the normalised problem, and the result, unchanged.
* A vertex whose nearest cloud point is farther than the threshold gets data weight 0 and is
  carried only by the stiffness term: that is what lets a partial, single-view scan work. If too
  few vertices are within the threshold the normal equations are singular.
* ``steps`` rows are ``[ws, wl, wn, max_iter]``: stiffness, landmark weight (here: anchor weight),
  normal-weighting
  exponent (data weight *= ``|cos|**wn``), iteration cap. ``ws`` multiplies the (edge-length
  weighted) smoothness rows of the least-squares system, so it enters the energy squared. Each
  step also stops early once the weighted mean error improves by less than ``eps``.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from rig.errors import InputError

__all__ = ["DEFAULT_STEPS", "BaselineResult", "nricp_baseline"]

#: Default ``[ws, wl, wn, max_iter]`` schedule: one step, ``ws`` = 0.01, anchors ``wl`` = 1,
#: normal weighting ``wn`` = 0.5, at most 10 iterations (the eps rule usually ends it after ~4).
#:
#: Units: nricp_amberg divides everything by the template's bounding-box diagonal first, so ``ws``
#: is unit-free and needs no rescaling for millimetres. The useful range of ``ws`` on the rig template
#: is narrow: too stiff is one global affine map, too soft lets vertices snap to single cloud points.
#: A coarse-to-fine schedule with decreasing stiffness (Amberg et al.) was tried and was *worse*: the
#: stiff steps cannot represent a local deformation, so the nearly-affine template slides tangentially
#: to absorb it, and nearest-point data cannot pull it back (sliding along the surface costs nothing).
#: With a good rigid pre-alignment, as here, one step at the softest stable stiffness is the better
#: baseline (the trials and their figures: ``docs/fit_scan.md``, "The baseline"). ``wl`` weights the
#: anchors that hold unseen vertices at their pre-aligned positions (see :func:`nricp_baseline`); 0
#: turns them off.
DEFAULT_STEPS: tuple[tuple[float, float, float, int], ...] = ((0.01, 1.0, 0.5, 10),)


@dataclass(frozen=True)
class BaselineResult:
    """Result of :func:`nricp_baseline`.

    Attributes:
        vertices: ``(V, 3)`` float64 registered template vertices in the cloud's frame, mm
            (same order as the template; faces unchanged).
        seconds: wall time of the ``nricp_amberg`` call alone, s (excludes validation,
            subsampling and the pre-alignment).
        steps: the ``[ws, wl, wn, max_iter]`` schedule that was used, as a list of lists.
    """

    vertices: np.ndarray
    seconds: float
    steps: list = field(default_factory=list)


def _array(x, name: str, shape: tuple[int | None, ...]) -> np.ndarray:
    """``x`` as a finite float64 array of ``shape`` (``None`` = any size), else ValueError."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(
            f"nricp_baseline: {name} must be a float array of shape {shape}; got {type(x).__name__}"
        ) from None
    if a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape)):
        raise InputError(f"nricp_baseline: {name} must have shape {shape}; got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"nricp_baseline: {name} contains NaN or inf")
    return a


def _check_steps(steps) -> list[list]:
    """Validate a step schedule; returns it as a list of ``[ws, wl, wn, max_iter]`` lists."""
    try:
        rows = [list(s) for s in steps]
    except TypeError:
        raise InputError("nricp_baseline: steps must be a sequence of [ws, wl, wn, max_iter]") from None
    if not rows:
        raise InputError("nricp_baseline: steps must not be empty")
    out = []
    for i, row in enumerate(rows):
        if len(row) != 4:
            raise InputError(f"nricp_baseline: steps[{i}] must be [ws, wl, wn, max_iter]; got {row}")
        ws, wl, wn, max_iter = row
        if not all(np.isfinite(v) and v >= 0 for v in (ws, wl, wn)) or ws <= 0:
            raise InputError(f"nricp_baseline: steps[{i}] needs ws > 0 and wl, wn >= 0 finite; got {row}")
        if max_iter is not None and (int(max_iter) != max_iter or max_iter < 1):
            raise InputError(f"nricp_baseline: steps[{i}] max_iter must be a positive int or None; got {max_iter}")
        out.append([float(ws), float(wl), float(wn), None if max_iter is None else int(max_iter)])
    return out


def nricp_baseline(
    template_vertices: np.ndarray,
    faces: np.ndarray,
    cloud: np.ndarray,
    *,
    rotation: np.ndarray,
    translation: np.ndarray,
    scale: float = 1.0,
    cloud_normals: np.ndarray | None = None,
    steps: list | None = None,
    distance_threshold_mm: float = 10.0,
    max_points: int | None = 20000,
    seed: int = 0,
) -> BaselineResult:
    """Register the template to a point cloud with trimesh's non-rigid ICP (the baseline).

    The template is moved into the cloud frame, ``x = scale * rotation @ x_rig + translation``,
    then deformed by :func:`trimesh.registration.nricp_amberg` towards the cloud (nearest-point
    correspondences, no landmarks). Template vertices whose nearest cloud point is farther than
    ``distance_threshold_mm`` get no data term in that iteration and follow their neighbours, so
    a partial single-view scan leaves the unseen side of the head smoothly carried along. Vertices
    with no cloud point within the threshold *after the pre-alignment* are also passed to
    nricp_amberg as landmarks pinned to their pre-aligned positions (weight ``wl`` of each step):
    without this, their per-vertex affine maps are extrapolated from the scan's border and the back
    of the head drifts (``docs/fit_scan.md``, "The baseline").

    Args:
        template_vertices: ``(V, 3)`` template vertices in rig space, mm.
        faces: ``(F, 3)`` int triangle indices into ``template_vertices``.
        cloud: ``(N, 3)`` target points in the cloud's frame, mm (N >= 4).
        rotation: ``(3, 3)`` rotation matrix (rig -> cloud), det +1.
        translation: ``(3,)`` translation, mm.
        scale: similarity scale (> 0), unitless.
        cloud_normals: optional ``(N, 3)`` normals. Validated but **not used**: nricp_amberg has
            no way to take target normals for a point cloud (it estimates them itself), so a
            ``UserWarning`` is issued when they are given.
        steps: ``[ws, wl, wn, max_iter]`` rows (see the module docstring); default
            :data:`DEFAULT_STEPS`.
        distance_threshold_mm: matches farther than this are ignored, mm (> 0).
        max_points: if the cloud has more points, a deterministic random subset of this size
            (drawn with ``seed``) is used; ``None`` keeps all points.
        seed: seed of the subsampling.

    Returns:
        :class:`BaselineResult` with the ``(V, 3)`` registered vertices in the cloud frame, mm.

    Raises:
        ValueError: on wrong shapes, NaN/inf, a non-rotation, a bad schedule or threshold, or when
            fewer than 4 template vertices lie within ``distance_threshold_mm`` of the cloud after
            the pre-alignment (the registration would be singular).

    Example:
        >>> from rig.asset import load_asset
        >>> a = load_asset()
        >>> res = nricp_baseline(a.vertices, a.faces, cloud_mm, rotation=R, translation=t)  # doctest: +SKIP
        >>> res.vertices.shape  # doctest: +SKIP
        (4978, 3)
    """
    import trimesh
    from scipy.spatial import cKDTree
    from trimesh.registration import nricp_amberg

    verts = _array(template_vertices, "template_vertices", (None, 3))
    try:
        tri = np.asarray(faces)
    except (TypeError, ValueError):
        raise InputError("nricp_baseline: faces must be an (F, 3) int array") from None
    if tri.ndim != 2 or tri.shape[1] != 3 or len(tri) == 0 or not np.issubdtype(tri.dtype, np.integer):
        raise InputError(f"nricp_baseline: faces must be a non-empty (F, 3) int array; got {tri.shape} {tri.dtype}")
    if tri.min() < 0 or tri.max() >= len(verts):
        raise InputError(f"nricp_baseline: faces index outside [0, {len(verts)}); got range [{tri.min()}, {tri.max()}]")
    points = _array(cloud, "cloud", (None, 3))
    if len(points) < 4:
        raise InputError(f"nricp_baseline: cloud needs at least 4 points; got {len(points)}")
    R = _array(rotation, "rotation", (3, 3))
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) <= 0:
        raise InputError(
            f"nricp_baseline: rotation must be a proper rotation (R^T R = I, det +1); got det {np.linalg.det(R):.6g}"
        )
    t = _array(translation, "translation", (3,))
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"nricp_baseline: scale must be finite and > 0; got {scale}")
    if not (np.isfinite(distance_threshold_mm) and distance_threshold_mm > 0):
        raise InputError(f"nricp_baseline: distance_threshold_mm must be finite and > 0; got {distance_threshold_mm}")
    if max_points is not None and (int(max_points) != max_points or max_points < 4):
        raise InputError(f"nricp_baseline: max_points must be an int >= 4 or None; got {max_points}")
    if cloud_normals is not None:
        _array(cloud_normals, "cloud_normals", (len(points), 3))
        warnings.warn(
            "nricp_baseline: cloud_normals are ignored; trimesh's nricp_amberg cannot take target "
            "normals for a point cloud and estimates them from point neighbourhoods",
            UserWarning,
            stacklevel=2,
        )
    schedule = _check_steps(DEFAULT_STEPS if steps is None else steps)

    if max_points is not None and len(points) > max_points:
        keep = np.random.default_rng(seed).choice(len(points), int(max_points), replace=False)
        points = points[np.sort(keep)]

    source = trimesh.Trimesh(float(scale) * verts @ R.T + t, tri, process=False)  # process=False keeps order
    # nricp_amberg measures distances after dividing by the source's bounding-box diagonal.
    threshold = float(distance_threshold_mm) / float(source.scale)
    unseen = cKDTree(points).query(source.vertices)[0] > distance_threshold_mm
    n_close = int((~unseen).sum())
    if n_close < 4:
        raise InputError(
            f"nricp_baseline: only {n_close} template vertices lie within "
            f"{distance_threshold_mm} mm of the cloud after the pre-alignment (need >= 4); "
            "check rotation/translation/scale and the cloud's units"
        )

    start = time.perf_counter()
    # Anchors: vertices with no cloud point within the threshold after the pre-alignment (the unseen
    # side of a partial scan) are held at their pre-aligned positions through nricp_amberg's landmark
    # term, weighted per step by wl. Without them their per-vertex affine transforms are only
    # extrapolated from the scan's border and the back of the head drifts by centimetres.
    anchors = np.flatnonzero(unseen)
    use_anchors = len(anchors) > 0 and any(row[1] > 0 for row in schedule)
    registered = nricp_amberg(
        source,
        points,
        source_landmarks=anchors if use_anchors else None,
        target_positions=source.vertices[anchors].copy() if use_anchors else None,
        steps=schedule,
        distance_threshold=threshold,
        use_faces=False,
        use_vertex_normals=False,
    )
    seconds = time.perf_counter() - start

    registered = np.asarray(registered, dtype=np.float64)
    if registered.shape != verts.shape or not np.all(np.isfinite(registered)):
        raise RuntimeError("nricp_baseline: nricp_amberg returned a non-finite or mis-shaped result")
    return BaselineResult(vertices=registered, seconds=seconds, steps=schedule)
