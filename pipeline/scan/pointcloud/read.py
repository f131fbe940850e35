"""Reading point-cloud files: ``.ply``, ``.obj``, ``.xyz`` / ``.txt`` / ``.csv`` and ``.npy``
(:func:`read_point_cloud`; the formats: :mod:`pipeline.scan.pointcloud`)."""

from __future__ import annotations

import io
import os

import numpy as np

from pipeline.scan.pointcloud.cloud import CloudError, PointCloud
from pipeline.scan.pointcloud.validate import LARGE_CLOUD_POINTS, SUBSAMPLE_POINTS, validate_points
from rig.errors import InputError
from rig.io.inputs import regular_file

SUPPORTED_EXTENSIONS = (".ply", ".obj", ".xyz", ".txt", ".csv", ".npy")


MAX_CLOUD_BYTES = 4 << 30
"""The largest point-cloud file read (4 GiB)."""


def read_point_cloud(
    path,
    *,
    units: str = "auto",
    frame: str = "y-up",
    min_points: int = 500,
    large_cloud_points: int = LARGE_CLOUD_POINTS,
    subsample_points: int = SUBSAMPLE_POINTS,
) -> PointCloud:
    """Read a point cloud file and return it validated, in mm and in the rig frame (reduced if large).

    Args:
        path: a ``.ply``, ``.obj``, ``.xyz``, ``.txt``, ``.csv`` or ``.npy`` file (see :mod:`pipeline.scan.pointcloud`).
            PLY/OBJ meshes are fine: their vertices are used, and their vertex normals only if stored.
        units: ``"auto"`` (detect mm, cm or m from the cloud's size), ``"mm"``, ``"cm"``, ``"m"`` or ``"in"``.
        frame: ``"y-up"`` (the file is in the rig frame) or ``"opencv"`` (x right, y down, z forward).
        min_points: fewest distinct points accepted.
        large_cloud_points, subsample_points: clouds of more points than the first are replaced by a
            random subsample of the second (:func:`validate_points`).

    Returns:
        A :class:`PointCloud` with ``(N, 3)`` float64 points in mm and ``(N, 3)`` unit normals or None.

    Raises:
        FileNotFoundError: the file does not exist.
        CloudError: unknown extension, unparseable file or a cloud that fails :func:`validate_points`.

    Example:
        >>> cloud = read_point_cloud("scan.ply", units="auto")  # doctest: +SKIP
        >>> cloud.points.shape, cloud.units  # doctest: +SKIP
        ((48213, 3), 'm')
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in SUPPORTED_EXTENSIONS:
        raise CloudError(
            f"{path}: unknown point-cloud extension {ext or '(none)'!r}; supported: {', '.join(SUPPORTED_EXTENSIONS)}"
        )
    try:
        regular_file(path, "point cloud", MAX_CLOUD_BYTES)
    except InputError as exc:
        raise CloudError(str(exc)) from None
    reader = {".ply": _read_ply, ".obj": _read_obj, ".npy": _read_npy}.get(ext, _read_table)
    try:
        points, normals, stored = reader(path)
    except CloudError:
        raise
    except (ValueError, TypeError, KeyError, IndexError, EOFError) as exc:  # parser errors, not I/O errors
        raise CloudError(
            f"{path}: cannot parse this {ext} file ({type(exc).__name__}: {exc}); is it a valid, complete {ext} file?"
        ) from exc
    return validate_points(
        points,
        normals,
        units=units,
        frame=frame,
        min_points=min_points,
        path=path,
        large_cloud_points=large_cloud_points,
        subsample_points=subsample_points,
        stored_dtype=stored,
    )


def _read_ply(path: str) -> tuple[np.ndarray, np.ndarray | None, np.dtype | None]:
    # trimesh parses both encodings; for a point cloud it returns normals only in the raw vertex data
    # (metadata['_ply_raw']), so take x y z and nx ny nz from there, which also works for meshes.
    from trimesh.exchange.ply import load_ply

    with open(path, "rb") as fh:  # a point cloud needs no texture: a TextureFile the header names is not opened
        loaded = load_ply(fh, skip_materials=True)
    raw = loaded.get("metadata", {}).get("_ply_raw", {}).get("vertex")
    if raw is None:
        vertices = loaded.get("vertices")
        if vertices is None:
            raise CloudError(f"{path}: the PLY file has no 'vertex' element; is it a point cloud or mesh?")
        return np.asarray(vertices, dtype=np.float64), None, np.asarray(vertices).dtype
    data = raw["data"]
    names = set(data.keys()) if isinstance(data, dict) else set(data.dtype.names or ())
    if not {"x", "y", "z"} <= names:
        raise CloudError(f"{path}: the PLY vertices have no x y z properties (found {sorted(names)})")
    points = _columns(data, ("x", "y", "z"))
    normals = _columns(data, ("nx", "ny", "nz")) if {"nx", "ny", "nz"} <= names else None
    return points, normals, np.asarray(data["x"]).dtype


def _columns(data, names: tuple[str, str, str]) -> np.ndarray:
    """``(N, 3)`` float64 from three named fields, filled in place rather than stacked from three float64
    copies (faster and steadier on a 10 M-point cloud with normals: ``docs/fit_scan.md``, "Large clouds")."""
    first = np.asarray(data[names[0]]).reshape(-1)
    out = np.empty((len(first), 3), dtype=np.float64)
    for i, name in enumerate(names):
        out[:, i] = np.asarray(data[name]).reshape(-1)
    return out


def _read_obj(path: str) -> tuple[np.ndarray, np.ndarray | None, None]:
    # A line scan is enough: trimesh re-indexes OBJ vertices by face corners, which would break the
    # one-normal-per-vertex pairing we need, and drops vertices of point-only OBJ files.
    vertices, vertex_normals = [], []
    with open(path, encoding="utf-8") as fh:
        for number, line in enumerate(fh, 1):
            tokens = line.split()
            if not tokens or tokens[0] not in ("v", "vn"):
                continue
            if len(tokens) < 4:
                raise CloudError(f"{path}: line {number}: {tokens[0]!r} needs 3 numbers, got {line.strip()!r}")
            try:
                xyz = (float(tokens[1]), float(tokens[2]), float(tokens[3]))
            except ValueError as exc:
                raise CloudError(f"{path}: line {number}: not a number in {line.strip()!r}") from exc
            (vertices if tokens[0] == "v" else vertex_normals).append(xyz)
    points = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    if vertex_normals and len(vertex_normals) != len(vertices):
        # vn indexed per face corner cannot be paired with vertices; estimate normals later instead.
        return points, None, None
    return points, (np.array(vertex_normals, dtype=np.float64).reshape(-1, 3) if vertex_normals else None), None


def _read_table(path: str) -> tuple[np.ndarray, np.ndarray | None, None]:
    with open(path, encoding="utf-8") as fh:
        lines = [line for line in fh.read().splitlines() if line.strip() and not line.lstrip().startswith("#")]
    if lines and not _is_numeric_row(lines[0]):
        lines = lines[1:]  # a single header line (e.g. "x,y,z,nx,ny,nz")
    if not lines:
        return np.zeros((0, 3)), None, None
    table = np.loadtxt(io.StringIO("\n".join(lines).replace(",", " ")), dtype=np.float64, comments="#", ndmin=2)
    return (*_split_columns(table, path), None)


def _is_numeric_row(line: str) -> bool:
    try:
        [float(token) for token in line.replace(",", " ").split()]
    except ValueError:
        return False
    return True


def _read_npy(path: str) -> tuple[np.ndarray, np.ndarray | None, np.dtype]:
    array = np.load(path, allow_pickle=False)
    if not isinstance(array, np.ndarray) or not (
        np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)
    ):
        raise CloudError(f"{path}: expected a numeric (N, 3) or (N, 6) array, got dtype {array.dtype}")
    return (*_split_columns(array.astype(np.float64), path), array.dtype)


def _split_columns(table: np.ndarray, path: str) -> tuple[np.ndarray, np.ndarray | None]:
    if table.ndim != 2 or table.shape[1] not in (3, 6):
        raise CloudError(f"{path}: expected 3 columns (x y z) or 6 (x y z nx ny nz), got shape {table.shape}")
    return table[:, :3], (table[:, 3:] if table.shape[1] == 6 else None)


__all__ = ["SUPPORTED_EXTENSIONS", "read_point_cloud"]
