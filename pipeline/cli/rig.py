"""``jnr rig info | build | export | edit``: the face rig."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from pipeline.cli.common import EXIT_FAILURE, EXIT_OK, CliError, check_output, log
from pipeline.formats import MESH_FORMATS, MESH_SUFFIXES


def format_for(path: Path, explicit: str | None) -> str:
    """The mesh format of an output: from ``--format`` (which must agree with the suffix) or the suffix."""
    suffix = path.suffix.lower()
    if explicit:
        if suffix not in MESH_SUFFIXES[explicit]:
            raise CliError(
                f"--format {explicit} writes {' or '.join(MESH_SUFFIXES[explicit])} files, but --out is "
                f"{path}; change the suffix or the format"
            )
        return explicit
    for name, suffixes in MESH_SUFFIXES.items():
        if suffix in suffixes:
            return name
    raise CliError(f"cannot tell the mesh format of {path}: use .obj, .ply, .glb or .gltf, or pass --format")


def cmd_rig_info(args: argparse.Namespace) -> int:
    from rig.info import rig_info

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
        check_output(out, args.force or (args.out is None))
    log.info("generating the template head, joints and weights")
    asset = build_asset()
    if args.check:
        committed = read_asset(args.out or DEFAULT_ASSET)
        diff = float(np.abs(committed.vertices - asset.vertices).max())
        differing = [
            name
            for name in type(asset).__dataclass_fields__
            if not np.array_equal(np.asarray(getattr(committed, name)), np.asarray(getattr(asset, name)))
        ]
        same = not differing
        print(
            f"rebuilt in {time.perf_counter() - t0:.1f} s; largest vertex difference {diff:.3g} mm; "
            + ("identical, bit for bit" if same else f"DIFFERENT: {', '.join(differing)}")
        )
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
    atomically (:func:`pipeline.edit.write_edited_head`)."""
    from pipeline.edit import write_edited_head

    out = Path(args.out)
    fitted = write_edited_head(args.params, out, format_for(out, args.format), clamp=args.clamp, force=args.force)
    print(f"wrote {out}" + (" (the fitted head: joints, latent Z and expressions, rig space, mm)" if fitted else ""))
    return EXIT_OK


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr rig ...``."""
    rig = sub.add_parser("rig", help="the face rig: info, build, export, edit")
    rig_sub = rig.add_subparsers(dest="rig_command", metavar="RIG_COMMAND")
    rig_sub.required = True

    info = rig_sub.add_parser("info", help="print the rig's sizes")
    info.add_argument("--json", action="store_true", help="print JSON")
    info.set_defaults(func=cmd_rig_info)

    build = rig_sub.add_parser(
        "build",
        help="regenerate the template asset from code",
        description="Regenerate the template head, joints and initial skinning weights. "
        "Without --out, rewrites the packaged asset.",
    )
    build.add_argument("--out", help="where to write the .npz (default: the packaged asset)")
    build.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    build.add_argument(
        "--check",
        action="store_true",
        help="do not write; compare the rebuilt asset with --out (default: the packaged one) "
        "and exit 1 if they differ by more than 1e-6 mm",
    )
    build.set_defaults(func=cmd_rig_build)

    export = rig_sub.add_parser(
        "export",
        help="write the rig as OBJ, PLY or skinned glTF 2.0",
        description="OBJ and PLY hold the (posed) mesh; glTF (.glb) holds the rest mesh "
        "with 52 posable joints, inverse bind matrices and skin weights, "
        "posed by --params.",
    )
    export.add_argument("--format", choices=sorted(MESH_FORMATS), required=True)
    export.add_argument("--out", help="output file (default: jnr_rig.<ext> here)")
    export.add_argument("--params", help="parameter JSON to pose the rig with (default: rest pose)")
    export.add_argument("--clamp", action="store_true", help="clamp out-of-limit parameters (with a warning)")
    export.add_argument("--force", action="store_true", help="overwrite the output")
    export.set_defaults(func=cmd_rig_export)

    edit = rig_sub.add_parser(
        "edit",
        help="write the head edited by a parameter file",
        description="Pose the rig with named parameters and write the edited head.",
    )
    edit.add_argument("params", help='parameter JSON, e.g. {"joints": {"nose_tip.translate_z": 5}}')
    edit.add_argument("--out", required=True, help="output mesh: .obj, .ply, .glb or .gltf")
    edit.add_argument("--format", choices=sorted(MESH_FORMATS), help="override the format chosen by suffix")
    edit.add_argument("--clamp", action="store_true", help="clamp out-of-limit parameters (with a warning)")
    edit.add_argument("--force", action="store_true", help="overwrite the output")
    edit.set_defaults(func=cmd_rig_edit)
