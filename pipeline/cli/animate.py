"""``jnr animate FIT_DIR CURVES.csv --out OUT.glb`` and ``jnr retarget SOURCE_FIT TARGET_FIT --out DIR``
(:mod:`pipeline.animation`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.cli.common import EXIT_OK, CliError, StageBars, check_output
from pipeline.head.folders import RETARGET_FOLDER


def _curves_path(text: str) -> Path:
    from pipeline.animation import EXAMPLE_CURVES

    return EXAMPLE_CURVES if text == "example" else Path(text)


def _track_fps(fit_dir: str, curves_path: Path) -> float | None:
    """The frame rate of a ``jnr track`` folder's own curves (its ``livelink.csv`` has timecodes at the clip's
    rate, which the file does not state): ``params.json``'s ``track.fps`` when ``curves_path`` is in
    ``fit_dir``; None otherwise (the layout's default rate)."""
    import json

    from rig.errors import InputError
    from rig.io.inputs import regular_file

    try:
        if Path(curves_path).resolve().parent != Path(fit_dir).resolve():
            return None
        data = json.loads(regular_file(Path(fit_dir) / "params.json", "parameter file", 1 << 26).read_text())
        fps = data.get("track", {}).get("fps") if data.get("fit") == "track" else None
        return float(fps) if isinstance(fps, int | float) and 0.1 <= fps <= 1000 else None
    except (OSError, ValueError, AttributeError, InputError, RecursionError):
        return None


def cmd_animate(args: argparse.Namespace) -> int:
    from pipeline.animation import animate_fit, read_curves

    out = Path(args.out)
    if out.suffix.lower() not in (".glb", ".gltf"):
        raise CliError(f"--out {out}: the animation is glTF; use a .glb or .gltf name")
    if args.fps is not None and not 0 < args.fps <= 1000:  # 0 is a value given, not "not given"; NaN too
        raise CliError(f"--fps must be a frame rate in (0, 1000], got {args.fps:g}")
    if not 0 < args.preview_fps <= 60:  # NaN and inf too
        raise CliError(f"--preview-fps must be a number of frames per second in (0, 60], got {args.preview_fps}")
    preview = None if args.no_preview else Path(args.preview) if args.preview else out.with_suffix(".gif")
    if preview is not None and preview.suffix.lower() != ".gif":
        raise CliError(f"--preview {preview}: the preview is a GIF; use a .gif name")
    curves_path = _curves_path(args.curves)
    inputs = [args.fit_dir, curves_path]
    check_output(out, args.force, inputs=inputs)
    if preview is not None:
        check_output(preview, args.force, inputs=inputs)
    fps = args.fps if args.fps is not None else _track_fps(args.fit_dir, curves_path)
    curves = read_curves(curves_path, fps=fps, head_units=args.head_units)
    bars = StageBars(args.quiet)
    try:
        summary = animate_fit(
            args.fit_dir,
            curves,
            out,
            preview=preview,
            preview_fps=args.preview_fps,
            force=args.force,
            inputs=inputs,
            progress=bars,
        )
    finally:
        bars.close()
    turn = ", head rotation" if summary["head_rotation"] else ""
    print(
        f"animated {summary['keyframes']} keyframes over {summary['duration_s']:.2f} s "
        f"({summary['layout']} curves{turn}); wrote {out}"
        + (f" and {preview} ({summary['preview_frames']} frames)" if preview is not None else "")
    )
    return EXIT_OK


def cmd_retarget(args: argparse.Namespace) -> int:
    from pipeline.animation import retarget_fit

    out = Path(args.out)
    check_output(out, args.force, inputs=[args.source, args.target], kind="folder")
    report = retarget_fit(args.source, args.target, out, force=args.force)
    print(
        f"the expression of {args.source} on the identity of {args.target} (largest vertex change "
        f"{report['max_vertex_change_mm']:.1f} mm); wrote {out}/: {RETARGET_FOLDER.listing(out)}"
    )
    return EXIT_OK


ANIMATE_EPILOG = (
    "Curves: a Live Link Face CSV (Timecode, BlendShapeCount, the 52 ARKit names, HeadYaw/HeadPitch/HeadRoll in "
    "radians, eye angles ignored; timecodes HH:MM:SS:FF at --fps, else at the rate their frame numbers show) or a "
    "plain CSV (a header of ARKit names, any subset, optional time column in seconds, else rows at --fps, "
    "default 30; optional head_yaw, "
    "head_pitch, head_roll in degrees). 'example' is the shipped blink and smile (pipeline/assets/animation/"
    "blink_smile.csv).\nHead angles turn the head about the skull_root joint: +yaw towards the subject's left, +pitch "
    "nods down, +roll tilts the top towards the subject's left.\nOutputs: OUT.glb (the fit's skinned head with 52 "
    "ARKit morph targets and one animation: morph weights at every row, the skull_root rotation when the curves "
    "turn the head; glTF metres) and OUT.gif (grey preview rendered by jnr's renderer at --preview-fps).\n"
    "Try it: jnr demo --out out/demo && jnr animate out/demo/astronaut example --out out/smile.glb"
)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr animate`` and ``jnr retarget``."""
    an = sub.add_parser(
        "animate",
        help="drive a fitted head with ARKit curves (Live Link Face CSV): animated glTF + GIF preview",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Animate a fit (a jnr fit or jnr fit-scan output folder) with ARKit expression curves: every row "
        "of the curves becomes a keyframe of the 52 morph-target weights (and of the head's rotation), "
        "written as a glTF animation that plays in Blender, Unity and three.js.",
        epilog=ANIMATE_EPILOG,
    )
    an.add_argument("fit_dir", help="a jnr fit / jnr fit-scan output folder (its params.json)")
    an.add_argument("curves", help="curves CSV (Live Link Face or plain), or 'example'")
    an.add_argument("--out", required=True, help="animated glTF to write (.glb or .gltf)")
    an.add_argument("--preview", help="preview GIF to write (default: --out with .gif)")
    an.add_argument("--no-preview", action="store_true", help="write no preview")
    an.add_argument("--preview-fps", type=float, default=12.0, help="frames per second of the preview (default 12)")
    an.add_argument(
        "--fps",
        type=float,
        help="frame rate of the curves' timecodes or rows (default: a Live Link Face file's rate read from its "
        "timecodes' frame numbers, 60 with a warning when it stays within one second; 30 for a plain CSV without "
        "a time column; a jnr track folder's own livelink.csv: its clip's)",
    )
    an.add_argument(
        "--head-units",
        choices=["rad", "deg"],
        help="unit of the head angles (default: rad for Live Link Face, deg for a plain CSV)",
    )
    an.add_argument("--force", action="store_true", help="replace existing outputs")
    an.add_argument("--quiet", action="store_true", help="no progress bars")
    an.set_defaults(func=cmd_animate)

    rt = sub.add_parser(
        "retarget",
        help="put one fit's expression on another fit's identity (JNR Fig. 7)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Retarget an expression: the source fit's 52 ARKit coefficients (the jaw's jawOpen, jawForward, "
        "jawLeft, jawRight among them) replace the target fit's; the target keeps its identity (joints, "
        "latent Z), camera, pose, light and texture.",
        epilog=f"Outputs in --out: {RETARGET_FOLDER.help_text()}.",
    )
    rt.add_argument("source", help="the fit whose expression is taken")
    rt.add_argument("target", help="the fit whose identity is kept")
    rt.add_argument("--out", required=True, help="output folder (must not exist unless --force)")
    rt.add_argument("--force", action="store_true", help="replace the output folder if it exists")
    rt.set_defaults(func=cmd_retarget)
