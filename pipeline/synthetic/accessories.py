"""The two example accessories jnr ships, generated from the template by code: glasses and a cap.

Both are closed triangle meshes in rig space (mm, +Y up, +Z out of the face, +X the subject's left),
placed on the template in its bind pose, mirror-symmetric (to 0.01 mm), and clear of the outer skin
(:data:`rig.accessory.OUTER_SKIN_REGIONS`) by at least :data:`MIN_CLEARANCE_MM` at every vertex:

* **glasses** (:func:`glasses_mesh`): two rounded rims (superellipses) in front of the eyes with a
  pantoscopic tilt and a wrap, a bridge over the nose, and temples that run back along the side of the
  head above the ears and drop behind them; every part a closed tube (capped at open ends) swept along
  its path with parallel-transport frames (:func:`tube_mesh`). Rims, bridge and temple paths are fitted
  to the skin by ray casting and closest points (the rims moved forward until they clear the brows and
  the nose; the temples hug the skull at a fixed gap).
* **cap** (:func:`cap_mesh`): a crown shell over the scalp (inner surface 3 mm, outer 6 mm off the skin
  along its normals, joined at the edge), bounded by a plane tilted from the forehead (front edge
  50 mm above the eyes' level) to the occiput, and a brim in front.

``python -m pipeline.synthetic.accessories [--out FOLDER]`` regenerates the committed OBJ files in
``pipeline/assets/accessories/`` (:func:`write_example_accessories`); a test checks that the regenerated
meshes equal them.

The glasses are made here and the cap in :mod:`pipeline.synthetic.accessory_cap`, both from the tubes and
skin measurements of :mod:`pipeline.synthetic.accessory_parts`; :func:`cap_mesh`, :func:`tube_mesh` and
:data:`MIN_CLEARANCE_MM` are re-exported here.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from pipeline.synthetic.accessory_cap import cap_mesh
from pipeline.synthetic.accessory_parts import (
    MIN_CLEARANCE_MM,
    _check_clear,
    _combine,
    _first_hits,
    _landmarks,
    _mirror,
    _push_out,
    _resample,
    _skin,
    _smooth_path,
    tube_mesh,
)
from rig.accessory import signed_distance
from rig.io.atomic import write_bytes_atomic
from rig.io.mesh import RIG_SPACE_COMMENT

__all__ = [
    "ACCESSORY_DIGITS",
    "EXAMPLES",
    "MIN_CLEARANCE_MM",
    "cap_mesh",
    "glasses_mesh",
    "obj_text",
    "tube_mesh",
    "write_example_accessories",
]

ACCESSORY_DIGITS = 4
"""Decimal places of the committed OBJ files (0.1 micrometre)."""


# ----------------------------------------------------------------------------------------------------
# Glasses
# ----------------------------------------------------------------------------------------------------

_RIM_FROM_EYE = (4.2, -2.0)  # the left rim's centre (x, y) from the left eyeball's centre: outward, down, mm
_RIM_START_DEPTH = 22.0  # the rims' first depth in front of the eyeballs' centres (then moved forward), mm
_RIM_AXES = (21.0, 15.0)  # half width, half height, mm
_RIM_EXPONENT = 2.6  # superellipse exponent (2: an ellipse; larger: squarer)
_RIM_SAMPLES = 48
_RIM_RADIUS, _BRIDGE_RADIUS, _TEMPLE_RADIUS = 1.6, 1.4, 1.3
_GAP_MM = 1.5  # skin to tube surface where a part hugs the head
_TILT, _WRAP = 0.15, 0.12  # dz/dy (pantoscopic tilt: the bottom nearer the cheeks), dz/d|x| (face form)


# The temple's centre line in the (z, y) plane, as offsets from the left ear's back (z) and top (y), mm: forward
# of the ear, 3-4 mm above it, then down 6-14 mm behind it (on the MakeHuman head, ear back z = -40.5 and top
# y = 25.4, these were the knots (45, 22), (20, 28.5), (-10, 29.5), (-38, 28.5), (-47, 20), (-52, 6), (-54, -4)).
_TEMPLE_FROM_EAR = ((85.5, -3.4), (60.5, 3.1), (30.5, 4.1), (2.5, 3.1), (-6.5, -5.4), (-11.5, -19.4), (-13.5, -29.4))


def _rim_path(centre: tuple[float, float], z0: float) -> np.ndarray:
    """The left rim's centre line ``(M, 3)``: a superellipse around ``centre`` (x, y) in a tilted, wrapped
    plane at depth ``z0``."""
    t = 2.0 * np.pi * np.arange(_RIM_SAMPLES) / _RIM_SAMPLES
    e = 2.0 / _RIM_EXPONENT
    x = centre[0] + _RIM_AXES[0] * np.sign(np.cos(t)) * np.abs(np.cos(t)) ** e
    y = centre[1] + _RIM_AXES[1] * np.sign(np.sin(t)) * np.abs(np.sin(t)) ** e
    z = z0 + _TILT * (y - centre[1]) - _WRAP * (x - (centre[0] - _RIM_AXES[0]))
    return np.stack([x, y, z], 1)


def _rim_at(path: np.ndarray, angle_deg: float) -> np.ndarray:
    """The rim's centre-line point nearest the direction ``angle_deg`` (0: outward +X, 90: up)."""
    centre = path.mean(0)
    a = np.arctan2(path[:, 1] - centre[1], path[:, 0] - centre[0])
    return path[np.argmin(np.abs(np.angle(np.exp(1j * (a - math.radians(angle_deg))))))]


def glasses_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The example glasses on the template: ``vertices (N, 3)`` mm and ``faces (F, 3)`` (closed tubes:
    two rims, a bridge, two temples), mirror-symmetric, clear of the skin."""
    skin_v, skin_f = _skin()
    marks = _landmarks()
    centre = (marks.eye[0] + _RIM_FROM_EYE[0], marks.eye[1] + _RIM_FROM_EYE[1])
    # Rims: forward until every centre-line point clears the skin by radius + gap.
    z0 = marks.eye[2] + _RIM_START_DEPTH
    for _ in range(20):
        low = float(signed_distance(_rim_path(centre, z0), skin_v, skin_f).min())
        if low >= _RIM_RADIUS + _GAP_MM:
            break
        z0 += _RIM_RADIUS + _GAP_MM - low + 0.1
    rim = _rim_path(centre, z0)
    # Bridge: from the left rim's upper inner side over the nose to its mirror image, a gap above the skin.
    start = _rim_at(rim, 150.0)
    mid_y = start[1] + 1.0
    mid_z = skin_v[:, 2][(np.abs(skin_v[:, 0]) < 3) & (np.abs(skin_v[:, 1] - mid_y) < 3)].max()
    end = start * np.array([-1.0, 1.0, 1.0])
    control = np.array([0.0, mid_y + 2.0, mid_z + _BRIDGE_RADIUS + _GAP_MM])
    t = np.linspace(0.0, 1.0, 25)[:, None]
    bridge = (1 - t) ** 2 * start + 2 * t * (1 - t) * control + t**2 * end
    bridge = _push_out(bridge, _BRIDGE_RADIUS + _GAP_MM, skin_v, skin_f)
    bridge = _smooth_path(bridge, 4)
    bridge = 0.5 * (bridge + bridge[::-1] * np.array([-1.0, 1.0, 1.0]))  # exactly symmetric
    # Temple: from the hinge on the rim's outer side back along the head above the ear, then down behind it.
    hinge = _rim_at(rim, 20.0) + np.array([_RIM_RADIUS, 0.0, -_RIM_RADIUS])
    ear = np.array([marks.ear_back, marks.ear_top])
    knots_zy = np.concatenate([[[hinge[2], hinge[1]]], ear + np.array(_TEMPLE_FROM_EAR)])
    z = np.linspace(knots_zy[0, 0], knots_zy[-1, 0], 80)
    y = np.interp(-z, -knots_zy[:, 0], knots_zy[:, 1])
    origins = np.stack([np.zeros_like(z), y, z], 1)
    side = _first_hits(origins, np.tile([1.0, 0.0, 0.0], (len(z), 1)), skin_v, skin_f)
    x = np.maximum(side + _TEMPLE_RADIUS + _GAP_MM, hinge[0])
    temple = np.concatenate([hinge[None], np.stack([x, y, z], 1)[1:]])
    temple = _smooth_path(_resample(temple, 2.5), 6)
    temple = _push_out(temple, _TEMPLE_RADIUS + _GAP_MM, skin_v, skin_f)
    temple = _smooth_path(temple, 2)
    left = _combine([tube_mesh(rim, _RIM_RADIUS, closed=True), tube_mesh(temple, _TEMPLE_RADIUS)])
    vertices, faces = _combine([left, _mirror(*left), tube_mesh(bridge, _BRIDGE_RADIUS)])
    _check_clear("glasses", vertices, skin_v, skin_f)
    return vertices, faces


# ----------------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------------

EXAMPLES = {"glasses": glasses_mesh, "cap": cap_mesh}
"""The shipped example accessories by name, and the functions that make them."""


def obj_text(vertices: np.ndarray, faces: np.ndarray, header: list[str] | tuple[str, ...] = (), digits: int = 6) -> str:
    """Wavefront OBJ text of a triangle mesh: ``# header`` lines, ``v x y z`` (fixed-point, ``digits``
    decimals; ``-0`` written as ``0``), ``f a b c`` (1-based)."""
    v = np.round(np.asarray(vertices, float), digits) + 0.0  # + 0.0: no "-0.0000"
    fmt = f"{{:.{digits}f}}"
    lines = [f"# {h}" for h in header]
    lines += ["v " + " ".join(fmt.format(c) for c in row) for row in v]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces)]
    return "\n".join(lines) + "\n"


def example_obj_text(name: str) -> str:
    """The OBJ text of a shipped example (``glasses`` or ``cap``), as committed."""
    vertices, faces = EXAMPLES[name]()
    header = [
        f"jnr: {RIG_SPACE_COMMENT}",
        f"jnr example accessory {name!r} on the jnr template, made by pipeline/synthetic/accessories.py",
        f"{len(vertices)} vertices, {len(faces)} triangles; closed parts, faces outward",
    ]
    return obj_text(vertices, faces, header, ACCESSORY_DIGITS)


def write_example_accessories(folder: str | Path) -> list[Path]:
    """Write ``glasses.obj`` and ``cap.obj`` into ``folder`` (created if missing), each atomically."""
    folder = Path(folder)
    paths = []
    for name in EXAMPLES:
        path = folder / f"{name}.obj"
        write_bytes_atomic(path, example_obj_text(name).encode(), make_parents=True)
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> None:
    """``python -m pipeline.synthetic.accessories [--out FOLDER]``: regenerate the shipped examples."""
    parser = argparse.ArgumentParser(description="Regenerate jnr's example accessories (glasses, cap).")
    parser.add_argument(
        "--out",
        default=str(Path(__file__).resolve().parents[1] / "assets" / "accessories"),
        help="folder (default: pipeline/assets/accessories)",
    )
    args = parser.parse_args(argv)
    for path in write_example_accessories(args.out):
        print(path)


if __name__ == "__main__":
    main()
