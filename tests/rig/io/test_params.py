"""The parameter JSON file (rig/io/params.py)."""

import json
import os

import pytest
import torch

from rig.io.params import PARAMS_UNITS, load_params_json, save_params_json
from rig.parameters import CHANNELS, ParameterError, params_to_theta, theta_to_params


def test_named_parameters_round_trip(tmp_path):
    theta = params_to_theta({"nose_tip.translate_y": 2.5, "neck.scale": 1.2, "left_ear_rotate_scale.rotate_z": -10})
    assert theta[[c.name for c in CHANNELS].index("neck.scale")] == pytest.approx(0.2)
    path = tmp_path / "p.json"
    save_params_json(theta, path)
    back = load_params_json(path)
    assert torch.allclose(back, theta)
    assert theta_to_params(theta)["neck.scale"] == pytest.approx(1.2)


def test_saved_file_holds_units_and_the_moved_channels_only(tmp_path):
    theta = params_to_theta({"nose_tip.translate_y": 2.5})
    path = tmp_path / "p.json"
    save_params_json(theta, path)
    data = json.loads(path.read_text())
    assert data == {"units": PARAMS_UNITS, "joints": {"nose_tip.translate_y": 2.5}}
    save_params_json(theta, path, include_rest=True)  # replaces the file
    assert len(json.loads(path.read_text())["joints"]) == len(CHANNELS)
    assert [p.name for p in tmp_path.iterdir()] == ["p.json"]  # no temporary left
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask


def test_joints_object_or_plain_object(tmp_path):
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"neck.scale": 1.1}))
    plain = load_params_json(path)
    path.write_text(json.dumps({"joints": {"neck.scale": 1.1}}))
    assert torch.equal(load_params_json(path), plain)
    assert theta_to_params(plain)["neck.scale"] == pytest.approx(1.1)


def test_bad_parameter_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_params_json(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ParameterError, match="not valid JSON"):
        load_params_json(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(ParameterError, match="JSON object"):
        load_params_json(bad)


def test_units_other_than_the_rigs_are_refused(tmp_path):
    """Issue 38: a file stating ``translate: cm`` was read as millimetres (exit 0); the rig's own units and
    files without a units entry still read, other keys of the entry (a fit's pixel convention) are the file's."""
    path = tmp_path / "p.json"
    joints = {"nose_tip.translate_y": 2.5}
    path.write_text(json.dumps({"units": {**PARAMS_UNITS, "pixels": "OpenCV, 0-based"}, "joints": joints}))
    assert load_params_json(path).abs().sum() > 0
    for units, message in [
        ({"rotate": "deg", "translate": "cm", "scale": "factor"}, r"units \{'translate': 'cm'\} are not the rig's"),
        ({"rotate": "rad"}, r"units \{'rotate': 'rad'\}"),
        ("mm", "'units' must be an object"),
    ]:
        path.write_text(json.dumps({"units": units, "joints": joints}))
        with pytest.raises(ParameterError, match=message):
            load_params_json(path)


def test_a_key_twice_and_a_device_are_named_for_what_they_are(tmp_path):
    """Issue 38: a duplicate key was accepted silently (the last value won); a link to /dev/zero was reported
    as a missing file."""
    path = tmp_path / "p.json"
    path.write_text('{"joints": {"neck.scale": 1.2, "neck.scale": 0.8}}')
    with pytest.raises(ParameterError, match="'neck.scale' appears twice"):
        load_params_json(path)
    link = tmp_path / "zero.json"
    os.symlink("/dev/zero", link)
    with pytest.raises(ParameterError, match="not a regular file|device"):
        load_params_json(link)
