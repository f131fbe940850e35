"""The output folder of ``jnr track`` (:data:`pipeline.head.folders.TRACK_FOLDER`), written atomically:

- ``livelink.csv``: the curves in Live Link Face's CSV (Timecode at the clip's frame rate, BlendShapeCount,
  the 52 capitalised names, head yaw/pitch/roll in radians): ``jnr animate`` and Live Link importers read it;
- ``curves.csv``: the same, plain (``time`` in seconds, ARKit names, head angles in degrees);
- ``track.glb``: the fitted head, skinned, animated by the curves (morph weights and the head's rotation
  per frame; the head stays in place: translation is in ``params.npz``);
- ``params.json``: the clip's identity as a fit's parameter file (fit ``track``; ``jnr animate``,
  ``jnr rig edit`` and ``jnr accessory`` take the folder as a fit's);
- ``params.npz``: every frame's ``rotations (T, 3, 3)``, ``translations (T, 3)`` mm, ``coefficients (T, 52)``,
  ``observed (T,)``, ``landmarks (T, 478, 2)`` px (NaN where no face), ``rms_px (T,)``, and ``fps``,
  ``focal``, ``width``, ``height``, ``keyframes``;
- ``preview.mp4``: the clip with the fitted face's landmarks drawn over it, beside the fitted grey head seen
  from the camera (frames without a face marked);
- ``report.json``: frames, lost frames, keyframes, errors, seconds and frames per second per phase, the settings;
- ``config.yaml``: the settings, every field resolved (``jnr track --config`` repeats the run).

A clip with shot cuts (:func:`write_shot_outputs`): one such folder per tracked shot, ``shot_<k>/``, and the
clip's ``report.json`` (the shots, the cuts) and ``config.yaml`` beside them.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from pipeline.animation.keyframes import curve_keyframes
from pipeline.config import CONFIG_FILE, config_to_dict, dump_config
from pipeline.files import staged_folder
from pipeline.head.curves import Curves, write_curves
from pipeline.head.params import params_payload
from pipeline.head.skinned import write_skinned_head, write_static_head
from pipeline.track.tracker import ShotTracks, TrackResult
from pipeline.track.video import Clip
from rig.geometry import head_angles

_log = logging.getLogger(__name__)


def track_curves(result: TrackResult) -> Curves:
    """The track as ARKit curves: frame times at the clip's rate, the coefficients, the head angles (yaw,
    pitch, roll of each frame's head pose, :func:`rig.geometry.head_angles`, degrees)."""
    times = np.arange(result.frames) / result.fps
    angles = np.array([head_angles(r) for r in result.rotations], np.float64)
    return Curves(times, np.clip(result.coefficients, 0.0, 1.0), angles, "live-link-face")


def report_payload(result: TrackResult, clip: Clip, seconds: dict, command: str | None = None) -> dict:
    """``report.json``."""
    observed = result.rms_px[result.observed]
    fit_frames = result.frames
    return {
        "format": "jnr-track-report/1",
        "command": command,
        "input": {
            "path": str(Path(clip.path).absolute()),
            "kind": "frames folder" if clip.is_folder else "video",
            "fps": clip.fps,
            "width": clip.size[0],
            "height": clip.size[1],
        },
        "frames": fit_frames,
        "first_frame": int(result.first_frame),
        "lost_frames": list(result.lost),
        "keyframes": list(result.keyframes),
        "focal_px": result.focal,
        "landmark_rms_px": {
            "median": float(np.median(observed)) if len(observed) else None,
            "p95": float(np.percentile(observed, 95)) if len(observed) else None,
        },
        "identity_fit": {
            "mean_error_px": float(result.identity_fit.mean_error_px),
            "views": len(result.identity_fit.views),
        },
        "seconds": {k: float(v) for k, v in seconds.items()},
        "frames_per_second": {
            "follow": fit_frames / max(seconds.get("follow", 0.0), 1e-9),
            "fit": fit_frames / max(seconds.get("fit", 0.0), 1e-9),
            "follow_and_fit": fit_frames / max(seconds.get("follow", 0.0) + seconds.get("fit", 0.0), 1e-9),
            "all": fit_frames / max(sum(seconds.values()), 1e-9),
        },
    }


def write_track_outputs(
    out: str | Path,
    clip: Clip,
    result: TrackResult,
    *,
    force: bool = False,
    inputs=(),
    command: str | None = None,
    preview: bool = True,
    progress=None,
    config=None,
    extra: dict | None = None,
) -> dict:
    """Write the output folder (module docstring) atomically; returns ``report.json``'s content (with
    ``extra``'s entries).

    Raises:
        pipeline.files.OutputError: ``out`` is refused or cannot be written.
    """
    out = Path(out)
    seconds = dict(result.seconds)
    seconds = {k: v for k, v in seconds.items() if not k.endswith("_ms_per_frame")}
    t0 = time.perf_counter()
    curves = track_curves(result)
    head = result.head
    with staged_folder(out, force, inputs=inputs, marker={"command": command}) as tmp:
        write_curves(tmp / "livelink.csv", curves, layout="live-link-face", fps=result.fps)
        write_curves(tmp / "curves.csv", curves, layout="plain")
        if head.model.posable:
            write_skinned_head(
                tmp / "track.glb",
                head.asset,
                head.weights,
                head.tau,
                curves.coefficients[0],
                animation=curve_keyframes(head, curves),
            )
        else:
            animation = curve_keyframes(head, curves)
            write_static_head(tmp / "track.glb", head.asset, head.vertices, animation=animation)
        payload = params_payload(
            head.model,
            head.params,
            fit="track",
            track={
                "description": "the clip's identity (fitted on its keyframes); each frame's pose and "
                "expressions are in params.npz and the curves files",
                "frames": result.frames,
                "fps": result.fps,
                "keyframes": list(result.keyframes),
            },
        )
        (tmp / "params.json").write_text(json.dumps(payload, indent=2) + "\n")
        np.savez_compressed(
            tmp / "params.npz",
            rotations=result.rotations,
            translations=result.translations,
            coefficients=result.coefficients,
            observed=result.observed,
            landmarks=result.landmarks.astype(np.float32),
            rms_px=result.rms_px,
            fps=np.float64(result.fps),
            focal=np.float64(result.focal),
            width=np.int64(clip.size[0]),
            height=np.int64(clip.size[1]),
            keyframes=np.asarray(result.keyframes, np.int64),
        )
        seconds["files"] = time.perf_counter() - t0
        if preview:
            from pipeline.track.preview import write_preview

            t1 = time.perf_counter()
            write_preview(tmp / "preview.mp4", clip, result, progress=progress)
            seconds["preview"] = time.perf_counter() - t1
        report = report_payload(result, clip, seconds, command)
        report.update(extra or {})
        report["config"] = None if config is None else config_to_dict(config)
        (tmp / "report.json").write_text(json.dumps(report, indent=2) + "\n")
        if config is not None:
            dump_config(config, tmp / CONFIG_FILE, command=command)
    return report


def shots_payload(tracked: ShotTracks, fps: float, folders: list[str] | None) -> list[dict]:
    """``report.json``'s ``shots``: each shot's frames (clip frames ``start`` to ``end``, excluded), times,
    whether it was tracked, its folder (``shot_<k>``; None in a one-shot run) or why not."""
    tracked_starts = [t.first_frame for t in tracked.tracks]
    rows = []
    for shot in tracked.shots:
        k = tracked_starts.index(shot.start) if shot.start in tracked_starts else None
        reason = next((r for s, r in tracked.skipped if s == shot), None)
        rows.append(
            {
                "start_frame": shot.start,
                "end_frame": shot.end,
                "start_s": shot.start / fps,
                "end_s": shot.end / fps,
                "tracked": k is not None,
                "folder": None if k is None or folders is None else folders[k],
                "skipped_because": reason,
            }
        )
    return rows


def write_shot_outputs(
    out: str | Path,
    clip: Clip,
    tracked: ShotTracks,
    *,
    force: bool = False,
    inputs=(),
    command: str | None = None,
    preview: bool = True,
    progress=None,
    config=None,
) -> dict:
    """The output of :func:`pipeline.track.tracker.track_shots`: a clip of one shot as
    :func:`write_track_outputs` (its ``report.json`` with ``shots`` and ``cuts``); a clip of several, one such
    folder per tracked shot, ``shot_<k>/``, and ``report.json`` (``format: jnr-track-shots/1``: the shots, the
    cuts, why a shot was skipped) and ``config.yaml`` beside them, all atomically. Returns the top
    ``report.json``'s content.

    Raises:
        pipeline.files.OutputError: ``out`` is refused or cannot be written.
    """
    cuts = [s.start for s in tracked.shots[1:]]
    if len(tracked.shots) == 1:
        report = write_track_outputs(
            out, clip, tracked.tracks[0], force=force, inputs=inputs, command=command, preview=preview,
            progress=progress, config=config, extra={"shots": shots_payload(tracked, clip.fps, None), "cuts": cuts},
        )  # fmt: skip
        return report
    folders = [f"shot_{k}" for k in range(len(tracked.tracks))]
    with staged_folder(Path(out), force, inputs=inputs, marker={"command": command}) as tmp:
        reports = [
            write_track_outputs(
                tmp / folder,
                clip,
                track,
                inputs=inputs,
                command=command,
                preview=preview,
                progress=progress,
                config=config,
            )  # fmt: skip
            for folder, track in zip(folders, tracked.tracks, strict=True)
        ]
        report = {
            "format": "jnr-track-shots/1",
            "command": command,
            "input": reports[0]["input"],
            "frames": tracked.frames,
            "cuts": cuts,
            "shots": shots_payload(tracked, clip.fps, folders),
            "config": None if config is None else config_to_dict(config),
        }
        (tmp / "report.json").write_text(json.dumps(report, indent=2) + "\n")
        if config is not None:
            dump_config(config, tmp / CONFIG_FILE, command=command)
    return report


__all__ = ["report_payload", "shots_payload", "track_curves", "write_shot_outputs", "write_track_outputs"]
