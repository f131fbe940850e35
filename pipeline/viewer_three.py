"""The shared three.js of a folder run (:data:`SHARED_THREE_FILE`, :func:`pipeline.viewer.write_shared_three`):
the vendored ``three.module.min.js`` rewritten as a classic script, refused (:class:`ThreeModuleError`) when it is
not the one self-contained module that rewrite expects."""

from __future__ import annotations

import functools
import re
from pathlib import Path

from rig.errors import SetupError

THREE_FILE = "three.module.min.js"
SHARED_THREE_FILE = "three.jnr.js"
"""The shared copy of three.js of a folder run (:func:`pipeline.viewer.write_shared_three`): a classic script,
in the run's output folder beside the photos' folders, that pages written with ``three_src`` load instead of
inlining three.js."""
SHARED_THREE_GLOBAL = "JNR_THREE"
"""The global that :data:`SHARED_THREE_FILE` sets: a frozen object of three.js's exports (``THREE``)."""


class ThreeModuleError(SetupError):
    """The vendored ``three.module.min.js`` is not the one self-contained module (no imports, one final
    ``export{...}``) that :func:`pipeline.viewer.shared_three_script` turns into a classic script."""


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
