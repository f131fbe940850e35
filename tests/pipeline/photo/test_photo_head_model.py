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
from rig.expressions import EXPRESSION_NAMES
from rig.geometry import head_rotation
from rig.head_model import (
    HeadModelError,
    HeadParams,
    HeadPose,
    ParameterGroup,
    create,
    register_head_model,
    unregister_head_model,
)

KIND = "test_stretched"


class StretchedHead:
    """A throwaway head model: the template stretched vertically about its centre by ``1 + grow`` (one float, in a
    group named ``joints`` so the fit's joint stages free it), not posable, no expressions."""

    kind = KIND
    posable = False

    def __init__(self, asset=None) -> None:
        from rig.asset import load_asset

        self.asset = asset or load_asset()
        self.template = torch.as_tensor(self.asset.vertices, dtype=torch.float64)
        self.centre = self.template.mean(0)

    def groups(self):
        return (ParameterGroup("joints", ("grow",), np.array([-0.3]), np.array([0.3]), "fraction"),)

    def initial(self):
        return HeadParams(KIND, {"joints": np.zeros(1)})

    def vertices(self, values, vertex_ids=None):
        grow = values["joints"][:, 0].to(torch.float64)
        v = self.template if vertex_ids is None else self.template[vertex_ids]
        stretch = torch.stack([torch.ones_like(grow), 1.0 + grow, torch.ones_like(grow)], -1)[:, None]
        return self.centre + stretch * (v - self.centre)

    def forward(self, params):
        v = self.vertices({"joints": torch.as_tensor(np.asarray(params["joints"], np.float64))[None]})[0].numpy()
        return HeadPose(v, v, None, None, np.zeros(len(EXPRESSION_NAMES)))

    def to_dict(self, params):
        return {"model": KIND, "grow": float(params["joints"][0])}

    def from_dict(self, data):
        return HeadParams(KIND, {"joints": np.array([float(data["grow"])])})

    @staticmethod
    def options_from_dict(data):
        return {}


@pytest.fixture
def stretched():
    register_head_model(KIND, StretchedHead)
    try:
        yield create(KIND)
    finally:
        unregister_head_model(KIND)


def _photo_points(model, grow, size, rotation, translation, focal):
    layout = mediapipe_layout(model.asset)
    v = model.vertices({"joints": torch.tensor([[grow]], dtype=torch.float64)})[0]
    camera = make_camera(size, size, focal, rotation=rotation, translation=translation, dtype=torch.float64)
    points = layout.points3d(v, model.asset.faces, camera_center_in_rig(rotation, translation))
    return project_points(points[None], camera)[0].numpy(), layout


def test_the_generic_landmark_fit_recovers_the_models_parameter_and_the_pose(stretched):
    rotation, translation = head_rotation(14.0, -6.0, 3.0), np.array([6.0, -9.0, 620.0])
    px, layout = _photo_points(stretched, 0.08, 512, rotation, translation, 720.0)
    fit = fit_model_landmarks(px, 512, 512, stretched, focal=720.0, layout=layout)
    assert fit.head.kind == KIND and abs(fit.head["joints"][0] - 0.08) < 1e-3
    angle = np.degrees(np.arccos(np.clip((np.trace(fit.rotation.T @ rotation) - 1) / 2, -1, 1)))
    assert angle < 0.1 and np.abs(fit.translation - translation).max() < 0.5
    assert fit.error_px.mean() < 0.01  # noise-free points of the model's own head


def test_a_registered_head_model_is_fitted_by_jnr_fit_and_written(stretched, tmp_path, capsys):
    size, truth = 384, 0.08
    rotation, translation = head_rotation(-15.0, 5.0, -2.0), np.array([-4.0, 8.0, 560.0])
    px, _ = _photo_points(stretched, truth, size, rotation, translation, default_focal(size, size))
    Image.fromarray(np.full((size, size, 3), 128, np.uint8)).save(tmp_path / "grey.png")
    write_landmarks(tmp_path / "grey.json", px)
    out = tmp_path / "out"
    argv = ["fit", str(tmp_path / "grey.png"), "--landmarks", str(tmp_path / "grey.json"), "--out", str(out)]
    code = main([*argv, "--set", f"model={KIND}", "--quiet"])
    assert code == 0, capsys.readouterr().err
    params = json.loads((out / "params.json").read_text())
    assert params["model"] == KIND and abs(params["grow"] - truth) < 1e-3
    expected = stretched.forward(HeadParams(KIND, {"joints": np.array([truth])})).vertices
    obj = np.asarray(trimesh.load(out / "mesh.obj", process=False).vertices)[: len(expected)]
    assert np.abs(obj - expected).max() < 0.05  # mm (the OBJ's digits)
    glb = trimesh.load(out / "mesh.glb", force="mesh", process=False)  # the mesh as it is, in metres
    gap, _ = cKDTree(expected).query(np.asarray(glb.vertices) * 1000.0)  # its UV seams split vertices: nearest
    assert gap.max() < 0.01
    # a model with photometric stages asked for: a clear error before anything is written
    code = main([*argv[:-1], str(tmp_path / "b"), "--set", f"model={KIND}", "--photometric"])
    assert code == 2 and "photometric" in capsys.readouterr().err and not (tmp_path / "b").exists()


def test_an_unknown_model_and_a_built_in_ones_removal_are_errors(tmp_path, capsys):
    Image.fromarray(np.full((64, 64, 3), 128, np.uint8)).save(tmp_path / "grey.png")
    code = main(["fit", str(tmp_path / "grey.png"), "--out", str(tmp_path / "out"), "--set", "model=nosuch"])
    err = capsys.readouterr().err
    assert code == 2 and "nosuch" in err and "jnr" in err and not (tmp_path / "out").exists()
    with pytest.raises(HeadModelError):
        unregister_head_model("jnr")
