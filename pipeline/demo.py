"""The README's main job on built-in input (``jnr demo``): the rig, and two photo fits.

:func:`run_demo` rebuilds the template from code and compares it with the committed asset, exports it
as OBJ/PLY/glTF, makes a randomly edited head and a picture of both, then reconstructs the astronaut
portrait that scikit-image ships (detected landmarks) and a synthetic photo of a held-out head with
known truth (:func:`pipeline.photo.photo_file.fit_photo_file`), all into one output folder (written
atomically) with a ``summary.json``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

from pipeline.edit import write_head
from pipeline.evaluation.photos import face_error
from pipeline.files import check_output, staged_folder
from pipeline.formats import MESH_FORMATS
from pipeline.photo.outputs import mesh_from_photo_params
from pipeline.photo.photo_file import fit_photo_file
from pipeline.synthetic.photos.simulate import synthetic_photo
from pipeline.synthetic.photos.write import write_synthetic_photo
from render.preview import render_preview, save_png
from rig.asset import build_asset, load_asset
from rig.info import rig_info
from rig.io.params import save_params_json
from rig.model import JointRig
from rig.parameters import random_theta

DEMO_SYNTHETIC_HEAD = 21
"""The held-out head of the demo's synthetic photo (the photo fit's defaults were chosen on heads 0-5)."""
DEMO_STEPS = ("build", "export", "edit", "picture", "astronaut fit", "synthetic photo", "synthetic fit")
"""The steps :func:`run_demo` reports to its ``progress``."""


def _step(progress, name: str, done: bool = True) -> None:
    if progress is not None:
        progress(name, DEMO_STEPS.index(name) + int(done), len(DEMO_STEPS))


def _edit(stage: Path, rig, seed: int, spread: float, spp: int, progress) -> tuple[object, object]:
    """The template and a random edit as meshes and a picture: ``(theta (P,), posed (2, V, 3) mm)``."""
    import numpy as np
    import torch

    zero = torch.zeros(rig.num_parameters, dtype=torch.float64)
    for fmt, ext in MESH_FORMATS.items():
        write_head(stage / f"template{ext}", fmt, zero, rig)
    _step(progress, "export")
    gen = torch.Generator().manual_seed(seed)
    theta = random_theta(gen, 1, spread=spread, dtype=torch.float64)[0]
    save_params_json(theta, stage / "edited_params.json")
    for fmt, ext in (("obj", ".obj"), ("gltf", ".glb")):
        write_head(stage / f"edited{ext}", fmt, theta, rig)
    _step(progress, "edit")
    with torch.no_grad():
        posed = rig(torch.stack([zero, theta])).vertices.numpy()
    tiles = [
        render_preview(
            v, rig.asset.faces, view=view, size=(360, 440), spp=spp, distance=700.0, target=(0.0, -20.0, 20.0)
        )
        for v in posed
        for view in ("front", "three_quarter")
    ]
    picture = np.concatenate([np.concatenate(tiles[:2], 1), np.concatenate(tiles[2:], 1)], 0)
    save_png(picture, stage / "edited.png")
    _step(progress, "picture")
    return theta, posed


def _relative_to(value, stage: Path, base: Path):
    """A JSON value with every string that is a path inside the staged folder ``stage`` made relative to
    ``base`` (a folder inside ``stage``): what the fits record of the demo's own files still points at them
    once the folder is moved into place (and wherever it is moved later)."""
    import os

    if isinstance(value, dict):
        return {k: _relative_to(v, stage, base) for k, v in value.items()}
    if isinstance(value, list):
        return [_relative_to(v, stage, base) for v in value]
    if isinstance(value, str) and value:
        path, root = os.path.abspath(value), os.path.abspath(stage)
        if path == root or path.startswith(root + os.sep):
            return os.path.relpath(path, os.path.abspath(base))
    return value


def _fits(stage: Path, config, progress) -> tuple[dict, dict]:
    """The demo's photo fits: the astronaut (detected landmarks) and a synthetic photo with known truth."""
    from PIL import Image
    from skimage import data

    inputs = stage / "inputs"
    inputs.mkdir()
    Image.fromarray(data.astronaut()).save(inputs / "astronaut.png")
    astronaut = fit_photo_file(inputs / "astronaut.png", stage / "astronaut", config=config, command="jnr demo")
    _step(progress, "astronaut fit")
    photo = synthetic_photo(DEMO_SYNTHETIC_HEAD, expressive=True, seed=0)
    truth_dir = write_synthetic_photo(photo, inputs / "synthetic")
    _step(progress, "synthetic photo")
    synthetic = fit_photo_file(
        truth_dir / "photo.png",
        stage / "synthetic",
        config=config,
        landmarks=str(truth_dir / "landmarks.pts"),
        focal=photo.focal,
        command="jnr demo",
    )
    fitted = mesh_from_photo_params(stage / "synthetic" / "params.json")
    error = face_error(fitted, photo.gt_vertices)
    template = face_error(load_asset().vertices, photo.gt_vertices)
    synthetic.update(
        {
            "head": photo.name,
            "truth": str(truth_dir / "truth.ply"),
            **error,
            "template_vertex_mean_mm": template["vertex_mean_mm"],
            "template_s2m_median_mm": template["s2m_median_mm"],
        }
    )
    for name in ("astronaut", "synthetic"):  # their inputs are in the staged folder: recorded relative to the fit
        report = stage / name / "report.json"
        relative = _relative_to(json.loads(report.read_text()), stage, stage / name)
        report.write_text(json.dumps(relative, indent=2) + "\n")
    _step(progress, "synthetic fit")
    return astronaut, synthetic


def run_demo(
    out: str | Path = "out/demo",
    *,
    config=None,
    seed: int = 7,
    spread: float = 0.3,
    spp: int = 32,
    force: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict:
    """Run the demo into the folder ``out`` (its parent is created if missing).

    Args:
        config: the photo fits' :class:`pipeline.photo.fit.FitPhotoConfig` (default: its defaults).
        seed: of the random edit; spread: its strength, a fraction of each parameter's range.
        spp: samples per pixel of the picture ``edited.png``.
        force: replace an existing ``out`` (only one jnr wrote).
        progress: ``progress(step, done, total)``: ``done = 0`` once ``out`` is accepted, then after each
            of :data:`DEMO_STEPS`.

    Returns:
        The content of ``summary.json``: ``output`` (absolute), ``rig`` (:func:`rig.info.rig_info`),
        ``rebuild_max_difference_mm``, ``seed``, ``edited_parameters`` (non-zero ones),
        ``edit_max_displacement_mm``, ``astronaut`` and ``synthetic`` (the fits' summaries, the
        synthetic one with its errors against the truth, mm; their paths relative to ``out``, as the
        fits' report.json files give their inputs relative to their own folder), ``seconds``.

    Raises:
        pipeline.files.OutputError: ``out`` is refused; as :func:`pipeline.photo.photo_file.fit_photo_file`.
    """
    import numpy as np
    import torch

    out = Path(out)
    if not out.parent.exists():
        out.parent.mkdir(parents=True)  # the README's command writes out/demo in a fresh clone
    check_output(out, force=force, kind="folder")
    _step(progress, "build", done=False)
    with staged_folder(out, force, marker={"command": "jnr demo"}) as stage:
        t0 = time.perf_counter()
        built = build_asset()
        committed = load_asset()
        rebuild_diff = float(np.abs(built.vertices - committed.vertices).max())
        _step(progress, "build")
        rig = JointRig(committed, dtype=torch.float64)
        theta, posed = _edit(stage, rig, seed, spread, spp, progress)
        astronaut, synthetic = _fits(stage, config, progress)

        def final(summary: dict) -> dict:  # paths as they will be once the folder is in place
            return _relative_to(summary, stage, stage)

        summary = {
            "output": str(out.resolve()),
            "rig": rig_info(),
            "rebuild_max_difference_mm": rebuild_diff,
            "seed": seed,
            "edited_parameters": int((theta != 0).sum()),
            "edit_max_displacement_mm": float(np.linalg.norm(posed[1] - posed[0], axis=1).max()),
            "astronaut": final(astronaut),
            "synthetic": final(synthetic),
            "seconds": round(time.perf_counter() - t0, 2),
        }
        (stage / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


__all__ = ["DEMO_STEPS", "DEMO_SYNTHETIC_HEAD", "run_demo"]
