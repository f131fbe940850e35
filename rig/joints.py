"""JNR's 52-joint face rig (supplementary Table 1 of the paper), as data.

Every joint has a snake_case name, a parent, a bind position on the template head (millimetres, rig
space: right-handed, +Y up, +Z out of the face, +X towards the subject's left) and the transform
channels Table 1 gives it, with limits.

Units of the channels
---------------------
- ``rotate_x|y|z``: degrees, as in Table 1. Euler order: the local rotation is
  ``R = Rz @ Ry @ Rx`` acting on column vectors (rotate about x first).
- ``translate_x|y|z``: millimetres. Table 1's translation limits fit centimetres on a real head
  (``crown`` moves by up to 4, mouth corners by 0.2), so we read them as centimetres and store
  10x the table value in millimetres.
- ``scale`` (uniform) and ``scale_x|y|z``: factors, 1 = rest. Table 1 gives lower bounds of 0 (and -1
  for the cranium) that would collapse a region to a point or mirror it; every lower bound is raised
  to the floor ``SCALE_FLOOR`` = 0.5 and every upper bound to at least ``1 + SCALE_MIN_SPAN`` so a
  region can also grow. The flat parameter vector stores ``scale - 1`` so that the zero vector is the
  rest pose.

Where Table 1 is not symmetric but the anatomy is (its left orbital has ``rotate_y`` and its right
brow outer has one, a row shift in the table), we give both orbitals ``rotate_y`` and neither brow
outer one. Ranges that exclude the rest value (``nose_tip.translate_z``: [0.2, 1.1] cm) are widened
to include it, so the zero vector is always a legal pose.

Left/right pairs are independent channels (105 in Table 1, as JNR reports, and 2 added by issue 25: the
neck's ``translate_y`` and ``translate_z``, +-2 cm, chosen by fitting real-scan identities:
``docs/joints.md``; 107 in all); ``mirror_parameters`` maps a parameter vector to the one that gives the
mirrored mesh, and ``symmetric`` fitting ties the pairs (80 free variables).
"""

from __future__ import annotations

from dataclasses import dataclass

SCALE_FLOOR = 0.5
SCALE_MIN_SPAN = 0.1
CM_TO_MM = 10.0

ROTATE = ("rotate_x", "rotate_y", "rotate_z")
TRANSLATE = ("translate_x", "translate_y", "translate_z")
SCALE_AXES = ("scale_x", "scale_y", "scale_z")
UNIFORM_SCALE = "scale"
CHANNEL_KINDS = ROTATE + TRANSLATE + SCALE_AXES + (UNIFORM_SCALE,)


@dataclass(frozen=True)
class JointSpec:
    """One joint of the rig.

    Attributes:
        name: snake_case joint name (``left_eye_socket``).
        parent: parent joint name, ``None`` for the root.
        position: bind position, ``(x, y, z)`` in mm, rig space.
        channels: ``{channel: (low, high)}`` in the channel's own unit (deg, mm, factor).
        table_channels: the same limits as printed in Table 1 (deg, cm, factor), for the docs.
    """

    name: str
    parent: str | None
    position: tuple[float, float, float]
    channels: dict[str, tuple[float, float]]
    table_channels: dict[str, tuple[float, float]]


def _convert_limits(table: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
    out: dict[str, tuple[float, float]] = {}
    for channel, (lo, hi) in table.items():
        if channel.startswith("translate"):
            lo, hi = lo * CM_TO_MM, hi * CM_TO_MM
            lo, hi = min(lo, 0.0), max(hi, 0.0)
        elif channel.startswith("rotate"):
            lo, hi = min(lo, 0.0), max(hi, 0.0)
        else:  # scale factor
            lo, hi = max(lo, SCALE_FLOOR), max(hi, 1.0 + SCALE_MIN_SPAN)
            lo = min(lo, 1.0)
        out[channel] = (float(lo), float(hi))
    return out


# name, parent, bind position (mm), Table-1 channels (deg / cm / factor).
# Positions on the MakeHuman template (rig.template): eyeball centres (+-28.8, 5, 58), nasion (0, 10, 81),
# nose tip (0, -31, 99.5), lip corners (+-22.5, -62.8, 73.5), menton (0, -104, 60), crown (0, 111, -8),
# MakeHuman's jaw pivot (0, -36.2, 1.2), ear centroid (+-73, -12, -15); face towards +Z.
_S = "scale"
_TABLE: list[tuple[str, str | None, tuple[float, float, float], dict[str, tuple[float, float]]]] = [
    ("root", None, (0.0, -160.0, -30.0), {}),
    (
        "neck",
        "root",
        (0.0, -125.0, -25.0),
        {
            "rotate_x": (-15, 15),
            "rotate_y": (-2.4, 1),
            "rotate_z": (-15, 15),
            _S: (0, 1.5),
            "translate_y": (-2, 2),
            "translate_z": (-2, 2),
        },
    ),
    (
        "skull_root",
        "root",
        (0.0, -50.0, -20.0),
        {"rotate_x": (-25, 25), "rotate_y": (-15, 15), "rotate_z": (-15, 15), "scale_x": (0, 1.1)},
    ),
    ("cranium", "skull_root", (0.0, 55.0, -15.0), {"scale_x": (-1, 1), "scale_z": (-1, 1)}),
    ("crown", "cranium", (0.0, 105.0, -15.0), {"translate_y": (-4, 4)}),
    ("skull_center", "skull_root", (0.0, 10.0, 20.0), {}),
    ("brow_center", "skull_center", (0.0, 24.0, 82.0), {"translate_z": (-1, 1), "scale_y": (0, 1.5)}),
    (
        "left_orbital",
        "skull_center",
        (30.0, 8.0, 66.0),
        {"rotate_y": (-2, 2), "translate_x": (-1, 1), "translate_z": (-0.3, 0.3)},
    ),
    ("left_brow_outer", "left_orbital", (45.0, 25.0, 68.0), {"translate_z": (-1, 1), "scale_y": (0, 1.5)}),
    (
        "left_eye_socket",
        "left_orbital",
        (28.8, 5.0, 64.0),
        {"rotate_y": (-6.5, 9), "translate_x": (-1, 1), "translate_y": (-1, 1), _S: (0, 1.5)},
    ),
    ("left_upper_eyelid", "left_eye_socket", (28.8, 5.0, 58.0), {"rotate_x": (-6, 15)}),
    ("left_lower_eyelid", "left_eye_socket", (28.8, 5.0, 58.0), {"rotate_x": (-11, 4)}),
    ("left_cheek_bone", "left_orbital", (47.0, -15.0, 62.0), {"translate_y": (-1.7, 2)}),
    (
        "right_orbital",
        "skull_center",
        (-30.0, 8.0, 66.0),
        {"rotate_y": (-2, 2), "translate_x": (-1, 1), "translate_z": (-0.3, 0.3)},
    ),
    ("right_brow_outer", "right_orbital", (-45.0, 25.0, 68.0), {"translate_z": (-1, 1), "scale_y": (0, 1.5)}),
    (
        "right_eye_socket",
        "right_orbital",
        (-28.8, 5.0, 64.0),
        {"rotate_y": (-6.5, 9), "translate_x": (-1, 1), "translate_y": (-1, 1), _S: (0, 1.5)},
    ),
    ("right_upper_eyelid", "right_eye_socket", (-28.8, 5.0, 58.0), {"rotate_x": (-6, 15)}),
    ("right_lower_eyelid", "right_eye_socket", (-28.8, 5.0, 58.0), {"rotate_x": (-11, 4)}),
    ("right_cheek_bone", "right_orbital", (-47.0, -15.0, 62.0), {"translate_y": (-1.7, 2)}),
    (
        "nose_root_a",
        "skull_center",
        (0.0, 12.0, 80.0),
        {"translate_y": (-1, 1), "translate_z": (-1, 1), "scale_x": (0, 1.2)},
    ),
    ("nose_root_b", "nose_root_a", (0.0, 5.0, 82.0), {}),
    ("nose_bridge", "nose_root_b", (0.0, -5.0, 85.0), {"translate_y": (-0.5, 0.8)}),
    (
        "nose_ridge_a",
        "nose_bridge",
        (0.0, -15.0, 90.0),
        {"rotate_x": (-10, 8), "rotate_z": (-2, 2), "scale_y": (0, 1.5)},
    ),
    ("nose_ridge_b", "nose_ridge_a", (0.0, -26.0, 95.0), {"rotate_x": (-2, 2), "scale_y": (0, 1.5)}),
    ("ears", "skull_root", (0.0, -12.0, -15.0), {}),
    ("left_ear_position", "ears", (70.0, -12.0, -15.0), {"translate_x": (-1, 1), "translate_z": (-1.4, 1)}),
    ("left_ear_rotate_scale", "left_ear_position", (73.0, -12.0, -15.0), {"rotate_z": (-30, 15), _S: (0, 1.3)}),
    ("right_ear_position", "ears", (-70.0, -12.0, -15.0), {"translate_x": (-1, 1), "translate_z": (-1.4, 1)}),
    ("right_ear_rotate_scale", "right_ear_position", (-73.0, -12.0, -15.0), {"rotate_z": (-30, 15), _S: (0, 1.3)}),
    ("lower_face_root", "skull_root", (0.0, -40.0, 30.0), {}),
    (
        "jaw_root",
        "lower_face_root",
        (0.0, -36.2, 1.2),
        {"translate_y": (-1.3, 0.6), "translate_z": (-1.3, 0.6), "scale_x": (0, 1.1)},
    ),
    ("maxilla", "lower_face_root", (0.0, -45.0, 75.0), {"translate_y": (-0.5, 0.7), "translate_z": (-1, 1)}),
    (
        "nose_base_position",
        "maxilla",
        (0.0, -44.0, 86.0),
        {"translate_x": (-0.4, 0.4), "translate_z": (-0.6, 0.6), "scale_x": (0, 1.2)},
    ),
    ("nose_base_rotate", "nose_base_position", (0.0, -45.0, 88.0), {"rotate_x": (-8, 8)}),
    (
        "nose_tip",
        "nose_base_rotate",
        (0.0, -33.0, 96.0),
        {"translate_y": (-0.6, 0.6), "translate_z": (0.2, 1.1), _S: (0, 1.2)},
    ),
    ("nose_nostril", "nose_base_rotate", (0.0, -42.0, 90.0), {"rotate_x": (-8, 8), _S: (0, 1.2)}),
    (
        "mouth_center_top",
        "maxilla",
        (0.0, -58.0, 85.0),
        {"translate_y": (-1.3, 0.6), "translate_z": (-1.3, 0.6), "scale_x": (0, 1.2)},
    ),
    (
        "mouth_left_corner",
        "mouth_center_top",
        (22.0, -62.5, 72.0),
        {"translate_x": (-0.2, 0.2), "translate_y": (-0.2, 0.2)},
    ),
    (
        "mouth_right_corner",
        "mouth_center_top",
        (-22.0, -62.5, 72.0),
        {"translate_x": (-0.2, 0.2), "translate_y": (-0.2, 0.2)},
    ),
    (
        "jaw_front",
        "mouth_center_top",
        (0.0, -88.0, 76.0),
        {"rotate_z": (-0.9, 0.9), "translate_y": (-0.8, 0.5), "translate_z": (-0.5, 0.5), _S: (0, 1.5)},
    ),
    ("chin", "jaw_front", (0.0, -96.0, 76.0), {"translate_y": (-0.8, 0.5), "translate_z": (-0.5, 0.5), _S: (0, 1.5)}),
    ("top_lip", "jaw_front", (0.0, -57.0, 90.0), {"scale_y": (0, 1.4), "scale_z": (0, 2)}),
    ("mouth_center_bottom", "mouth_center_top", (0.0, -67.0, 85.0), {"translate_y": (-0.3, 0.8)}),
    ("bottom_lip", "mouth_center_bottom", (0.0, -69.0, 87.0), {"scale_y": (0, 1.4), "scale_z": (0, 1.5)}),
    ("left_cheek", "maxilla", (42.0, -38.0, 66.0), {"translate_y": (-1.7, 2), _S: (0, 1.5)}),
    ("right_cheek", "maxilla", (-42.0, -38.0, 66.0), {"translate_y": (-1.7, 2), _S: (0, 1.5)}),
    ("left_chin", "chin", (15.0, -98.0, 72.0), {"translate_x": (-0.2, 0.2), "translate_y": (-0.6, 0.6)}),
    ("right_chin", "chin", (-15.0, -98.0, 72.0), {"translate_x": (-0.2, 0.2), "translate_y": (-0.6, 0.6)}),
    ("left_jaw_root", "jaw_front", (50.0, -75.0, 15.0), {"translate_y": (-0.8, 0.8), "translate_z": (-0.5, 1.5)}),
    ("right_jaw_root", "jaw_front", (-50.0, -75.0, 15.0), {"translate_y": (-0.8, 0.8), "translate_z": (-0.5, 1.5)}),
    (
        "left_crown_outer",
        "crown",
        (45.0, 95.0, -20.0),
        {"translate_x": (-0.1, 0.1), "translate_y": (-0.1, 0.1), "translate_z": (-0.1, 0.1)},
    ),
    (
        "right_crown_outer",
        "crown",
        (-45.0, 95.0, -20.0),
        {"translate_x": (-0.1, 0.1), "translate_y": (-0.1, 0.1), "translate_z": (-0.1, 0.1)},
    ),
]

JOINTS: tuple[JointSpec, ...] = tuple(
    JointSpec(name, parent, position, _convert_limits(table), dict(table)) for name, parent, position, table in _TABLE
)
JOINT_NAMES: tuple[str, ...] = tuple(j.name for j in JOINTS)
JOINT_INDEX: dict[str, int] = {n: i for i, n in enumerate(JOINT_NAMES)}
PARENTS: tuple[int, ...] = tuple(-1 if j.parent is None else JOINT_INDEX[j.parent] for j in JOINTS)


def mirror_joint_name(name: str) -> str:
    """The name of the joint on the other side (``left_cheek`` <-> ``right_cheek``); midline joints map to
    themselves."""
    for a, b in (("left_", "right_"), ("right_", "left_")):
        if name.startswith(a):
            return b + name[len(a) :]
    if name == "mouth_left_corner":
        return "mouth_right_corner"
    if name == "mouth_right_corner":
        return "mouth_left_corner"
    return name


JOINT_MIRROR: tuple[int, ...] = tuple(JOINT_INDEX[mirror_joint_name(n)] for n in JOINT_NAMES)


ADDED_CHANNELS: dict[str, tuple[str, ...]] = {"neck": ("translate_y", "translate_z")}
"""Channels that are not in JNR's Table 1, added by issue 25 (``docs/joints.md``: the neck's place under the
head, where the real-scan identities differ most and Table 1's rig could not follow)."""


def _check_table() -> None:
    if len(JOINTS) != 52:
        raise RuntimeError(f"the JNR rig has 52 joints, the table lists {len(JOINTS)}")
    for i, p in enumerate(PARENTS):
        if p >= i:
            raise RuntimeError(f"joint {JOINT_NAMES[i]} is listed before its parent")
    for j in JOINTS:
        m = JOINTS[JOINT_INDEX[mirror_joint_name(j.name)]]
        if m.channels != j.channels or abs(m.position[0] + j.position[0]) > 1e-9:
            raise RuntimeError(f"joints {j.name} and {m.name} are not mirror images")


_check_table()


def joint_table_markdown() -> str:
    """Markdown table of the joints: name, parent, bind position, channels with our limits and Table 1's.

    ``docs/joints.md`` holds this table (a test keeps the two the same).
    """

    def fmt(x: float) -> str:
        return f"{x:g}"

    lines = [
        "| # | joint | parent | bind position (mm) | channel: limits (deg / mm / factor) "
        "| Table 1 (deg / cm / factor) |",
        "|---|---|---|---|---|---|",
    ]
    for i, j in enumerate(JOINTS):
        ours = "<br>".join(f"`{c}`: [{fmt(lo)}, {fmt(hi)}]" for c, (lo, hi) in j.channels.items()) or "-"
        added = ADDED_CHANNELS.get(j.name, ())
        table = "<br>".join(
            f"{c}: [{fmt(lo)}, {fmt(hi)}]" if c not in added else f"{c}: – (added, issue 25)"
            for c, (lo, hi) in j.table_channels.items()
        )
        table = table or "-"
        pos = ", ".join(fmt(p) for p in j.position)
        lines.append(f"| {i} | `{j.name}` | {j.parent or '-'} | ({pos}) | {ours} | {table} |")
    return "\n".join(lines) + "\n"
