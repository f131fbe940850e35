import hashlib

import pytest
import torch

from rig.joints import JOINT_MIRROR, JOINT_NAMES, JOINTS, PARENTS, SCALE_FLOOR
from rig.parameters import (
    CHANNELS,
    NUM_PARAMETERS,
    ParameterError,
    mirror_theta,
    params_to_theta,
    symmetric_groups,
    theta_limits,
)


def test_joint_table_golden_order():
    assert len(JOINTS) == 52
    assert JOINT_NAMES[0] == "root" and JOINT_NAMES[-1] == "right_crown_outer"
    digest = hashlib.sha256(",".join(JOINT_NAMES).encode()).hexdigest()[:16]
    # Pinned: changing the joint order breaks saved parameter files and assets.
    assert digest == GOLDEN_DIGEST, digest


GOLDEN_DIGEST = hashlib.sha256(
    ",".join(
        [
            "root",
            "neck",
            "skull_root",
            "cranium",
            "crown",
            "skull_center",
            "brow_center",
            "left_orbital",
            "left_brow_outer",
            "left_eye_socket",
            "left_upper_eyelid",
            "left_lower_eyelid",
            "left_cheek_bone",
            "right_orbital",
            "right_brow_outer",
            "right_eye_socket",
            "right_upper_eyelid",
            "right_lower_eyelid",
            "right_cheek_bone",
            "nose_root_a",
            "nose_root_b",
            "nose_bridge",
            "nose_ridge_a",
            "nose_ridge_b",
            "ears",
            "left_ear_position",
            "left_ear_rotate_scale",
            "right_ear_position",
            "right_ear_rotate_scale",
            "lower_face_root",
            "jaw_root",
            "maxilla",
            "nose_base_position",
            "nose_base_rotate",
            "nose_tip",
            "nose_nostril",
            "mouth_center_top",
            "mouth_left_corner",
            "mouth_right_corner",
            "jaw_front",
            "chin",
            "top_lip",
            "mouth_center_bottom",
            "bottom_lip",
            "left_cheek",
            "right_cheek",
            "left_chin",
            "right_chin",
            "left_jaw_root",
            "right_jaw_root",
            "left_crown_outer",
            "right_crown_outer",
        ]
    ).encode()
).hexdigest()[:16]


def test_parents_match_table_1():
    parent = {j.name: j.parent for j in JOINTS}
    assert parent["nose_tip"] == "nose_base_rotate"
    assert parent["top_lip"] == "jaw_front"
    assert parent["left_upper_eyelid"] == "left_eye_socket"
    assert parent["chin"] == "jaw_front"
    assert all(p < i for i, p in enumerate(PARENTS))
    assert sum(p < 0 for p in PARENTS) == 1


def test_mirror_is_an_involution_and_pairs_left_right():
    assert all(JOINT_MIRROR[JOINT_MIRROR[k]] == k for k in range(52))
    assert JOINT_NAMES[JOINT_MIRROR[JOINT_NAMES.index("left_cheek")]] == "right_cheek"
    assert JOINT_NAMES[JOINT_MIRROR[JOINT_NAMES.index("mouth_left_corner")]] == "mouth_right_corner"
    for k, j in enumerate(JOINTS):
        assert JOINTS[JOINT_MIRROR[k]].position[0] == pytest.approx(-j.position[0])


def test_parameter_counts():
    from rig.joints import ADDED_CHANNELS

    added = sum(len(c) for c in ADDED_CHANNELS.values())
    assert NUM_PARAMETERS - added == 105  # JNR's Table 1: 105
    assert added == 2  # issue 25: the neck's translate_y and translate_z (docs/joints.md)
    assert len(symmetric_groups()) == 80  # 78 + the two midline neck channels


def test_limits_contain_rest_and_respect_units():
    low, high = theta_limits(torch.float64)
    assert torch.all(low <= 0) and torch.all(high >= 0)
    for c in CHANNELS:
        if c.is_scale:
            assert c.low >= SCALE_FLOOR and c.high > 1.0
    crown = CHANNELS[[c.name for c in CHANNELS].index("crown.translate_y")]
    assert (crown.low, crown.high) == (-40.0, 40.0)  # Table 1: [-4, 4] cm
    assert CHANNELS[[c.name for c in CHANNELS].index("neck.rotate_x")].high == 15.0


def test_unknown_name_and_out_of_limits_are_errors():
    with pytest.raises(ParameterError, match="unknown rig parameter 'nose_tip.rotate_q'"):
        params_to_theta({"nose_tip.rotate_q": 1.0})
    with pytest.raises(ParameterError, match="outside its limits"):
        params_to_theta({"crown.translate_y": 45.0})
    with pytest.raises(ParameterError, match="finite"):
        params_to_theta({"crown.translate_y": float("nan")})
    with pytest.warns(UserWarning, match="clamped"):
        theta = params_to_theta({"crown.translate_y": 45.0}, clamp=True)
    assert theta[[c.name for c in CHANNELS].index("crown.translate_y")] == 40.0


def test_mirror_theta_involution():
    g = torch.Generator().manual_seed(0)
    theta = torch.randn(3, NUM_PARAMETERS, generator=g, dtype=torch.float64)
    assert torch.equal(mirror_theta(mirror_theta(theta)), theta)
