"""Synthetic clips with known truth for ``jnr track``: a held-out head of the synthetic population
(:func:`pipeline.synthetic.population.population_split`) wearing the rig's ARKit shapes driven by known
curves, turned by known head motion, photographed frame by frame by
:func:`pipeline.synthetic.photos.simulate.simulate_photo` with one camera, light, albedo and background for the whole
clip (the same seed every frame; only the head changes).

The curves (:func:`clip_truth`, ``seconds`` long, 10 by default) run through four segments:

- **still** (the first 20 %): neutral head, a constant light smile, no motion: where jitter is measured;
- **blinks and smiles** (to 40 %): both eyes blink (0.25 s pulses), the smile rises and falls, the head turns
  to 35 degrees and back;
- **speech** (to 70 %): the jaw opens and closes at speech rates (2-4 Hz, irregular), funnel and pucker, the
  head turns to the other side (-35 degrees);
- **brows and gaze** (to the end): brows raised, the eyes look left and right, the head nods (+-12 degrees).

The expressive head is the population head plus the rig's expression offsets (:class:`rig.expressions.
ExpressionModel`: the shapes and the jaw hinge, on the head's rest vertices), so the true coefficients are the
ones a fit of the rig's ARKit shapes should find.

Example:
    >>> truth = clip_truth(seconds=2.0, fps=10.0)
    >>> truth.coefficients.shape, truth.angles_deg.shape, truth.still
    ((20, 52), (20, 3), (0, 4))
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from rig.asset import RigAsset, load_asset
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES, ExpressionModel

STILL_FRACTION = 0.2
"""The share of the clip, at its start, where nothing moves."""
STILL_SMILE = 0.15
"""The constant smile of the still segment (a still face need not be neutral)."""


@dataclass(frozen=True)
class ClipTruth:
    """The known motion of a synthetic clip.

    Attributes:
        fps: frames per second.
        coefficients: ``(T, 52)`` ARKit coefficients (:data:`rig.expressions.EXPRESSION_NAMES` order).
        angles_deg: ``(T, 3)`` head yaw, pitch, roll in degrees (:func:`rig.geometry.head_rotation`).
        still: ``(first, end)`` frames of the still segment (end exclusive).
    """

    fps: float
    coefficients: np.ndarray
    angles_deg: np.ndarray
    still: tuple[int, int]

    @property
    def frames(self) -> int:
        return len(self.coefficients)


def _index(name: str) -> int:
    return EXPRESSION_NAMES.index(name)


def _pulse(t: np.ndarray, centre: float, width: float) -> np.ndarray:
    """A smooth bump of height 1, ``width`` seconds wide at its base."""
    x = np.clip((t - centre) / (width / 2.0), -1.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * x))


def _window(t: np.ndarray, start: float, end: float, ramp: float = 0.3) -> np.ndarray:
    """1 inside ``[start, end]`` with cosine ramps of ``ramp`` seconds inside its ends, 0 outside."""
    up = np.clip((t - start) / ramp, 0.0, 1.0)
    down = np.clip((end - t) / ramp, 0.0, 1.0)
    return 0.5 * (1.0 - np.cos(np.pi * np.minimum(up, down)))


def clip_truth(seconds: float = 10.0, fps: float = 30.0, seed: int = 0) -> ClipTruth:
    """The curves and head motion of a clip (module docstring); ``seed`` varies the speech's rhythm.

    Raises:
        ValueError: ``seconds`` or ``fps`` not positive, or fewer than 5 frames.
    """
    if not (seconds > 0 and fps > 0):
        raise InputError(f"clip_truth: seconds and fps must be > 0, got {seconds}, {fps}")
    count = int(round(seconds * fps))
    if count < 5:
        raise InputError(f"clip_truth: at least 5 frames, got {count}")
    rng = np.random.default_rng(seed)
    t = np.arange(count) / fps
    c = np.zeros((count, len(EXPRESSION_NAMES)))
    s = seconds
    a, b, d = STILL_FRACTION * s, 0.4 * s, 0.7 * s
    still_end = int(math.ceil(a * fps))
    # the still segment's constant smile, fading out after it
    smile = STILL_SMILE * (t < a) + STILL_SMILE * _window(t, a - 0.3, a + 0.3, 0.3) * (t >= a)
    # blinks and smiles
    smile = np.maximum(smile, 0.8 * _window(t, a + 0.1 * s, b - 0.02 * s, 0.25 * s))
    for name in ("mouthSmileLeft", "mouthSmileRight"):
        c[:, _index(name)] = smile
    blink = np.zeros(count)
    for centre in np.arange(a + 0.05 * s, s, 0.12 * s):
        blink = np.maximum(blink, _pulse(t, centre, 0.25))
    for name in ("eyeBlinkLeft", "eyeBlinkRight"):
        c[:, _index(name)] = blink * (t >= a)
    # speech: the jaw at 2-4 Hz with a varying rate, funnel and pucker now and then
    rate = 3.0 + 0.8 * np.sin(2 * np.pi * 0.37 * t + rng.uniform(0, 2 * np.pi))
    phase = 2 * np.pi * np.cumsum(rate) / fps
    speech = _window(t, b, d, 0.2)
    c[:, _index("jawOpen")] = speech * 0.3 * (1.0 + np.sin(phase)) * (0.7 + 0.3 * np.sin(0.9 * phase))
    c[:, _index("mouthFunnel")] = speech * 0.4 * np.clip(np.sin(0.5 * phase + 1.0), 0.0, 1.0)
    c[:, _index("mouthPucker")] = speech * 0.3 * np.clip(np.sin(0.33 * phase + 2.0), 0.0, 1.0)
    # brows and gaze
    late = _window(t, d, s + 1.0, 0.3)
    c[:, _index("browInnerUp")] = 0.7 * late * (0.5 + 0.5 * np.sin(2 * np.pi * t / (0.15 * s)))
    for name in ("browOuterUpLeft", "browOuterUpRight"):
        c[:, _index(name)] = 0.5 * late * (0.5 + 0.5 * np.sin(2 * np.pi * t / (0.15 * s)))
    look = np.sin(2 * np.pi * (t - d) / (0.2 * s)) * late
    c[:, _index("eyeLookOutLeft")] = np.clip(look, 0, 1) * 0.6
    c[:, _index("eyeLookInRight")] = np.clip(look, 0, 1) * 0.6
    c[:, _index("eyeLookInLeft")] = np.clip(-look, 0, 1) * 0.6
    c[:, _index("eyeLookOutRight")] = np.clip(-look, 0, 1) * 0.6
    c = np.clip(c, 0.0, 1.0)
    # head motion: a turn each way, then nods; a little roll with the turns
    yaw = 35.0 * np.sin(np.pi * np.clip((t - a) / (b - a), 0, 1)) - 35.0 * np.sin(
        np.pi * np.clip((t - b) / (d - b), 0, 1)
    )
    pitch = 12.0 * np.sin(2 * np.pi * (t - d) / (0.1 * s)) * _window(t, d, s + 1.0, 0.2)
    roll = 0.1 * yaw
    c[:still_end] = c[0]
    angles = np.stack([yaw, pitch, roll], axis=1)
    angles[:still_end] = angles[0]
    return ClipTruth(float(fps), c, angles, (0, still_end))


def expressive_vertices(head: np.ndarray, coefficients: np.ndarray, model: ExpressionModel | None = None) -> np.ndarray:
    """``(T, V, 3)`` mm: the head's rest vertices ``(V, 3)`` plus the rig's expression offsets of
    ``coefficients (T, 52)``."""
    model = model or ExpressionModel(dtype=torch.float64)
    with torch.no_grad():
        offsets = model(torch.as_tensor(np.asarray(coefficients, np.float64))).numpy()
    return np.asarray(head, np.float64)[None] + offsets


def render_clip(
    folder: str | Path,
    truth: ClipTruth,
    *,
    head_index: int = 0,
    split: str = "heldout",
    seed: int = 0,
    width: int = 640,
    height: int = 480,
    spp: int = 8,
    frames: slice | None = None,
    asset: RigAsset | None = None,
    progress=None,
) -> dict:
    """Render the clip's frames into ``folder`` (``frame_00000.png`` ...) and its truth into
    ``folder/truth.npz`` (``coefficients``, ``angles_deg``, ``rotations``, ``translations``, ``focal``,
    ``head`` (V, 3) rest vertices, ``still``, ``fps``, ``frames``: the rendered indices); returns the same as a dict.

    Args:
        truth: :func:`clip_truth`'s. head_index, split: the population head. seed: the camera, light, albedo
            and background (one draw for the whole clip). width, height, spp: the frames.
        frames: only these frames (default all). progress: ``progress(done, total)``.
    """
    from PIL import Image

    from pipeline.synthetic.photos.settings import PhotoSettings
    from pipeline.synthetic.photos.simulate import simulate_photo
    from pipeline.synthetic.population import population_split

    asset = asset or load_asset()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    head = population_split(split, 0, asset=asset, first=head_index + 1).vertices[head_index]
    settings = PhotoSettings(
        width=width,
        height=height,
        spp=spp,
        offset_px=0.0,
        landmark_noise_px=0.0,
        margin_px=0.0,
        distance_mm_range=(650.0, 750.0),
        focal_factor_range=(1.2, 1.4),
    )
    indices = range(truth.frames)[frames or slice(None)]
    verts = expressive_vertices(head, truth.coefficients[list(indices)])
    rotations, translations, focal, albedo = [], [], None, None
    for n, (k, v) in enumerate(zip(indices, verts, strict=True)):
        yaw, pitch, roll = truth.angles_deg[k]
        photo = simulate_photo(
            v, seed, settings, asset, yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll, albedo=albedo, name=f"frame_{k}"
        )
        albedo = photo.albedo
        Image.fromarray(photo.image).save(folder / f"frame_{k:05d}.png")
        rotations.append(photo.rotation)
        translations.append(photo.translation)
        focal = photo.focal
        if progress is not None:
            progress(n + 1, len(indices))
    data = {
        "coefficients": truth.coefficients[list(indices)],
        "angles_deg": truth.angles_deg[list(indices)],
        "rotations": np.asarray(rotations),
        "translations": np.asarray(translations),
        "focal": float(focal),
        "head": np.asarray(head, np.float64),
        "still": np.asarray(truth.still),
        "fps": truth.fps,
        "frames": np.asarray(list(indices)),
    }
    np.savez_compressed(folder / "truth.npz", **data)
    (folder / "truth.json").write_text(
        json.dumps(
            {"fps": truth.fps, "focal": float(focal), "still": list(truth.still), "width": width, "height": height}
        )
        + "\n"
    )
    return data


__all__ = ["ClipTruth", "clip_truth", "expressive_vertices", "render_clip"]
