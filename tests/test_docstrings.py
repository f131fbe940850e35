"""Docstrings name only what exists: the files, face detectors, rig counts and modules they mention.

Docstrings say what and why; measured figures live in ``docs/`` and ``benchmarks/results/``. What a docstring
names can go stale when the code moves, so these checks read every docstring of the packages (the module's,
each class's and function's, and the string after an assignment that documents it) with :mod:`ast`, without
importing the packages' modules:

* **files**: a path under ``docs/``, ``benchmarks/``, ``configs/``, ``notebooks/``, ``tests/`` or a package
  (``docs/fit_photo.md``, ``benchmarks/results/pose_bench.json``, ``rig/assets/jnr_rig_v3.npz``) exists in the
  repository. Paths with a placeholder (``<name>``, ``*``) or inside another path (``out/docs/x.md``,
  ``~/.cache/x.json``) are not checked.
* **detectors**: ``--detector NAME``, ``detector="NAME"`` and ``create_detector("NAME")`` name a detector of
  the registry (:func:`landmarks.detector.detector_names`) or one the same docstring registers
  (``register_detector("NAME", ...)``, as an example may).
* **counts**: "N channels", "N joint channels", "N-channel", "N joints", "N-joint" with N >= 10 are the rig's
  (:data:`rig.parameters.NUM_PARAMETERS`, :data:`rig.joints.JOINTS`); smaller counts (an image's 3 channels,
  the jaw's joints) are not checked.
* **modules of cross-references**: in ``:mod:`/``:class:`/``:func:`/``:meth:`/``:data:`/``:attr:`/``:exc:`/
  ``:obj:`` references to ``rig.``, ``landmarks.``, ``render.`` or ``pipeline.`` targets (a target may be
  broken over lines), the module part exists: for ``:mod:`` the whole target, otherwise the longest dotted
  prefix that is a module, followed by one name (``module.function``) or by a class and one of its names
  (``module.Class.method``, the class capitalised). Modules are found with the import system's path finder,
  one package level at a time, so no package is imported. Whether the name itself exists is checked, by
  importing, in ``tests/test_references.py``.
"""

from __future__ import annotations

import ast
import importlib.machinery
import re
from collections.abc import Collection, Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rig", "landmarks", "render", "pipeline")

_FILE = re.compile(
    r"(?<![\w./~<>*-])"
    r"((?:docs|benchmarks|configs|notebooks|tests|rig|landmarks|render|pipeline)/[\w./-]*?"
    r"\.(?:md|py|yaml|yml|json|ipynb|npz|png|jpg|csv|html|txt|dat|tflite|obj|ply|glb))"
    r"(?![\w/<>*-])"
)
"""A repository path: a top folder, then folders and a file name with a known extension."""

_NAME = r"([a-z][a-z0-9_-]*)"
_DETECTOR = re.compile(rf"--detector[ =]+[`'\"]*{_NAME}|\bdetector=[`'\"]+{_NAME}|\bcreate_detector\(\s*[`'\"]+{_NAME}")
"""A detector named in a docstring (lower case: ``--detector NAME`` is a placeholder)."""
_REGISTERED = re.compile(rf"\bregister_detector\(\s*[`'\"]+{_NAME}")

_CHANNELS = re.compile(r"\b(\d+)[\s-]+(?:joint[\s-]+)?channels?\b")
_JOINTS = re.compile(r"\b(\d+)[\s-]+joints?\b(?![\s-]+channel)")
MIN_CHECKED_COUNT = 10
"""Counts below this are not the rig's (an image's channels, a few joints of a region)."""

_REFERENCE = re.compile(r":(mod|class|func|meth|data|attr|exc|obj):`([^`]+)`")


# ------------------------------------------------------------------------------------------ reading


def docstrings(path: Path) -> Iterator[tuple[int, str]]:
    """``(line, text)`` of every docstring in a Python file: the module's, each class's and function's, and
    every other bare string statement of their bodies (attribute docstrings)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            for statement in node.body:
                if (
                    isinstance(statement, ast.Expr)
                    and isinstance(statement.value, ast.Constant)
                    and isinstance(statement.value.value, str)
                ):
                    yield statement.lineno, statement.value.value


def package_docstrings() -> list[tuple[str, str]]:
    """``("path:line", text)`` of every docstring in the packages."""
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            where = path.relative_to(ROOT).as_posix()
            found += [(f"{where}:{line}", text) for line, text in docstrings(path)]
    return found


# ------------------------------------------------------------------------------------------ checks


def missing_files(text: str, root: Path = ROOT) -> list[str]:
    """The repository paths ``text`` names that do not exist under ``root``."""
    return [m.group(1) for m in _FILE.finditer(text) if not (root / m.group(1)).exists()]


def unknown_detectors(text: str, known: Collection[str]) -> list[str]:
    """The detector names ``text`` uses that are neither in ``known`` nor registered in ``text`` itself."""
    registered = set(known) | {m.group(1) for m in _REGISTERED.finditer(text)}
    names = [next(g for g in m.groups() if g) for m in _DETECTOR.finditer(text)]
    return [n for n in names if n not in registered]


def wrong_counts(text: str, channels: int, joints: int) -> list[str]:
    """The rig counts in ``text`` (``"105 channels"``, ``"50 joints"``) that differ from ``channels`` and
    ``joints``; counts below :data:`MIN_CHECKED_COUNT` are not the rig's and are skipped."""
    wrong = []
    for pattern, count in ((_CHANNELS, channels), (_JOINTS, joints)):
        for m in pattern.finditer(text):
            n = int(m.group(1))
            if n >= MIN_CHECKED_COUNT and n != count:
                wrong.append(f"{m.group(0)!r} (the rig has {count})")
    return wrong


def module_exists(dotted: str, root: Path = ROOT) -> bool:
    """Whether ``dotted`` is a module or package under ``root``, found one level at a time by the path finder
    (no package's ``__init__`` runs; :func:`importlib.util.find_spec` would import the parents)."""
    path: list[str] | None = [str(root)]
    for part in dotted.split("."):
        if not path or not part.isidentifier():
            return False
        spec = importlib.machinery.PathFinder.find_spec(part, path)
        if spec is None:
            return False
        path = list(spec.submodule_search_locations or [])
    return True


def unresolved_references(text: str, root: Path = ROOT) -> list[str]:
    """The cross-references in ``text`` to the packages whose module part does not exist (module docstring)."""
    bad = []
    for m in _REFERENCE.finditer(text):
        role, target = m.group(1), re.sub(r"\s+", "", m.group(2))
        if "<" in target:  # :func:`title <target>`
            target = target[target.index("<") + 1 : target.rindex(">")] if ">" in target else ""
        target = target.lstrip("~!.").removesuffix("()")
        parts = target.split(".")
        if len(parts) < 2 or parts[0] not in PACKAGES:
            continue  # another library's, or relative to the docstring's own module (:meth:`render`)
        modules = [k for k in range(len(parts), 0, -1) if module_exists(".".join(parts[:k]), root)]
        k = modules[0] if modules else 0
        rest = parts[k:]
        if role == "mod":
            ok = not rest
        else:
            ok = len(rest) == 1 or (len(rest) == 2 and rest[0][:1].isupper())
        if not ok:
            bad.append(f":{role}:`{target}`")
    return bad


# ------------------------------------------------------------------------------------------ the packages


DOCSTRINGS = package_docstrings()


def _report(problems: list[str], what: str) -> str:
    return f"{len(problems)} docstring(s) name {what}:\n" + "\n".join(problems)


def test_the_packages_have_docstrings_to_check():
    assert len(DOCSTRINGS) > 1000
    assert any("docs/fit_photo.md" in text for _, text in DOCSTRINGS)


def test_docstrings_name_existing_files():
    problems = [f"{where}: {path}" for where, text in DOCSTRINGS for path in missing_files(text)]
    assert not problems, _report(problems, "files that do not exist")


def test_docstrings_name_registered_detectors():
    from landmarks.detector import detector_names

    known = detector_names()
    problems = [f"{where}: {name}" for where, text in DOCSTRINGS for name in unknown_detectors(text, known)]
    assert not problems, _report(problems, f"detectors that are not registered ({', '.join(known)})")


def test_docstrings_give_the_rigs_counts():
    from rig.joints import JOINTS
    from rig.parameters import NUM_PARAMETERS

    problems = [
        f"{where}: {count}" for where, text in DOCSTRINGS for count in wrong_counts(text, NUM_PARAMETERS, len(JOINTS))
    ]
    assert not problems, _report(problems, "a rig count that is not the rig's")


def test_docstring_references_name_existing_modules():
    problems = [f"{where}: {ref}" for where, text in DOCSTRINGS for ref in unresolved_references(text)]
    assert not problems, _report(problems, "cross-references to modules that do not exist")


# ------------------------------------------------------------------------------------------ the checkers


def test_docstrings_reads_module_class_function_and_attribute_docstrings(tmp_path):
    source = tmp_path / "m.py"
    source.write_text(
        '"""module"""\nX = 1\n"""attribute"""\n\n\nclass C:\n    """class"""\n\n    def f(self):\n'
        '        """method"""\n        return "not a docstring"\n'
    )
    assert [text for _, text in docstrings(source)] == ["module", "attribute", "class", "method"]


def test_missing_files_flags_a_path_that_does_not_exist():
    text = (
        "Measured in ``docs/fit_photo.md`` (``benchmarks/bench_pose.py``, ``configs/fit_photo.yaml``); "
        "gone: ``docs/no_such_page.md``, benchmarks/results/no_such_record.json and configs/nothing.yaml."
    )
    assert missing_files(text) == [
        "docs/no_such_page.md",
        "benchmarks/results/no_such_record.json",
        "configs/nothing.yaml",
    ]


def test_missing_files_skips_placeholders_and_paths_inside_other_paths():
    text = (
        "``benchmarks/results/<name>.json``, ``docs/*.md``, ``out/docs/x.md``, ``~/.cache/docs/y.json``, "
        "``rig/assets/jnr_skinning_v<template version>.npz``"
    )
    assert missing_files(text) == []


def test_unknown_detectors_flags_a_name_that_is_not_registered():
    known = ("hog", "cnn", "dlib", "mediapipe", "auto")
    text = "``--detector dlib`` or ``--detector=mediapipe``; ``create_detector('retina')``, detector=\"yolo\""
    assert unknown_detectors(text, known) == ["retina", "yolo"]
    assert unknown_detectors("``jnr fit --detector NAME``; --detector auto", known) == []
    example = 'register_detector("fixed", lambda: Fixed())\ncreate_detector("fixed").detect(image)'
    assert unknown_detectors(example, known) == []
    assert unknown_detectors("--detector fixed", known) == ["fixed"]


def test_wrong_counts_flags_a_count_that_is_not_the_rigs():
    text = (
        "the 105 joint\nchannels, a 105-channel vector, 107 channels, the 52-joint rig, 50 joints; 3 channels, 2 joints"
    )
    assert wrong_counts(text, channels=107, joints=52) == [
        "'105 joint\\nchannels' (the rig has 107)",
        "'105-channel' (the rig has 107)",
        "'50 joints' (the rig has 52)",
    ]


def test_module_exists_finds_modules_without_importing_them():
    assert module_exists("pipeline") and module_exists("pipeline.photo.fit") and module_exists("landmarks.mediapipe")
    assert not module_exists("pipeline.photo.no_such_module") and not module_exists("pipeline.photo.fit.fit_photo")


def test_unresolved_references_flags_a_module_that_does_not_exist():
    good = (
        ":mod:`pipeline.photo.fit`, :func:`~pipeline.photo.fit.fit_photo`, :class:`render.lighting.Lighting`, "
        ":meth:`pipeline.fitting.state.FitState.term_inputs`, :func:`pipeline.fitting.least_squares.\n"
        "     run_lm_stage`, :data:`numpy.pi`, :func:`detection_tiles`, :attr:`~LandmarkLayout.embedding`, "
        ":meth:`render`"
    )
    assert unresolved_references(good) == []
    bad = (
        ":mod:`pipeline.photo.gone`, :func:`pipeline.photo.gone.fit`, :class:`pipeline.fitting.Old.Model.x`, "
        ":func:`landmarks.nowhere.detect`"
    )
    assert unresolved_references(bad) == [
        ":mod:`pipeline.photo.gone`",
        ":func:`pipeline.photo.gone.fit`",
        ":class:`pipeline.fitting.Old.Model.x`",
        ":func:`landmarks.nowhere.detect`",
    ]


@pytest.mark.parametrize("text", ["", "no references here", ":func:`torch.linalg.solve`"])
def test_checkers_pass_text_without_names(text):
    assert not missing_files(text) and not unresolved_references(text)
    assert not unknown_detectors(text, ()) and not wrong_counts(text, 107, 52)
