"""Issue 39's limits on the code's size, kept true: no package file over 500 lines, no function in ``pipeline/``
whose code (its docstring left out) runs over 80 lines, the README at most 300 lines."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rig", "render", "landmarks", "pipeline")


def _python_files(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def _code_lines(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines from the first statement after the docstring to the function's end."""
    body = node.body
    first = body[0]
    if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
        if len(body) == 1:
            return 0
        first = body[1]
    return node.end_lineno - first.lineno + 1


def test_code_lines_counts_a_known_function():
    source = 'def f(x):\n    """Doc,\n    two lines."""\n    y = x\n\n    return y\n'
    node = ast.parse(source).body[0]
    assert _code_lines(node) == 3


def test_no_package_file_over_500_lines():
    long = {}
    for package in PACKAGES:
        for path in _python_files(package):
            n = len(path.read_text(encoding="utf-8").splitlines())
            if n > 500:
                long[str(path.relative_to(ROOT))] = n
    assert not long, f"files over 500 lines: {long}"


def test_no_pipeline_function_over_80_lines():
    long = {}
    for path in _python_files("pipeline"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and _code_lines(node) > 80:
                long[f"{path.relative_to(ROOT)}:{node.name}"] = _code_lines(node)
    assert not long, f"pipeline functions with over 80 lines of code: {long}"


def test_readme_at_most_300_lines():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines"
