"""The versioned rig asset: template mesh, joints and initial skinning weights in one ``.npz``.

``build_asset()`` regenerates everything from MakeHuman's data and code (deterministic); the committed file
``rig/assets/jnr_rig_v<template version>.npz`` (:data:`DEFAULT_ASSET`) is its output, loaded once per process
by :func:`load_asset`. Arrays are named and typed; the joint order is :data:`rig.joints.JOINT_NAMES` and the
region order is :data:`rig.template.REGION_NAMES` (both stored in the file and checked on load).
"""

from __future__ import annotations

import functools
import io
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.errors import SetupError
from rig.io.atomic import write_bytes_atomic
from rig.joints import JOINT_NAMES, PARENTS
from rig.skinning.initial import SkinningLayout
from rig.template import REGION_NAMES, TEMPLATE_VERSION


def cached_per_asset(build):
    """Decorator: ``build(asset)`` is computed once per asset object (held weakly, keyed by identity)."""
    cache: dict[int, tuple[weakref.ref, object]] = {}

    @functools.wraps(build)
    def get(asset):
        hit = cache.get(id(asset))
        if hit is not None and hit[0]() is asset:
            return hit[1]
        value = build(asset)
        cache[id(asset)] = (weakref.ref(asset), value)
        return value

    return get


ASSET_DIR = Path(__file__).resolve().parent / "assets"
DEFAULT_ASSET = ASSET_DIR / f"jnr_rig_v{TEMPLATE_VERSION}.npz"


def default_skinning_path() -> Path:
    """The committed learned skinning (``rig/assets/jnr_skinning_v<template version>.npz``)."""
    return ASSET_DIR / f"jnr_skinning_v{TEMPLATE_VERSION}.npz"


class AssetError(SetupError):
    """The rig asset is missing, corrupt or of another version."""


@dataclass(frozen=True)
class RigAsset:
    """Everything the rig needs, as numpy arrays.

    Attributes:
        vertices: ``(V, 3)`` float64 template vertices, mm.
        faces: ``(F, 3)`` int64.
        face_uvs: ``(F, 3, 2)`` float64 per-corner UVs.
        regions: ``(V,)`` int64 index into ``region_names``.
        region_names: region names.
        mirror: ``(V,)`` int64 vertex mirror map.
        joint_names: ``K`` joint names; ``parents``: ``(K,)`` int64; ``joint_positions``: ``(K, 3)`` mm.
        weight_rows, weight_cols, weight_free_index: the sparse symmetric layout of the weights.
        weight_free: ``(S,)`` float64 initial weights' free floats.
        eye_loops: ``(2, n)`` int64 eyelid-rim loops (left, right); ``mouth_loop``: ``(m,)`` lip rim.
        version: asset version.
        ict_rotation: ``(3, 3)``; ict_translation: ``(3,)`` mm: the ICT Face Model's frame -> the rig frame
            (``x_rig = ict_rotation @ x_ict + ict_translation``).
        ict_covered: ``(C,)`` int64 vertices that lie on the ICT surface; ict_triangle: ``(C,)`` int64 their
            ICT skin triangle, ict_barycentric: ``(C, 3)`` float64 (:mod:`rig.ict.transfer`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_uvs: np.ndarray
    regions: np.ndarray
    region_names: tuple[str, ...]
    mirror: np.ndarray
    joint_names: tuple[str, ...]
    parents: np.ndarray
    joint_positions: np.ndarray
    weight_rows: np.ndarray
    weight_cols: np.ndarray
    weight_free_index: np.ndarray
    weight_free: np.ndarray
    eye_loops: np.ndarray
    mouth_loop: np.ndarray
    version: int
    ict_rotation: np.ndarray
    ict_translation: np.ndarray
    ict_covered: np.ndarray
    ict_triangle: np.ndarray
    ict_barycentric: np.ndarray

    @property
    def layout(self) -> SkinningLayout:
        return SkinningLayout(
            self.weight_rows,
            self.weight_cols,
            self.weight_free_index,
            len(self.weight_free),
            (len(self.vertices), len(self.joint_names)),
        )

    @property
    def weights(self) -> np.ndarray:
        """Dense ``(V, K)`` initial weights."""
        return self.layout.dense(self.weight_free)

    def region_mask(self, *names: str) -> np.ndarray:
        """``(V,)`` bool: vertices in any of the named regions."""
        unknown = [n for n in names if n not in self.region_names]
        if unknown:
            raise KeyError(f"unknown region(s) {unknown}; regions are {list(self.region_names)}")
        return np.isin(self.regions, [self.region_names.index(n) for n in names])


def build_asset() -> RigAsset:
    """Generate the template, joints and initial weights from code and the committed ICT copy (deterministic):
    MakeHuman's topology with the ICT mean's shape (:func:`rig.ict.mean.ict_template`)."""
    from rig.ict.mean import ict_template

    made = ict_template()
    mesh, w = made.mesh, made.weights
    layout = SkinningLayout.from_weights(w, mesh.mirror)
    return RigAsset(
        vertices=mesh.vertices,
        faces=mesh.faces,
        face_uvs=mesh.face_uvs,
        regions=mesh.regions,
        region_names=REGION_NAMES,
        mirror=mesh.mirror,
        joint_names=JOINT_NAMES,
        parents=np.asarray(PARENTS, np.int64),
        joint_positions=made.joint_positions,
        weight_rows=layout.rows,
        weight_cols=layout.cols,
        weight_free_index=layout.free_index,
        weight_free=layout.free_values(w),
        eye_loops=np.stack(mesh.eye_loops),
        mouth_loop=mesh.mouth_loop,
        version=TEMPLATE_VERSION,
        ict_rotation=made.rotation,
        ict_translation=made.translation,
        ict_covered=made.registration.covered,
        ict_triangle=made.registration.triangle,
        ict_barycentric=made.registration.barycentric,
    )


def save_asset(asset: RigAsset, path: str | Path) -> None:
    """Write the asset as a compressed ``.npz`` (atomically)."""
    arrays = {k: getattr(asset, k) for k in RigAsset.__dataclass_fields__}
    arrays["region_names"] = np.array(asset.region_names)
    arrays["joint_names"] = np.array(asset.joint_names)
    arrays["version"] = np.array(asset.version)
    write_npz_atomic(path, arrays)


def write_npz_atomic(path: str | Path, arrays: dict[str, np.ndarray]) -> None:
    """``np.savez_compressed`` written atomically (:func:`rig.io.atomic.write_bytes_atomic`; missing parent
    folders are created)."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    write_bytes_atomic(path, buffer.getvalue(), make_parents=True)


def read_npz(path: str | Path, error: type[Exception], what: str, remedy: str, keys=None) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` file (``keys``, default all), read in full; a missing file raises
    ``error("<what> not found: <path> (<remedy>)")``, an unreadable one (or a missing key)
    ``error("<what> <path> is unreadable: ...")``."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{what} not found: {path} ({remedy})")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in (data.files if keys is None else keys)}
    except Exception as exc:  # zip/npz errors come in many types
        raise error(f"{what} {path} is unreadable: {exc}") from None


def read_asset(path: str | Path) -> RigAsset:
    """Read an asset file (no caching). Raises :class:`AssetError` when it is unusable."""
    fields = read_npz(
        path, AssetError, "rig asset", "rebuild it with `jnr rig build`", keys=RigAsset.__dataclass_fields__
    )
    fields["region_names"] = tuple(str(s) for s in fields["region_names"])
    fields["joint_names"] = tuple(str(s) for s in fields["joint_names"])
    fields["version"] = int(fields["version"])
    asset = RigAsset(**fields)
    if asset.version != TEMPLATE_VERSION or asset.joint_names != JOINT_NAMES or asset.region_names != REGION_NAMES:
        raise AssetError(
            f"rig asset {path} is version {asset.version} with another joint/region order; "
            f"this code expects version {TEMPLATE_VERSION} (rebuild it with `jnr rig build`)"
        )
    return asset


@functools.lru_cache(maxsize=4)
def load_asset(path: str | None = None) -> RigAsset:
    """The rig asset, loaded once per process (default: the committed one)."""
    return read_asset(path or DEFAULT_ASSET)
