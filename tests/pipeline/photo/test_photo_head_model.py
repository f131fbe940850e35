"""A head model the project has never seen, registered by a test as a :class:`rig.head_model.HeadModel` and nothing
else, is fitted by ``jnr fit`` and written as every output (issue 39: a new head model is one file plus its
registration)."""

import json

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image
from scipy.spatial import cKDTree

from landmarks.formats import write_landmarks
from landmarks.loss import project_points
from landmarks.mediapipe.layout import mediapipe_layout
from pipeline.camera import camera_center_in_rig, default_focal, make_camera
from pipeline.cli import main
from pipeline.photo.model_fit import fit_model_landmarks
from rig.geometry import head_rotation
from rig.head_model import (
    HeadModelError,
    HeadParams,
    unregister_head_model,
)


def _photo_points(model, grow, size, rotation, translation, focal):
    layout = mediapipe_layout(model.asset)
    v = model.vertices({"joints": torch.tensor([[grow]], dtype=torch.float64)})[0]
    camera = make_camera(size, size, focal, rotation=rotation, translation=translation, dtype=torch.float64)
    points = layout.points3d(v, model.asset.faces, camera_center_in_rig(rotation, translation))
    return project_points(points[None], camera)[0].numpy(), layout


def test_the_generic_landmark_fit_recovers_the_models_parameter_and_the_pose(stretched_model):
    rotation, translation = head_rotation(14.0, -6.0, 3.0), np.array([6.0, -9.0, 620.0])
    px, layout = _photo_points(stretched_model, 0.08, 512, rotation, translation, 720.0)
    fit = fit_model_landmarks(px, 512, 512, stretched_model, focal=720.0, layout=layout)
    assert fit.head.kind == stretched_model.kind and abs(fit.head["joints"][0] - 0.08) < 1e-3
    angle = np.degrees(np.arccos(np.clip((np.trace(fit.rotation.T @ rotation) - 1) / 2, -1, 1)))
    assert angle < 0.1 and np.abs(fit.translation - translation).max() < 0.5
    assert fit.error_px.mean() < 0.01  # noise-free points of the model's own head


def test_a_registered_head_model_is_fitted_by_jnr_fit_and_written(stretched_model, tmp_path, capsys):
    size, truth = 384, 0.08
    rotation, translation = head_rotation(-15.0, 5.0, -2.0), np.array([-4.0, 8.0, 560.0])
    px, _ = _photo_points(stretched_model, truth, size, rotation, translation, default_focal(size, size))
    Image.fromarray(np.full((size, size, 3), 128, np.uint8)).save(tmp_path / "grey.png")
    write_landmarks(tmp_path / "grey.json", px)
    out = tmp_path / "out"
    argv = ["fit", str(tmp_path / "grey.png"), "--landmarks", str(tmp_path / "grey.json"), "--out", str(out)]
    code = main([*argv, "--set", f"model={stretched_model.kind}", "--quiet"])
    assert code == 0, capsys.readouterr().err
    params = json.loads((out / "params.json").read_text())
    assert params["model"] == stretched_model.kind and abs(params["grow"] - truth) < 1e-3
    expected = stretched_model.forward(HeadParams(stretched_model.kind, {"joints": np.array([truth])})).vertices
    obj = np.asarray(trimesh.load(out / "mesh.obj", process=False).vertices)[: len(expected)]
    assert np.abs(obj - expected).max() < 0.05  # mm (the OBJ's digits)
    glb = trimesh.load(out / "mesh.glb", force="mesh", process=False)  # the mesh as it is, in metres
    gap, _ = cKDTree(expected).query(np.asarray(glb.vertices) * 1000.0)  # its UV seams split vertices: nearest
    assert gap.max() < 0.01
    # a model with photometric stages asked for: a clear error before anything is written
    code = main([*argv[:-1], str(tmp_path / "b"), "--set", f"model={stretched_model.kind}", "--photometric"])
    assert code == 2 and "photometric" in capsys.readouterr().err and not (tmp_path / "b").exists()


def test_an_unknown_model_and_a_built_in_ones_removal_are_errors(tmp_path, capsys):
    Image.fromarray(np.full((64, 64, 3), 128, np.uint8)).save(tmp_path / "grey.png")
    code = main(["fit", str(tmp_path / "grey.png"), "--out", str(tmp_path / "out"), "--set", "model=nosuch"])
    err = capsys.readouterr().err
    assert code == 2 and "nosuch" in err and "jnr" in err and not (tmp_path / "out").exists()
    with pytest.raises(HeadModelError):
        unregister_head_model("jnr")


def test_a_model_of_structured_groups_asked_for_one_photo_says_which_fits_take_it():
    """ASM's parameters are one structured group (bones, mixtures): the one-photo fit refuses it with the fits that
    take it, not a bare shape complaint."""
    from rig.head_model import create

    px = np.random.default_rng(0).uniform(100, 300, (478, 2))
    with pytest.raises(HeadModelError, match=r"--views --skinning asm.*fit-scan --skinning asm"):
        fit_model_landmarks(px, 512, 512, create("asm"), layout=mediapipe_layout(create("jnr").asset))


def test_a_registered_head_model_is_the_identity_of_jnr_fit_views(stretched_model, tmp_path, capsys):
    size, truth = 384, 0.08
    focal = default_focal(size, size)
    photos = []
    for k, yaw in enumerate((-30.0, 0.0, 25.0)):
        rotation, translation = head_rotation(yaw, 4.0, 1.0), np.array([3.0 * k, -6.0, 580.0])
        px, _ = _photo_points(stretched_model, truth, size, rotation, translation, focal)
        Image.fromarray(np.full((size, size, 3), 128, np.uint8)).save(tmp_path / f"v{k}.png")
        write_landmarks(tmp_path / f"v{k}.json", px)
        photos.append(str(tmp_path / f"v{k}.png"))
    out = tmp_path / "views"
    argv = ["fit", *photos, "--views", "--landmarks", "auto", "--out", str(out), "--quiet"]
    code = main([*argv, "--set", f"skinning={stretched_model.kind}"])
    assert code == 0, capsys.readouterr().err
    params = json.loads((out / "params.json").read_text())
    assert params["model"] == stretched_model.kind and abs(params["grow"] - truth) < 2e-3
    report = json.loads((out / "report.json").read_text())
    assert [s["name"] for s in report["stages"]][-2:] == [
        f"{stretched_model.kind} register",
        f"{stretched_model.kind} refine",
    ]
    expected = stretched_model.forward(HeadParams(stretched_model.kind, {"joints": np.array([truth])})).vertices
    obj = np.asarray(trimesh.load(out / "mesh.obj", process=False).vertices)[: len(expected)]
    assert np.abs(obj - expected).max() < 0.5  # mm
