"""The ``jnr`` command line.

    jnr demo [--out DIR]                       the rig, and jnr fit on the astronaut and a synthetic photo
    jnr rig info [--json]                      sizes of the rig
    jnr rig build [--out FILE | --check]       regenerate the template asset from code
    jnr rig export --format obj|ply|gltf --out FILE [--params PARAMS.json]
    jnr rig edit PARAMS.json --out FILE        write the head edited by named parameters
    jnr data synth --out DIR                   write the synthetic head population
    jnr train                                  learn linear + neural skinning weights
    jnr data scan --out FILE.ply               a simulated depth scan of a held-out synthetic head
    jnr fit PHOTO... --out DIR                 reconstruct the head in a photo (or several, in parallel)
    jnr fit-scan CLOUD --out DIR               fit the rig to a point cloud (non-rigid ICP)
    jnr eval capacity [--json]                 known-correspondence error of each skinning variant
    jnr eval scans [--neutral N --expressive N]  fit-scan vs nricp_amberg on simulated depth scans
    jnr eval photos [--neutral N --expressive N] jnr fit on synthetic renders with known truth

Errors in the input (:class:`rig.errors.InputError` and its subclasses: missing or malformed files,
unknown parameter names, values outside limits, refused outputs) end with a one-line message on
stderr and exit status 2; a broken installation (:class:`rig.errors.SetupError`, render's
``LLVMError``), an error while writing or a diverged fit, 1. Nothing half-written is left behind.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import shutil
import sys
import time
from pathlib import Path

from rig.errors import JnrError

log = logging.getLogger("jnr")

EXIT_OK, EXIT_FAILURE, EXIT_USAGE = 0, 1, 2
MESH_FORMATS = {"obj": ".obj", "ply": ".ply", "gltf": ".glb"}


class CliError(JnrError):
    """An error to report to the user in one line (exit status ``code``)."""

    def __init__(self, message: str, code: int = EXIT_USAGE) -> None:
        super().__init__(message)
        self.code = code


# ----------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------

def _check_output(path: Path, force: bool, inputs=()) -> None:
    """Refuse an output file before any work (:func:`pipeline.files.check_output`; its
    :class:`~pipeline.files.OutputError` is an InputError, which :func:`main` reports with exit 2)."""
    from pipeline.files import check_output

    check_output(path, force=force, inputs=[p for p in inputs if p], kind="file")


MESH_SUFFIXES = {"obj": (".obj",), "ply": (".ply",), "gltf": (".glb", ".gltf")}


def _format_for(path: Path, explicit: str | None) -> str:
    """The mesh format of an output: from ``--format`` (which must agree with the suffix) or the suffix."""
    suffix = path.suffix.lower()
    if explicit:
        if suffix not in MESH_SUFFIXES[explicit]:
            raise CliError(f"--format {explicit} writes {' or '.join(MESH_SUFFIXES[explicit])} files, but --out is "
                           f"{path}; change the suffix or the format")
        return explicit
    for name, suffixes in MESH_SUFFIXES.items():
        if suffix in suffixes:
            return name
    raise CliError(f"cannot tell the mesh format of {path}: use .obj, .ply, .glb or .gltf, or pass --format")


FIT_PARAMS_KEYS = {"joints", "latent_z", "expressions"}
PARAMS_FILE_KEYS = {"joints", "units", "format"}


def _load_edit_params(params: str | None, clamp: bool) -> tuple[object, tuple | None]:
    """A parameter file for ``rig export/edit``: ``(theta (P,) float64, None)`` for joint parameters, or
    ``(None, arrays)`` for the ``params.json`` of a fit, whose joints, latent Z and expressions are all
    used (``arrays``: :func:`pipeline.scan.outputs.head_arrays_from_params`).

    Raises:
        CliError / ParameterError: unreadable file, unknown keys, a fit file with ``--clamp``.
    """
    import torch

    from rig.parameters import NUM_PARAMETERS, ParameterError, load_params_json

    if params is None:
        return torch.zeros(NUM_PARAMETERS, dtype=torch.float64), None
    path = Path(params)
    try:
        data = json.loads(path.read_text()) if path.is_file() else None
    except (json.JSONDecodeError, UnicodeDecodeError):
        data = None  # load_params_json reports it
    if isinstance(data, dict) and (FIT_PARAMS_KEYS - {"joints"}) & set(data):
        missing = sorted(FIT_PARAMS_KEYS - set(data))
        if missing:
            raise ParameterError(f"{path}: a fit's parameter file needs {sorted(FIT_PARAMS_KEYS)}; {missing} missing")
        if clamp:
            raise CliError(f"{path} is the parameter file of a fit; --clamp applies to joint parameters only")
        from pipeline.scan.outputs import head_arrays_from_params

        try:
            return None, head_arrays_from_params(data)
        except (ValueError, TypeError) as exc:
            raise ParameterError(f"{path}: {exc}") from None
    if isinstance(data, dict) and isinstance(data.get("joints"), dict):
        unknown = sorted(set(data) - PARAMS_FILE_KEYS)
        if unknown:
            raise ParameterError(f"{path}: unknown key(s) {unknown}; a parameter file holds {sorted(PARAMS_FILE_KEYS)} "
                                 f"(or a fit's {sorted(FIT_PARAMS_KEYS)})")
    return load_params_json(path, clamp=clamp).double(), None


def _write_head(path: Path, fmt: str, theta, rig=None, fit_arrays: tuple | None = None) -> None:
    """Write the rig posed by ``theta (P,)`` as OBJ/PLY (posed vertices) or skinned glTF (posable joints);
    with ``fit_arrays`` (of a fit's ``params.json``, :func:`_load_edit_params`), the fitted head."""
    import torch

    from rig.io.export import export_mesh, export_skinned_gltf
    from rig.model import JointRig

    rig = rig or JointRig(dtype=torch.float64)
    asset = rig.asset
    if fit_arrays is not None:
        posed, rest, weights, tau = fit_arrays
    else:
        with torch.no_grad():
            posed = rig(theta[None]).vertices[0].numpy()
            tau = rig.channel_transforms(theta[None])[0].numpy()
        rest, weights = asset.vertices, asset.weights
    if fmt == "gltf":
        export_skinned_gltf(path, rest, asset.faces, joint_names=list(asset.joint_names),
                            parents=asset.parents, joint_positions=asset.joint_positions, weights=weights,
                            face_uvs=asset.face_uvs, joint_transforms=tau)
    else:
        export_mesh(path, posed, asset.faces, face_uvs=asset.face_uvs if fmt == "obj" else None,
                    file_format=fmt)


def _write_output_file(out: Path, force: bool, inputs, write) -> None:
    """``write(tmp_path)`` into a staged file that replaces ``out`` atomically when it succeeds."""
    from pipeline.files import staged_file

    with staged_file(out, force, inputs=[p for p in inputs if p]) as tmp:
        write(tmp)


# ----------------------------------------------------------------------------------------------------
# commands
# ----------------------------------------------------------------------------------------------------

def rig_info() -> dict:
    """Sizes of the rig (what ``jnr rig info --json`` prints)."""
    from rig.asset import load_asset
    from rig.parameters import NUM_PARAMETERS, symmetric_groups

    asset = load_asset()
    skinning = len(asset.weight_free)
    return {
        "vertices": len(asset.vertices),
        "faces": len(asset.faces),
        "joints": len(asset.joint_names),
        "free_parameters": NUM_PARAMETERS,
        "free_parameters_symmetric": len(symmetric_groups()),
        "skinning_floats": int(skinning),
        "skinning_nonzeros": len(asset.weight_rows),
        "max_influences": int(max(1, (asset.weights > 0).sum(1).max())),
        "model_floats": int(asset.vertices.size + asset.joint_positions.size + skinning),
        "regions": list(asset.region_names),
        "units": "mm",
        "asset_version": asset.version,
    }


def cmd_rig_info(args: argparse.Namespace) -> int:
    info = rig_info()
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for key, value in info.items():
            print(f"{key:26s} {value}")
    return EXIT_OK


def cmd_rig_build(args: argparse.Namespace) -> int:
    import numpy as np

    from rig.asset import DEFAULT_ASSET, build_asset, read_asset, save_asset

    t0 = time.perf_counter()
    out = Path(args.out) if args.out else DEFAULT_ASSET
    if not args.check:
        _check_output(out, args.force or (args.out is None))
    log.info("generating the template head, joints and weights")
    asset = build_asset()
    if args.check:
        committed = read_asset(args.out or DEFAULT_ASSET)
        diff = float(np.abs(committed.vertices - asset.vertices).max())
        same = (diff <= 1e-6 and np.array_equal(committed.faces, asset.faces)
                and float(np.abs(committed.weight_free - asset.weight_free).max()) <= 1e-9)
        print(f"rebuilt in {time.perf_counter() - t0:.1f} s; largest vertex difference {diff:.3g} mm; "
              f"{'identical' if same else 'DIFFERENT'}")
        return EXIT_OK if same else EXIT_FAILURE
    save_asset(asset, out)
    print(f"wrote {out} ({len(asset.vertices)} vertices, {len(asset.faces)} faces) in {time.perf_counter() - t0:.1f} s")
    return EXIT_OK


def cmd_rig_export(args: argparse.Namespace) -> int:
    """``jnr rig export``: :func:`cmd_rig_edit` with an optional parameter file and a default output."""
    args.out = args.out or f"jnr_rig{MESH_FORMATS[args.format]}"
    return cmd_rig_edit(args)


def cmd_rig_edit(args: argparse.Namespace) -> int:
    """``jnr rig edit`` / ``export``: the rig posed by a parameter file (or a fit's params.json), written
    atomically."""
    out = Path(args.out)
    fmt = _format_for(out, args.format)
    _check_output(out, args.force, inputs=[args.params])
    theta, fit_arrays = _load_edit_params(args.params, args.clamp)
    _write_output_file(out, args.force, [args.params], lambda tmp: _write_head(tmp, fmt, theta, fit_arrays=fit_arrays))
    print(f"wrote {out}" + (" (the fitted head: joints, latent Z and expressions, rig space, mm)" if fit_arrays else ""))
    return EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    """Build the rig from code and export/edit it; reconstruct the astronaut portrait and a synthetic photo
    with known truth (the README's main job)."""
    import numpy as np
    import torch

    from pipeline.files import check_output, staged_folder
    from rig.asset import build_asset, load_asset
    from rig.model import JointRig
    from rig.parameters import random_theta, save_params_json

    out = Path(args.out)
    config = _load_fit_photo_config(args)
    if not out.parent.exists():
        out.parent.mkdir(parents=True)  # the README's command writes out/demo in a fresh clone
    check_output(out, force=args.force, kind="folder")
    steps = ["build", "export", "edit", "picture", "astronaut fit", "synthetic photo", "synthetic fit"]
    from tqdm import tqdm

    bar = tqdm(total=len(steps), desc="jnr demo", unit="step", disable=args.quiet)
    try:
        with staged_folder(out, args.force, marker={"command": "jnr demo"}) as stage:
            t0 = time.perf_counter()
            built = build_asset()
            committed = load_asset()
            rebuild_diff = float(np.abs(built.vertices - committed.vertices).max())
            bar.update()
            rig = JointRig(committed, dtype=torch.float64)
            zero = torch.zeros(rig.num_parameters, dtype=torch.float64)
            for fmt, ext in MESH_FORMATS.items():
                _write_head(stage / f"template{ext}", fmt, zero, rig)
            bar.update()
            gen = torch.Generator().manual_seed(args.seed)
            theta = random_theta(gen, 1, spread=args.spread, dtype=torch.float64)[0]
            save_params_json(theta, stage / "edited_params.json")
            for fmt, ext in (("obj", ".obj"), ("gltf", ".glb")):
                _write_head(stage / f"edited{ext}", fmt, theta, rig)
            bar.update()
            from render.preview import render_preview, save_png

            with torch.no_grad():
                posed = rig(torch.stack([zero, theta])).vertices.numpy()
            faces = committed.faces
            tiles = [render_preview(v, faces, view=view, size=(360, 440), spp=args.spp, distance=700.0,
                                    target=(0.0, -20.0, 20.0)) for v in posed for view in ("front", "three_quarter")]
            picture = np.concatenate([np.concatenate(tiles[:2], 1), np.concatenate(tiles[2:], 1)], 0)
            save_png(picture, stage / "edited.png")
            bar.update()
            astronaut, synthetic = _demo_fits(stage, config, bar)
            summary = {
                "output": str(out),
                "rig": rig_info(),
                "rebuild_max_difference_mm": rebuild_diff,
                "seed": args.seed,
                "edited_parameters": int((theta != 0).sum()),
                "edit_max_displacement_mm": float(np.linalg.norm(posed[1] - posed[0], axis=1).max()),
                "astronaut": {k: v.replace(str(stage), str(out)) if isinstance(v, str) else v
                              for k, v in astronaut.items()},
                "synthetic": {k: v.replace(str(stage), str(out)) if isinstance(v, str) else v
                              for k, v in synthetic.items()},
                "seconds": round(time.perf_counter() - t0, 2),
            }
            (stage / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    finally:
        bar.close()
    print(f"jnr demo: wrote {out}/ in {summary['seconds']:.0f} s")
    for name in sorted(p.name for p in out.iterdir()):
        print(f"  {name}{'/' if (out / name).is_dir() else ''}")
    print(f"template rebuilt from code: largest difference to the committed asset {rebuild_diff:.2g} mm")
    print(f"edited head (seed {args.seed}): {summary['edited_parameters']} parameters, largest vertex move "
          f"{summary['edit_max_displacement_mm']:.1f} mm; picture: {out / 'edited.png'}")
    print(f"astronaut portrait (scikit-image): landmark error {astronaut['mean_error_px']:.2f} px, NME "
          f"{astronaut['nme']:.4f}, {astronaut['fit_seconds']:.1f} s; see {out / 'astronaut' / 'overlay.png'}")
    print(f"synthetic photo of {synthetic['head']} (known truth): face scan-to-mesh median "
          f"{synthetic['s2m_median_mm']:.2f} mm, mean {synthetic['s2m_mean_mm']:.2f} mm; true vertex error "
          f"{synthetic['vertex_mean_mm']:.2f} mm (template {synthetic['template_vertex_mean_mm']:.2f} mm); "
          f"landmark error {synthetic['mean_error_px']:.2f} px, {synthetic['fit_seconds']:.1f} s; "
          f"see {out / 'synthetic' / 'overlay.png'}")
    return EXIT_OK


DEMO_SYNTHETIC_HEAD = 21
"""The held-out head of the demo's synthetic photo (the photo fit's defaults were chosen on heads 0-5)."""


def _demo_fits(stage: Path, config, bar) -> tuple[dict, dict]:
    """The demo's photo fits: the astronaut (detected landmarks) and a synthetic photo with known truth."""
    from PIL import Image
    from skimage import data

    from pipeline.evaluation.photos import face_error
    from pipeline.photo.outputs import mesh_from_photo_params
    from pipeline.synthetic.photos import synthetic_photo, write_synthetic_photo
    from rig.asset import load_asset

    inputs = stage / "inputs"
    inputs.mkdir()
    Image.fromarray(data.astronaut()).save(inputs / "astronaut.png")
    astronaut = fit_one_photo(inputs / "astronaut.png", stage / "astronaut", config=config, command="jnr demo")
    bar.update()
    photo = synthetic_photo(DEMO_SYNTHETIC_HEAD, expressive=True, seed=0)
    truth_dir = write_synthetic_photo(photo, inputs / "synthetic")
    bar.update()
    synthetic = fit_one_photo(truth_dir / "photo.png", stage / "synthetic", config=config,
                              landmarks=str(truth_dir / "landmarks.pts"), focal=photo.focal, command="jnr demo")
    fitted = mesh_from_photo_params(stage / "synthetic" / "params.json")
    error = face_error(fitted, photo.gt_vertices)
    template = face_error(load_asset().vertices, photo.gt_vertices)
    synthetic.update({"head": photo.name, "truth": str(truth_dir / "truth.ply"), **error,
                      "template_vertex_mean_mm": template["vertex_mean_mm"],
                      "template_s2m_median_mm": template["s2m_median_mm"]})
    bar.update()
    return astronaut, synthetic


class _StageBars:
    """One tqdm bar per stage name: ``bars(stage, done, total)``."""

    def __init__(self, disable: bool = False) -> None:
        self.disable = disable
        self.bar = None
        self.stage = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        from tqdm import tqdm

        if stage != self.stage:
            self.close()
            self.stage = stage
            self.bar = tqdm(total=total, desc=stage, disable=self.disable, leave=False)
        self.bar.n = done
        self.bar.refresh() if done == total or done % 10 == 0 else None

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def cmd_data_synth(args: argparse.Namespace) -> int:
    from pipeline.files import staged_folder
    from pipeline.synthetic.population import MANIFEST_NAME, write_population

    out = Path(args.out)
    bars = _StageBars(args.quiet)
    try:
        with staged_folder(out, args.force, marker={"command": "jnr data synth"}) as tmp:
            write_population(tmp, seed=args.seed, splits=tuple(args.splits), file_format=args.format,
                             overwrite=True, progress=lambda d, t: bars("synthesising heads", d, t))
    finally:
        bars.close()
    print(f"wrote {out / MANIFEST_NAME}")
    return EXIT_OK


def _parse_overrides(items: list[str]) -> dict:
    from pipeline.config import ConfigError, parse_overrides

    try:
        return parse_overrides(items)
    except ConfigError as exc:
        raise CliError(str(exc)) from None


def cmd_train(args: argparse.Namespace) -> int:
    from pipeline.train import load_config, train
    from rig.asset import ASSET_DIR

    try:
        config = load_config(args.config, _parse_overrides(args.set))
    except (TypeError, ValueError) as exc:
        raise CliError(str(exc)) from None
    out = Path(args.out) if args.out else ASSET_DIR / "jnr_skinning_v1.npz"
    _check_output(out, args.force or args.out is None)
    log_path = Path(args.log) if args.log else out.with_suffix(".log.json")
    bars = _StageBars(args.quiet)
    try:
        report = train(config, out, log_path=log_path, progress=bars)
    finally:
        bars.close()
    print(json.dumps({"artifact": str(out), "log": str(log_path), "counts": report.counts,
                      "seconds": report.seconds, "train_rmse_mm_per_joint_fit": report.rmse_train_mm["per_joint_fit"]},
                     indent=2))
    return EXIT_OK


def cmd_eval_capacity(args: argparse.Namespace) -> int:
    from pipeline.evaluation.capacity import CapacitySettings, evaluate_capacity

    if args.out:
        _check_output(Path(args.out), args.force)
    settings = CapacitySettings(joint_iterations=args.joint_iterations, z_iterations=args.z_iterations,
                                cycles=args.cycles, seed=args.seed)
    bars = _StageBars(args.quiet)
    try:
        result = evaluate_capacity(tuple(args.splits), settings, neural_path=args.skinning, limit=args.limit,
                                   progress=bars, oracle=args.oracle)
    finally:
        bars.close()
    text = json.dumps(result, indent=2)
    if args.out:
        _write_output_file(Path(args.out), args.force, (), lambda tmp: tmp.write_text(text + "\n"))
    if args.json:
        print(text)
    else:
        print(f"{'split':10s} {'weights':16s} {'mean mm':>9s} {'std mm':>8s} {'heads':>6s}")
        for split, row in result["splits"].items():
            for name in ("initial", "learned_linear", "neural", "per_head_optimal_weights"):
                if name not in row:
                    continue
                r = row[name]
                print(f"{split:10s} {name:16s} {r['mean_mm']:9.3f} {r['std_mm']:8.3f} {r['heads']:6d}")
    return EXIT_OK


def _load_fit_scan_config(args: argparse.Namespace, seed_is_fit_seed: bool = True):
    from pipeline.config import ConfigError, load_config
    from pipeline.scan.fit import FitScanConfig

    overrides = _parse_overrides(args.set)
    try:
        if seed_is_fit_seed and args.seed is not None:
            overrides["seed"] = args.seed
        return load_config(FitScanConfig, args.config, overrides)
    except ConfigError as exc:
        raise CliError(str(exc)) from None


def cmd_fit_scan(args: argparse.Namespace) -> int:
    """``jnr fit-scan CLOUD --out DIR``: NICP fit of the rig to a point cloud (see pipeline.scan.fit)."""
    import numpy as np

    from landmarks.points3d import LandmarkError
    from pipeline.files import check_output
    from pipeline.scan.fit import fit_scan, scan_to_mesh
    from pipeline.scan.outputs import write_scan_outputs
    from pipeline.scan.pointcloud import (
        CloudError,
        read_landmarks3d,
        read_point_cloud,
        to_rig_frame,
    )
    from rig.asset import load_asset

    out = Path(args.out)
    inputs = [p for p in (args.cloud, args.landmarks, args.config) if p]
    check_output(out, force=args.force, inputs=inputs)
    config = _load_fit_scan_config(args)
    t0 = time.perf_counter()
    try:
        cloud = read_point_cloud(args.cloud, units=args.units, frame=args.frame)
        landmarks = None
        if args.landmarks:
            raw = read_landmarks3d(args.landmarks)
            landmarks = {k: to_rig_frame(np.asarray(v, float)[None] * cloud.scale_to_mm, args.frame)[0]
                         for k, v in raw.items()}
        bars = _StageBars(args.quiet)
        try:
            fit = fit_scan(cloud, config, landmarks=landmarks, progress=bars, landmarks_source=str(args.landmarks))
        finally:
            bars.close()
    except (CloudError, LandmarkError) as exc:
        raise CliError(str(exc)) from None
    except FloatingPointError as exc:
        raise CliError(str(exc), EXIT_FAILURE) from None
    distances = scan_to_mesh(cloud.points, fit.vertices, load_asset().faces)
    write_scan_outputs(out, cloud, fit, distances, frame=args.frame, config=config, force=args.force,
                       extra={"command": "jnr " + " ".join(sys.argv[1:]) if sys.argv[1:] else "jnr fit-scan",
                              "wall_seconds": time.perf_counter() - t0}, inputs=tuple(inputs))
    used = (f"{len(cloud.points)} points (a random subsample of its {cloud.input_points})"
            if cloud.input_points > len(cloud.points) else f"{len(cloud.points)} points")
    print(f"fitted {used} ({cloud.units}) in {fit.timings['total']:.1f} s; "
          f"scan-to-mesh median {np.median(distances):.2f} mm, mean {distances.mean():.2f} mm, "
          f"std {distances.std():.2f} mm")
    print(f"wrote {out}/: mesh.ply, mesh.obj, params.json, cloud_error.ply, report.json")
    return EXIT_OK


IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".gif", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pnm")
"""What ``jnr fit`` reads as photos, named directly or found in a folder (the same rule for both)."""


def photo_inputs(items: list[str]) -> tuple[list[Path], list[Path]]:
    """``(photos, folders)``: image files named directly, or found (non-recursively, sorted) in named
    folders; a file is a photo when its suffix is one of :data:`IMAGE_SUFFIXES`."""
    photos: list[Path] = []
    folders: list[Path] = []
    supported = ", ".join(IMAGE_SUFFIXES)
    for item in items:
        path = Path(item)
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise CliError(f"folder {path} holds no images ({supported})")
            photos.extend(found)
            folders.append(path)
        elif path.is_file():
            if path.suffix.lower() not in IMAGE_SUFFIXES:
                raise CliError(f"{path} is not a photo jnr reads (the file name must end in one of {supported})")
            photos.append(path)
        else:
            raise CliError(f"image file not found: {path}")
    return photos, folders


LANDMARK_SUFFIXES = (".pts", ".json", ".csv")


def _sidecar_landmarks(photo: Path) -> Path:
    """``--landmarks auto``: the landmarks file beside the photo with the same name (``face.png`` ->
    ``face.pts``, ``.json`` or ``.csv``), as the iBUG 300-W sets ship them."""
    for suffix in LANDMARK_SUFFIXES:
        candidate = photo.with_suffix(suffix)
        if candidate.is_file():
            return candidate
    raise CliError(f"--landmarks auto: no {'/'.join(LANDMARK_SUFFIXES)} file beside {photo}")


def _load_fit_photo_config(args: argparse.Namespace):
    from pipeline.config import ConfigError, load_config
    from pipeline.photo.fit import FitPhotoConfig

    overrides = _parse_overrides(args.set)
    if args.landmarks_only:
        overrides["photometric"] = False
    try:
        return load_config(FitPhotoConfig, args.config, overrides)
    except ConfigError as exc:
        raise CliError(str(exc)) from None


def fit_one_photo(photo_path: str | Path, out: str | Path, *, config=None, landmarks: str | None = None,
                  face: int | None = None, focal: float | None = None, force: bool = False,
                  progress=None, command: str = "jnr fit", inputs: tuple = ()) -> dict:
    """Detect (or read) the landmarks of one photo, fit it and write its output folder.

    Everything that can be checked cheaply is checked before the fit: the output path (not an input,
    not the working directory, writable; an existing one only with ``force`` and only if jnr wrote
    it), the image (readable, at most :data:`landmarks.detect.MAX_IMAGE_PIXELS`), ``focal`` (within
    :data:`pipeline.photo.camera.FOCAL_RANGE` times the longer side), the landmarks (a readable file
    with 68 points, in or near the image, a face-like and not mirrored configuration). Photos longer
    than :data:`landmarks.detect.WORKING_MAX_SIDE` are fitted reduced by a power of two; the outputs
    give the camera and landmarks in the photo's own pixels.

    Args:
        inputs: more input paths the output must not be, contain or lie in (e.g. the photo's folder).

    Returns:
        A summary dict (output folder, landmark error in the photo's pixels, timings).

    Raises:
        CliError: any of the above (exit status 2, nothing written); a diverged fit (1).
    """
    from landmarks.detect import DetectionError, detect_landmarks, load_working_image
    from landmarks.formats import read_landmarks
    from landmarks.plausibility import check_landmarks_2d
    from pipeline.files import check_output
    from pipeline.photo.camera import check_focal
    from pipeline.photo.fit import FitPhotoConfig, fit_photo
    from pipeline.photo.outputs import write_photo_outputs

    t0 = time.perf_counter()
    photo_path, out = Path(photo_path), Path(out)
    if face is not None and landmarks:
        raise CliError("--face picks one of the faces the detector finds; it cannot be used with --landmarks")
    landmarks_path = _sidecar_landmarks(photo_path) if landmarks == "auto" else (Path(landmarks) if landmarks else None)
    all_inputs = [photo_path, *([landmarks_path] if landmarks_path else []), *inputs]
    config = config or FitPhotoConfig()
    try:
        check_output(out, force=force, inputs=all_inputs)
        photo = load_working_image(photo_path)
        width, height = photo.original_size
        if focal is not None:
            check_focal(focal, width, height)
        if landmarks_path:
            points = read_landmarks(landmarks_path)
            check_landmarks_2d(points, width, height, source=str(landmarks_path))
            points = photo.to_working(points)
            source = {"landmarks": str(landmarks_path)}
        else:
            detection = detect_landmarks(photo.image, face=face)
            points = detection.landmarks
            source = {"landmarks": "dlib 68-point detector", "face_box": photo.to_original(
                detection.box.reshape(2, 2)).reshape(-1).tolist(), "face_score": detection.score,
                      "face_index": 0 if face is None else face}
    except DetectionError as exc:  # name the photo (the other InputErrors name their file or option)
        message = str(exc)
        raise CliError(message if str(photo_path) in message else f"{photo_path}: {message}") from None
    k = photo.factor
    try:
        fit = fit_photo(photo.image, points, focal=None if focal is None else focal / k, config=config,
                        progress=progress)
    except FloatingPointError as exc:  # a diverged fit
        raise CliError(f"{photo_path}: {exc}", EXIT_FAILURE) from None
    except ValueError as exc:  # bad image or landmarks for the fit (InputError and plain ValueError)
        raise CliError(f"{photo_path}: {exc}") from None
    extra = {"input": {"photo": str(photo_path), "width": width, "height": height,
                       "fitted_width": fit.width, "fitted_height": fit.height, "reduction": k,
                       "focal_px": fit.focal * k, "focal_source": "--focal" if focal else "default 1.4 * max(W, H)",
                       **source},
             "command": command}
    write_photo_outputs(out, photo.image, fit, config=config, force=force, extra=extra, inputs=all_inputs,
                        image_factor=k, original_size=photo.original_size)
    return {"photo": str(photo_path), "output": str(out), "mean_error_px": float(fit.error_px.mean()) * k,
            "nme": float(fit.nme), "seconds": time.perf_counter() - t0, "fit_seconds": fit.timings["total"]}


def _fit_worker(task: tuple) -> tuple[str, dict | None, str | None, int]:
    """One photo in a worker process: ``(photo, summary, error message, exit code)``."""
    photo, out, config, landmarks, focal, force, threads, command, inputs = task
    import torch

    from pipeline.signals import worker_task
    from rig.errors import InputError

    torch.set_num_threads(threads)
    try:
        with worker_task():
            return photo, fit_one_photo(photo, out, config=config, landmarks=landmarks, focal=focal, force=force,
                                        command=command, inputs=inputs), None, 0
    except CliError as exc:
        return photo, None, str(exc), exc.code
    except InputError as exc:
        return photo, None, str(exc), EXIT_USAGE
    except Exception as exc:  # noqa: BLE001 - reported per photo; the batch goes on
        return photo, None, f"{photo}: {type(exc).__name__}: {exc}", EXIT_FAILURE


def _run_workers(tasks: list[tuple], jobs: int, bar) -> list[tuple]:
    """Fit ``tasks`` in ``jobs`` spawned processes that die with this one: on an interrupt or SIGTERM here
    they are terminated (and remove their staged outputs) before the exception goes on."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from pipeline.signals import stop_children, worker_init

    results = []
    pool = ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"), initializer=worker_init,
                               initargs=(os.getpid(),))
    try:
        futures = [pool.submit(_fit_worker, t) for t in tasks]
        for future in as_completed(futures):
            results.append(future.result())
            bar.update()
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        stop_children()
        raise
    pool.shutdown()
    return results


def cmd_fit(args: argparse.Namespace) -> int:
    """``jnr fit PHOTO... --out DIR``: single-photo reconstruction (see pipeline.photo.fit)."""
    from pipeline.files import OutputError, check_output, make_output_folder

    if args.jobs is not None and args.jobs < 1:
        raise CliError(f"--jobs must be at least 1, got {args.jobs}")
    if args.focal is not None and not math.isfinite(args.focal):
        raise CliError(f"--focal must be a number of pixels, got {args.focal}")
    photos, folders = photo_inputs(args.photos)
    config = _load_fit_photo_config(args)
    out = Path(args.out)
    command = "jnr " + " ".join(sys.argv[1:]) if sys.argv[1:] else "jnr fit"
    if len(photos) == 1 and not folders:
        bars = _StageBars(args.quiet)
        try:
            summary = fit_one_photo(photos[0], out, config=config, landmarks=args.landmarks, face=args.face,
                                    focal=args.focal, force=args.force, progress=bars, command=command)
        finally:
            bars.close()
        print(f"fitted {photos[0]} in {summary['fit_seconds']:.1f} s: landmark error {summary['mean_error_px']:.2f} px "
              f"(NME {summary['nme']:.4f})")
        print(f"wrote {out}/: mesh.obj, mesh.ply, mesh.glb, params.json, overlay.png, render.png, landmarks.pts, "
              "report.json")
        return EXIT_OK

    if (args.landmarks and args.landmarks != "auto") or args.face is not None:
        raise CliError("--landmarks FILE and --face apply to a single photo; for several, use --landmarks auto "
                       "(a .pts/.json/.csv file beside each photo) or detection")
    stems = [p.stem for p in photos]
    names = [s if stems.count(s) == 1 else f"{s}_{i}" for i, s in enumerate(stems)]
    inputs = [str(p) for p in (*photos, *folders)]
    created = make_output_folder(out, inputs=inputs)
    try:
        for n in names:
            check_output(out / n, force=args.force, inputs=inputs)
    except OutputError:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    jobs = max(1, min(args.jobs or (os.cpu_count() or 1), len(photos)))
    threads = max(1, (os.cpu_count() or 1) // jobs)
    tasks = [(str(p), str(out / n), config, args.landmarks, args.focal, args.force, threads, command, tuple(inputs))
             for p, n in zip(photos, names)]
    from tqdm import tqdm

    results = []
    bar = tqdm(total=len(tasks), desc="photos", unit="photo", disable=args.quiet)
    try:
        if jobs == 1:
            for task in tasks:
                results.append(_fit_worker(task))
                bar.update()
        else:
            results = _run_workers(tasks, jobs, bar)
    finally:
        bar.close()
        if created and not any(r[1] for r in results):
            shutil.rmtree(out, ignore_errors=True)  # nothing of ours in it
    results.sort(key=lambda r: [str(p) for p in photos].index(r[0]))
    failed = [r for r in results if r[2] is not None]
    for photo, summary, _, _ in results:
        if summary is not None:
            print(f"{photo}: {summary['mean_error_px']:.2f} px (NME {summary['nme']:.4f}), "
                  f"{summary['fit_seconds']:.1f} s -> {summary['output']}")
    for _, _, message, _ in failed:
        print(f"jnr: error: {message}", file=sys.stderr)
    print(f"fitted {len(results) - len(failed)} of {len(results)} photos with {jobs} process(es); outputs in {out}/")
    if failed:
        return max(code for *_, code in failed)
    return EXIT_OK


def cmd_data_scan(args: argparse.Namespace) -> int:
    """``jnr data scan --out FILE``: a simulated depth scan of a held-out synthetic head."""
    import numpy as np

    from pipeline.scan.pointcloud import write_point_cloud_ply
    from pipeline.synthetic.expressive import expressive_split
    from pipeline.synthetic.scans import DepthCamera, simulate_scan
    from rig.asset import load_asset

    out = Path(args.out)
    if out.suffix.lower() != ".ply":
        raise CliError(f"--out must be a .ply file, got {out}")
    _check_output(out, args.force)
    truth = out.with_name(out.stem + "_truth.ply")
    _check_output(truth, args.force)
    if args.head < 0 or args.head >= 100:
        raise CliError(f"--head must be in 0..99 (the held-out heads), got {args.head}")
    heads = expressive_split("heldout", seed=args.population_seed, n=args.head + 1)
    vertices = heads.vertices[args.head] if args.expressive else heads.neutral[args.head]
    camera = DepthCamera(640, 576, 504.0, 504.0, 320.0, 288.0) if args.hires else DepthCamera()
    asset = load_asset()
    scan = simulate_scan(vertices, asset.faces, rng=np.random.default_rng(args.seed), camera=camera)
    import trimesh

    _write_output_file(out, args.force, (), lambda tmp: write_point_cloud_ply(tmp, scan.points, normals=scan.normals))
    _write_output_file(truth, args.force, (), lambda tmp: trimesh.Trimesh(scan.gt_vertices, asset.faces,
                                                                           process=False).export(tmp))
    print(f"wrote {out} ({len(scan.points)} points, mm, +Y up) and the true head {truth}")
    return EXIT_OK


def _run_evaluation(args: argparse.Namespace, label: str, evaluate) -> int:
    """Shared by the ``jnr eval`` commands over synthetic data: a progress bar over the ``jnr`` records,
    the Markdown table (or ``--json``), and ``--out``."""
    total = args.neutral + args.expressive
    bars = _StageBars(args.quiet)
    done = []

    def progress(record) -> None:
        if record.method == "jnr":
            done.append(record)
            bars(label, len(done), total)

    try:
        result = evaluate(progress)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    finally:
        bars.close()
    payload = {"summary": result.summary(), "records": [r.__dict__ for r in result.records],
               "settings": result.settings}
    text = json.dumps(payload, indent=2, default=float)
    if args.out:
        _write_output_file(Path(args.out), args.force, (), lambda tmp: tmp.write_text(text + "\n"))
    print(text if args.json else result.table_markdown())
    return EXIT_OK


def cmd_eval_scans(args: argparse.Namespace) -> int:
    """``jnr eval scans``: fit-scan vs trimesh's nricp_amberg on simulated scans of held-out heads."""
    from pipeline.evaluation.scans import evaluate_scans

    if args.out:
        _check_output(Path(args.out), args.force)
    config = _load_fit_scan_config(args, seed_is_fit_seed=False)
    return _run_evaluation(args, "simulated scans", lambda progress: evaluate_scans(
        args.neutral, args.expressive, seed=args.seed or 0, config=config, baseline=not args.no_baseline,
        progress=progress))


def cmd_eval_photos(args: argparse.Namespace) -> int:
    """``jnr eval photos``: the photo fit on synthetic renders of held-out heads (NoW-style errors)."""
    from pipeline.evaluation.photos import evaluate_photos

    if args.out:
        _check_output(Path(args.out), args.force)
    config = _load_fit_photo_config(args)
    return _run_evaluation(args, "synthetic photos", lambda progress: evaluate_photos(
        args.neutral, args.expressive, first=args.first, seed=args.seed, config=config, progress=progress))


# ----------------------------------------------------------------------------------------------------
# parser
# ----------------------------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jnr", description="Joint-based Neural Rig: a 52-joint face rig, fitted to photos and point clouds.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Units: millimetres in rig space (right-handed, +Y up, +Z out of the face); rotations in "
               "degrees; scales as factors.\nParameter files: JSON {\"joints\": {\"nose_tip.translate_y\": 2.0, ...}}.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    demo = sub.add_parser("demo", help="the README's main job on built-in input: the rig, and two photo fits",
                          description="Rebuild the template from code and compare it with the committed asset, "
                                      "export it as OBJ/PLY/glTF, make a randomly edited head and a picture of both; "
                                      "then reconstruct the astronaut portrait that scikit-image ships and a "
                                      "synthetic photo of a held-out head with known truth (jnr fit), and print "
                                      "where the outputs are and the errors.")
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    demo.add_argument("--force", action="store_true", help="replace the output folder if it exists")
    demo.add_argument("--seed", type=int, default=7, help="seed of the random edit (default: 7)")
    demo.add_argument("--spread", type=float, default=0.3,
                      help="random edit strength, a fraction of each parameter's range (default: 0.3)")
    demo.add_argument("--spp", type=int, default=32, help="samples per pixel of the picture (default: 32)")
    demo.add_argument("--landmarks-only", action="store_true", help="fit the photos without the photometric stages")
    demo.add_argument("--config", help="YAML overriding the photo-fitting settings (configs/fit_photo.yaml)")
    demo.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one photo-fitting setting")
    demo.add_argument("--quiet", action="store_true", help="no progress bar")
    demo.set_defaults(func=cmd_demo)

    fit = sub.add_parser(
        "fit", help="reconstruct the head in a photo (landmarks + differentiable rendering)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Fit the rig (head pose, 105 joint channels, neural-skinning latent Z, 24 expressions), a "
                    "per-vertex albedo and an ambient + directional light to one photo: detect the 68 iBUG "
                    "landmarks (dlib), place a pinhole camera (--focal, default 1.4 x the image's larger side) "
                    "by solvePnP, fit the landmarks, then alternate joint / latent / expression stages with a "
                    "robust photometric loss on the face pixels (Mitsuba 3 on the CPU) and the landmarks.",
        epilog="Inputs: one or more image files (.jpg .jpeg .png .bmp .gif .tif .tiff .webp .ppm .pgm .pnm) or "
               "folders of them. Several photos are fitted in parallel processes (--jobs); each gets "
               "OUT/<name>/.\nLimits: images up to 120 megapixels; photos longer than 2048 px are fitted reduced "
               "by a power of two (camera and landmarks are still written in the photo's pixels); --focal within "
               "0.25-25 x the longer side; landmark files must look like a face in iBUG-68 order, in or near the "
               "image, not mirrored.\nSafety: --out must not be, contain or lie in an input or the working "
               "directory; --force replaces only a folder jnr wrote (it holds a .jnr-output file); outputs are "
               "moved into place atomically, and nothing is left behind on an error, Ctrl-C or SIGTERM.\n"
               "Outputs: mesh.obj, mesh.ply "
               "(rig space, mm, +Y up, vertex colours = albedo), mesh.glb (skinned glTF), params.json (joints "
               "by name, Z, expressions, camera, pose, light), overlay.png, render.png, landmarks.pts, "
               "report.json (landmark error in px and NME, losses per stage, timings).\nLandmarks: --landmarks "
               "FILE (.pts 1-based as in iBUG 300-W, .json {\"landmarks\": [[x, y], ...]} or .csv index,x,y; 0-based "
               "OpenCV pixels) skips detection.\nSchedule and settings: configs/fit_photo.yaml (--config) and "
               "--set KEY=VALUE (nested: --set landmarks.lambda_m=0.5).\nTry it: jnr fit photo.jpg --out out/photo")
    fit.add_argument("photos", nargs="+", metavar="PHOTO", help="image file(s) or folder(s) of images")
    fit.add_argument("--out", required=True, help="output folder (per photo: OUT/<name>/ when several)")
    fit.add_argument("--landmarks", metavar="FILE|auto",
                     help="68 landmarks file (.pts, .json, .csv) instead of detection (one photo); 'auto': the "
                          "file with the photo's name beside each photo (face.png -> face.pts), as in iBUG 300-W")
    fit.add_argument("--face", type=int, help="which detected face, 0 = the largest (default: 0; not with --landmarks)")
    fit.add_argument("--focal", type=float, help="focal length in pixels (default: 1.4 x max(width, height))")
    fit.add_argument("--landmarks-only", action="store_true", help="skip the photometric stages (~2 s a photo)")
    fit.add_argument("--config", help="YAML overriding the fitting settings (e.g. configs/fit_photo.yaml)")
    fit.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one setting (repeatable)")
    fit.add_argument("--jobs", type=int, help="parallel processes for several photos (default: the CPU count)")
    fit.add_argument("--force", action="store_true", help="replace output folders that exist (only jnr's own)")
    fit.add_argument("--quiet", action="store_true", help="no progress bars")
    fit.set_defaults(func=cmd_fit)

    fs = sub.add_parser(
        "fit-scan", help="fit the rig to a point cloud (depth scan) by non-rigid ICP",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Fit the rig (pose, 105 joint channels, neural-skinning latent Z, 24 expressions) to a point "
                    "cloud: robust rigid pre-alignment, then JNR's alternating schedule (joints, Z; expressions) "
                    "with closest-point correspondences both ways (rejected by distance, normals and the scan "
                    "border) and a regulariser that diminishes as they settle. Holes and unseen parts are "
                    "filled by the rig's prior.",
        epilog="Clouds: .ply, .obj, .xyz/.txt/.csv (x y z [nx ny nz]), .npy ((N,3) or (N,6)); normals are "
               "estimated when absent.\nUnits: detected from the cloud's size (a head is 80-450 mm across) "
               "unless --units is given; metres and centimetres are converted with a warning.\nFrame: +Y up "
               "(any position, any yaw; pitch/roll within ~30 deg), or --frame opencv for camera coordinates "
               "(x right, y down, z forward).\nLandmarks (optional): JSON {\"nose_tip\": [x, y, z], ...} in the "
               "cloud's units and frame; names: left_eye_outer, left_eye_inner, right_eye_inner, right_eye_outer, "
               "nose_tip, mouth_left, mouth_right, chin (at least 3).\nOutputs in --out: mesh.ply, mesh.obj (in "
               "the cloud's frame and units), params.json, cloud_error.ply, report.json.\nSchedule and settings: "
               "configs/fit_scan.yaml (--config) and --set KEY=VALUE.\nTry it: jnr data scan --out scan.ply && "
               "jnr fit-scan scan.ply --out out/scan")
    fs.add_argument("cloud", help="point-cloud file")
    fs.add_argument("--out", required=True, help="output folder (must not exist unless --force)")
    fs.add_argument("--units", default="auto", choices=["auto", "mm", "cm", "m"], help="units of the cloud (default: auto)")
    fs.add_argument("--frame", default="y-up", choices=["y-up", "opencv"], help="frame of the cloud (default: y-up)")
    fs.add_argument("--landmarks", help="3D landmarks JSON (see below)")
    fs.add_argument("--config", help="YAML overriding the fitting settings (e.g. configs/fit_scan.yaml)")
    fs.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one setting (repeatable)")
    fs.add_argument("--seed", type=int, help="seed of the cloud subsampling (default: the config's, 0)")
    fs.add_argument("--force", action="store_true", help="replace the output folder if it exists")
    fs.add_argument("--quiet", action="store_true", help="no progress bars")
    fs.set_defaults(func=cmd_fit_scan)

    rig = sub.add_parser("rig", help="the face rig: info, build, export, edit")
    rig_sub = rig.add_subparsers(dest="rig_command", metavar="RIG_COMMAND")
    rig_sub.required = True

    info = rig_sub.add_parser("info", help="print the rig's sizes")
    info.add_argument("--json", action="store_true", help="print JSON")
    info.set_defaults(func=cmd_rig_info)

    build = rig_sub.add_parser("build", help="regenerate the template asset from code",
                               description="Regenerate the template head, joints and initial skinning weights. "
                                           "Without --out, rewrites the packaged asset.")
    build.add_argument("--out", help="where to write the .npz (default: the packaged asset)")
    build.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    build.add_argument("--check", action="store_true",
                       help="do not write; compare the rebuilt asset with --out (default: the packaged one) "
                            "and exit 1 if they differ by more than 1e-6 mm")
    build.set_defaults(func=cmd_rig_build)

    export = rig_sub.add_parser("export", help="write the rig as OBJ, PLY or skinned glTF 2.0",
                                description="OBJ and PLY hold the (posed) mesh; glTF (.glb) holds the rest mesh "
                                            "with 52 posable joints, inverse bind matrices and skin weights, "
                                            "posed by --params.")
    export.add_argument("--format", choices=sorted(MESH_FORMATS), required=True)
    export.add_argument("--out", help="output file (default: jnr_rig.<ext> here)")
    export.add_argument("--params", help="parameter JSON to pose the rig with (default: rest pose)")
    export.add_argument("--clamp", action="store_true", help="clamp out-of-limit parameters (with a warning)")
    export.add_argument("--force", action="store_true", help="overwrite the output")
    export.set_defaults(func=cmd_rig_export)

    edit = rig_sub.add_parser("edit", help="write the head edited by a parameter file",
                              description="Pose the rig with named parameters and write the edited head.")
    edit.add_argument("params", help="parameter JSON, e.g. {\"joints\": {\"nose_tip.translate_z\": 5}}")
    edit.add_argument("--out", required=True, help="output mesh: .obj, .ply, .glb or .gltf")
    edit.add_argument("--format", choices=sorted(MESH_FORMATS), help="override the format chosen by suffix")
    edit.add_argument("--clamp", action="store_true", help="clamp out-of-limit parameters (with a warning)")
    edit.add_argument("--force", action="store_true", help="overwrite the output")
    edit.set_defaults(func=cmd_rig_edit)

    data = sub.add_parser("data", help="synthetic data: the head population that stands in for scans")
    data_sub = data.add_subparsers(dest="data_command", metavar="DATA_COMMAND")
    data_sub.required = True
    synth = data_sub.add_parser("synth", help="write the synthetic head population as meshes with a manifest",
                                description="Write the 85 train / 2 validation / 7 test identities and the "
                                            "100 held-out heads (template topology, mm) and manifest.json.")
    synth.add_argument("--out", required=True, help="output folder")
    synth.add_argument("--seed", type=int, default=0, help="population seed (default: 0)")
    synth.add_argument("--format", choices=("ply", "obj"), default="ply")
    synth.add_argument("--splits", nargs="+", default=["train", "val", "test", "heldout"],
                       choices=["train", "val", "test", "heldout"])
    synth.add_argument("--force", action="store_true", help="replace the output folder")
    synth.add_argument("--quiet", action="store_true", help="no progress bar")
    synth.set_defaults(func=cmd_data_synth)
    scan = data_sub.add_parser("scan", help="write a simulated depth scan of a held-out synthetic head (PLY)",
                               description="Render one held-out synthetic head (neutral or expressive) with a "
                                           "Kinect-like depth camera: random yaw within +-45 deg, noise, holes, "
                                           "outliers. Writes the cloud (mm, +Y up, with normals) and the true "
                                           "head as OUT_truth.ply.")
    scan.add_argument("--out", required=True, help="output .ply file")
    scan.add_argument("--head", type=int, default=0, help="held-out head index, 0..99 (default: 0)")
    scan.add_argument("--expressive", action="store_true", help="add a synthetic expression")
    scan.add_argument("--hires", action="store_true", help="640x576 camera (~15-20k points) instead of 320x288")
    scan.add_argument("--seed", type=int, default=0, help="seed of the scan (placement, noise, holes)")
    scan.add_argument("--population-seed", type=int, default=0, help="seed of the synthetic population")
    scan.add_argument("--force", action="store_true", help="overwrite the outputs")
    scan.set_defaults(func=cmd_data_scan)

    tr = sub.add_parser("train", help="learn the linear and neural skinning weights from the synthetic population",
                        description="Fit joints, learn global linear weights (alternating), synthesise "
                                    "skinning-weight sets, train the auto-encoder and fine-tune the decoder "
                                    "WGAN-style. Writes rig/assets/jnr_skinning_v1.npz unless --out is given.")
    tr.add_argument("--config", help="YAML file overriding TrainConfig fields (configs/train.yaml)")
    tr.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one setting (repeatable)")
    tr.add_argument("--out", help="artifact path (default: the packaged rig/assets/jnr_skinning_v1.npz)")
    tr.add_argument("--log", help="training log JSON (default: next to the artifact)")
    tr.add_argument("--force", action="store_true", help="overwrite --out")
    tr.add_argument("--quiet", action="store_true", help="no progress bars")
    tr.set_defaults(func=cmd_train)

    ev = sub.add_parser("eval", help="evaluations")
    ev_sub = ev.add_subparsers(dest="eval_command", metavar="EVAL_COMMAND")
    ev_sub.required = True
    cap = ev_sub.add_parser("capacity", help="known-correspondence error of initial / learned linear / neural skinning",
                            description="Fit the rig to the synthetic test and held-out heads with each skinning "
                                        "variant; point-to-point error in mm (mean, std over heads) and model sizes.")
    cap.add_argument("--json", action="store_true", help="print JSON")
    cap.add_argument("--splits", nargs="+", default=["test", "heldout"], choices=["train", "val", "test", "heldout"])
    cap.add_argument("--limit", type=int, help="only the first N heads of each split")
    cap.add_argument("--skinning", help="learned-skinning artifact (default: the packaged one)")
    cap.add_argument("--joint-iterations", type=int, default=400)
    cap.add_argument("--z-iterations", type=int, default=300)
    cap.add_argument("--cycles", type=int, default=2)
    cap.add_argument("--seed", type=int, default=0, help="population seed (default: 0)")
    cap.add_argument("--oracle", action="store_true",
                     help="also report per-head optimal weights (the bound for any skinning model with this pattern)")
    cap.add_argument("--out", help="also write the JSON here")
    cap.add_argument("--force", action="store_true", help="overwrite --out")
    cap.add_argument("--quiet", action="store_true", help="no progress bars")
    cap.set_defaults(func=cmd_eval_capacity)
    sc = ev_sub.add_parser("scans", help="fit-scan vs trimesh's nricp_amberg on simulated depth scans",
                           description="Simulate one Kinect-like depth scan of each of the first N held-out "
                                       "heads (neutral and expressive), fit it with jnr fit-scan and with "
                                       "trimesh.registration.nricp_amberg from the same rigid pre-alignment, and "
                                       "report scan-to-mesh distance, true vertex error (known correspondence) "
                                       "and seconds (JNR Tables 2-3 style).")
    sc.add_argument("--neutral", type=int, default=5, help="neutral scans (default: 5)")
    sc.add_argument("--expressive", type=int, default=5, help="expressive scans (default: 5)")
    sc.add_argument("--seed", type=int, help="seed of the scans (default: 0)")
    sc.add_argument("--no-baseline", action="store_true", help="skip nricp_amberg")
    sc.add_argument("--config", help="YAML overriding the fitting settings")
    sc.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one fitting setting")
    sc.add_argument("--json", action="store_true", help="print JSON instead of the table")
    sc.add_argument("--out", help="also write the JSON here")
    sc.add_argument("--force", action="store_true", help="overwrite --out")
    sc.add_argument("--quiet", action="store_true", help="no progress bar")
    sc.set_defaults(func=cmd_eval_scans)
    ph = ev_sub.add_parser("photos", help="jnr fit on synthetic renders of held-out heads (NoW-style errors)",
                           description="Render held-out synthetic heads (neutral and expressive; yaw within +-30 "
                                       "deg; path-traced with a point light and an environment, unlike the "
                                       "fitting renderer), give the fit the projected true landmarks + 1 px noise, "
                                       "align the result to the truth (similarity on the inner landmarks, then "
                                       "ICP) and report face-region scan-to-mesh distances and the true vertex "
                                       "error (mm) for the full fit, its landmark-only stage and the template.")
    ph.add_argument("--neutral", type=int, default=5, help="neutral photos (default: 5)")
    ph.add_argument("--expressive", type=int, default=5, help="expressive photos (default: 5)")
    ph.add_argument("--first", type=int, default=20,
                    help="first held-out head (default: 20; the defaults were chosen on heads 0-5)")
    ph.add_argument("--seed", type=int, default=0, help="seed of the photos (default: 0)")
    ph.add_argument("--landmarks-only", action="store_true", help="skip the photometric stages")
    ph.add_argument("--config", help="YAML overriding the fitting settings")
    ph.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one fitting setting")
    ph.add_argument("--json", action="store_true", help="print JSON instead of the table")
    ph.add_argument("--out", help="also write the JSON here")
    ph.add_argument("--force", action="store_true", help="overwrite --out")
    ph.add_argument("--quiet", action="store_true", help="no progress bar")
    ph.set_defaults(func=cmd_eval_photos)
    return parser


def _format_warning(message, category, filename, lineno, line=None) -> str:
    """Warnings as one line for users: no Python file, line number or source line."""
    return f"warning: {message}"


def main(argv: list[str] | None = None) -> int:
    import signal
    import threading
    import warnings

    from pipeline.signals import Terminated, terminate_as_exception

    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="jnr: %(message)s")
    logging.captureWarnings(True)
    saved_format, warnings.formatwarning = warnings.formatwarning, _format_warning
    from render.backend import LLVMError
    from rig.errors import InputError, JnrError

    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM) if main_thread else None
    if main_thread:
        terminate_as_exception()
    try:
        return args.func(args)
    except CliError as exc:
        print(f"jnr: error: {exc}", file=sys.stderr)
        return exc.code
    except (InputError, FileNotFoundError, FileExistsError, IsADirectoryError, NotADirectoryError,
            PermissionError) as exc:
        print(f"jnr: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except (JnrError, LLVMError, OSError, ValueError) as exc:
        print(f"jnr: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("jnr: interrupted; nothing half-written was left behind", file=sys.stderr)
        return 130
    except Terminated:
        print("jnr: terminated (SIGTERM); nothing half-written was left behind", file=sys.stderr)
        return 143
    finally:
        warnings.formatwarning = saved_format
        if main_thread:
            signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (OSError: strerror and the file)."""
    if isinstance(exc, OSError) and exc.strerror and exc.filename:
        return f"{exc.filename}: {exc.strerror}"
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
