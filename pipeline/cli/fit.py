"""``jnr fit PHOTO... --out DIR``: reconstruct the head in a photo, or in several in parallel processes or
on a Dask cluster (:mod:`pipeline.photo.photo_file`, :mod:`pipeline.photo.batch`,
:mod:`pipeline.photo.dask_runner`).

The ``--detector`` choices are the names in :mod:`landmarks.detector`'s registry (a light module: the
detectors themselves, numpy and dlib are imported only when a photo is fitted)."""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from landmarks.detector import DEFAULT_DETECTOR, detector_names, detector_summary
from pipeline.cli.common import (
    EXIT_FAILURE,
    EXIT_OK,
    EXIT_USAGE,
    CliError,
    StageBars,
    command_line,
    load_fit_photo_config,
    printable,
    progress_bars_wanted,
)
from pipeline.head.folders import PHOTO_FOLDER, PHOTO_OUTPUT_SETS, VIEWS_FOLDER


def _fit_worker(task, threads: int):
    """One photo (:class:`pipeline.photo.task.PhotoTask`) in a worker process, or in this one for
    ``--jobs 1``: its :class:`~pipeline.photo.summary.PhotoFileResult` (one per face with ``--face all``)."""
    import torch

    from pipeline.photo.task import fit_photo_task
    from pipeline.signals import worker_task

    torch.set_num_threads(threads)
    with worker_task():
        return fit_photo_task(task)


def _with_bar(run, quiet: bool):
    """``run(tasks)`` that also draws a progress bar over the tasks (on a terminal, without ``--quiet``)."""
    from tqdm import tqdm

    def with_bar(tasks):
        bar = tqdm(total=len(tasks), desc="photos", unit="photo", disable=quiet or not progress_bars_wanted())
        try:
            for result in run(tasks):
                bar.update()
                yield result
        finally:
            bar.close()

    return with_bar


def _runner(jobs: int, threads: int, quiet: bool):
    """``run(tasks)`` for :func:`pipeline.photo.batch.fit_photo_files`, with a progress bar: in this
    process for one job, else in ``jobs`` spawned processes that die with this one: on an interrupt or
    SIGTERM here they are terminated (and remove their staged outputs) before the exception goes on."""

    def one_by_one(tasks):
        for task in tasks:
            yield _fit_worker(task, threads)

    def in_processes(tasks):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        from pipeline.signals import stop_children, worker_init

        if min(jobs, len(tasks)) == 1:  # e.g. one photo left to fit when resuming: no pool to start
            yield from one_by_one(tasks)
            return
        pool = ProcessPoolExecutor(
            min(jobs, len(tasks)),
            mp_context=multiprocessing.get_context("spawn"),
            initializer=worker_init,
            initargs=(os.getpid(),),
        )
        results = []
        try:
            futures = [pool.submit(_fit_worker, t, threads) for t in tasks]
            for future in as_completed(futures):
                results.append(future.result())
                yield results[-1]
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            stop_children()
            raise
        pool.shutdown()

    return _with_bar(one_by_one if jobs == 1 else in_processes, quiet)


def _output_names(config=None, folder: Path | None = None) -> str:
    """The files of one fit's folder (of the ``--outputs`` set of ``config``), as printed: an optional file
    only if ``folder`` holds it (without ``folder``: marked as optional)."""
    files = "all" if config is None else config.outputs.files
    optional = set(PHOTO_FOLDER.names) - set(PHOTO_FOLDER.required)
    names = [
        f"{n} (if MediaPipe's points were fitted)" if n in optional and folder is None else n
        for n in PHOTO_OUTPUT_SETS[files]
        if n not in optional or folder is None or (folder / n).is_file()
    ]
    return ", ".join(names)


def _face_option(text: str | None) -> int | str | None:
    """``--face``: None, a face number or ``all``."""
    from pipeline.photo.detection import FACE_ALL

    if text is None or text == FACE_ALL:
        return text
    try:
        return int(text)
    except ValueError:
        raise CliError(f"--face must be a face number (0 = the largest) or '{FACE_ALL}', got {text!r}") from None


def _print_results(results) -> list:
    """One line per photo (or face) fitted now on stdout (not those kept from an earlier run), one
    ``jnr: error:`` line per failure on stderr; returns the failures."""
    failed = [r for r in results if r.error is not None]
    for r in results:
        if r.summary is not None and not r.kept:
            face = "" if r.face is None or r.faces_found is None else f" face {r.face} of {r.faces_found}"
            print(
                f"{printable(str(r.photo))}{face}: {r.summary['mean_error_px']:.2f} px (NME {r.summary['nme']:.4f}), "
                f"{r.summary['fit_seconds']:.1f} s -> {printable(str(r.summary['output']))}"
            )
    for r in failed:
        print(f"jnr: error: {printable(r.error)}", file=sys.stderr)
    return failed


def _exit_status(failed) -> int:
    if failed:
        return max(EXIT_USAGE if r.bad_input else EXIT_FAILURE for r in failed)
    return EXIT_OK


def _fit_faces(args: argparse.Namespace, photo: Path, config, out: Path) -> int:
    """``jnr fit PHOTO --face all``: every face into OUT/face_<k>/ and OUT/summary.csv."""
    from pipeline.photo.photo_file import fit_photo_faces
    from pipeline.photo.summary import SUMMARY_FILE

    bars = StageBars(args.quiet)
    try:
        results = fit_photo_faces(
            photo,
            out,
            config=config,
            focal=args.focal,
            force=args.force,
            progress=bars,
            command=command_line("jnr fit"),
            detector=args.detector,
        )
    except FloatingPointError as exc:  # every face's fit diverged
        raise CliError(str(exc), EXIT_FAILURE) from None
    finally:
        bars.close()
    failed = _print_results(results)
    print(
        f"fitted {len(results) - len(failed)} of {len(results)} faces in {photo}; wrote {out}/: face_<k>/ "
        f"({_output_names(config)}) and {SUMMARY_FILE}"
    )
    return _exit_status(failed)


def _fit_one(args: argparse.Namespace, photo: Path, config, out: Path) -> int:
    from pipeline.photo.photo_file import fit_photo_file

    bars = StageBars(args.quiet)
    try:
        summary = fit_photo_file(
            photo,
            out,
            config=config,
            landmarks=args.landmarks,
            face=args.face,
            focal=args.focal,
            force=args.force,
            progress=bars,
            command=command_line("jnr fit"),
            detector=args.detector,
        )
    except FloatingPointError as exc:  # a diverged fit
        raise CliError(str(exc), EXIT_FAILURE) from None
    finally:
        bars.close()
    print(
        f"fitted {photo} in {summary['fit_seconds']:.1f} s ({summary['seconds']:.1f} s with detection and "
        f"outputs; summary.csv's fit_seconds and seconds): landmark error {summary['mean_error_px']:.2f} px "
        f"(NME {summary['nme']:.4f})"
    )
    print(f"wrote {out}/: {_output_names(config, out)}")
    return EXIT_OK


def _fit_several(args: argparse.Namespace, photos: list[Path], folders: list[Path], config, out: Path) -> int:
    """Several photos into OUT/<name>/ and OUT/summary.csv: resumed, in local processes or on a Dask cluster."""
    from pipeline.photo.batch import fit_photo_files
    from pipeline.photo.detection import FACE_ALL
    from pipeline.photo.summary import SUMMARY_FILE

    if (args.landmarks and args.landmarks != "auto") or args.face not in (None, FACE_ALL):
        raise CliError(
            "--landmarks FILE and --face N apply to a single photo; for several, use --landmarks auto "
            "(a .pts/.json/.csv file beside each photo), detection or --face all"
        )
    common = dict(
        folders=folders,
        config=config,
        landmarks=args.landmarks,
        focal=args.focal,
        force=args.force,
        command=command_line("jnr fit"),
        detector=args.detector,
        face=args.face,
    )
    if args.scheduler:
        from pipeline.photo.dask_runner import DaskRunner

        with DaskRunner(args.scheduler) as dask:
            how = f"on the Dask cluster at {dask.address} ({dask.workers} worker(s))"
            results = fit_photo_files(photos, out, run=_with_bar(dask, args.quiet), **common)
    else:
        jobs = max(1, min(args.jobs or (os.cpu_count() or 1), len(photos)))
        threads = max(1, (os.cpu_count() or 1) // jobs)
        how = f"with {jobs} process(es)"
        results = fit_photo_files(photos, out, run=_runner(jobs, threads, args.quiet), **common)
    failed = _print_results(results)
    kept = [r for r in results if r.kept and r.error is None]
    fitted = len(results) - len(failed) - len(kept)
    if args.face == FACE_ALL:
        photos_done = len({r.photo for r in results if r.summary})
        done = f"{fitted} faces in {photos_done} of {len(photos)} photos {how}"
    else:
        done = f"{fitted} of {len(results)} photos {how}"
    written = f"outputs and {SUMMARY_FILE} in {out}/" if out.is_dir() else "nothing written"
    print(f"fitted {done}; kept {len(kept)} (fitted earlier), {len(failed)} failed; {written}")
    return _exit_status(failed)


def _fit_views(args: argparse.Namespace, photos: list[Path]) -> int:
    """``jnr fit a b c --views --out DIR``: one head from several photos of one person
    (:mod:`pipeline.photo.multiview_outputs`)."""
    from pipeline.cli.common import fit_photo_overrides
    from pipeline.config import ConfigError, load_config
    from pipeline.photo.multiview import MultiViewConfig
    from pipeline.photo.multiview_outputs import MIN_VIEWS, fit_multiview_files

    if len(photos) < MIN_VIEWS:
        raise CliError(f"--views needs at least {MIN_VIEWS} photos of the same person, got {len(photos)}")
    if args.face is not None:
        raise CliError("--face cannot be used with --views (each photo's largest face is fitted)")
    overrides = fit_photo_overrides(args)
    if args.skinning is not None:
        overrides["skinning"] = args.skinning
    try:
        config = load_config(MultiViewConfig, args.config, overrides)
    except ConfigError as exc:
        raise CliError(str(exc)) from None
    try:
        summary = fit_multiview_files(
            photos,
            args.out,
            config=config,
            landmarks=args.landmarks,
            focal=args.focal,
            force=args.force,
            command=command_line("jnr fit"),
            detector=args.detector,
        )
    except FloatingPointError as exc:
        raise CliError(str(exc), EXIT_FAILURE) from None
    print(
        f"fitted {summary['views']} views of one head in {summary['seconds']:.1f} s: landmark error "
        f"{summary['mean_error_px']:.2f} px (mean over views)"
    )
    print(f"wrote {args.out}/: {VIEWS_FOLDER.listing(args.out)}")
    return EXIT_OK


def cmd_fit(args: argparse.Namespace) -> int:
    """``jnr fit PHOTO... --out DIR``: single-photo reconstruction (see pipeline.photo.fit)."""
    from pipeline.photo.detection import FACE_ALL
    from pipeline.photo.inputs import photo_inputs

    if args.jobs is not None and args.jobs < 1:
        raise CliError(f"--jobs must be at least 1, got {args.jobs}")
    if args.scheduler is not None and args.jobs is not None:
        raise CliError(
            "--jobs sets the local processes; with --scheduler the Dask workers fit the photos (start "
            "them with `dask worker ADDRESS --nworkers N`): give one or the other"
        )
    if args.focal is not None and not math.isfinite(args.focal):
        raise CliError(f"--focal must be a number of pixels, got {args.focal}")
    args.face = _face_option(args.face)
    if args.face is not None and args.landmarks:
        raise CliError("--face picks among the faces the detector finds; it cannot be used with --landmarks")
    photos, folders = photo_inputs(args.photos)
    if args.scheduler is not None and (args.views or (len(photos) == 1 and not folders)):
        raise CliError(
            "--scheduler fits several photos (a folder or a list) on a Dask cluster; one photo, or "
            "--views, is fitted here: leave --scheduler out"
        )
    if args.views:
        return _fit_views(args, photos)
    if args.skinning is not None:
        raise CliError(
            "--skinning applies to --views (several photos of one person) or fit-scan: one photo's 68 "
            "landmarks do not determine ASM's 1,196 parameters, so the single-photo fit is JNR's"
        )
    config = load_fit_photo_config(args)
    if len(photos) == 1 and not folders:
        fit = _fit_faces if args.face == FACE_ALL else _fit_one
        return fit(args, photos[0], config, Path(args.out))
    return _fit_several(args, photos, folders, config, Path(args.out))


FIT_DESCRIPTION = (
    "Fit the rig (head pose, 107 joint channels, the 52 ARKit expressions and gaze) to one photo: detect the "
    "face's landmarks (MediaPipe's 478 points with the irises; dlib's 68 iBUG points when MediaPipe finds no "
    "face), place a pinhole camera (--focal, default 1.4 x the image's larger side) by solvePnP, then fit the "
    "landmarks by Levenberg-Marquardt (~0.5 s) with an identity prior: when MediaPipe found the face, the head "
    "its 3D mesh says (a map learned from 20,000 photographed synthetic heads; faces turned up to 30 deg), else "
    "the synthetic head population's (--set landmarks.regression.enabled=false: always that). --photometric "
    "adds a stage that renders the head (Mitsuba 3 on the CPU; the face's median colour, ambient + directional "
    "or SH light) and moves its identity along the prior's main directions to "
    "match the face pixels, keeping a quarter of that step (photometric.identity_step), ~15 s; about 1 % closer to "
    "the person on 100 synthetic photos (docs/fit_photo.md)."
)
FIT_EPILOG = (
    "Inputs: one or more image files (.jpg .jpeg .png .bmp .gif .tif .tiff .webp .ppm .pgm .pnm) or "
    "folders of them. Several photos are fitted in parallel processes (--jobs) or on a Dask cluster "
    "(--scheduler ADDRESS); each gets OUT/<name>/, and OUT/summary.csv lists them, one row per photo (per "
    "face with --face all): photo, face, status (ok/error), error, output folder, landmark error px, NME, "
    "seconds in all and of the fit alone (fit_seconds, what stdout prints), faces detected, face box and "
    "score, kept (yes: the output of an earlier run, kept). It is "
    "written also when some photos fail (the exit status is then 2, or 1 when every failure is a diverged "
    "fit).\n"
    "Resuming: run the same command again and the photos whose output folder is complete are kept (not "
    "fitted again; their rows are rebuilt from their report.json), failed or missing ones are fitted, what "
    "a killed run left is cleaned up; --force fits every photo again (docs/datasets.md).\n"
    "Faces: --face N fits the N-th face the detector finds (0 = the largest); --face all fits every face, "
    "into OUT/face_<k>/ (k = 0, 1, ... as --face numbers them), or OUT/<name>/face_<k>/ for several "
    "photos, each with all the outputs below, and summary.csv beside them (one row per face)."
    "\nViews: --views fits the photos as views of ONE person (at least 2): one identity, a pose, expression "
    "and focal per view (single-view fits averaged, then refined together, the views' landmark terms averaged "
    "and the turned ones weighed less, as a detector's errors are shared by the views and grow with the yaw; "
    "points with independent errors, e.g. placed by hand: --set view_correlation=0 --set view_yaw_deg=0; "
    "--photometric adds photometric "
    "consistency between views, off by default, see docs/multiview.md; --skinning asm the ASM identity "
    f"model); OUT/ gets {VIEWS_FOLDER.listing()}."
    "\nLimits: images up to 120 megapixels; photos longer than 2048 px are fitted reduced "
    "by a power of two (camera and landmarks are still written in the photo's pixels); --focal within "
    "0.25-25 x the longer side; landmark files (68 iBUG points, or MediaPipe's 468 or 478) must look like a "
    "face, in or near the image, not mirrored.\nSafety: --out must not be, contain or lie in an input or the working "
    "directory; --force replaces only a folder jnr wrote (it holds a .jnr-output file); outputs are "
    "moved into place atomically, and nothing is left behind on an error, Ctrl-C or SIGTERM.\n"
    f"Outputs: {PHOTO_FOLDER.help_text()}."
    "\nLandmarks: --landmarks "
    'FILE (.pts 1-based as in iBUG 300-W, .json {"landmarks": [[x, y], ...]} or .csv index,x,y; 0-based '
    "OpenCV pixels) skips detection.\nSchedule and settings: configs/fit_photo.yaml (--config) and "
    "--set GROUP.KEY=VALUE (e.g. --set landmarks.prior.lambda_identity=0.1, --set photometric.spp=4).\n"
    "Try it: jnr fit photo.jpg --out out/photo"
)


def _detector_help() -> str:
    """The registered detectors for ``--help``: ``name (summary)``, the default marked."""
    listed = []
    for name in detector_names():
        summary = detector_summary(name)
        if name == DEFAULT_DETECTOR:
            summary = f"default: {summary}" if summary else "default"
        listed.append(f"{name} ({summary})" if summary else name)
    return ", ".join(listed)


def _add_input_arguments(parser: argparse.ArgumentParser) -> None:
    """``jnr fit``'s inputs: the photos, the output folder, the landmarks, face, detector and focal."""
    parser.add_argument("photos", nargs="+", metavar="PHOTO", help="image file(s) or folder(s) of images")
    parser.add_argument("--out", required=True, help="output folder (per photo: OUT/<name>/ when several)")
    parser.add_argument(
        "--landmarks",
        metavar="FILE|auto",
        help="landmarks file (.pts, .json, .csv; 68 iBUG points, or MediaPipe's 468/478) instead of "
        "detection (one photo); 'auto': the "
        "file with the photo's name beside each photo (face.png -> face.pts), as in iBUG 300-W",
    )
    parser.add_argument(
        "--face",
        metavar="N|all",
        help="which detected face, 0 = the largest (default: 0), or 'all': every face, into "
        "OUT/face_<k>/ with OUT/summary.csv (not with --landmarks)",
    )
    parser.add_argument(
        "--detector",
        choices=detector_names(),
        default=DEFAULT_DETECTOR,
        help=f"the face detector: {_detector_help()}; report.json lists every face found",
    )
    parser.add_argument("--focal", type=float, help="focal length in pixels (default: 1.4 x max(width, height))")


def _add_output_arguments(parser: argparse.ArgumentParser) -> None:
    """Which files each fit writes, in which units and axes (shortcuts of ``--set outputs.*``)."""
    parser.add_argument(
        "--outputs",
        choices=("all", "mesh", "minimal"),
        help="which files each fit writes: all (default), mesh (mesh.obj/.mtl/.ply/.glb, texture.png, params.json, "
        "report.json, config.yaml) or minimal (params.json, report.json, config.yaml; jnr rig edit rebuilds the "
        "head from them); fewer files take less time (= --set outputs.files=...)",
    )
    parser.add_argument(
        "--units",
        choices=("mm", "m"),
        help="units of mesh.obj and mesh.ply (default mm, rig space; m for Blender and tools that read metres; "
        "mesh.glb is in metres either way; = --set outputs.units=...)",
    )
    parser.add_argument(
        "--ply-up",
        choices=("y", "z"),
        help="up axis of mesh.ply: y (default, rig space; MeshLab, Open3D, CloudCompare) or z (upright in "
        "Blender's PLY importer with its default axes); mesh.obj stays Y-up (= --set outputs.ply_up=...)",
    )


def _add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    """What is fitted (landmarks, photometric stages, views, identity model) and its settings."""
    parser.add_argument(
        "--landmarks-only", action="store_true", help="the landmark fit only (the default; kept for scripts)"
    )
    parser.add_argument(
        "--photometric",
        action="store_true",
        help="after the landmark fit, the photometric identity stage (render + photo loss, ~8 s a photo; off by "
        "default: about 1 %% closer to the person on synthetic photos, see docs/fit_photo.md)",
    )
    parser.add_argument(
        "--views",
        action="store_true",
        help="the photos are views of ONE person: fit one shared identity with a pose, expression and "
        "focal per view (at least 2 photos; OUT/ gets one mesh and overlay_<k>.png per view; "
        "--photometric adds photometric consistency between views; docs/multiview.md)",
    )
    parser.add_argument(
        "--skinning",
        metavar="MODEL",
        help="with --views: the identity model, jnr (the rig's joints, default), asm (adaptive skinning) or "
        "another registered head model (one photo: --set model=MODEL, for a model of flat parameter groups; "
        "asm's are not)",
    )
    parser.add_argument("--config", help="YAML overriding the fitting settings (e.g. configs/fit_photo.yaml)")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one setting (repeatable)")


def _add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """How several photos are run (processes or a Dask cluster), replaced and reported."""
    parser.add_argument("--jobs", type=int, help="parallel processes for several photos (default: the CPU count)")
    parser.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="fit several photos on a Dask cluster: the address of its scheduler (e.g. tcp://host:8786, "
        "as `dask scheduler` prints it); the workers need jnr installed and the photos and --out "
        "at the same paths (docs/datasets.md); not with --jobs",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace output folders that exist (only jnr's own); for several photos: fit every photo "
        "again instead of keeping the complete outputs of an earlier run",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr fit``."""
    fit = sub.add_parser(
        "fit",
        help="reconstruct the head in a photo (landmarks + differentiable rendering)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=FIT_DESCRIPTION,
        epilog=FIT_EPILOG,
    )
    _add_input_arguments(fit)
    _add_output_arguments(fit)
    _add_fit_arguments(fit)
    _add_run_arguments(fit)
    fit.set_defaults(func=cmd_fit)
