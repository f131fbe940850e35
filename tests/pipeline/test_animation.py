"""jnr animate / jnr retarget: curves files, the animated glTF against the rig, retargeted expressions."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from pipeline.animation import (
    EXAMPLE_CURVES,
    HEAD_JOINT,
    Curves,
    CurvesError,
    example_curves,
    head_rotation_matrices,
    load_fit_head,
    posed_frames,
    read_curves,
    write_curves,
)
from pipeline.cli import main
from rig.expressions import EXPRESSION_NAMES, expression_limits
from rig.model import JointRig
from rig.parameters import random_theta, theta_to_params
from tests.pipeline.conftest import rig_head_vertices
from tests.support.gltf_reader import read_skinned_gltf


def _fit_folder(root, seed: int, expressions: dict | None = None):
    """A fit folder as jnr fit / fit-scan leave it, as far as animate and retarget read it: params.json of a
    random identity (joints, latent Z) and expression."""
    generator = torch.Generator().manual_seed(seed)
    theta = random_theta(generator, 1, spread=0.5)[0].double()
    z = torch.randn(50, generator=generator, dtype=torch.float64) * 0.5
    params = {
        "joints": theta_to_params(theta),
        "latent_z": z.tolist(),
        "expressions": expressions if expressions is not None else {"mouthSmileLeft": 0.3},
    }
    folder = root / f"fit{seed}"
    folder.mkdir()
    (folder / "params.json").write_text(json.dumps(params))
    return folder


# ----------------------------------------------------------------------------------------------
# curves files
# ----------------------------------------------------------------------------------------------


def test_shipped_example_is_what_the_code_makes():
    """The committed example equals example_curves() (regenerate: write_curves(EXAMPLE_CURVES, example_curves()))."""
    shipped, made = read_curves(EXAMPLE_CURVES), example_curves()
    np.testing.assert_array_equal(shipped.times, made.times)
    np.testing.assert_array_equal(shipped.coefficients, made.coefficients)
    np.testing.assert_array_equal(shipped.head_rotation, made.head_rotation)
    index = EXPRESSION_NAMES.index
    # a blink (both eyes closed at 0.45 s) and a smile (peak at 1.5 s) that are over by the end
    at = lambda t: int(np.argmin(np.abs(made.times - t)))  # noqa: E731
    assert made.coefficients[at(0.45), index("eyeBlinkLeft")] > 0.9
    assert made.coefficients[at(1.5), index("mouthSmileRight")] > 0.85
    assert np.abs(made.coefficients[-1]).max() == 0.0


def test_live_link_face_layout_round_trip(tmp_path):
    """Live Link Face's layout (Timecode at 60 fps, BlendShapeCount, capitalised names, head angles in radians,
    eye angles) reads back to the same curves."""
    curves = example_curves()
    path = tmp_path / "take.csv"
    write_curves(path, curves, layout="live-link-face")
    header = path.read_text().splitlines()[0].split(",")
    assert header[:3] == ["Timecode", "BlendShapeCount", "EyeBlinkLeft"] and header[-1] == "RightEyeRoll"
    assert len(header) == 2 + 52 + 9
    back = read_curves(path)
    assert back.layout == "live-link-face"
    np.testing.assert_allclose(back.times, curves.times, atol=1e-9)
    np.testing.assert_allclose(back.coefficients, curves.coefficients, atol=1e-6)
    np.testing.assert_allclose(back.head_rotation, curves.head_rotation, atol=1e-4)  # degrees via radians
    # read at a lower rate than recorded: the frame numbers give it away
    with pytest.raises(CurvesError, match="--fps"):
        read_curves(path, fps=30.0)


def test_plain_layout_subset_frames_and_units(tmp_path):
    path = tmp_path / "plain.csv"
    path.write_text("JAWOPEN,eyeBlinkLeft,head_yaw\n0,0,0\n0.5,1,10\n1,0.25,20\n")
    curves = read_curves(path, fps=10.0)
    np.testing.assert_allclose(curves.times, [0.0, 0.1, 0.2])
    np.testing.assert_allclose(curves.coefficients[:, EXPRESSION_NAMES.index("jawOpen")], [0, 0.5, 1])
    assert np.count_nonzero(curves.coefficients) == 4  # the other 50 shapes stay 0
    np.testing.assert_allclose(curves.head_rotation[:, 0], [0, 10, 20])  # degrees in a plain file
    np.testing.assert_allclose(read_curves(path, head_units="rad").head_rotation[2, 0], np.degrees(20.0))


@pytest.mark.parametrize(
    "text, match",
    [
        ("jawOpen,smileyness\n0,0\n", "unknown column"),
        ("time,jawOpen\n0,0\n0,0.5\n", "increase"),
        ("jawOpen\nnan\n", "finite"),
        ("jawOpen\nabc\n", "not a number"),
        ("jawOpen\n", "no rows"),
        ("time\n0\n", "no ARKit"),
        ("jawOpen,eyeBlinkLeft\n0\n", "cells"),
    ],
)
def test_bad_curves_are_refused(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(CurvesError, match=match):
        read_curves(path)


def test_out_of_range_coefficients_are_clamped_with_a_warning(tmp_path):
    path = tmp_path / "loud.csv"
    path.write_text("jawOpen\n1.4\n-0.2\n")
    with pytest.warns(UserWarning, match="clamped"):
        curves = read_curves(path)
    np.testing.assert_allclose(curves.coefficients[:, EXPRESSION_NAMES.index("jawOpen")], [1.0, 0.0])


# ----------------------------------------------------------------------------------------------
# the animated head
# ----------------------------------------------------------------------------------------------


def test_animated_head_is_the_rig_at_every_keyframe(tmp_path):
    """Without head angles each keyframe's head is the fit's parameters with that row's expressions, as the rig
    itself poses it (rig_head_vertices: the rig forward pass with the fit's neural weights)."""
    head = load_fit_head(_fit_folder(tmp_path, 3))
    curves = example_curves()
    rows = [0, 13, 45]
    taus = np.repeat(head.tau[None], len(rows), axis=0)
    frames = posed_frames(head, curves.coefficients[rows], taus)
    for k, row in enumerate(rows):
        params = dict(
            head.fit.data,
            expressions={n: float(c) for n, c in zip(EXPRESSION_NAMES, curves.coefficients[row]) if c != 0.0},
        )
        np.testing.assert_allclose(frames[k], rig_head_vertices(params, rig=JointRig(dtype=torch.float64)), atol=1e-6)
    assert np.abs(frames[1] - frames[0]).max() > 1.0  # the blink row moves the eyelids


def test_head_angles_turn_the_skull_about_its_joint(tmp_path):
    """A yaw/pitch/roll turns every vertex skinned only below skull_root rigidly about skull_root's posed
    position, by the rotation conjugated into the world frame; vertices skinned only above it stay."""
    from pipeline.animation import curve_keyframes
    from rig.joints import JOINT_INDEX, JOINTS
    from rig.lbs import joint_world_transforms

    head = load_fit_head(_fit_folder(tmp_path, 4, expressions={}))
    angles = np.array([[0.0, 0.0, 0.0], [20.0, -10.0, 5.0]])
    curves = Curves(np.array([0.0, 1.0]), np.zeros((2, 52)), angles)
    animation = curve_keyframes(head, curves)
    frames = posed_frames(head, curves.coefficients, animation.joint_transforms)

    rig = JointRig(dtype=torch.float64)
    j = JOINT_INDEX[HEAD_JOINT]
    below = np.zeros(len(JOINTS), bool)
    for k in range(len(JOINTS)):  # skull_root and its descendants (parents come first)
        below[k] = k == j or (rig.parents[k] >= 0 and below[int(rig.parents[k])])
    world, _ = joint_world_transforms(torch.as_tensor(head.tau[None]), rig.bind_positions, rig.parents, rig.levels)
    parent = world[0, int(rig.parents[j])].numpy()
    frame = parent.copy()
    frame[:3, 3] = (
        parent[:3, :3] @ (rig.bind_positions[j] - rig.bind_positions[int(rig.parents[j])]).numpy() + parent[:3, 3]
    )
    turn = np.eye(4)
    turn[:3, :3] = head_rotation_matrices(angles[1:])[0]
    expected_move = frame @ turn @ np.linalg.inv(frame)

    only_below = head.weights[:, ~below].sum(axis=1) < 1e-9
    only_above = head.weights[:, below].sum(axis=1) < 1e-9
    assert only_below.sum() > 500 and only_above.sum() > 50
    moved = (np.column_stack([frames[0], np.ones(len(frames[0]))]) @ expected_move.T)[:, :3]
    np.testing.assert_allclose(frames[1][only_below], moved[only_below], atol=1e-6)
    np.testing.assert_allclose(frames[1][only_above], frames[0][only_above], atol=1e-9)
    assert np.linalg.norm(frames[1] - frames[0], axis=1).max() > 30.0  # a 20 deg turn moves the nose a lot


def test_jnr_animate_writes_an_animated_gltf_and_a_preview(tmp_path, capsys):
    fit = _fit_folder(tmp_path, 5)
    out = tmp_path / "smile.glb"
    assert main(["animate", str(fit), "example", "--out", str(out), "--preview-fps", "2", "--quiet"]) == 0
    assert "73 keyframes" in capsys.readouterr().out
    gltf = read_skinned_gltf(out)
    assert gltf["morph_names"] == list(EXPRESSION_NAMES) and gltf["morph_targets"].shape[0] == 52
    (animation,) = gltf["animations"]
    channels = {(c["node"], c["path"]): c for c in animation["channels"]}
    assert set(channels) == {("mesh", "weights"), (HEAD_JOINT, "rotation")}
    curves = example_curves()
    weights = channels[("mesh", "weights")]
    assert len(weights["times"]) == 73
    np.testing.assert_allclose(weights["times"], curves.times, atol=1e-6)
    np.testing.assert_allclose(weights["values"], curves.coefficients, atol=1e-6)
    # the rotation keys are the turn composed with the fitted skull_root rotation
    from scipy.spatial.transform import Rotation

    head = load_fit_head(fit)
    j = list(gltf["joint_names"]).index(HEAD_JOINT)
    fitted = head.tau[j, :3, :3] / np.linalg.norm(head.tau[j, :3, :3], axis=0)
    keys = Rotation.from_quat(channels[(HEAD_JOINT, "rotation")]["values"]).as_matrix()
    np.testing.assert_allclose(keys, head_rotation_matrices(curves.head_rotation) @ fitted, atol=1e-5)

    from PIL import Image

    gif = Image.open(tmp_path / "smile.gif")
    assert gif.format == "GIF" and gif.n_frames >= 4 and gif.size == (240, 300)
    # outputs are not replaced without --force
    assert main(["animate", str(fit), "example", "--out", str(out), "--quiet"]) == 2
    assert "exists" in capsys.readouterr().err


def test_jnr_animate_bad_input_is_one_line(tmp_path, capsys):
    fit = _fit_folder(tmp_path, 6)
    bad = tmp_path / "bad.csv"
    bad.write_text("jawOpen,wink\n0,1\n")
    asm = tmp_path / "asm"
    asm.mkdir()
    (asm / "params.json").write_text(json.dumps({"skinning": "asm", "expressions": {}}))
    cases = [
        ([str(fit), str(bad), "--out", str(tmp_path / "a.glb")], "unknown column"),
        ([str(tmp_path / "nofit"), "example", "--out", str(tmp_path / "b.glb")], "not a fit folder"),
        ([str(asm), "example", "--out", str(tmp_path / "c.glb")], "ASM fit"),
        ([str(fit), "example", "--out", str(tmp_path / "d.obj")], ".glb or .gltf"),
        ([str(fit), "example", "--out", str(tmp_path / "e.glb"), "--fps", "0"], "--fps must be"),  # not "unset"
        ([str(fit), "example", "--out", str(tmp_path / "f.glb"), "--fps", "-30"], "--fps must be"),
    ]
    for k, (args, message) in enumerate(cases):
        if k == 0:  # once as a user runs it: a separate process, one line on stderr, no traceback
            run = subprocess.run(
                [sys.executable, "-m", "pipeline.cli", "animate", *args, "--no-preview"], capture_output=True, text=True
            )
            code, err = run.returncode, run.stderr
        else:
            code, err = main(["animate", *args, "--no-preview"]), capsys.readouterr().err
        assert code == 2, err
        assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["asm", "bad.csv", "fit6"]  # nothing half-written


# ----------------------------------------------------------------------------------------------
# retargeting
# ----------------------------------------------------------------------------------------------


def test_jnr_retarget_puts_the_source_expression_on_the_target(tmp_path):
    smile = {"mouthSmileLeft": 0.8, "mouthSmileRight": 0.7, "jawOpen": 0.4, "browInnerUp": 0.5}
    source = _fit_folder(tmp_path, 7, expressions=smile)
    target = _fit_folder(tmp_path, 8, expressions={"eyeBlinkLeft": 1.0})
    out = tmp_path / "retargeted"
    assert main(["retarget", str(source), str(target), "--out", str(out)]) == 0
    params = json.loads((out / "params.json").read_text())
    target_params = json.loads((target / "params.json").read_text())
    assert params["expressions"] == smile  # the source's coefficients, exactly
    assert params["joints"] == target_params["joints"] and params["latent_z"] == target_params["latent_z"]
    expected = rig_head_vertices(dict(target_params, expressions=smile), rig=JointRig(dtype=torch.float64))
    import trimesh

    ply = trimesh.load(out / "mesh.ply", process=False)
    np.testing.assert_allclose(np.asarray(ply.vertices), expected, atol=1e-3)  # float32 PLY
    glb = read_skinned_gltf(out / "mesh.glb")  # the expressive head is its bind mesh, the expression recorded
    baked = np.asarray(glb["extras"]["bakedMorphWeights"])
    np.testing.assert_allclose(baked[[EXPRESSION_NAMES.index(n) for n in smile]], list(smile.values()))
    assert np.count_nonzero(baked) == len(smile) and not np.any(glb["morph_weights"])
    np.testing.assert_allclose(glb["vertices"], expected, atol=1e-3)
    # the expression really moved the target's head, and only the expression did
    unchanged = rig_head_vertices(dict(target_params, expressions={}))
    assert np.linalg.norm(expected - unchanged, axis=1).max() > 3.0
    report = json.loads((out / "report.json").read_text())
    assert report["max_vertex_change_mm"] == pytest.approx(
        np.linalg.norm(expected - rig_head_vertices(target_params, rig=JointRig(dtype=torch.float64)), axis=1).max(),
        abs=1e-6,
    )
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == sorted(
        ["mesh.obj", "mesh.ply", "mesh.glb", "params.json", "expressions.csv", "preview.png", "report.json"]
    )
    # the retargeted params.json is itself a fit: it animates, and retargets again to the same head
    again = tmp_path / "again"
    assert main(["retarget", str(out), str(out), "--out", str(again)]) == 0
    np.testing.assert_allclose(
        np.asarray(trimesh.load(again / "mesh.ply", process=False).vertices), expected, atol=1e-3
    )


def test_mediapipe_blendshapes_and_arkit_raw_keys_read_as_arkit_curves(tmp_path):
    """MediaPipe's face blendshapes (its ``_neutral`` first, no ``tongueOut``, ``timestamp_ms``) and ARKit's
    raw ``ARFaceAnchor`` keys (``eyeBlink_L``) read into the same ARKit coefficients."""
    from pipeline.animation import read_curves

    names = [n for n in EXPRESSION_NAMES if n != "tongueOut"]
    rng = np.random.default_rng(27)
    values = rng.uniform(0.0, 1.0, (3, len(names)))
    rows = [["timestamp_ms", "_neutral", *names]]
    rows += [[f"{33.3 * k:.1f}", "0.9", *(f"{v:.6f}" for v in values[k])] for k in range(3)]
    (tmp_path / "mediapipe.csv").write_text("\n".join(",".join(r) for r in rows) + "\n")
    curves = read_curves(tmp_path / "mediapipe.csv")
    np.testing.assert_allclose(curves.times, [0.0, 0.0333, 0.0666], atol=1e-9)
    for j, name in enumerate(names):
        np.testing.assert_allclose(curves.coefficients[:, EXPRESSION_NAMES.index(name)], values[:, j], atol=1e-6)
    assert np.all(curves.coefficients[:, EXPRESSION_NAMES.index("tongueOut")] == 0.0)

    raw = "time,eyeBlink_L,mouthSmile_R,jawOpen,browInnerUp\n0,0.8,0.5,0.3,0.2\n0.1,0.1,0.2,0.0,0.0\n"
    (tmp_path / "arkit_raw.csv").write_text(raw)
    curves = read_curves(tmp_path / "arkit_raw.csv")
    first = dict(zip(EXPRESSION_NAMES, curves.coefficients[0]))
    assert (first["eyeBlinkLeft"], first["mouthSmileRight"], first["jawOpen"], first["browInnerUp"]) == pytest.approx(
        (0.8, 0.5, 0.3, 0.2)
    )
    assert sum(v != 0 for v in first.values()) == 4


def test_a_written_live_link_file_reads_back_to_the_same_coefficients(tmp_path):
    from pipeline.animation import read_curves
    from pipeline.head.curves import Curves, write_curves

    rng = np.random.default_rng(3)
    low, high = (t.numpy() for t in expression_limits())
    coefficients = rng.uniform(np.maximum(low, 0.0), np.minimum(high, 1.0), (4, len(EXPRESSION_NAMES)))
    head = rng.uniform(-20.0, 20.0, (4, 3))
    write_curves(tmp_path / "take.csv", Curves(np.arange(4) / 60.0, coefficients, head), layout="live-link-face")
    header = (tmp_path / "take.csv").read_text().splitlines()[0].split(",")
    assert header[:3] == ["Timecode", "BlendShapeCount", "EyeBlinkLeft"]
    with pytest.warns(UserWarning, match="assumed 60 fps"):  # 4 frames: within one second, the rate unseen
        back = read_curves(tmp_path / "take.csv")
    np.testing.assert_allclose(back.coefficients, coefficients, atol=1e-6)
    np.testing.assert_allclose(back.head_rotation, head, atol=1e-4)
    np.testing.assert_allclose(back.times, np.arange(4) / 60.0, atol=1e-6)


APP_HEADER = (
    "Timecode,BlendShapeCount,EyeBlinkLeft,EyeLookDownLeft,EyeLookInLeft,EyeLookOutLeft,EyeLookUpLeft,"
    "EyeSquintLeft,EyeWideLeft,EyeBlinkRight,EyeLookDownRight,EyeLookInRight,EyeLookOutRight,EyeLookUpRight,"
    "EyeSquintRight,EyeWideRight,JawForward,JawRight,JawLeft,JawOpen,MouthClose,MouthFunnel,MouthPucker,"
    "MouthRight,MouthLeft,MouthSmileLeft,MouthSmileRight,MouthFrownLeft,MouthFrownRight,MouthDimpleLeft,"
    "MouthDimpleRight,MouthStretchLeft,MouthStretchRight,MouthRollLower,MouthRollUpper,MouthShrugLower,"
    "MouthShrugUpper,MouthPressLeft,MouthPressRight,MouthLowerDownLeft,MouthLowerDownRight,MouthUpperUpLeft,"
    "MouthUpperUpRight,BrowDownLeft,BrowDownRight,BrowInnerUp,BrowOuterUpLeft,BrowOuterUpRight,CheekPuff,"
    "CheekSquintLeft,CheekSquintRight,NoseSneerLeft,NoseSneerRight,TongueOut,HeadYaw,HeadPitch,HeadRoll,"
    "LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll"
)
"""The header row of a take recorded by Epic's Live Link Face iOS app (the copy that public importers of its
takes carry, e.g. the PyLiveLinkFace Blender add-on's LIVE_LINK_FACE_HEADER): JawRight before JawLeft,
MouthRight before MouthLeft, 52 shapes and 9 rotations; the app writes BlendShapeCount 61 on every row."""


def test_the_live_link_file_has_the_apps_header_column_for_column(tmp_path):
    """Issue 38: the columns were in ARKit's documentation order (JawLeft before JawRight) and the count 52;
    a reader that goes by position (the app's own order) swapped the jaw and mouth sideways shapes."""
    c = np.zeros((3, len(EXPRESSION_NAMES)))
    c[:, EXPRESSION_NAMES.index("jawLeft")] = 0.7
    c[:, EXPRESSION_NAMES.index("mouthRight")] = 0.4
    write_curves(tmp_path / "take.csv", Curves(np.arange(3) / 60.0, c), layout="live-link-face")
    lines = (tmp_path / "take.csv").read_text().splitlines()
    assert lines[0] == APP_HEADER
    app = APP_HEADER.split(",")
    row = lines[1].split(",")
    assert row[1] == "61" and len(row) == len(app)
    assert float(row[app.index("JawLeft")]) == 0.7 and float(row[app.index("JawRight")]) == 0.0
    assert float(row[app.index("MouthRight")]) == 0.4 and float(row[app.index("MouthLeft")]) == 0.0


@pytest.mark.parametrize("rate", [24.0, 30.0, 60.0])
def test_the_frame_rate_is_read_from_the_timecodes(tmp_path, rate):
    """Issue 38: a 30 fps take was played at the default 60 fps (twice as fast) without a word. The timecodes'
    frame numbers wrap at the rate, so a take over a second long shows it; written at one rate, read at it."""
    n = int(2.5 * rate)
    c = np.zeros((n, len(EXPRESSION_NAMES)))
    c[:, EXPRESSION_NAMES.index("jawOpen")] = np.linspace(0.0, 1.0, n)
    write_curves(tmp_path / "take.csv", Curves(np.arange(n) / rate, c), layout="live-link-face", fps=rate)
    back = read_curves(tmp_path / "take.csv")
    assert back.fps == rate
    np.testing.assert_allclose(back.times, np.arange(n) / rate, atol=1e-6)
    assert read_curves(tmp_path / "take.csv", fps=120.0).fps == 120.0  # a given rate wins


def test_a_29_97_take_reads_at_30_and_a_short_take_warns(tmp_path):
    """An NTSC take (29.97 fps: frame numbers 0-29) reads at 30 fps, 0.1 % off, not at 60; a take shorter than
    a second cannot show its rate: assumed 60 with a warning."""
    rows = ["Timecode,BlendShapeCount,JawOpen"]
    rows += [f"10:00:{s:02d}:{f:02d}.000,61,0.5" for s in (1, 2) for f in range(30)]
    (tmp_path / "ntsc.csv").write_text("\n".join(rows) + "\n")
    back = read_curves(tmp_path / "ntsc.csv")
    assert back.fps == 30.0 and back.times[-1] == pytest.approx(59 / 30.0)
    short = "Timecode,BlendShapeCount,JawOpen\n10:00:01:03.000,61,0\n10:00:01:04.000,61,1\n"
    (tmp_path / "short.csv").write_text(short)
    with pytest.warns(UserWarning, match="within one second.*assumed 60 fps"):
        assert read_curves(tmp_path / "short.csv").fps == 60.0


def test_a_long_takes_preview_is_posed_a_chunk_at_a_time(tmp_path, monkeypatch):
    """Issue 38: a 4,500-row take's preview posed every frame in one batch (6 GB for a minute); frames are posed
    a chunk at a time now, and each rendered head is still the one the whole batch gives."""
    from pipeline.animation import keyframes

    head = load_fit_head(_fit_folder(tmp_path, 4))
    n = 150
    c = np.zeros((n, len(EXPRESSION_NAMES)))
    c[:, EXPRESSION_NAMES.index("jawOpen")] = np.linspace(0.0, 1.0, n)
    curves = Curves(np.arange(n) / 30.0, c, np.stack([np.linspace(0, 20, n), np.zeros(n), np.zeros(n)], 1))
    batches, rendered = [], []
    real = keyframes.posed_frames

    def counting(head, coefficients, taus):
        batches.append(len(coefficients))
        return real(head, coefficients, taus)

    monkeypatch.setattr(keyframes, "posed_frames", counting)
    monkeypatch.setattr(keyframes, "render_preview", lambda v, *a, **k: rendered.append(v) or np.zeros((2, 2, 3)))
    frames, rows = keyframes.render_frames(head, curves, fps=30.0)
    assert len(frames) == len(rows) == n and max(batches) <= keyframes.POSE_CHUNK and sum(batches) == n
    taus = keyframes.curve_keyframes(head, curves).joint_transforms
    whole = real(head, c[rows], taus[rows])
    np.testing.assert_allclose(np.stack(rendered), whole, atol=1e-9)
