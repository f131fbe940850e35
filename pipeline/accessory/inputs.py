"""What ``jnr accessory`` reads: the accessory mesh (an OBJ file or a shipped example) and the fitted head."""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.head.fitted import FittedHead, read_fit_folder
from rig.accessory import (
    outer_skin_faces,
)
from rig.asset import load_asset
from rig.errors import InputError
from rig.geometry import closest_surface_points
from rig.io.inputs import regular_file

ACCESSORY_DIR = Path(__file__).resolve().parents[1] / "assets" / "accessories"
"""The shipped example accessories (``<name>.obj``)."""
EXAMPLE_NAMES = ("glasses", "cap")
"""Names ``jnr accessory`` accepts instead of a file."""
EXAMPLE_COLORS = {"glasses": (0.05, 0.18, 0.65), "cap": (0.75, 0.12, 0.08)}
"""Linear RGB of the examples in previews and glTF; any other accessory is teal."""
OTHER_COLOR = (0.05, 0.45, 0.40)
MAX_ACCESSORY_VERTICES = 200_000
"""An accessory with more vertices is refused (the transfer is exact and per vertex; decimate it first)."""
MAX_ACCESSORY_FACES = 400_000
"""An accessory with more triangles is refused (twice the vertex limit: a closed mesh has about two per vertex)."""
MAX_SKIN_DISTANCE_MM = 40.0
"""An accessory whose nearest vertex is farther than this from the template's skin is not placed on it."""
MAX_EXTENT_MM = 1000.0
"""An accessory larger than this (bounding-box diagonal) is not in millimetres."""


class AccessoryInputError(InputError):
    """A bad accessory file or fit folder (one line; exit status 2 on the command line)."""


@dataclass(frozen=True)
class Accessory:
    """An accessory mesh on the template's bind pose.

    Attributes:
        name: the example's name or the file's stem; path: where it was read from.
        vertices: ``(N, 3)`` mm, rig space; faces: ``(F, 3)`` int64.
    """

    name: str
    path: Path
    vertices: np.ndarray
    faces: np.ndarray


MAX_ACCESSORY_BYTES = 256 << 20
"""The largest accessory OBJ read (256 MiB)."""


def accessory_path(accessory: str | Path) -> Path:
    """The file of an accessory argument: an existing file as it is, else a shipped example's name."""
    path = Path(accessory)
    if not path.exists() and str(accessory) in EXAMPLE_NAMES:
        return ACCESSORY_DIR / f"{accessory}.obj"
    return path


def read_accessory(accessory: str | Path, asset=None) -> Accessory:
    """Read and check an accessory (an OBJ file or a shipped example's name, :func:`accessory_path`).

    Raises:
        AccessoryInputError: missing, not an OBJ, a binary file, unreadable, no triangles, non-finite
            vertices, more vertices than :data:`MAX_ACCESSORY_VERTICES` or faces than :data:`MAX_ACCESSORY_FACES`,
            larger than :data:`MAX_EXTENT_MM` (not millimetres?) or farther than :data:`MAX_SKIN_DISTANCE_MM` from
            the template (not placed on it?).
    """
    import trimesh

    path = accessory_path(accessory)
    if not path.exists():
        raise AccessoryInputError(
            f"accessory {accessory} not found (give a Wavefront .obj file or one of {', '.join(EXAMPLE_NAMES)})"
        )
    if not path.is_file():
        raise AccessoryInputError(f"accessory {path} is not a file")
    if path.suffix.lower() != ".obj":
        raise AccessoryInputError(f"accessory {path} must be a Wavefront .obj file")
    try:
        data = regular_file(path, "accessory", MAX_ACCESSORY_BYTES).read_bytes()
    except InputError as exc:
        raise AccessoryInputError(str(exc)) from None
    if b"\x00" in data:  # an OBJ is text; a binary file made trimesh guess its encoding (and fail on an import)
        raise AccessoryInputError(f"accessory {path} is a binary file, not a Wavefront .obj (text)")
    # the material is optional: a file an OBJ names (mtllib, possibly a FIFO or a device) is never opened
    data = b"\n".join(line for line in data.splitlines() if not line.lstrip().startswith(b"mtllib"))
    text = data.decode("utf-8", errors="replace")  # names and comments in another encoding do not matter
    faces_listed = sum(1 for line in text.splitlines() if line.startswith("f "))
    if faces_listed > MAX_ACCESSORY_FACES:
        raise AccessoryInputError(
            f"accessory {path} lists {faces_listed} faces; at most {MAX_ACCESSORY_FACES} (decimate it)"
        )
    try:
        mesh = trimesh.load(io.StringIO(text), file_type="obj", force="mesh", process=False)
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
    except Exception as exc:  # trimesh's OBJ parser raises many types
        raise AccessoryInputError(f"accessory {path} is unreadable as OBJ: {exc}") from None
    if faces.ndim != 2 or faces.shape[1:] != (3,) or len(faces) == 0 or len(vertices) < 3:
        raise AccessoryInputError(f"accessory {path} holds no triangles")
    if not np.isfinite(vertices).all():
        raise AccessoryInputError(f"accessory {path} has non-finite vertex coordinates")
    if len(vertices) > MAX_ACCESSORY_VERTICES:
        raise AccessoryInputError(
            f"accessory {path} has {len(vertices)} vertices; at most {MAX_ACCESSORY_VERTICES} (decimate it)"
        )
    extent = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    if extent > MAX_EXTENT_MM:
        raise AccessoryInputError(
            f"accessory {path} is {extent:.0f} units across; accessories are in millimetres "
            f"on the jnr template (a head is about 250 mm)"
        )
    asset = asset or load_asset()
    nearest = float(closest_surface_points(vertices, asset.vertices, outer_skin_faces(asset)).distance.min())
    if nearest > MAX_SKIN_DISTANCE_MM:
        raise AccessoryInputError(
            f"accessory {path} lies {nearest:.0f} mm from the template's skin at its nearest; "
            f"place it on the jnr template in millimetres (jnr rig export --format obj "
            f"writes the template)"
        )
    name = str(accessory) if str(accessory) in EXAMPLE_NAMES and path.parent == ACCESSORY_DIR else path.stem
    return Accessory(name=name, path=path, vertices=vertices, faces=faces)


ACCESSORY_TASK = "accessories, whose skinning weights they inherit"


def read_fit_head(fit_dir: str | Path) -> FittedHead:
    """The fitted head of a ``jnr fit`` / ``jnr fit-scan`` output folder (its ``params.json``,
    :func:`pipeline.head.fitted.read_fit_folder`), posable by the joints.

    Raises:
        AccessoryInputError: not a folder, no ``params.json``, unreadable, an ASM fit (its weights are not the
            rig's), or parameters out of their limits.
    """
    try:
        return read_fit_folder(fit_dir, posable_for=ACCESSORY_TASK)
    except InputError as exc:
        raise AccessoryInputError(str(exc)) from None
