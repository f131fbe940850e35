"""Every Sphinx cross-reference in the packages' docstrings (``:func:`rig.lbs.skin_vertices```) names
something that exists: module moves and splits leave no stale pointers behind."""

import importlib
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGES = ("rig", "render", "landmarks", "pipeline")
REFERENCE = re.compile(
    r":(?:func|class|mod|data|meth|attr|exc):`~?(?:[^`<]*<)?((?:rig|render|landmarks|pipeline)\.[A-Za-z0-9_.]+)>?`"
)


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            if hasattr(obj, name):
                obj = getattr(obj, name)
            elif name in (getattr(obj, "__dataclass_fields__", None) or {}) or name in getattr(
                obj, "__annotations__", {}
            ):
                return True  # a dataclass field or an annotated attribute
            else:
                return False
        return True
    return False


def _references():
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            for match in REFERENCE.finditer(text):
                line = text.count("\n", 0, match.start()) + 1
                yield f"{path.relative_to(ROOT)}:{line}", match.group(1)


def test_every_docstring_reference_resolves():
    pytest.importorskip("dlib")  # landmarks' detector modules import it where they are referenced
    stale = [f"{where}: {target}" for where, target in _references() if not _resolves(target)]
    assert not stale, "stale references:\n" + "\n".join(stale)
