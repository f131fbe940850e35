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

:mod:`pipeline.viewer_data` gathers that data (:func:`viewer_payload`); this module fills the page with it.

The page's JavaScript poses the head as :class:`rig.model.JointRig` does (channel transforms, the joint
hierarchy, linear blend skinning, expression offsets) in float64, so what it draws agrees with Python to
float32 rounding of the data (``tests/pipeline/test_viewer.py`` compares them in headless Chromium).
ASM fits (``skinning: asm``) are shown as their fitted mesh with the expression sliders only (their bones
are not the rig's joints).

A folder run's pages can share one copy of three.js instead (``three_src``, :func:`write_shared_three`):
:data:`SHARED_THREE_FILE`, the module rewritten as a classic script (Chrome refuses module scripts from
``file://`` URLs, not classic ones) in the run's output folder, ~0.9 MB less per page
(:mod:`pipeline.viewer_three` rewrites the module).

The page's "Save pose" button downloads the sliders as a parameter file of ``jnr rig edit``
(:data:`SAVE_FILE`): with the fit's ``latent_z`` the whole head as a fit's ``params.json`` holds it (joints,
latent Z, expressions), without it the joint channels (:mod:`rig.io.params`). See ``docs/viewer.md``.
"""

from __future__ import annotations

import base64
import functools
import html
import json
import os
import re
import time
import urllib.parse
import warnings
from dataclasses import dataclass
from pathlib import Path

from pipeline.viewer_data import JPEG_QUALITY as JPEG_QUALITY
from pipeline.viewer_data import PHOTO_MAX_SIDE as PHOTO_MAX_SIDE
from pipeline.viewer_data import SAMPLE_VERTICES as SAMPLE_VERTICES
from pipeline.viewer_data import (
    SAVE_FILE,
    VIEWER_FORMAT,
    ViewerError,
    ViewerView,
    decode_array,
    encode_array,
    viewer_payload,
)
from pipeline.viewer_data import TEXTURE_MAX_SIDE as TEXTURE_MAX_SIDE
from pipeline.viewer_data import _top4 as _top4
from pipeline.viewer_three import (
    SHARED_THREE_FILE,
    SHARED_THREE_GLOBAL,
    THREE_FILE,
    ThreeModuleError,
    _shared_three_text,
)
from rig.errors import InputError, SetupError
from rig.io.atomic import write_bytes_atomic

VIEWER_FILE = "viewer.html"
"""The page's name in an output folder."""
ASSETS_DIR = Path(__file__).with_name("viewer_assets")
"""Where ``make venv`` copies three.js from ``node_modules/three`` (gitignored, package data)."""
TEMPLATE_FILE = Path(__file__).with_name("viewer_template.html")
_warned_missing = False


@dataclass(frozen=True)
class ViewerInfo:
    """What :func:`write_viewer` wrote: the file, its size in bytes, the seconds it took, and the largest
    skinning weight left out by keeping 4 per vertex (0 for the rig's own weights)."""

    path: Path
    bytes: int
    seconds: float
    dropped_weight: float


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
