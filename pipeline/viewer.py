"""``viewer.html``: one self-contained web page beside every fit, to look at and pose the fitted head.

The page (:data:`TEMPLATE_FILE` filled in by :func:`write_viewer`) holds everything it shows, so it opens
from ``file://`` with no network: three.js (its ``three.module.min.js``, MIT, vendored at build time from the
npm package pinned in ``package.json``/``package-lock.json`` into :data:`ASSETS_DIR` by ``make venv``,
inlined as an import map ``data:`` URL) and the head as JSON with base64 arrays:

- the template bind mesh (``(V, 3)`` float32 mm), its triangles over vertices split at UV seams, the UVs;
- the skinning weights, at most 4 per vertex (joint ``uint8``, weight float32; the fits' weights have <= 4,
  so the page skins exactly as the rig);
- the 52 joints (names, parents, bind positions) and the 107 channels with their limits and fitted values;
- the 52 ARKit shapes, sparse (vertex ``uint16``, offset float32: ~50k non-zero rows, not 52 x V), and the
  ``jawOpen`` hinge (weights, pivot, angle) of :class:`rig.expressions.ExpressionModel`;
- the fitted expression coefficients, the texture (JPEG) or vertex colours;
- per photo: the photo (JPEG, longer side at most :data:`PHOTO_MAX_SIDE`) and its camera as in
  ``params.json`` (OpenCV intrinsics in the photo file's pixels, rig -> camera extrinsics).

The page's JavaScript poses the head as :class:`rig.model.JointRig` does (channel transforms, the joint
hierarchy, linear blend skinning, expression offsets) in float64, so what it draws agrees with Python to
float32 rounding of the data (``tests/pipeline/test_viewer.py`` compares them in headless Chromium).
ASM fits (``skinning: asm``) are shown as their fitted mesh with the expression sliders only (their bones
are not the rig's joints).

A folder run's pages can share one copy of three.js instead (``three_src``, :func:`write_shared_three`):
:data:`SHARED_THREE_FILE`, the module rewritten as a classic script (Chrome refuses module scripts from
``file://`` URLs, not classic ones) in the run's output folder, ~0.9 MB less per page.

The page's "Save pose" button downloads the sliders as a parameter file of ``jnr rig edit``
(:data:`SAVE_FILE`): with the fit's ``latent_z`` the whole head as a fit's ``params.json`` holds it (joints,
latent Z, expressions), without it the joint channels (:mod:`rig.io.params`). See ``docs/viewer.md``.
"""

from __future__ import annotations

import base64
import functools
import html
import io
import json
import os
import re
import time
import urllib.parse
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.errors import InputError, SetupError
from rig.expressions import EXPRESSION_NAMES, EXPRESSIONS, JAW_ANGLE_DEG, JAW_INDEX, ExpressionModel, jaw_pivot
from rig.io.atomic import write_bytes_atomic
from rig.io.params import PARAMS_UNITS
from rig.joints import CHANNEL_KINDS
from rig.parameters import CHANNELS, NUM_PARAMETERS

VIEWER_FILE = "viewer.html"
"""The page's name in an output folder."""
ASSETS_DIR = Path(__file__).with_name("viewer_assets")
"""Where ``make venv`` copies three.js from ``node_modules/three`` (gitignored, package data)."""
THREE_FILE = "three.module.min.js"
SHARED_THREE_FILE = "three.jnr.js"
"""The shared copy of three.js of a folder run (:func:`write_shared_three`): a classic script, in the run's
output folder beside the photos' folders, that pages written with ``three_src`` load instead of inlining
three.js."""
SHARED_THREE_GLOBAL = "JNR_THREE"
"""The global that :data:`SHARED_THREE_FILE` sets: a frozen object of three.js's exports (``THREE``)."""
SAVE_FILE = "params_edited.json"
"""The name the page's "Save pose" button downloads its parameter file as."""
TEMPLATE_FILE = Path(__file__).with_name("viewer_template.html")
VIEWER_FORMAT = "jnr-viewer/1"
PHOTO_MAX_SIDE = 1280
"""Photos are embedded reduced to this longer side (pixels); the camera does not change with it."""
TEXTURE_MAX_SIDE = 1024
JPEG_QUALITY = 88
SAMPLE_VERTICES = 24
"""How many vertices the page reports in its ``#jnr-state`` check (all of them with ``#state=all``)."""
_DTYPES = {"float32": np.float32, "uint8": np.uint8, "uint16": np.uint16, "uint32": np.uint32}
_warned_missing = False


class ViewerError(ValueError):
    """Bad arguments to :func:`write_viewer` (a programming error, not a user's input)."""


@dataclass(frozen=True)
class ViewerView:
    """One photo of a fit and its camera.

    Attributes:
        name: shown in the page's view menu (e.g. the photo's file name).
        camera: ``params.json``'s ``camera`` entry: ``width``, ``height`` (pixels), ``focal_px``,
            ``principal_point_px`` ``[cx, cy]`` (OpenCV, 0-based), ``extrinsics_rig_to_camera`` ``(4, 4)``
            (``x_cam = E @ [x_rig, 1]``, OpenCV axes: x right, y down, z forward).
        photo: ``(H, W, 3)`` uint8 sRGB, the photo as the camera sees it (any size with the camera's aspect:
            a photo fitted reduced is shown with the camera of the full-size file), or None.
        expressions: ``(E,)`` this view's ARKit coefficients (multi-view fits), None: the head's.
    """

    name: str
    camera: dict
    photo: np.ndarray | None = None
    expressions: np.ndarray | None = None


@dataclass(frozen=True)
class ViewerInfo:
    """What :func:`write_viewer` wrote: the file, its size in bytes, the seconds it took, and the largest
    skinning weight left out by keeping 4 per vertex (0 for the rig's own weights)."""

    path: Path
    bytes: int
    seconds: float
    dropped_weight: float


# ------------------------------------------------------------------------------------------ arrays


def encode_array(array: np.ndarray, dtype: str) -> dict:
    """``{"dtype", "shape", "b64"}``: ``array`` as little-endian ``dtype`` bytes in base64 (the page decodes
    it into a typed array)."""
    a = np.ascontiguousarray(np.asarray(array).astype(np.dtype(_DTYPES[dtype]).newbyteorder("<")))
    return {"dtype": dtype, "shape": list(a.shape), "b64": base64.b64encode(a.tobytes()).decode("ascii")}


def decode_array(entry: dict | None) -> np.ndarray | None:
    """The inverse of :func:`encode_array` (None stays None)."""
    if entry is None:
        return None
    dtype = np.dtype(_DTYPES[entry["dtype"]]).newbyteorder("<")
    return np.frombuffer(base64.b64decode(entry["b64"]), dtype=dtype).reshape(entry["shape"])


def _jpeg_data_url(image: np.ndarray, max_side: int) -> str:
    from PIL import Image

    im = Image.fromarray(np.ascontiguousarray(np.asarray(image, np.uint8)[..., :3]))
    if max(im.size) > max_side:
        scale = max_side / max(im.size)
        im = im.resize((max(1, round(im.width * scale)), max(1, round(im.height * scale))), Image.LANCZOS)
    buffer = io.BytesIO()
    im.save(buffer, format="JPEG", quality=JPEG_QUALITY)
    return "data:image/jpeg;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


# ------------------------------------------------------------------------------------------ three.js


def three_js_path() -> Path:
    """Where the vendored ``three.module.min.js`` is expected (:data:`ASSETS_DIR`)."""
    return ASSETS_DIR / THREE_FILE


def viewer_available() -> bool:
    """Whether three.js was vendored (``make venv``), so that :func:`write_viewer` can write a page."""
    return three_js_path().is_file()


@functools.lru_cache(maxsize=2)
def _three_data_url(path: str, mtime: float) -> tuple[str, str]:
    """``(data: URL of the module, three.js revision)``."""
    code = Path(path).read_bytes()
    match = re.search(rb'const [A-Za-z_$]+="(\d+)"', code[:2000])
    return "data:text/javascript;base64," + base64.b64encode(code).decode("ascii"), (
        match.group(1).decode() if match else "unknown"
    )


class ViewerUnavailableError(SetupError):
    """three.js was not vendored (a ``pip install`` without ``make venv``)."""


def _require_three() -> Path:
    path = three_js_path()
    if not path.is_file():
        raise ViewerUnavailableError(
            f"three.js is not installed ({path}); run `make venv` (npm ci, then the copy into {ASSETS_DIR.name}/)"
        )
    return path


def _three() -> tuple[str, str]:
    path = _require_three()
    return _three_data_url(str(path), path.stat().st_mtime)


class ThreeModuleError(SetupError):
    """The vendored ``three.module.min.js`` is not the one self-contained module (no imports, one final
    ``export{...}``) that :func:`shared_three_script` turns into a classic script."""


_IMPORT = re.compile(r"(?<![\w$.])import(?:\s*[({*\"'`.]|\s+[\w$]+\s*(?:,|from\b))")
"""An import statement, a dynamic ``import(...)`` or ``import.meta`` (not the word in a string such as
"imported")."""
_EXPORT_WORD = re.compile(r"(?<![\w$.])export(?![\w$])")
_FINAL_EXPORT = re.compile(r"export\s*\{([^{}]*)\}\s*;?\s*$")
_EXPORT_ITEM = re.compile(r"([A-Za-z_$][\w$]*)(?:\s+as\s+([A-Za-z_$][\w$]*))?")
_LICENSE = re.compile(r"\s*(/\*.*?\*/)", re.S)


@functools.lru_cache(maxsize=2)
def _shared_three_text(path: str, mtime: float) -> str:
    code = Path(path).read_text(encoding="utf-8")

    def refuse(why: str) -> ThreeModuleError:
        return ThreeModuleError(
            f"{path} cannot be made into {SHARED_THREE_FILE}: {why}; the shared mode needs three.js's "
            f"{THREE_FILE} as one module without imports whose only export is a final `export{{...}};` "
            f"(three r170; from r171 the build imports three.core.js)"
        )

    header = _LICENSE.match(code)
    if not header or "@license" not in header.group(1):
        raise refuse("it does not start with its @license comment")
    body = code[header.end() :]
    final = _FINAL_EXPORT.search(body)
    if not final:
        raise refuse("it does not end with one export{...} statement")
    if len(_EXPORT_WORD.findall(body)) != 1:
        raise refuse("it has more than the final export")
    if _IMPORT.search(body):
        raise refuse("it imports other modules")
    names = []
    for item in final.group(1).split(","):
        match = _EXPORT_ITEM.fullmatch(item.strip())
        if not match:
            raise refuse(f"its export list has an entry that is not `local as Name`: {item.strip()[:40]!r}")
        names.append((match.group(1), match.group(2) or match.group(1)))
    exported = [name for _, name in names]
    if len(set(exported)) != len(exported):
        raise refuse("its export list names an export twice")
    revision = re.search(r'const [A-Za-z_$]+="(\d+)"', code[:2000])
    exports = ",".join(f"{name}:{local}" for local, name in names)
    return (
        f"{header.group(1)}\n"
        f"/* jnr (pipeline.viewer.write_shared_three): three.js r{revision.group(1) if revision else '?'} "
        f"({THREE_FILE}, MIT, licence above) as a classic script for the viewer.html pages in the folders beside it.\n"
        f"   Pages opened from file:// may not load module scripts from files, so the module's code runs in a\n"
        f"   strict-mode function and its {len(names)} exports are the frozen global {SHARED_THREE_GLOBAL}. */\n"
        f'(function () {{\n"use strict";\n{body[: final.start()].strip()}\n'
        f"globalThis.{SHARED_THREE_GLOBAL}=Object.freeze({{{exports}}});\n}})();\n"
    )


def shared_three_script() -> str:
    """The text of :data:`SHARED_THREE_FILE`: the vendored ``three.module.min.js`` rewritten as a classic
    script. Its ``@license`` header stays first; the module's code (which imports nothing) runs in a
    strict-mode function scope, and its one final ``export{a as B,...};`` becomes
    ``globalThis.JNR_THREE=Object.freeze({B:a,...})`` (:data:`SHARED_THREE_GLOBAL`).

    Raises:
        ViewerUnavailableError: three.js was not vendored.
        ThreeModuleError: the vendored file does not have that shape (another three.js build).
    """
    path = _require_three()
    return _shared_three_text(str(path), path.stat().st_mtime)


def write_shared_three(folder: str | Path) -> Path:
    """Write :data:`SHARED_THREE_FILE` (:func:`shared_three_script`) into ``folder``, the output folder of
    a folder run, for the pages written with ``three_src`` (:func:`shared_three_src`) in its subfolders.

    Atomic (a temporary file beside it, then a rename: :func:`rig.io.atomic.write_bytes_atomic`) and
    idempotent: a file with the same bytes already there is left as it is, so concurrent fits of one run
    may all call it.

    Args:
        folder: an existing folder.

    Returns:
        The file's path.

    Raises:
        ViewerUnavailableError: three.js was not vendored; ThreeModuleError: not the expected three.js
        build; OSError: the folder is missing or not writable.
    """
    target = Path(folder) / SHARED_THREE_FILE
    payload = shared_three_script().encode("utf-8")
    try:
        if target.is_file() and target.stat().st_size == len(payload) and target.read_bytes() == payload:
            return target
    except OSError:
        pass  # replaced meanwhile, or unreadable: write it
    write_bytes_atomic(target, payload)
    return target


def shared_three_src(page_folder: str | Path, shared_folder: str | Path) -> str:
    """The ``three_src`` of :func:`write_viewer` for a page that will be in ``page_folder`` (where it ends
    up, not a temporary staging folder) and :data:`SHARED_THREE_FILE` in ``shared_folder``: a relative URL,
    e.g. ``"../three.jnr.js"`` for ``OUT/<photo>/viewer.html`` and ``OUT/three.jnr.js``."""
    relative = os.path.relpath(Path(shared_folder).absolute() / SHARED_THREE_FILE, Path(page_folder).absolute())
    return urllib.parse.quote(Path(relative).as_posix())


# ------------------------------------------------------------------------------------------ payload


def _top4(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(joints (V, 4) int, weights (V, 4), largest dropped weight)``: each vertex's 4 largest weights,
    renormalised to sum 1 when any was dropped."""
    w = np.asarray(weights, np.float64)
    order = np.argsort(-w, axis=1, kind="stable")[:, :4]
    top = np.take_along_axis(w, order, 1)
    dropped = float(np.sort(w, axis=1)[:, :-4].max()) if w.shape[1] > 4 else 0.0
    if dropped > 0:
        top = top / top.sum(1, keepdims=True)
    top[top <= 0] = 0.0
    return order, top, dropped


def _render_vertices(asset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices split where the UVs are (seams): ``(render_vertex (R,), faces (F, 3) into them, uv (R, 2))``."""
    corners_v = np.asarray(asset.faces, np.int64).reshape(-1)
    corners_uv = np.asarray(asset.face_uvs, np.float64).reshape(-1, 2)
    keys = np.column_stack([corners_v.astype(np.float64), corners_uv])
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    return unique[:, 0].astype(np.int64), inverse.reshape(-1, 3), unique[:, 1:]


def viewer_payload(
    asset,
    *,
    theta: np.ndarray | None = None,
    expressions: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    latent_z: np.ndarray | None = None,
    views: tuple[ViewerView, ...] | list = (),
    texture: np.ndarray | None = None,
    vertex_colors: np.ndarray | None = None,
    static_vertices: np.ndarray | None = None,
    title: str = "jnr fit",
    subtitle: str = "",
) -> tuple[dict, float]:
    """The data of a page (module docstring) and the largest skinning weight left out.

    Args:
        asset: the fit's :class:`rig.asset.RigAsset` (template, faces, UVs, joints).
        theta: ``(P,)`` fitted channels (deg, mm, ``scale - 1``; :mod:`rig.parameters`); None: rest.
        expressions: ``(E,)`` fitted ARKit coefficients; None: zeros.
        weights: ``(V, K)`` the fit's skinning weights (its latent Z's); None: the asset's.
        latent_z: ``(50,)`` the fit's latent Z (the one ``weights`` were decoded from), or None. With it the
            page's "Save pose" writes a whole head (joints, latent Z, expressions: what a fit's ``params.json``
            holds for ``jnr rig edit``); without it the joint channels only.
        views: the photos and cameras (none: an orbit view only).
        texture: ``(T, T, 3)`` uint8 sRGB texture in the asset's UVs, or None.
        vertex_colors: ``(V, 3)`` uint8 sRGB, used when there is no texture, or None.
        static_vertices: ``(V, 3)`` mm: show this mesh (an ASM fit's, with ``expressions`` applied) instead
            of posing the rig; the page then has expression sliders only.
        title, subtitle: shown in the page.

    Raises:
        ViewerError: arrays of the wrong shape.
    """
    import torch

    from rig.skinning.neural import LATENT

    n_vertices, n_joints = len(asset.vertices), len(asset.joint_names)
    parents = np.asarray(asset.parents, np.int64)
    if any(p >= k for k, p in enumerate(parents)):
        raise ViewerError("viewer_payload: the joints must be ordered parents first")
    theta = np.zeros(NUM_PARAMETERS) if theta is None else np.asarray(theta, np.float64).reshape(-1)
    coefficients = np.zeros(len(EXPRESSION_NAMES)) if expressions is None else np.asarray(expressions, np.float64)
    if theta.shape != (NUM_PARAMETERS,):
        raise ViewerError(f"viewer_payload: theta must have shape ({NUM_PARAMETERS},), got {theta.shape}")
    if coefficients.shape != (len(EXPRESSION_NAMES),):
        raise ViewerError(
            f"viewer_payload: expressions must have shape ({len(EXPRESSION_NAMES)},), got {coefficients.shape}"
        )
    weights = asset.weights if weights is None else np.asarray(weights, np.float64)
    if weights.shape != (n_vertices, n_joints):
        raise ViewerError(f"viewer_payload: weights must have shape ({n_vertices}, {n_joints}), got {weights.shape}")
    if latent_z is not None:
        latent_z = np.asarray(latent_z, np.float64).reshape(-1)
        if latent_z.shape != (LATENT,) or not np.isfinite(latent_z).all():
            raise ViewerError(f"viewer_payload: latent_z must be ({LATENT},) finite values, got {latent_z.shape}")
    if n_joints > 255 or n_vertices >= 2**16:
        raise ViewerError(f"viewer_payload: at most 255 joints and 65535 vertices, got {n_joints} and {n_vertices}")
    skin_joints, skin_weights, dropped = _top4(weights)

    model = ExpressionModel(asset, dtype=torch.float64)
    basis = model.basis.numpy()  # (E, V, 3); jawOpen: its corrective
    rows = [np.flatnonzero(np.any(basis[e] != 0, axis=1)) for e in range(len(basis))]
    jaw_weight = model.jaw_weight.numpy()
    jaw_rows = np.flatnonzero(jaw_weight != 0)
    render_vertex, render_faces, uv = _render_vertices(asset)

    channels = [
        {
            "name": c.name,
            "joint": int(c.joint),
            "kind": CHANNEL_KINDS.index(c.kind),
            "low": float(c.low),
            "high": float(c.high),
            "unit": c.unit,
            "value": float(c.from_theta(t)),
        }
        for c, t in zip(CHANNELS, theta)
    ]
    static = static_vertices is not None
    if static:
        static_vertices = np.asarray(static_vertices, np.float64)
        if static_vertices.shape != (n_vertices, 3):
            raise ViewerError(
                f"viewer_payload: static_vertices must have shape ({n_vertices}, 3), got {static_vertices.shape}"
            )
    if vertex_colors is not None and np.shape(vertex_colors) != (n_vertices, 3):
        raise ViewerError(
            f"viewer_payload: vertex_colors must have shape ({n_vertices}, 3), got {np.shape(vertex_colors)}"
        )
    images = {}  # <img> id -> data: URL (render_html writes them as elements of the page)
    view_entries = []
    for k, view in enumerate(views):
        cam = view.camera
        if view.photo is not None:
            images[f"jnr-photo-{k}"] = _jpeg_data_url(view.photo, PHOTO_MAX_SIDE)
        entry = {
            "name": view.name,
            "photo": None if view.photo is None else f"jnr-photo-{k}",
            "camera": {
                "width": float(cam["width"]),
                "height": float(cam["height"]),
                "focal_px": float(cam["focal_px"]),
                "principal_point_px": [float(x) for x in cam["principal_point_px"]],
                "extrinsics_rig_to_camera": np.asarray(cam["extrinsics_rig_to_camera"], float).tolist(),
            },
            "expressions": None if view.expressions is None else [float(x) for x in view.expressions],
        }
        view_entries.append(entry)
    if texture is not None:
        images["jnr-texture"] = _jpeg_data_url(texture, TEXTURE_MAX_SIDE)
    head = static_vertices if static else np.asarray(asset.vertices, np.float64)
    data = {
        "format": VIEWER_FORMAT,
        "title": title,
        "subtitle": subtitle,
        "mode": "static" if static else "rig",
        "vertex_count": n_vertices,
        "template": encode_array(asset.vertices, "float32"),
        "base": encode_array(static_vertices, "float32") if static else None,
        "base_expressions": [float(x) for x in coefficients] if static else None,
        "render_vertex": encode_array(render_vertex, "uint16"),
        "faces": encode_array(render_faces, "uint16" if len(render_vertex) < 2**16 else "uint32"),
        "uv": encode_array(uv, "float32"),
        "skin_joints": encode_array(skin_joints, "uint8"),
        "skin_weights": encode_array(skin_weights, "float32"),
        "joints": {
            "names": list(asset.joint_names),
            "parents": parents.tolist(),
            "bind": np.asarray(asset.joint_positions, np.float64).tolist(),
        },
        "channels": [] if static else channels,
        "expressions": {
            "names": list(EXPRESSION_NAMES),
            "low": [float(s.low) for s in EXPRESSIONS],
            "high": [float(s.high) for s in EXPRESSIONS],
            "values": [float(x) for x in coefficients],
        },
        "morph": {
            "counts": [len(r) for r in rows],
            "index": encode_array(np.concatenate(rows), "uint16"),
            "offsets": encode_array(np.concatenate([basis[e, r] for e, r in enumerate(rows)]), "float32"),
        },
        "jaw": {
            "expression": int(JAW_INDEX),
            "angle_deg": float(JAW_ANGLE_DEG),
            "pivot": [float(x) for x in jaw_pivot(asset)],
            "index": encode_array(jaw_rows, "uint16"),
            "weight": encode_array(jaw_weight[jaw_rows], "float32"),
        },
        "colors": None if vertex_colors is None or texture is not None else encode_array(vertex_colors, "uint8"),
        "texture": None if texture is None else "jnr-texture",
        "images": images,
        "views": view_entries,
        "head_centre": [float(x) for x in (head.min(0) + head.max(0)) / 2],
        "sample_vertices": np.linspace(0, n_vertices - 1, SAMPLE_VERTICES).round().astype(int).tolist(),
        # the Save button's parameter file: its name, units, model and the head's latent Z
        "save": {
            "file": SAVE_FILE,
            "units": dict(PARAMS_UNITS),
            "model": "jnr",
            "latent_z": None if static or latent_z is None else [float(x) for x in latent_z],
        },
    }
    return data, dropped


_INLINE_THREE = '<script type="importmap">{"imports": {"three": "%s"}}</script>'
_SHARED_THREE = (
    '<script id="jnr-three" src="%s"></script>\n'
    "<script>if (!globalThis.%s) jnrThreeMissing();\n"
    "/** The shared three.js file did not load (not copied with the page): say so in the page. */\n"
    "function jnrThreeMissing() {\n"
    '  const src = document.getElementById("jnr-three"), name = src.getAttribute("src");\n'
    '  const box = document.createElement("div");\n'
    '  box.id = "jnr-error";\n'
    '  box.style.cssText = "max-width: 34em; padding: 16px; font-size: 14px; line-height: 1.5; color: #ffd27a";\n'
    '  let file = name.split("/").pop();\n'
    "  try { file = decodeURIComponent(file); } catch (err) { /* shown as written */ }\n"
    "  box.textContent = `This page could not load three.js from the file ${file}, which must be at ${name} ` +\n"
    "    `from the page (${src.src}). jnr fit FOLDER writes that file once into its output folder, beside ` +\n"
    "    `the photos' folders: copy it along with the page's folder, keeping that layout.`;\n"
    '  document.body.classList.add("no-ui");\n'
    '  document.getElementById("viewport").appendChild(box);\n'
    "}</script>"
)
_SHARED_IMPORT = (
    "const THREE = globalThis.%s;\n"
    'if (!THREE) throw new Error("jnr viewer: three.js did not load from " + document.getElementById("jnr-three").src);'
)


def _check_three_src(three_src: str) -> str:
    if not isinstance(three_src, str) or not three_src.strip() or re.search(r"[\x00-\x1f\x7f]", three_src):
        raise ViewerError(f"three_src must be a URL (e.g. '../{SHARED_THREE_FILE}'), got {three_src!r}")
    return three_src


def render_html(data: dict, *, three_src: str | None = None) -> str:
    """The page: :data:`TEMPLATE_FILE` with three.js and ``data`` filled in.

    Args:
        data: :func:`viewer_payload`'s data.
        three_src: None: three.js inlined (an import map ``data:`` URL; the page needs nothing else). A URL
            relative to the page (:func:`shared_three_src`, e.g. ``"../three.jnr.js"``): the page loads
            :data:`SHARED_THREE_FILE` (:func:`write_shared_three`) from there as a classic script and takes
            ``THREE`` from its global; without that file it says in the page which file it needs.

    Raises:
        ViewerUnavailableError: inline three.js that was not vendored (:func:`viewer_available`).
        ViewerError: a ``three_src`` that is not a URL.
    """
    if three_src is None:
        three_url, _ = _three()
        three_script, three_import = _INLINE_THREE % three_url, 'import * as THREE from "three";'
    else:
        three_script = _SHARED_THREE % (html.escape(_check_three_src(three_src), quote=True), SHARED_THREE_GLOBAL)
        three_import = _SHARED_IMPORT % SHARED_THREE_GLOBAL
    text = TEMPLATE_FILE.read_text(encoding="utf-8")
    data = dict(data)
    images = "".join(f'<img id="{key}" alt="" src="{url}">' for key, url in data.pop("images", {}).items())
    # "</" cannot end the script element early once escaped; JSON reads "<\/" as "</"
    payload = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    fills = {
        "TITLE": html.escape(data.get("title", "jnr")),
        "THREE_SCRIPT": three_script,
        "THREE_IMPORT": three_import,
        "IMAGES": images,
        "DATA": payload,
    }
    return re.sub(r"__JNR_(TITLE|THREE_SCRIPT|THREE_IMPORT|IMAGES|DATA)__", lambda m: fills[m.group(1)], text)


def write_viewer(path: str | Path, asset, *, three_src: str | None = None, **head) -> ViewerInfo:
    """Write ``viewer.html`` (module docstring) to ``path``, a file in a folder being staged by the caller
    (:func:`pipeline.files.staged_folder`).

    Args:
        path: the file to write.
        asset: the fit's rig asset.
        three_src: None: three.js inlined (the page is self-contained). A URL relative to the page
            (:func:`shared_three_src`): the page loads :data:`SHARED_THREE_FILE` from there (a folder run's
            one copy, :func:`write_shared_three`; the caller writes it) and is ~0.9 MB smaller.
        **head: :func:`viewer_payload`'s keyword arguments (``theta``, ``expressions``, ``weights``,
            ``latent_z``, ``views``, ``texture``, ``vertex_colors``, ``static_vertices``, ``title``,
            ``subtitle``).

    Returns:
        :class:`ViewerInfo`.

    Raises:
        ViewerUnavailableError: three.js was not vendored (inline); ViewerError: bad arrays or ``three_src``.

    Example:
        >>> from rig.asset import load_asset
        >>> info = write_viewer("/tmp/rest_viewer.html", load_asset())   # the template at rest, orbit view
        >>> info.bytes < 8e6
        True
    """
    t0 = time.perf_counter()
    if three_src is not None:
        _check_three_src(three_src)
    data, dropped = viewer_payload(asset, **head)
    text = render_html(data, three_src=three_src)
    path = Path(path)
    path.write_text(text, encoding="utf-8")
    return ViewerInfo(path, len(text.encode("utf-8")), time.perf_counter() - t0, dropped)


def fit_viewer_ready() -> bool:
    """Whether a fit can write its ``viewer.html`` (:func:`viewer_available`); when it cannot (a ``pip
    install`` without ``make venv``), warns once per process with the fix, so the fit goes on without it."""
    global _warned_missing
    if viewer_available():
        return True
    if not _warned_missing:
        _warned_missing = True
        warnings.warn(
            f"{VIEWER_FILE} not written: three.js is not installed ({three_js_path()}); run `make venv` "
            f"(npm ci --no-audit --no-fund, then the copy into {ASSETS_DIR})",
            RuntimeWarning,
            stacklevel=3,
        )
    return False


def write_fit_viewer(path: str | Path, asset, *, three_src: str | None = None, **head) -> ViewerInfo | None:
    """:func:`write_viewer` for the fits' output folders (``three_src`` as there), skipped (None) when not
    :func:`fit_viewer_ready`."""
    if not fit_viewer_ready():
        return None
    return write_viewer(path, asset, three_src=three_src, **head)


def read_viewer_data(page: str | Path) -> dict:
    """The data of a written page (its ``#jnr-data`` JSON) with every encoded array decoded to numpy.

    Raises:
        ValueError: not a jnr viewer page.
    """
    text = Path(page).read_text(encoding="utf-8") if not str(page).lstrip().startswith("<") else str(page)
    match = re.search(r'<script type="application/json" id="jnr-data">(.*?)</script>', text, re.S)
    if not match:
        raise InputError(f"{page if len(str(page)) < 200 else 'the page'} is not a jnr viewer page (no #jnr-data)")
    data = json.loads(match.group(1))
    if data.get("format") != VIEWER_FORMAT:
        raise InputError(f"not a {VIEWER_FORMAT} page: format {data.get('format')!r}")
    data["images"] = dict(re.findall(r'<img id="([^"]+)" alt="" src="([^"]+)">', text))

    def walk(node):
        if isinstance(node, dict):
            if set(node) == {"dtype", "shape", "b64"}:
                return decode_array(node)
            return {k: walk(v) for k, v in node.items()}
        if isinstance(node, list):
            return [walk(v) for v in node]
        return node

    return walk(data)


def read_viewer_state(dom: str) -> dict:
    """The page's ``#jnr-state`` check (JSON written once the head is drawn) from its DOM (``chromium
    --dump-dom``).

    Raises:
        ValueError: the DOM holds no state (the page did not finish drawing).
    """
    match = re.search(r'<pre id="jnr-state" hidden="">(.*?)</pre>', dom, re.S)
    if not match or not match.group(1).strip():
        raise InputError("the page wrote no #jnr-state (it did not draw the head)")
    return json.loads(html.unescape(match.group(1)))


__all__ = [
    "ASSETS_DIR",
    "SAVE_FILE",
    "SHARED_THREE_FILE",
    "SHARED_THREE_GLOBAL",
    "VIEWER_FILE",
    "ThreeModuleError",
    "ViewerError",
    "ViewerInfo",
    "ViewerUnavailableError",
    "ViewerView",
    "decode_array",
    "encode_array",
    "fit_viewer_ready",
    "read_viewer_data",
    "read_viewer_state",
    "render_html",
    "shared_three_script",
    "shared_three_src",
    "three_js_path",
    "viewer_available",
    "viewer_payload",
    "write_fit_viewer",
    "write_shared_three",
    "write_viewer",
]
