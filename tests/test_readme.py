"""The README's Python example runs as written, and the layout it describes exists."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_python_example_runs(capsys):
    block = re.search(r"### From Python\n\n```python\n(.*?)```", README, re.DOTALL).group(1)
    namespace: dict = {}
    exec(compile(block, "README.md", "exec"), namespace)
    fit, vertices = namespace["fit"], namespace["vertices"]
    assert fit.rig_vertices.shape == (4874, 3) and tuple(vertices.shape) == (1, 4874, 3)
    assert 0 < fit.landmarks.nme < 0.2 and fit.landmark_fit.stages and not fit.stages  # photometric off
    assert "landmarks_px2" in fit.landmark_fit.stages[-1].terms


def test_layout_lists_existing_packages():
    block = re.search(r"## Layout\n\n```text\n(.*?)```", README, re.DOTALL).group(1)
    top = None
    for line in block.splitlines():
        name = line.split()[0] if line.strip() else ""
        if name.endswith("/") and not line.startswith(" "):
            top = name
            assert (ROOT / name).is_dir(), name
        elif name.endswith("/") and top:
            assert (ROOT / top / name).is_dir(), top + name
