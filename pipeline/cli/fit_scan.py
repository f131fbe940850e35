"""``jnr fit-scan CLOUD --out DIR``: fit the rig to a point cloud by non-rigid ICP (:mod:`pipeline.scan.files`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.cli.common import (
    EXIT_FAILURE,
    EXIT_OK,
    CliError,
    StageBars,
    check_output,
    command_line,
    load_fit_scan_config,
)
from pipeline.head.folders import SCAN_FOLDER


def cmd_fit_scan(args: argparse.Namespace) -> int:
    """``jnr fit-scan CLOUD --out DIR``: NICP fit of the rig to a point cloud (see pipeline.scan.fit)."""
    from pipeline.scan.files import fit_scan_file

    out = Path(args.out)
    check_output(out, args.force, inputs=[args.cloud, args.landmarks, args.config], kind="folder")
    config = load_fit_scan_config(args)
    bars = StageBars(args.quiet)
    try:
        result = fit_scan_file(
            args.cloud,
            out,
            config=config,
            landmarks=args.landmarks,
            units=args.units,
            frame=args.frame,
            force=args.force,
            progress=bars,
            command=command_line("jnr fit-scan"),
            inputs=[args.config],
        )
    except FloatingPointError as exc:  # a diverged fit
        raise CliError(str(exc), EXIT_FAILURE) from None
    finally:
        bars.close()
    points, total = result["points"], result["input_points"]
    used = f"{points} points (a random subsample of its {total})" if total > points else f"{points} points"
    print(
        f"fitted {used} ({result['units']}) in {result['fit_seconds']:.1f} s; "
        f"scan-to-mesh median {result['s2m_median_mm']:.2f} mm, mean {result['s2m_mean_mm']:.2f} mm, "
        f"std {result['s2m_std_mm']:.2f} mm"
    )
    print(f"wrote {out}/: {SCAN_FOLDER.listing(out)}")
    return EXIT_OK


FIT_SCAN_EPILOG = (
    "Clouds: .ply, .obj, .xyz/.txt/.csv (x y z [nx ny nz]), .npy ((N,3) or (N,6)); normals are "
    "estimated when absent.\nUnits: detected from the cloud's size (a head is 80-450 mm across) "
    "unless --units is given; metres and centimetres are converted with a warning; inches (--units in) "
    "are never guessed, but a cloud the head fits far better in other units than those detected is "
    "refused with both figures.\nFrame: +Y up "
    "(any position, any yaw; pitch/roll within ~30 deg), or --frame opencv for camera coordinates "
    "(x right, y down, z forward); a cloud the head fits far better turned over is refused.\n"
    "Far from the origin (georeferenced) is fine in float64; float32 coordinates that resolve less than "
    "0.1 mm where they lie are refused.\n"
    'Landmarks (optional): JSON {"nose_tip": [x, y, z], ...} in the '
    "cloud's units and frame; names: left_eye_outer, left_eye_inner, right_eye_inner, right_eye_outer, "
    "nose_tip, mouth_left, mouth_right, chin (at least 3).\n"
    f"Outputs in --out: {SCAN_FOLDER.help_text()}.\n"
    "Schedule and settings: configs/fit_scan.yaml (--config) and --set GROUP.KEY=VALUE (e.g. --set "
    "prior.lambda_m_end=0.01).\nTry it: jnr data scan --out scan.ply && "
    "jnr fit-scan scan.ply --out out/scan"
)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr fit-scan``."""
    fs = sub.add_parser(
        "fit-scan",
        help="fit the rig to a point cloud (depth scan) by non-rigid ICP",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Fit the rig (pose, 107 joint channels, neural-skinning latent Z, the 52 ARKit expressions) "
        "to a point "
        "cloud: robust rigid pre-alignment, then JNR's alternating schedule (joints, Z; expressions) "
        "with closest-point correspondences both ways (rejected by distance, normals and the scan "
        "border) and a regulariser that diminishes as they settle. Holes and unseen parts are "
        "filled by the rig's prior.",
        epilog=FIT_SCAN_EPILOG,
    )
    fs.add_argument("cloud", help="point-cloud file")
    fs.add_argument("--out", required=True, help="output folder (must not exist unless --force)")
    fs.add_argument(
        "--units", default="auto", choices=["auto", "mm", "cm", "m", "in"], help="units of the cloud (default: auto)"
    )
    fs.add_argument("--frame", default="y-up", choices=["y-up", "opencv"], help="frame of the cloud (default: y-up)")
    fs.add_argument("--landmarks", help="3D landmarks JSON (see below)")
    fs.add_argument("--config", help="YAML overriding the fitting settings (e.g. configs/fit_scan.yaml)")
    fs.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one setting (repeatable)")
    fs.add_argument("--seed", type=int, help="seed of the cloud subsampling (default: the config's, 0)")
    fs.add_argument("--force", action="store_true", help="replace the output folder if it exists")
    fs.add_argument("--quiet", action="store_true", help="no progress bars")
    fs.set_defaults(func=cmd_fit_scan)
