"""Track a face through a clip: follow it (:mod:`pipeline.track.follow`), fit one identity jointly on a few
keyframes (:func:`pipeline.photo.multiview.fit_multiview`, as ``jnr fit --views`` does), then each frame's
head pose and 52 ARKit coefficients on that identity, warm started from the frame before, with a temporal
prior (:func:`pipeline.track.solver.solve_frame`), and the whole track smoothed at the end
(:func:`pipeline.track.smooth.smooth_track`: no lag, it sees the frames after too). Frames without a face
are bridged (coefficients and translation interpolated, rotations slerped between the frames around them;
held at the clip's ends) and listed.

Example:
    >>> result = track_clip(open_clip("clip.mp4"))  # doctest: +SKIP
    >>> result.coefficients.shape, result.lost  # doctest: +SKIP
    ((300, 52), (41, 42))
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from landmarks.mediapipe.layout import mediapipe_layout
from pipeline.camera import default_focal
from pipeline.head.fitted import FittedHead, fitted_head_from_params
from pipeline.photo.multiview import MultiViewFit, fit_multiview
from pipeline.photo.multiview_config import INDEPENDENT_VIEWS, MultiViewConfig
from pipeline.track.follow import FaceFollower
from pipeline.track.shots import CutDetector, Shot, split_shots
from pipeline.track.smooth import SmoothSettings, smooth_track
from pipeline.track.solver import FrameModel, FrameState, TrackSettings, solve_frame
from pipeline.track.video import MAX_FRAMES, Clip
from rig.errors import InputError
from rig.head_model import head_model_kinds
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS

_log = logging.getLogger(__name__)

Progress = Callable[[str, int, int], None]
"""``progress(phase, done, total)``: ``follow`` per frame read, ``identity`` per keyframe's fit and at the joint
refinement's end, ``fit`` per frame."""


class NoTrackError(InputError):
    """A clip in which no face could be followed (or too few frames to fit an identity)."""


@dataclass(frozen=True)
class TrackConfig:
    """Settings of :func:`track_clip` (``configs/track.yaml``).

    Attributes:
        keyframes: frames the identity is fitted on (fewer if the clip has fewer frames with a face).
        keyframe_choice: ``poses`` (the most different head poses, :func:`choose_keyframes`) or ``time``
            (evenly spread over the frames with a face).
        face: which face of the first frame with faces (0 the largest).
        focal: the camera's focal length in pixels (default: :func:`pipeline.camera.default_focal`).
        cold_iterations: Gauss-Newton steps on a frame that starts from a keyframe rather than the last frame.
        max_frames: the most frames read.
        frame: the per-frame solve (:class:`~pipeline.track.solver.TrackSettings`).
        smooth: the whole track's smoothing (:class:`~pipeline.track.smooth.SmoothSettings`).
        model: the head model of the identity (a registered kind, as ``jnr fit``'s ``model``): ``jnr``'s joints,
            or another model's identity from the keyframes (``jnr fit --views``' ``skinning``) with the rig's
            52 ARKit shapes on it, each frame posed as a whole.
    """

    keyframes: int = 5
    keyframe_choice: str = "poses"
    face: int = 0
    focal: float | None = None
    cold_iterations: int = 15
    max_frames: int = MAX_FRAMES
    frame: TrackSettings = field(default_factory=TrackSettings)
    smooth: SmoothSettings = field(default_factory=SmoothSettings)
    model: str = "jnr"

    def __post_init__(self) -> None:
        if self.model not in head_model_kinds():
            raise InputError(f"model must be one of {list(head_model_kinds())}, got {self.model!r}")
        if not (isinstance(self.keyframes, int) and 2 <= self.keyframes <= 30):
            raise InputError(f"keyframes must be an integer within [2, 30], got {self.keyframes!r}")
        if self.keyframe_choice not in ("poses", "time"):
            raise InputError(f"keyframe_choice must be 'poses' or 'time', got {self.keyframe_choice!r}")
        if not (isinstance(self.face, int) and self.face >= 0):
            raise InputError(f"face must be an integer >= 0, got {self.face!r}")
        if self.focal is not None and (
            isinstance(self.focal, bool) or not isinstance(self.focal, int | float) or not 0 < self.focal < float("inf")
        ):
            raise InputError(f"focal must be a focal length in pixels > 0, got {self.focal!r}")
        if not (isinstance(self.cold_iterations, int) and 1 <= self.cold_iterations <= 100):
            raise InputError(f"cold_iterations must be an integer within [1, 100], got {self.cold_iterations!r}")
        if not (isinstance(self.max_frames, int) and 1 <= self.max_frames <= MAX_FRAMES):
            raise InputError(f"max_frames must be an integer within [1, {MAX_FRAMES}], got {self.max_frames!r}")


@dataclass
class TrackResult:
    """A tracked clip.

    Attributes:
        fps: frames per second; size: ``(width, height)``; focal: pixels (principal point: the image centre).
        head: the identity (:class:`pipeline.head.fitted.FittedHead` without expression).
        identity_fit: the keyframes' :class:`~pipeline.photo.multiview.MultiViewFit`; keyframes: their indices.
        rotations: ``(T, 3, 3)``, translations ``(T, 3)`` mm: each frame's head pose
            (``x_cam = RIG_TO_OPENCV @ R @ x_rig + t``); coefficients ``(T, 52)`` ARKit.
        observed: ``(T,)`` bool, the frames with a face; landmarks: ``(T, 478, 2)`` pixels (NaN without).
        rms_px: ``(T,)`` the weighted RMS landmark error of each observed frame (NaN for bridged ones).
        seconds: per phase (``follow``, ``identity``, ``fit``), and ``per_frame_ms`` of each.
        first_frame: the clip's frame that is frame 0 here (a shot's first frame; 0 for a whole clip).
    """

    fps: float
    size: tuple[int, int]
    focal: float
    head: FittedHead
    identity_fit: MultiViewFit
    keyframes: tuple[int, ...]
    rotations: np.ndarray
    translations: np.ndarray
    coefficients: np.ndarray
    observed: np.ndarray
    landmarks: np.ndarray
    rms_px: np.ndarray
    seconds: dict
    first_frame: int = 0
    """The clip's frame that is this track's frame 0 (a shot after a cut: its first frame)."""

    @property
    def frames(self) -> int:
        return len(self.coefficients)

    @property
    def lost(self) -> tuple[int, ...]:
        """The frames without a face (bridged)."""
        return tuple(int(i) for i in np.flatnonzero(~self.observed))


NOSE_TIP, EYE_CORNERS = 1, (33, 263)
"""MediaPipe's nose tip and outer eye corners: the keyframes' pose descriptor."""


def pose_descriptor(landmarks: np.ndarray) -> np.ndarray:
    """``(T, 2)`` a rough turn and nod of each frame from its points ``(T, 478, 2)``: the nose tip's offset from
    the eyes' midpoint over their distance (NaN where no face)."""
    eyes = landmarks[:, list(EYE_CORNERS)].astype(np.float64)
    middle = eyes.mean(axis=1)
    distance = np.linalg.norm(eyes[:, 1] - eyes[:, 0], axis=1).clip(1e-6)
    return (landmarks[:, NOSE_TIP].astype(np.float64) - middle) / distance[:, None]


def choose_keyframes(observed: np.ndarray, count: int, landmarks: np.ndarray | None = None) -> list[int]:
    """``count`` frame indices among the observed ones: without ``landmarks`` evenly spread in time; with them
    the most different head poses (:func:`pose_descriptor`, farthest-point sampling from the most frontal
    frame), which tell the head's depth best."""
    frames = np.flatnonzero(observed)
    if len(frames) <= count:
        return [int(i) for i in frames]
    if landmarks is None:
        picks = np.round(np.linspace(0, len(frames) - 1, count)).astype(int)
        return [int(frames[i]) for i in picks]
    pose = pose_descriptor(landmarks[frames])
    chosen = [int(np.argmin(np.linalg.norm(pose - np.median(pose, axis=0), axis=1)))]
    distance = np.linalg.norm(pose - pose[chosen[0]], axis=1)
    while len(chosen) < count:
        k = int(np.argmax(distance))
        chosen.append(k)
        distance = np.minimum(distance, np.linalg.norm(pose - pose[k], axis=1))
    return sorted(int(frames[k]) for k in chosen)


def follow_clip(
    clip: Clip, face: int = 0, max_frames: int = MAX_FRAMES, progress: Progress | None = None, cuts: list | None = None
):
    """``(landmarks (T, 478, 2) float32 px, NaN without a face; presence (T,); milliseconds (T,))``. With a
    ``cuts`` list, the shot cuts found (:class:`pipeline.track.shots.CutDetector`) are appended to it and the
    face is found anew after each (the ``face``-th largest again), not followed from the shot before."""
    follower = FaceFollower(face=face)
    detector = CutDetector() if cuts is not None else None
    points, presence, ms = [], [], []
    total = min(clip.count, max_frames)
    for index, frame in clip.frames(max_frames):
        if detector is not None and detector.step(frame):
            cuts.append(index)
            follower.reset()
        seen = follower.step(frame)
        points.append(
            np.full((478, 2), np.nan, np.float32) if seen.points is None else seen.points[:, :2].astype(np.float32)
        )
        presence.append(seen.presence)
        ms.append(seen.milliseconds)
        if progress is not None:
            progress("follow", index + 1, max(total, index + 1))
    if not points:
        raise NoTrackError(f"{clip.path}: no frame could be read")
    if not follower.found_once and follower.most_faces > 0:  # faces were there, not as many as asked for
        n = follower.most_faces
        raise NoTrackError(
            f"{clip.path}: found at most {n} {'face' if n == 1 else 'faces'} in a frame; --face must be 0..{n - 1} "
            f"(0 the largest), got {face}"
        )
    return np.stack(points), np.asarray(presence), np.asarray(ms)


def _slerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation, Slerp

    return Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([a, b])))([t]).as_matrix()[0]


def bridge(rotations: np.ndarray, translations: np.ndarray, coefficients: np.ndarray, observed: np.ndarray) -> None:
    """Fill the unobserved frames in place: between two observed frames interpolated (rotations slerped),
    before the first and after the last held."""
    seen = np.flatnonzero(observed)
    for index in np.flatnonzero(~observed):
        before = seen[seen < index]
        after = seen[seen > index]
        if len(before) and len(after):
            a, b = int(before[-1]), int(after[0])
            t = (index - a) / (b - a)
            rotations[index] = _slerp(rotations[a], rotations[b], t)
            translations[index] = (1 - t) * translations[a] + t * translations[b]
            coefficients[index] = (1 - t) * coefficients[a] + t * coefficients[b]
        else:
            k = int(before[-1]) if len(before) else int(after[0])
            rotations[index], translations[index], coefficients[index] = rotations[k], translations[k], coefficients[k]


def track_clip(
    clip: Clip,
    config: TrackConfig | None = None,
    *,
    rig: JointRig | None = None,
    progress: Progress | None = None,
    landmarks: np.ndarray | None = None,
) -> TrackResult:
    """Track the clip (module docstring).

    Args:
        clip: :func:`pipeline.track.video.open_clip`'s.
        config: :class:`TrackConfig`.
        rig: the joint rig (default: the committed one, float32 for the identity fit).
        progress: :data:`Progress`.
        landmarks: ``(T, 478, 2)`` the frames' points if already known (NaN rows: no face), instead of
            following the face (tests, benchmarks).

    Raises:
        NoTrackError: no frame with a face, or fewer than 2 to fit the identity on.
    """
    config = config or TrackConfig()
    t0 = time.perf_counter()
    if landmarks is None:
        landmarks, _, follow_ms = follow_clip(clip, config.face, config.max_frames, progress)
    else:
        landmarks = np.asarray(landmarks, np.float32)[: config.max_frames]
        follow_ms = np.zeros(len(landmarks))
    follow_s = time.perf_counter() - t0
    observed = np.isfinite(landmarks).all(axis=(1, 2))
    if not observed.any():
        raise NoTrackError(f"{clip.path}: no face found in any of its {len(landmarks)} frames")
    return _track_frames(clip, landmarks, follow_ms, follow_s, config, rig=rig, progress=progress)


@dataclass
class ShotTracks:
    """A clip tracked shot by shot (:func:`track_shots`).

    Attributes:
        shots: every :class:`~pipeline.track.shots.Shot` of the clip, in order.
        tracks: the :class:`TrackResult` of each shot that was tracked (``first_frame`` its shot's start).
        skipped: ``(shot, reason)`` of the shots that could not be (no face, or a face in one frame only).
        frames: the frames read.
    """

    shots: list[Shot]
    tracks: list[TrackResult]
    skipped: list[tuple[Shot, str]]
    frames: int


def track_shots(
    clip: Clip, config: TrackConfig | None = None, *, rig: JointRig | None = None, progress: Progress | None = None
) -> ShotTracks:
    """Track a clip that may hold several shots (:mod:`pipeline.track.shots`): the face followed through the
    clip and found anew after each cut, each shot with a face in at least 2 frames tracked on its own (its own
    identity; a gap is never bridged across a cut).

    Raises:
        NoTrackError: no shot could be tracked (no face, or a face in one frame only, in every shot).
    """
    config = config or TrackConfig()
    t0 = time.perf_counter()
    cuts: list[int] = []
    landmarks, _, follow_ms = follow_clip(clip, config.face, config.max_frames, progress, cuts=cuts)
    follow_s = time.perf_counter() - t0
    observed = np.isfinite(landmarks).all(axis=(1, 2))
    if not observed.any():
        raise NoTrackError(f"{clip.path}: no face found in any of its {len(landmarks)} frames")
    shots = split_shots(len(landmarks), cuts)
    tracks, skipped = [], []
    for shot in shots:
        seen = int(observed[shot.start : shot.end].sum())
        if seen < 2:
            reason = "no face" if seen == 0 else "a face in one frame only (at least 2 fit an identity)"
            skipped.append((shot, reason))
            continue
        part = slice(shot.start, shot.end)
        share = follow_s * shot.frames / len(landmarks)
        track = _track_frames(
            clip, landmarks[part], follow_ms[part], share, config, rig=rig, progress=progress, first_frame=shot.start
        )
        tracks.append(track)
    if not tracks:
        reasons = "; ".join(f"frames {s.start}-{s.end - 1}: {r}" for s, r in skipped)
        raise NoTrackError(f"{clip.path}: no shot could be tracked ({reasons})")
    return ShotTracks(shots, tracks, skipped, len(landmarks))


def _fit_every_frame(
    model: FrameModel,
    landmarks: np.ndarray,
    observed: np.ndarray,
    weights: np.ndarray,
    key_states: dict[int, FrameState],
    config: TrackConfig,
    progress: Progress | None,
) -> tuple[np.ndarray, ...]:
    """Every frame's fit in order (:func:`pipeline.track.solver.solve_frame`), each started from the frame before
    (at the clip's start or after a gap: from the nearest keyframe's state, with ``config.cold_iterations``).

    Returns:
        ``rotations (T, 3, 3)``, ``translations (T, 3)`` mm, ``coefficients (T, 52)``, ``rms (T,)`` px (NaN where
        no face), ``information (T, 58, 58)`` and ``fit_ms (T,)`` the milliseconds of each frame.
    """
    count = len(landmarks)
    rotations = np.zeros((count, 3, 3))
    translations = np.zeros((count, 3))
    coefficients = np.zeros((count, 52))
    rms = np.full(count, np.nan)
    fit_ms = np.zeros(count)
    information = np.zeros((count, 58, 58))
    previous: list[FrameState | None] = [None, None]
    settings = config.frame
    cold = replace(settings, iterations=config.cold_iterations)
    for index in range(count):
        tf = time.perf_counter()
        if not observed[index]:
            previous = [None, None]
        else:
            if previous[0] is None:  # the clip's start or after a gap: from the nearest keyframe
                nearest = min(key_states, key=lambda k: abs(k - index))
                start, step_settings = key_states[nearest].copy(), cold
            else:
                start, step_settings = previous[0].copy(), settings
            model.pick_contour(start)
            state, info = solve_frame(
                model, landmarks[index].astype(np.float64), weights, start, (previous[0], previous[1]), step_settings
            )
            rotations[index], translations[index], coefficients[index] = (
                state.rotation,
                state.translation,
                state.coefficients,
            )
            rms[index] = info["rms_px"]
            information[index] = info["information"]
            previous = [state, previous[0]]
        fit_ms[index] = 1e3 * (time.perf_counter() - tf)
        if progress is not None:
            progress("fit", index + 1, count)
    return rotations, translations, coefficients, rms, information, fit_ms


def _track_frames(
    clip: Clip,
    landmarks: np.ndarray,
    follow_ms: np.ndarray,
    follow_s: float,
    config: TrackConfig,
    *,
    rig: JointRig | None = None,
    progress: Progress | None = None,
    first_frame: int = 0,
) -> TrackResult:
    """The identity, every frame, the smoothing and the bridges of one run of frames (a clip or a shot)."""
    seconds: dict = {"follow": follow_s}
    observed = np.isfinite(landmarks).all(axis=(1, 2))
    if observed.sum() < 2:
        raise NoTrackError(f"{clip.path}: a face in only one frame; at least 2 are needed to fit its identity")

    # the identity, on keyframes
    t1 = time.perf_counter()
    width, height = clip.size
    focal = float(config.focal or default_focal(width, height))
    rig = rig or JointRig()
    layout = mediapipe_layout(rig.asset)
    keys = choose_keyframes(observed, config.keyframes, landmarks if config.keyframe_choice == "poses" else None)
    identity_fit = fit_multiview(
        [landmarks[k].astype(np.float64) for k in keys],
        [clip.size] * len(keys),
        focals=[focal] * len(keys),
        # every keyframe counts in full: an identity that takes up the detector's error shared by the frames keeps
        # it out of their expressions (the views' averaged, yaw-weighed terms, measured on the bench_track clips
        # 1-2: all 52 coefficients 0.044 / 0.051 -> 0.049 / 0.059, docs/track.md)
        config=MultiViewConfig(fit_focal=False, skinning=config.model, **INDEPENDENT_VIEWS),
        rig=rig,
        layouts=[layout] * len(keys),
        progress=progress,
    )
    head = fitted_head_from_params(identity_fit.identity)
    seconds["identity"] = time.perf_counter() - t1

    # every frame
    t2 = time.perf_counter()
    rig64 = JointRig(rig.asset, dtype=torch.float64)
    if head.model.posable:
        model = FrameModel(rig64, identity_fit.theta, head.weights, layout, focal, clip.size)
    else:  # another model's identity: the template's frame, the identity as an offset from it
        offsets = head.vertices - np.asarray(rig.asset.vertices, np.float64)
        model = FrameModel(rig64, np.zeros(NUM_PARAMETERS), None, layout, focal, clip.size, rest_offsets=offsets)
    weights = layout.weights("detector", 1.0, torch.float64).numpy()
    key_states = {
        k: FrameState(v.rotation, v.translation, np.asarray(v.expressions, np.float64))
        for k, v in zip(keys, identity_fit.views, strict=True)
    }
    rotations, translations, coefficients, rms, information, fit_ms = _fit_every_frame(
        model, landmarks, observed, weights, key_states, config, progress
    )
    smooth_track(rotations, translations, coefficients, information, observed, config.smooth, model.low, model.high)
    bridge(rotations, translations, coefficients, observed)
    seconds["fit"] = time.perf_counter() - t2
    seconds["follow_ms_per_frame"] = float(np.mean(follow_ms))
    seconds["fit_ms_per_frame"] = float(np.mean(fit_ms))
    return TrackResult(
        fps=clip.fps,
        size=clip.size,
        focal=focal,
        head=head,
        identity_fit=identity_fit,
        keyframes=tuple(keys),
        rotations=rotations,
        translations=translations,
        coefficients=coefficients,
        observed=observed,
        landmarks=landmarks,
        rms_px=rms,
        seconds=seconds,
        first_frame=first_frame,
    )


__all__ = [
    "NoTrackError",
    "ShotTracks",
    "TrackConfig",
    "TrackResult",
    "bridge",
    "choose_keyframes",
    "follow_clip",
    "track_clip",
    "track_shots",
]
