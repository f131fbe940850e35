"""ARKit expression curves: reading and writing Live Link Face and plain CSV files, the shipped example,
the head angles' rotations."""

from __future__ import annotations

import csv
import io
import logging
import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES, expression_limits
from rig.io.atomic import write_bytes_atomic
from rig.io.inputs import regular_file

log = logging.getLogger("jnr")

HEAD_COLUMNS = ("head_yaw", "head_pitch", "head_roll")
"""The plain layout's head angle columns (degrees), in :attr:`Curves.head_rotation` order."""
LIVE_LINK_HEAD = ("HeadYaw", "HeadPitch", "HeadRoll")
LIVE_LINK_EYES = ("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
LIVE_LINK_SHAPES = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeSquintLeft",
    "EyeWideLeft", "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight",
    "EyeSquintRight", "EyeWideRight", "JawForward", "JawRight", "JawLeft", "JawOpen", "MouthClose", "MouthFunnel",
    "MouthPucker", "MouthRight", "MouthLeft", "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft",
    "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft", "MouthStretchRight",
    "MouthRollLower", "MouthRollUpper", "MouthShrugLower", "MouthShrugUpper", "MouthPressLeft", "MouthPressRight",
    "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft", "MouthUpperUpRight", "BrowDownLeft",
    "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight", "CheekPuff", "CheekSquintLeft",
    "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight", "TongueOut",
)  # fmt: skip
"""The 52 shape columns of Live Link Face's CSV in the app's order (its header as recorded by the iOS app and as
read by Epic's and Blender importers: ``JawRight`` before ``JawLeft``, ``MouthRight`` before ``MouthLeft``, unlike
ARKit's documentation order of :data:`rig.expressions.EXPRESSION_NAMES`)."""
LIVE_LINK_BLENDSHAPE_COUNT = 61
"""The app's ``BlendShapeCount`` cell: the 52 shapes and the 9 head and eye rotations."""
LIVE_LINK_FPS = 60.0
"""Live Link Face's recording rate, the frame rate assumed for its timecodes when the file does not show it."""
TIMECODE_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 120.0)
"""The frame rates a file's timecodes are matched to (:func:`timecode_rate`; 29.97 reads as 30)."""
MAX_CURVES_BYTES = 512 << 20
"""The largest curves file read (512 MiB: millions of rows)."""
PLAIN_FPS = 30.0
"""The default frame rate of a plain CSV without a ``time`` column."""
HEAD_JOINT = "skull_root"
"""The joint the head angles turn."""
EXAMPLE_CURVES = Path(__file__).resolve().parents[1] / "assets" / "animation" / "blink_smile.csv"
"""The shipped example curves (:func:`example_curves`, written by :func:`write_curves`)."""


class CurvesError(InputError):
    """A curves file that cannot be read: its layout, names, times or values."""


@dataclass(frozen=True)
class Curves:
    """ARKit expression curves over time.

    Attributes:
        times: ``(T,)`` seconds from the first row, strictly increasing.
        coefficients: ``(T, 52)`` ARKit coefficients in :data:`rig.expressions.EXPRESSION_NAMES` order, in
            each shape's limits.
        head_rotation: ``(T, 3)`` head yaw, pitch, roll in degrees, or None.
        layout: ``"live-link-face"`` or ``"plain"``.
        fps: the frame rate of the file's timecodes or rows (given, read from the timecodes or assumed); None
            for curves made in memory or a plain file with a time column.
    """

    times: np.ndarray
    coefficients: np.ndarray
    head_rotation: np.ndarray | None = None
    layout: str = "plain"
    fps: float | None = None


def _expression_index() -> dict[str, int]:
    return {n.lower(): i for i, n in enumerate(EXPRESSION_NAMES)}


IGNORED_COLUMNS = ("_neutral",)
"""Columns read and dropped: MediaPipe's face blendshapes start with ``_neutral``, which ARKit has not."""
TIME_COLUMNS = {"time": 1.0, "time_s": 1.0, "seconds": 1.0, "timestamp_ms": 1e-3}
"""A plain file's time column names and their unit in seconds (MediaPipe's results carry ``timestamp_ms``)."""


def _shape_key(name: str) -> str:
    """A column name as the lower-case ARKit name: ARKit's raw ``ARFaceAnchor`` keys (``eyeBlink_L``,
    ``mouthSmile_R``) become ``eyeblinkleft``, ``mouthsmileright``; other names are only lower-cased."""
    key = name.strip().lower()
    if key.endswith("_l"):
        return key[:-2] + "left"
    if key.endswith("_r"):
        return key[:-2] + "right"
    return key


_TIMECODE = re.compile(r"^(\d+):(\d+):(\d+):(\d+(?:\.\d+)?)$")


def _timecode_fields(text: str, path: Path, row: int) -> tuple[float, float, float, float]:
    match = _TIMECODE.match(text.strip())
    if match is None:
        raise CurvesError(f"{path}: row {row}: timecode {text!r} is not HH:MM:SS:FF[.sub]")
    h, m, s, f = (float(g) for g in match.groups())
    return h, m, s, f


def timecode_rate(timecodes: list[str], path: Path | str = "curves") -> float | None:
    """The frame rate that ``HH:MM:SS:FF[.sub]`` timecodes show: the smallest of :data:`TIMECODE_RATES` above
    their largest whole frame number, when the timecodes pass a whole second (so that the frame numbers wrapped
    at the rate); None when they stay within one second (the rate cannot be told).

    Raises:
        CurvesError: a malformed timecode, or frame numbers past every known rate."""
    fields = [_timecode_fields(t, Path(path), r + 2) for r, t in enumerate(timecodes)]
    seconds = {3600.0 * h + 60.0 * m + s for h, m, s, _ in fields}
    if len(seconds) < 2:
        return None
    top = max(math.floor(f) for *_, f in fields)
    for rate in TIMECODE_RATES:
        if top < rate:
            return rate
    raise CurvesError(f"{path}: timecode frame numbers reach {top}, past {TIMECODE_RATES[-1]:g} fps; pass --fps")


def _timecode_seconds(text: str, fps: float, path: Path, row: int) -> float:
    h, m, s, f = _timecode_fields(text, path, row)
    if f >= fps:
        raise CurvesError(
            f"{path}: row {row}: timecode {text!r} has frame {f:g}, not below {fps:g} fps; "
            "pass the take's frame rate with --fps"
        )
    return 3600.0 * h + 60.0 * m + s + f / fps


def _number(text: str, path: Path, row: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise CurvesError(f"{path}: row {row}, column {column!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise CurvesError(f"{path}: row {row}, column {column!r}: value must be finite, got {text!r}")
    return value


def _read_rows(path: Path) -> tuple[list[str], list[list[str]]]:
    """The stripped header and the non-blank rows under it of a UTF-8 CSV, refusing empty or header-only files."""
    try:
        regular_file(path, "curves", MAX_CURVES_BYTES)
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise CurvesError(f"{path}: not a text CSV file") from None
    except InputError as exc:
        raise CurvesError(str(exc)) from None
    rows = [r for r in csv.reader(io.StringIO(text)) if any(cell.strip() for cell in r)]
    if not rows:
        raise CurvesError(f"{path}: empty curves file")
    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    if not body:
        raise CurvesError(f"{path}: no rows under the header")
    return header, body


def _header_columns(
    header: list[str], live_link: bool, path: Path
) -> tuple[list[tuple[int, str, int | None]], int | None, float]:
    """``(csv column, "shape" | "head", target index)`` per read column, and the time column and its unit (s)."""
    index = _expression_index()
    head_names = [h.lower() for h in (LIVE_LINK_HEAD if live_link else HEAD_COLUMNS)]
    ignored = {h.lower() for h in LIVE_LINK_EYES} if live_link else set()
    time_column, time_unit = None, 1.0
    columns: list[tuple[int, str, int | None]] = []  # (csv column, kind, target index)
    unknown = []
    for i, name in enumerate(header):
        key = name.lower()
        if live_link and i < 2:
            continue
        if _shape_key(name) in index:
            columns.append((i, "shape", index[_shape_key(name)]))
        elif key in head_names:
            columns.append((i, "head", head_names.index(key)))
        elif not live_link and key in TIME_COLUMNS:
            time_column, time_unit = i, TIME_COLUMNS[key]
        elif key in ignored or key in IGNORED_COLUMNS:
            continue
        else:
            unknown.append(name)
    if unknown:
        head_columns = "HeadYaw/HeadPitch/HeadRoll" if live_link else "time, head_yaw, head_pitch, head_roll"
        raise CurvesError(
            f"{path}: unknown column(s) {unknown}; a curves file has the 52 ARKit names "
            f"(e.g. eyeBlinkLeft or ARKit's raw eyeBlink_L, jawOpen; MediaPipe's _neutral is skipped), {head_columns}"
        )
    if not any(kind == "shape" for _, kind, _ in columns):
        raise CurvesError(f"{path}: no ARKit expression column (e.g. eyeBlinkLeft, jawOpen)")
    shapes = [n for _, kind, n in columns if kind == "shape"]
    if len(set(shapes)) != len(shapes):
        raise CurvesError(f"{path}: an ARKit name appears twice in the header")
    return columns, time_column, time_unit


def _frame_rate(fps: float | None, live_link: bool, body: list[list[str]], path: Path) -> float:
    """Frames per second: ``fps``, else the timecodes' rate (warning when unreadable) or the layout's default."""
    rate = fps
    if rate is None and live_link:
        rate = timecode_rate([row[0] if row else "" for row in body], path)
        if rate is None and len(body) > 1:  # one row (a photo fit's expression) has no timing to get wrong
            warnings.warn(
                f"{path}: the timecodes stay within one second, so their frame rate cannot be read from them; "
                f"assumed {LIVE_LINK_FPS:g} fps (pass --fps)",
                stacklevel=3,
            )
        rate = rate or LIVE_LINK_FPS
    elif rate is None:
        rate = PLAIN_FPS
    return rate


def _parse_rows(
    header: list[str],
    body: list[list[str]],
    columns: list[tuple[int, str, int | None]],
    live_link: bool,
    time_column: int | None,
    time_unit: float,
    rate: float,
    path: Path,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``(T,)`` times (s, from 0, increasing), ``(T, 52)`` raw coefficients and ``(T, 3)`` head angles (file units)."""
    n = len(body)
    coefficients = np.zeros((n, len(EXPRESSION_NAMES)))
    head = np.zeros((n, 3)) if any(kind == "head" for _, kind, _ in columns) else None
    times = np.zeros(n)
    for r, row in enumerate(body):
        line = r + 2
        if len(row) != len(header):
            raise CurvesError(f"{path}: row {line} has {len(row)} cells, the header {len(header)}")
        for i, kind, target in columns:
            value = _number(row[i], path, line, header[i])
            if kind == "shape":
                coefficients[r, target] = value
            else:
                head[r, target] = value
        if live_link:
            times[r] = _timecode_seconds(row[0], rate, path, line)
        elif time_column is not None:
            times[r] = _number(row[time_column], path, line, header[time_column]) * time_unit
        else:
            times[r] = r / rate
    times = times - times[0]
    if np.any(np.diff(times) <= 0.0):
        bad = int(np.flatnonzero(np.diff(times) <= 0.0)[0]) + 3
        raise CurvesError(f"{path}: times must increase from row to row; row {bad} does not")
    return times, coefficients, head


def _clamp_to_limits(coefficients: np.ndarray, path: Path) -> np.ndarray:
    """``(T, 52)`` coefficients clamped to the shapes' limits, warning (for the reader's caller) when any moved."""
    low, high = (t.numpy().astype(np.float64) for t in expression_limits())
    clamped = np.clip(coefficients, low, high)
    if np.any(np.abs(clamped - coefficients) > 1e-9):
        worst = float(np.max(np.abs(clamped - coefficients)))
        warnings.warn(f"{path}: coefficients outside their limits were clamped (by up to {worst:.3g})", stacklevel=3)
    return clamped


def read_curves(path: str | Path, *, fps: float | None = None, head_units: str | None = None) -> Curves:
    """Read a Live Link Face or plain curves CSV (module docstring). Shape columns may use ARKit's names
    (``eyeBlinkLeft``, any case) or its raw ``ARFaceAnchor`` keys (``eyeBlink_L``); MediaPipe's blendshape
    output reads as it is (its ``_neutral`` column skipped, its missing ``tongueOut`` 0, ``timestamp_ms`` a
    time column); shapes a file does not have are 0.

    Args:
        fps: frames per second of the timecodes (Live Link Face, default :data:`LIVE_LINK_FPS`) or of the
            rows of a plain file without a ``time`` column (default :data:`PLAIN_FPS`).
        head_units: ``"rad"`` or ``"deg"``: the head angles' unit (default: radians for Live Link Face,
            degrees for the plain layout).

    Returns:
        :class:`Curves`; coefficients outside a shape's limits are clamped with a warning.

    Raises:
        CurvesError: unreadable file, unknown column, bad number, times not increasing, no rows.
        FileNotFoundError: no such file.
    """
    path = Path(path)
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise CurvesError(f"fps must be a positive number, got {fps}")
    if head_units not in (None, "rad", "deg"):
        raise CurvesError(f"head units must be 'rad' or 'deg', got {head_units!r}")
    header, body = _read_rows(path)
    live_link = len(header) >= 2 and header[0].lower() == "timecode" and header[1].lower() == "blendshapecount"
    columns, time_column, time_unit = _header_columns(header, live_link, path)
    rate = _frame_rate(fps, live_link, body, path)
    times, coefficients, head = _parse_rows(header, body, columns, live_link, time_column, time_unit, rate, path)
    clamped = _clamp_to_limits(coefficients, path)
    if head is not None and (head_units or ("rad" if live_link else "deg")) == "rad":
        head = np.degrees(head)
    stated = rate if (live_link or time_column is None) else None
    return Curves(times, clamped, head, "live-link-face" if live_link else "plain", stated)


def write_curves(path: str | Path, curves: Curves, *, layout: str = "plain", fps: float = LIVE_LINK_FPS) -> None:
    """Write ``curves`` as CSV: ``layout="plain"`` (``time`` in seconds, the 52 ARKit names, head angles in
    degrees when present) or ``"live-link-face"`` (the app's header column for column: timecodes at ``fps``,
    ``BlendShapeCount`` 61, :data:`LIVE_LINK_SHAPES`, head angles in radians, zero eye angles), atomically. A
    reader finds the rate from the timecodes' frame numbers once they pass a second (:func:`timecode_rate`)."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    head = curves.head_rotation
    if layout == "plain":
        writer.writerow(["time", *EXPRESSION_NAMES, *(HEAD_COLUMNS if head is not None else ())])
        for t in range(len(curves.times)):
            writer.writerow(
                [
                    f"{curves.times[t]:.4f}",
                    *(f"{c:.4f}" for c in curves.coefficients[t]),
                    *((f"{a:.3f}" for a in head[t]) if head is not None else ()),
                ]
            )
    elif layout == "live-link-face":
        index = _expression_index()
        order = [index[n.lower()] for n in LIVE_LINK_SHAPES]
        writer.writerow(["Timecode", "BlendShapeCount", *LIVE_LINK_SHAPES, *LIVE_LINK_HEAD, *LIVE_LINK_EYES])
        for t in range(len(curves.times)):
            frames = curves.times[t] * fps
            seconds = int(frames // fps)
            code = f"00:{seconds // 60:02d}:{seconds % 60:02d}:{frames - seconds * fps:06.3f}"
            angles = np.radians(head[t]) if head is not None else np.zeros(3)
            writer.writerow(
                [
                    code,
                    LIVE_LINK_BLENDSHAPE_COUNT,
                    *(f"{c:.6f}" for c in curves.coefficients[t, order]),
                    *(f"{a:.6f}" for a in angles),
                    *("0",) * len(LIVE_LINK_EYES),
                ]
            )
    else:
        raise InputError(f"write_curves: layout must be 'plain' or 'live-link-face', got {layout!r}")
    write_bytes_atomic(Path(path), text.getvalue().encode("utf-8"))


def example_curves(fps: float = 30.0) -> Curves:
    """The shipped example (:data:`EXAMPLE_CURVES`), 2.4 s: a blink (both eyes, 0.3-0.6 s), then a smile
    that builds and fades (0.8-2.2 s) with a slight turn of the head towards the subject's left and back."""
    times = np.arange(int(round(2.4 * fps)) + 1) / fps
    index = {n: i for i, n in enumerate(EXPRESSION_NAMES)}

    def bump(t, start, end):
        """0 outside ``[start, end]``, a raised-cosine bump to 1 at the middle."""
        x = np.clip((t - start) / (end - start), 0.0, 1.0)
        return 0.5 - 0.5 * np.cos(2.0 * np.pi * x)

    c = np.zeros((len(times), len(EXPRESSION_NAMES)))
    blink = bump(times, 0.3, 0.6)
    smile = np.clip(1.6 * bump(times, 0.8, 2.2), 0.0, 1.0)
    for side in ("Left", "Right"):
        c[:, index[f"eyeBlink{side}"]] = blink
        c[:, index[f"mouthSmile{side}"]] = 0.9 * smile
        c[:, index[f"cheekSquint{side}"]] = 0.5 * smile
        c[:, index[f"eyeSquint{side}"]] = 0.3 * smile
    c[:, index["jawOpen"]] = 0.15 * smile
    head = np.zeros((len(times), 3))
    head[:, 0] = 12.0 * bump(times, 0.8, 2.2)
    head[:, 1] = -4.0 * bump(times, 0.8, 2.2)
    return Curves(np.round(times, 4), np.round(c, 4), np.round(head, 3), "plain")


def head_rotation_matrices(angles_deg: np.ndarray) -> np.ndarray:
    """``(T, 3)`` yaw, pitch, roll in degrees -> ``(T, 3, 3)`` rotations ``Ry(yaw) @ Rx(pitch) @ Rz(roll)`` in
    rig space (right-handed, +Y up, +Z out of the face)."""
    from scipy.spatial.transform import Rotation

    a = np.asarray(angles_deg, dtype=np.float64).reshape(-1, 3)
    return Rotation.from_euler("YXZ", a, degrees=True).as_matrix()
