"""The fitted head's home: one reader for every params.json layout, a new head model by registration only."""

import json
from typing import ClassVar

import numpy as np
import pytest

from pipeline.head.fitted import NotPosableError, fitted_head
from pipeline.head.params import ParamsFileError, params_payload, read_params
from rig.expressions import EXPRESSION_NAMES
from rig.head_model import _REGISTRY, HeadParams, HeadPose, ParameterGroup, create, register_head_model
from tests.pipeline.conftest import rig_head_vertices


class _Shifted:
    """A throwaway head model: the template moved by one named offset (mm), no joints."""

    kind: ClassVar[str] = "shifted-test"
    posable: ClassVar[bool] = False

    def __init__(self, asset=None):
        from rig.asset import load_asset

        self.asset = asset or load_asset()

    def groups(self):
        names = ("offset_x", "offset_y", "offset_z")
        return (ParameterGroup("offset", names, np.full(3, -10.0), np.full(3, 10.0), "mm"),)

    def initial(self):
        return HeadParams(self.kind, {"offset": np.zeros(3), "expressions": np.zeros(len(EXPRESSION_NAMES))})

    def forward(self, params):
        v = self.asset.vertices + np.asarray(params["offset"])
        return HeadPose(v, np.asarray(self.asset.vertices, float), None, None, np.asarray(params["expressions"]))

    def to_dict(self, params):
        return {"offset": [float(x) for x in params["offset"]], "expressions": {}}

    def from_dict(self, data):
        return HeadParams(self.kind, {"offset": np.asarray(data["offset"], float), "expressions": np.zeros(52)})

    @staticmethod
    def options_from_dict(data):
        return {}


def test_a_new_model_is_one_class_and_its_registration(asset):
    """The fitted-head reader takes a registered model by its kind: no branch on model names elsewhere."""
    register_head_model(_Shifted.kind, _Shifted)
    try:
        _check_shifted(asset)
    finally:
        _REGISTRY.pop(_Shifted.kind)


def _check_shifted(asset):
    model = create(_Shifted.kind)
    params = model.from_dict({"offset": [1.0, 2.0, 3.0]})
    payload = params_payload(model, params, fit="scan", pose={"scale": 1.0})
    head = fitted_head(json.loads(json.dumps(payload)))
    assert head.model.kind == _Shifted.kind and head.fit.fit == "scan"
    np.testing.assert_allclose(head.vertices - asset.vertices, np.broadcast_to([1.0, 2.0, 3.0], asset.vertices.shape))
    with pytest.raises(NotPosableError, match="SHIFTED-TEST fit has no joint rig for animation"):
        fitted_head(payload, posable_for="animation")


@pytest.fixture(scope="module")
def jnr_entries():
    rng = np.random.default_rng(3)
    model = create("jnr")
    joints = model.groups()[0]
    theta = np.clip(rng.normal(0, 0.1, joints.size) * (joints.high - joints.low), joints.low, joints.high)
    params = model.params(theta, rng.normal(0, 0.5, 50), np.full(len(EXPRESSION_NAMES), 0.1))
    return model.to_dict(params)


@pytest.mark.parametrize(
    ("layout", "fit"),
    [
        ({"format": "jnr-photo-params/1"}, "photo"),
        ({"format": "jnr-scan-params/1"}, "scan"),
        ({"format": "jnr-multiview-params/1", "skinning": "jnr"}, "views"),
        ({"format": "jnr-params/2", "fit": "views", "model": "jnr"}, "views"),
        ({}, None),
    ],
)
def test_every_params_layout_gives_the_same_head(jnr_entries, layout, fit):
    data = {**layout, **jnr_entries}
    assert read_params(data).fit == fit
    head = fitted_head(data)
    np.testing.assert_allclose(head.vertices, rig_head_vertices(jnr_entries), atol=1e-9)


def test_a_written_payload_reads_back(jnr_entries):
    model, params = create("jnr"), create("jnr").from_dict(jnr_entries)
    payload = params_payload(model, params, fit="photo", camera={"focal_px": 500.0})
    assert payload["format"] == "jnr-params/2" and payload["model"] == "jnr" and payload["joints"]
    head = fitted_head(json.loads(json.dumps(payload)))
    assert head.fit.data["camera"] == {"focal_px": 500.0}
    np.testing.assert_array_equal(head.params["joints"], params["joints"])
    with pytest.raises(ValueError, match="schema's or the model's"):
        params_payload(model, params, fit="photo", joints={})


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ([1, 2], "not a JSON object"),
        ({"format": "obj-params/9"}, "not a jnr fit's parameter file"),
        ({"format": "jnr-params/2", "fit": "video", "model": "jnr"}, "needs 'fit'"),
        ({"format": "jnr-params/2", "fit": "photo", "model": "flame"}, "unknown head model 'flame'"),
        ({"format": "jnr-photo-params/1", "joints": {}}, "lacks"),
        # issue 38: the units were never checked (a file in cm read as mm)
        (
            {"format": "jnr-params/2", "fit": "photo", "model": "jnr", "units": {"translate": "cm"}},
            r"units \{'translate': 'cm'\} are not the rig's",
        ),
    ],
)
def test_bad_params_are_one_clear_error(data, message):
    with pytest.raises(ParamsFileError, match=message):
        fitted_head(data)


def test_the_writer_the_resume_check_and_help_agree_on_the_file_list(capsys, tmp_path, photo_dir):
    """One description (pipeline.head.folders.PHOTO_FOLDER): what jnr fit writes, what a resumed folder run
    calls complete, and what --help and the printed summary list are the same files."""
    from pipeline.cli import main
    from pipeline.head.folders import PHOTO_FOLDER
    from pipeline.photo.resume import complete_report
    from tests.pipeline.conftest import fast_fit_args

    out = tmp_path / "fit"
    assert main(["fit", str(photo_dir / "face0.png"), "--out", str(out), *fast_fit_args()]) == 0
    printed = capsys.readouterr().out
    written = {p.name for p in out.iterdir()} - {".jnr-output"}
    report = json.loads((out / "report.json").read_text())
    # the one optional file is there exactly when the landmarks came from MediaPipe (its 478 points)
    dense = report["input"].get("fitted_layout") == "mediapipe"
    assert written == set(PHOTO_FOLDER.required) | ({"landmarks3d_mediapipe.json"} if dense else set())
    assert ", ".join(n for n in PHOTO_FOLDER.names if n in written) in printed
    assert complete_report(out) is not None
    (out / "expressions.csv").unlink()  # one file short: no longer complete, to be fitted again
    assert PHOTO_FOLDER.missing(out) == ("expressions.csv",) and complete_report(out) is None
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    for f in PHOTO_FOLDER.files:
        assert f"{f.name}: {' '.join(f.description.split())}" in help_text


def test_a_params_file_with_a_key_twice_is_refused(tmp_path):
    """Issue 38: ``json`` keeps the last of two equal keys silently."""
    from pipeline.head.params import load_params_file

    path = tmp_path / "params.json"
    path.write_text('{"format": "jnr-params/2", "fit": "photo", "fit": "scan", "model": "jnr"}')
    with pytest.raises(ParamsFileError, match="'fit' appears twice"):
        load_params_file(path)
