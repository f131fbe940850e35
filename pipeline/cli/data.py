"""``jnr data synth | scan``: the synthetic head population and simulated depth scans of it."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.cli.common import EXIT_OK, CliError, StageBars, check_output

SPLITS = ("train", "val", "test", "heldout", "makehuman")
"""The splits of ``jnr data synth`` (:data:`pipeline.synthetic.population.SPLIT_SIZES`, not imported here so
that ``jnr --help`` stays fast)."""


def cmd_data_synth(args: argparse.Namespace) -> int:
    from pipeline.files import staged_folder
    from pipeline.synthetic.population import MANIFEST_NAME, write_population

    out = Path(args.out)
    bars = StageBars(args.quiet)
    try:
        with staged_folder(out, args.force, marker={"command": "jnr data synth"}) as tmp:
            write_population(
                tmp, seed=args.seed, splits=tuple(args.splits), file_format=args.format, overwrite=True, progress=bars
            )
    finally:
        bars.close()
    print(f"wrote {out / MANIFEST_NAME}")
    return EXIT_OK


def cmd_data_scan(args: argparse.Namespace) -> int:
    """``jnr data scan --out FILE``: a simulated depth scan of a held-out synthetic head."""
    from pipeline.synthetic.scans import HIRES_CAMERA, DepthCamera, write_heldout_scan

    out = Path(args.out)
    if out.suffix.lower() != ".ply":
        raise CliError(f"--out must be a .ply file, got {out}")
    check_output(out, args.force)
    truth = out.with_name(out.stem + "_truth.ply")
    check_output(truth, args.force)
    if args.head < 0 or args.head >= 100:
        raise CliError(f"--head must be in 0..99 (the held-out heads), got {args.head}")
    scan = write_heldout_scan(
        out,
        truth,
        head=args.head,
        expressive=args.expressive,
        camera=HIRES_CAMERA if args.hires else DepthCamera(),
        seed=args.seed,
        population_seed=args.population_seed,
        force=args.force,
    )
    print(f"wrote {out} ({len(scan.points)} points, mm, +Y up) and the true head {truth}")
    return EXIT_OK


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr data ...``."""
    data = sub.add_parser("data", help="synthetic data: the head population that stands in for scans")
    data_sub = data.add_subparsers(dest="data_command", metavar="DATA_COMMAND")
    data_sub.required = True
    synth = data_sub.add_parser(
        "synth",
        help="write the synthetic head population as meshes with a manifest",
        description="Write synthetic identity heads (template topology, mm, neutral) and manifest.json. "
        "The splits: train (85), val (2) and test (7) are ICT Face Model identities (real-scan statistics: "
        "the model's identity modes with N(0, 1) coefficients); heldout (100) is ICT identities from a "
        "shifted distribution (a wider spread: sd 1.25 on modes 1-30, 2 on modes 31-100); makehuman (100) "
        "is the out-of-distribution split, MakeHuman heads drawn from MakeHuman's shifted held-out "
        "distribution (artist-made targets, with asymmetry and head-shape sliders). The manifest records "
        "each split's kind and each head's seed and coefficients (and, for MakeHuman heads, phenotype "
        "and age), enough to make every head again.",
    )
    synth.add_argument("--out", required=True, help="output folder")
    synth.add_argument("--seed", type=int, default=0, help="population seed (default: 0)")
    synth.add_argument("--format", choices=("ply", "obj"), default="ply")
    synth.add_argument(
        "--splits",
        nargs="+",
        default=list(SPLITS),
        choices=SPLITS,
        metavar="SPLIT",
        help="splits to write, of train, val, test, heldout (ICT identities) and makehuman (MakeHuman heads, "
        "out of distribution) (default: all)",
    )
    synth.add_argument("--force", action="store_true", help="replace the output folder")
    synth.add_argument("--quiet", action="store_true", help="no progress bar")
    synth.set_defaults(func=cmd_data_synth)
    scan = data_sub.add_parser(
        "scan",
        help="write a simulated depth scan of a held-out synthetic head (PLY)",
        description="Render one held-out synthetic head (neutral or expressive) with a "
        "Kinect-like depth camera: random yaw within +-45 deg, noise, holes, "
        "outliers. Writes the cloud (mm, +Y up, with normals) and the true "
        "head as OUT_truth.ply.",
    )
    scan.add_argument("--out", required=True, help="output .ply file")
    scan.add_argument("--head", type=int, default=0, help="held-out head index, 0..99 (default: 0)")
    scan.add_argument("--expressive", action="store_true", help="add a synthetic expression")
    scan.add_argument("--hires", action="store_true", help="640x576 camera (~15-20k points) instead of 320x288")
    scan.add_argument("--seed", type=int, default=0, help="seed of the scan (placement, noise, holes)")
    scan.add_argument("--population-seed", type=int, default=0, help="seed of the synthetic population")
    scan.add_argument("--force", action="store_true", help="overwrite the outputs")
    scan.set_defaults(func=cmd_data_scan)
