"""``jnr track VIDEO|FRAMES_FOLDER --out DIR`` (:mod:`pipeline.track`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.cli.common import EXIT_OK, CliError, StageBars, check_output
from pipeline.head.folders import TRACK_FOLDER


def load_track_config(args: argparse.Namespace):
    """:class:`pipeline.track.tracker.TrackConfig` from ``--config``, ``--set`` and the options that stand for
    settings (``--face``, ``--keyframes``, ``--focal``, ``--max-frames``)."""
    from pipeline.cli.common import parse_overrides
    from pipeline.config import ConfigError, load_config
    from pipeline.track.tracker import TrackConfig

    overrides = parse_overrides(args.set)
    for option in ("face", "keyframes", "focal", "max_frames"):
        value = getattr(args, option)
        if value is not None:
            overrides[option] = value
    try:
        return load_config(TrackConfig, args.config, overrides)
    except ConfigError as exc:
        raise CliError(str(exc)) from None
    except FileNotFoundError as exc:
        raise CliError(str(exc)) from None


def cmd_track(args: argparse.Namespace) -> int:
    import time

    from pipeline.track.outputs import write_shot_outputs
    from pipeline.track.tracker import track_shots
    from pipeline.track.video import open_clip

    t0 = time.perf_counter()
    out = Path(args.out)
    check_output(out, args.force, inputs=[args.clip], kind="folder")
    config = load_track_config(args)
    clip = open_clip(args.clip, fps=args.fps)
    bars = StageBars(args.quiet)
    try:
        tracked = track_shots(clip, config, progress=bars)
        report = write_shot_outputs(
            out,
            clip,
            tracked,
            force=args.force,
            inputs=[args.clip],
            command="jnr track",
            preview=not args.no_preview,
            progress=bars,
            config=config,
        )
    finally:
        bars.close()
    seconds = time.perf_counter() - t0
    size = f"{clip.size[0]}x{clip.size[1]}, {clip.fps:g} fps"
    if len(tracked.shots) == 1:
        track = tracked.tracks[0]
        fps = report["frames_per_second"]
        print(
            f"tracked {track.frames} frames of {args.clip} ({size}) in {seconds:.1f} s, {tracked.frames / seconds:.1f} "
            f"frames/s for the whole command: {len(track.lost)} without a face (bridged); landmark error median "
            f"{report['landmark_rms_px']['median']:.2f} px; follow and fit {fps['follow_and_fit']:.1f} frames/s "
            f"(identity {report['seconds']['identity']:.1f} s)"
        )
        print(f"wrote {out}/: {TRACK_FOLDER.listing(out)}")
        return EXIT_OK
    print(
        f"tracked {args.clip} ({size}, {tracked.frames} frames) in {seconds:.1f} s, {tracked.frames / seconds:.1f} "
        f"frames/s for the whole command: {len(tracked.shots)} shots (cuts at frames "
        f"{', '.join(str(c) for c in report['cuts'])}), each with its own identity; never bridged across a cut"
    )
    for row in report["shots"]:
        span = f"frames {row['start_frame']}-{row['end_frame'] - 1}"
        if row["tracked"]:
            print(f"  {row['folder']}/: {span}")
        else:
            print(f"  {span}: not tracked ({row['skipped_because']})")
    folders = ", ".join(f"{r['folder']}/" for r in report["shots"] if r["tracked"])
    each = TRACK_FOLDER.listing(out / "shot_0")
    print(f"wrote {out}/: {folders}, report.json, config.yaml (each shot folder: {each})")
    return EXIT_OK


TRACK_EPILOG = (
    "Input: a video OpenCV's FFmpeg decodes (mp4, mov, avi, webm, mkv) or a folder of numbered images "
    "(frame_0001.png ...; natural order; --fps, default 30).\n"
    "The face: the largest of the first frame with a face (--face N: the N-th by size), followed frame to frame by "
    "MediaPipe's mesh and iris models; detected again where it is lost. The identity is fitted jointly on "
    "--keyframes frames spread over the clip (as jnr fit --views); then each frame's head pose and 52 ARKit "
    "coefficients, warm started from the frame before, with a temporal prior. Frames without a face are bridged "
    "(interpolated) and listed in report.json.\n"
    "Shot cuts (the whole picture changes from one frame to the next) split the clip: the face is found anew "
    "after a cut, each shot gets its own identity, and no gap is bridged across a cut.\n"
    f"Outputs in --out: {TRACK_FOLDER.help_text()}. A clip with cuts: one such folder per shot, shot_<k>/, and "
    "report.json (the shots, their frames, the cuts) and config.yaml beside them.\n"
    "Try it: jnr track frames/ --out out/track && jnr animate out/track out/track/livelink.csv --out out/t.glb"
)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr track``."""
    tr = sub.add_parser(
        "track",
        help="follow a face through a video: ARKit curves (Live Link Face CSV), an animated head, a preview",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Track a face through a video on the CPU: one identity for the clip, each frame's head pose and "
        "ARKit expression coefficients, written as Live Link Face and plain CSV curves, an animated skinned glTF, "
        "every frame's parameters and a side-by-side preview video.",
        epilog=TRACK_EPILOG,
    )
    tr.add_argument("clip", help="a video file or a folder of numbered frames")
    tr.add_argument("--out", required=True, help="output folder (must not exist unless --force)")
    tr.add_argument("--face", type=int, help="which face of the first frame: 0 the largest (default)")
    tr.add_argument("--keyframes", type=int, help="frames the identity is fitted on (2-30, default 5)")
    tr.add_argument("--focal", type=float, help="the camera's focal length in pixels (default 1.4 x the longer side)")
    tr.add_argument("--fps", type=float, help="frame rate (default: the video's own; 30 for a frames folder)")
    tr.add_argument("--max-frames", type=int, help="read at most this many frames (default and most: 108000)")
    tr.add_argument("--no-preview", action="store_true", help="write no preview.mp4 (faster)")
    tr.add_argument("--config", help="YAML overriding the tracking settings (e.g. configs/track.yaml)")
    tr.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one setting (repeatable)")
    tr.add_argument("--force", action="store_true", help="replace the output folder if jnr wrote it")
    tr.set_defaults(func=cmd_track)
