"""The project's compact copy of the ICT Face Model *light* (USC ICT Vision and Graphics Lab, MIT licence).

The ICT Face Model is built from light-stage scans of real people registered to one topology: a neutral
mean, 100 identity modes (principal components; a head is ``mean + sum_i c_i identity[i]`` with
``c ~ N(0, I)``, the model's own sampler) and 53 expression shapes with ARKit names. jnr learns its template
mean, its synthetic population and everything trained on them from it (issue 25).

The copy (``rig/assets/ict/ict_face_light.npz``, with the model's ``LICENSE`` beside it and in ``NOTICE``)
is made once by :func:`make_compact` from ``shared/data/ict-facekit/ict_facekit_light.npz`` and committed,
so a fresh clone rebuilds every derived asset; nothing is fetched. It keeps what jnr uses:

- the skin of the face, head and neck (ICT vertices 0-11247: face 0-9408, head and neck 9409-11247) and its
  22,288 triangles (the triangles of the full model whose corners are all skin);
- every identity mode and expression shape on those vertices, stored as ``int16`` with one scale per
  shape (``q = round(x / s)``, ``s = max|x| / 32767``): the storage error of a delta is at most ``s / 2``
  (:data:`MAX_STORAGE_ERROR_MM`, 0.0002 mm for the identity modes, 0.0006 mm for the expressions);
- the centres of the two eyeballs (mean of their vertices) for the neutral, each identity mode and each
  expression, float32 (the eyeballs themselves are not kept: jnr's are MakeHuman's, moved rigidly);
- the 68 iBUG landmark vertex ids (all on the skin).

Units and axes here are **millimetres** (the source is in centimetres: x 10), ICT's own frame: +Y up,
+Z out of the face, +X the subject's left; its origin is not jnr's (:mod:`rig.ict.transfer` places it).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.errors import SetupError

__all__ = [
    "COMPACT_PATH",
    "MAX_STORAGE_ERROR_MM",
    "NUM_IDENTITY_MODES",
    "SKIN_VERTICES",
    "IctModel",
    "load_ict",
    "make_compact",
]

COMPACT_PATH = Path(__file__).resolve().parent.parent / "assets" / "ict" / "ict_face_light.npz"
SKIN_VERTICES = 11248
"""ICT vertices 0..11247: the skin of the face, head and neck (ICT's README)."""
NUM_IDENTITY_MODES = 100
EYEBALLS = ((21451, 23021), (23021, 24591))
"""ICT's left (+X) and right eyeball vertex ranges."""
CM_TO_MM = 10.0
MAX_STORAGE_ERROR_MM = {"identity": 2.1e-4, "expression": 6.0e-4}
"""Largest storage error of one vertex coordinate of one delta, measured by :func:`make_compact`'s
round trip (``max over shapes of s / 2``), mm."""


@dataclass(frozen=True)
class IctModel:
    """The ICT Face Model light, skin only, in mm (ICT's frame).

    Attributes:
        neutral: ``(N, 3)`` float64 mean head, mm (N = 11,248).
        identity: ``(100, N, 3)`` float32 identity modes (deltas per unit coefficient), mm.
        expression: ``(53, N, 3)`` float32 expression shape deltas (weights in [0, 1]), mm.
        expression_names: the 53 names, ICT's (``eyeBlink_L`` = ARKit ``eyeBlinkLeft``).
        triangles: ``(T, 3)`` int64 skin triangles (counter-clockwise seen from outside).
        landmarks68: ``(68,)`` int64 iBUG-68 vertex ids.
        eye_centres: ``(2, 3)`` neutral eyeball centres (left, right), mm.
        identity_eye_centres: ``(100, 2, 3)``; expression_eye_centres: ``(53, 2, 3)`` their deltas, mm.
    """

    neutral: np.ndarray
    identity: np.ndarray
    expression: np.ndarray
    expression_names: tuple[str, ...]
    triangles: np.ndarray
    landmarks68: np.ndarray
    eye_centres: np.ndarray
    identity_eye_centres: np.ndarray
    expression_eye_centres: np.ndarray

    def head(self, coefficients: np.ndarray) -> np.ndarray:
        """``(..., N, 3)`` mm: ``neutral + sum_i c_i identity[i]`` for ``coefficients`` ``(..., k)``, k <= 100
        (the first k modes)."""
        c = np.asarray(coefficients, np.float64)
        k = c.shape[-1]
        return self.neutral + np.tensordot(c, self.identity[:k].astype(np.float64), axes=([-1], [0]))


def _quantise(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(S, ...)`` float -> int16 values and ``(S,)`` float32 scales (one per shape)."""
    scale = np.abs(x.reshape(len(x), -1)).max(1) / 32767.0
    scale = np.where(scale > 0, scale, 1.0).astype(np.float32)
    q = np.round(x / scale.reshape((-1,) + (1,) * (x.ndim - 1))).astype(np.int16)
    return q, scale


def _dequantise(q: np.ndarray, scale: np.ndarray) -> np.ndarray:
    return q.astype(np.float32) * scale.reshape((-1,) + (1,) * (q.ndim - 1))


def make_compact(source: str | Path, out: str | Path = COMPACT_PATH) -> dict[str, float]:
    """Write the compact copy from ICT's ``ict_facekit_light.npz`` (``shared/data/ict-facekit/``).

    Returns the largest storage error per kind (mm), measured on the round trip.
    """
    import io

    from rig.io.atomic import write_bytes_atomic

    src = np.load(source, allow_pickle=False)
    n = SKIN_VERTICES
    tri = src["triangles"].astype(np.int64)
    tri = tri[tri.max(1) < n]
    arrays: dict[str, np.ndarray] = {
        "neutral": (src["neutral"][:n].astype(np.float64) * CM_TO_MM).astype(np.float32),
        "triangles": tri.astype(np.uint16),
        "landmarks68": src["landmarks68"].astype(np.int32),
        "expression_names": np.array([str(s) for s in src["expression_names"]]),
    }
    errors = {}
    for kind in ("identity", "expression"):
        full = src[kind].astype(np.float64) * CM_TO_MM
        q, s = _quantise(full[:, :n])
        arrays[f"{kind}_q"], arrays[f"{kind}_scale"] = q, s
        errors[kind] = float(np.abs(_dequantise(q, s) - full[:, :n]).max())
        arrays[f"{kind}_eye_centres"] = np.stack([full[:, a:b].mean(1) for a, b in EYEBALLS], 1).astype(
            np.float32
        )  # (S, 2, 3)
    neutral_full = src["neutral"].astype(np.float64) * CM_TO_MM
    arrays["eye_centres"] = np.stack([neutral_full[a:b].mean(0) for a, b in EYEBALLS]).astype(np.float32)
    if not set(arrays["landmarks68"].tolist()) <= set(range(n)):
        raise SetupError("ICT: a landmark is not on the skin")
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    write_bytes_atomic(out, buffer.getvalue(), make_parents=True)
    return errors


@functools.lru_cache(maxsize=2)
def load_ict(path: str | None = None) -> IctModel:
    """The compact ICT model (default: the committed copy), read once per process.

    Raises:
        SetupError: the file is missing or unreadable.
    """
    path = Path(path or COMPACT_PATH)
    if not path.is_file():
        raise SetupError(f"ICT face model copy not found: {path} (it is committed with jnr: restore it)")
    try:
        with np.load(path, allow_pickle=False) as data:
            d = {k: data[k] for k in data.files}
    except Exception as exc:  # zip/npz errors come in many types
        raise SetupError(f"ICT face model copy {path} is unreadable: {exc}") from None
    return IctModel(
        neutral=d["neutral"].astype(np.float64),
        identity=_dequantise(d["identity_q"], d["identity_scale"]),
        expression=_dequantise(d["expression_q"], d["expression_scale"]),
        expression_names=tuple(str(s) for s in d["expression_names"]),
        triangles=d["triangles"].astype(np.int64),
        landmarks68=d["landmarks68"].astype(np.int64),
        eye_centres=d["eye_centres"].astype(np.float64),
        identity_eye_centres=d["identity_eye_centres"].astype(np.float64),
        expression_eye_centres=d["expression_eye_centres"].astype(np.float64),
    )
