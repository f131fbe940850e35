"""Read and write 2D landmark files: iBUG ``.pts``, ``.json`` and ``.csv``.

In memory, points are always ``(N, 2)`` float64 **0-based OpenCV pixel coordinates** (origin at the centre
of the top-left pixel, x right, y down), in one of two layouts told apart by the count: iBUG-68 (68 points)
or MediaPipe's face mesh (468 points, or 478 with the two irises, centre first, the subject's right then
left: MediaPipe's own order).

=======  ======================================================================================
format   layout
=======  ======================================================================================
.pts     ``version: 1`` / ``n_points: 68`` / ``{`` / one ``x y`` line per point / ``}``. iBUG
         (300-W) files hold **1-based** (Matlab) pixel coordinates: 1 is subtracted on read and
         added on write.
.json    ``{"landmarks": [[x, y], ...], "convention": "ibug68", "pixel_origin": "opencv"}``
         (0-based; a file whose ``pixel_origin`` is ``"matlab"`` is shifted by -1 on read);
         ``"convention": "mediapipe"`` for 468 or 478 points; without ``convention`` the count
         tells it (68: iBUG, 468/478: MediaPipe).
.csv     header ``index,x,y`` then one ``i,x,y`` row per point, ``i`` = 0..N-1 in order (0-based).
=======  ======================================================================================
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np

from rig.errors import InputError
from rig.io.atomic import write_bytes_atomic
from rig.io.inputs import loads_json_strict, regular_file

MAX_LANDMARK_FILE_BYTES = 64 << 20
"""The largest landmark file read (64 MiB; 68 or 478 points are a few kB)."""

NUM_LANDMARKS = 68
MEDIAPIPE_COUNTS = (468, 478)
"""MediaPipe's face mesh without and with the irises."""
CONVENTIONS = {68: "ibug68", 468: "mediapipe", 478: "mediapipe"}
"""The JSON ``convention`` of each point count."""
FORMATS = (".pts", ".json", ".csv")


class LandmarkFileError(InputError):
    """A landmark file is malformed (wrong count, non-finite or unparsable values, bad structure)."""


def _error(path: Path, line: int | None, message: str) -> LandmarkFileError:
    where = f"{path}" if line is None else f"{path}, line {line}"
    return LandmarkFileError(f"{where}: {message}")


def _number(text: str, path: Path, line: int) -> float:
    try:
        value = float(text)
    except ValueError:
        raise _error(path, line, f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise _error(path, line, f"non-finite value {text!r}")
    return value


def _format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise LandmarkFileError(f"{path}: unknown landmark format {suffix!r}; expected one of {list(FORMATS)}")
    return suffix


def _check_count(points: np.ndarray, n_points: int | tuple[int, ...], path: Path) -> np.ndarray:
    allowed = (n_points,) if isinstance(n_points, int) else tuple(n_points)
    if len(points) not in allowed:
        expected = " or ".join(str(n) for n in allowed)
        raise _error(path, None, f"expected {expected} landmarks, got {len(points)}")
    return points


def _read_pts(path: Path, text: str, n_points: int) -> np.ndarray:
    lines = [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines())]
    lines = [(i, ln) for i, ln in lines if ln]
    header: dict[str, str] = {}
    k = 0
    while k < len(lines) and lines[k][1] != "{":
        lineno, ln = lines[k]
        key, sep, value = ln.partition(":")
        if not sep:
            raise _error(path, lineno, f"expected a 'key: value' header line or '{{', got {ln!r}")
        header[key.strip()] = value.strip()
        k += 1
    if k == len(lines):
        raise _error(path, None, "no '{' opening the point list")
    if "n_points" not in header:
        raise _error(path, None, "header has no 'n_points'")
    try:
        declared = int(header["n_points"])
    except ValueError:
        raise _error(path, None, f"n_points is not an integer: {header['n_points']!r}") from None
    points, closed = [], False
    for lineno, ln in lines[k + 1 :]:
        if ln == "}":
            closed = True
            break
        fields = ln.split()
        if len(fields) != 2:
            raise _error(path, lineno, f"expected 'x y', got {ln!r}")
        points.append([_number(f, path, lineno) for f in fields])
    if not closed:
        raise _error(path, None, "no '}' closing the point list")
    if len(points) != declared:
        raise _error(path, None, f"n_points says {declared} but the file lists {len(points)} points")
    return _check_count(np.array(points, np.float64).reshape(-1, 2), n_points, path) - 1.0  # 1-based -> 0-based


def _read_json(path: Path, text: str, n_points: int) -> np.ndarray:
    try:
        data = loads_json_strict(text)
    except json.JSONDecodeError as exc:
        raise _error(path, exc.lineno, f"invalid JSON: {exc.msg}") from None
    except ValueError as exc:  # a key twice in one object (json keeps the last silently)
        raise _error(path, None, str(exc)) from None
    except RecursionError:
        raise _error(path, None, "JSON nested too deeply to be a landmark file") from None
    if not isinstance(data, dict) or "landmarks" not in data:
        raise _error(path, None, "expected an object with a 'landmarks' list")
    convention = data.get("convention")  # without one: the convention of the count (68 iBUG, 468/478 MediaPipe)
    if convention is not None and convention not in ("ibug68", "mediapipe"):
        raise _error(path, None, f"unsupported convention {convention!r}; expected 'ibug68' or 'mediapipe'")
    origin = data.get("pixel_origin", "opencv")
    if origin not in ("opencv", "matlab"):
        raise _error(path, None, f"pixel_origin must be 'opencv' or 'matlab', got {origin!r}")
    rows = data["landmarks"]
    if not isinstance(rows, list):
        raise _error(path, None, "'landmarks' must be a list of [x, y] pairs")
    points = []
    for i, row in enumerate(rows):
        if (
            not isinstance(row, list)
            or len(row) != 2
            or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in row)
        ):
            raise _error(path, None, f"landmark {i} (0-based): expected [x, y] numbers, got {row!r}")
        if not all(math.isfinite(c) for c in row):
            raise _error(path, None, f"landmark {i} (0-based): non-finite value {row!r}")
        points.append([float(c) for c in row])
    points = _check_count(np.array(points, np.float64).reshape(-1, 2), n_points, path)
    if convention is not None and CONVENTIONS.get(len(points)) != convention:
        expected = " or ".join(str(n) for n, c in CONVENTIONS.items() if c == convention)
        raise _error(
            path,
            None,
            f"{len(points)} landmarks do not match the convention {convention!r} ({expected} points); "
            f"{len(points)} points are {CONVENTIONS[len(points)]!r}",
        )
    return points - 1.0 if origin == "matlab" else points


def _read_csv(path: Path, text: str, n_points: int) -> np.ndarray:
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or [c.strip().lower() for c in rows[0]] != ["index", "x", "y"]:
        raise _error(
            path, 1, f"expected the header 'index,x,y', got {','.join(rows[0]) if rows else 'an empty file'!r}"
        )
    points = []
    for lineno, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != 3:
            raise _error(path, lineno, f"expected 'index,x,y', got {','.join(row)!r}")
        index = row[0].strip()
        if index != str(len(points)):
            raise _error(path, lineno, f"expected index {len(points)}, got {index!r}")
        points.append([_number(row[1].strip(), path, lineno), _number(row[2].strip(), path, lineno)])
    return _check_count(np.array(points, np.float64).reshape(-1, 2), n_points, path)


def read_landmarks(path: str | Path, n_points: int | tuple[int, ...] = NUM_LANDMARKS) -> np.ndarray:
    """Read 2D landmarks; the format is chosen by the extension (``.pts``, ``.json``, ``.csv``).

    Args:
        path: the file.
        n_points: the count the file must have, or a tuple of the counts accepted (e.g. ``(68, 468, 478)``).

    Returns:
        ``(N, 2)`` float64, 0-based OpenCV pixel coordinates, ``N`` one of ``n_points``.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        LandmarkFileError: unknown extension, malformed content, wrong count or non-finite values (the
            message names the file and, where known, the line).
    """
    path = Path(path)
    fmt = _format(path)
    regular_file(path, "landmark file", MAX_LANDMARK_FILE_BYTES)  # a FIFO or a device is not "not found"
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise _error(path, None, "not a text file (UTF-8): a landmark file is .pts, .json or .csv text") from None
    reader = {".pts": _read_pts, ".json": _read_json, ".csv": _read_csv}[fmt]
    return reader(path, text, n_points)


def write_landmarks(path: str | Path, points) -> None:
    """Write ``(N, 2)`` 0-based OpenCV pixel coordinates in the format given by the extension
    (``.pts`` files get 1-based coordinates, as iBUG's). Values are written with ``repr`` precision, so a
    read gives back the same floats (up to the ±1 shift's rounding for ``.pts``)."""
    path = Path(path)
    fmt = _format(path)
    pts = np.asarray(points, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"write_landmarks: points must have shape (N, 2), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise InputError(
            "write_landmarks: points contain non-finite values "
            f"(rows {np.flatnonzero(~np.isfinite(pts).all(1)).tolist()})"
        )
    if fmt == ".pts":
        body = "\n".join(f"{x!r} {y!r}" for x, y in (pts + 1.0).tolist())
        text = f"version: 1\nn_points: {len(pts)}\n{{\n{body}\n}}\n"
    elif fmt == ".json":
        convention = CONVENTIONS.get(len(pts), "ibug68")
        text = (
            json.dumps({"landmarks": pts.tolist(), "convention": convention, "pixel_origin": "opencv"}, indent=1) + "\n"
        )
    else:
        text = "index,x,y\n" + "".join(f"{i},{x!r},{y!r}\n" for i, (x, y) in enumerate(pts.tolist()))
    write_bytes_atomic(path, text.encode("utf-8"))  # never a half-written landmarks file
