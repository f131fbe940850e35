"""``jnr accessory FIT_DIR ACCESSORY.obj --out DIR``: an accessory (glasses, a hat, hair) on a fitted head,
skinned by transfer from the head's surface (:mod:`pipeline.accessory`)."""

from __future__ import annotations

import argparse
import math

from pipeline.cli.common import EXIT_OK, CliError, check_output, command_line
from pipeline.head.folders import ACCESSORY_FOLDER
from rig.accessory_defaults import DEFAULT_FALLOFF_MM, DEFAULT_SMOOTHING_MM


def _mm(text: str) -> float:
    """A length in mm for argparse (``inf`` allowed; checked further by the library)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of mm: {text!r}") from None
    if math.isnan(value):
        raise argparse.ArgumentTypeError(f"not a number of mm: {text!r}")
    return value


def cmd_accessory(args: argparse.Namespace) -> int:
    """``jnr accessory FIT_DIR ACCESSORY --out DIR``."""
    from pipeline.accessory import accessory_path, run_accessory

    check_output(args.out, args.force, inputs=[args.fit_dir, accessory_path(args.accessory)], kind="folder")
    if not 1 <= args.spp <= 1024:
        raise CliError(f"--spp must be within [1, 1024], got {args.spp}")
    result = run_accessory(
        args.fit_dir,
        args.accessory,
        args.out,
        force=args.force,
        falloff_mm=args.falloff,
        smoothing_mm=args.smoothing,
        spp=args.spp,
        command=command_line("jnr accessory"),
    )
    sd = result.signed_distance
    print(
        f"{result.accessory.name}: {len(result.accessory.vertices)} vertices skinned from the fit "
        f"(falloff {result.skinning.falloff_mm:g} mm, smoothing {result.skinning.smoothing_mm:g} mm); on the fitted "
        f"head its nearest vertex is {sd.min():.2f} mm {'outside' if sd.min() >= 0 else 'inside'} the skin"
    )
    print(f"wrote {args.out}/: {ACCESSORY_FOLDER.listing(args.out)}")
    return EXIT_OK


ACCESSORY_EPILOG = (
    "The accessory: a Wavefront .obj placed on the jnr template in its bind pose, in millimetres, rig space "
    "(+Y up, +Z out of the face, +X the subject's left; `jnr rig export --format obj --out template.obj` "
    "writes the template to model it on), or `glasses` / `cap` for the shipped examples.\n"
    "Each accessory vertex takes the skinning weights of the closest point on the head's outer skin (the "
    "fit's own weights) and, within --falloff mm of the skin, its expression offsets; both are smoothed "
    "over the accessory (--smoothing) so that rigid parts do not shear. It then follows the head's joints "
    "and the 52 ARKit expressions, in jnr and in the glTF.\n"
    f"Outputs in --out: {ACCESSORY_FOLDER.help_text()}.\n"
    "Try it: jnr fit PHOTO --out fit && jnr accessory fit glasses --out fit_glasses"
)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr accessory``."""
    ac = sub.add_parser(
        "accessory",
        help="put an accessory (glasses, a hat, hair) on a fitted head, skinned to its joints",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Skin an accessory mesh by transfer from the closest point of a fitted head (JNR section 5.3), "
        "pose it on the fit, and write it with the head as one skinned glTF.",
        epilog=ACCESSORY_EPILOG,
    )
    ac.add_argument("fit_dir", metavar="FIT_DIR", help="output folder of jnr fit or jnr fit-scan (its params.json)")
    ac.add_argument("accessory", metavar="ACCESSORY", help="accessory .obj on the template, or glasses / cap")
    ac.add_argument("--out", required=True, help="output folder (must not exist unless --force)")
    ac.add_argument(
        "--falloff",
        type=_mm,
        default=DEFAULT_FALLOFF_MM,
        metavar="MM",
        help=f"contact falloff: expression offsets are followed fully up to half of it from the skin, "
        f"not at all beyond it (default {DEFAULT_FALLOFF_MM:g} mm)",
    )
    ac.add_argument(
        "--smoothing",
        type=_mm,
        default=DEFAULT_SMOOTHING_MM,
        metavar="MM",
        help=f"sigma of the Gaussian smoothing of weights and offsets over the accessory; 0: none, inf: "
        f"one blend for the whole accessory (default {DEFAULT_SMOOTHING_MM:g} mm)",
    )
    ac.add_argument("--spp", type=int, default=16, help="samples per pixel of preview.png (default 16)")
    ac.add_argument("--force", action="store_true", help="replace the output folder if it exists")
    ac.set_defaults(func=cmd_accessory)
