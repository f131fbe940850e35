"""A head model the project has never seen, registered by a test, is fitted by ``fit_scan`` without other code
(issue 39: a new head model is one file plus its registration)."""

import json

import numpy as np
import pytest
import torch
from torch import nn

from pipeline.cli import main
from pipeline.fitting.state import SCAN_STATES, ScanState, register_scan_state, scan_state_class
from pipeline.scan.fit import fit_scan
from pipeline.scan.fit_config import FitScanConfig
from pipeline.scan.pointcloud.validate import validate_points
from rig.geometry import head_rotation


class StretchedTemplate(ScanState):
    """A throwaway head model: the template stretched vertically about its centre by ``1 + g`` (one float, in
    the ``joints`` group; a uniform scale would be the pose's), no skinning, no expressions."""

    kind = "test_stretched"

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.grow = nn.Parameter(torch.zeros((), dtype=self.dtype))
        self.GROUPS = {**self.GROUPS, "joints": (("grow", "joints"),)}
        template = self.models.expressions.template
        self.register_buffer("centre", template.mean(0))

    @classmethod
    def for_scan(cls, rig, neural, expressions, config, *, fit_scale):
        return cls(rig, None, expressions, np.eye(3), np.zeros(3), 1.0, fit_scale=fit_scale)

    @staticmethod
    def label(config) -> str:
        return "stretched"

    def available(self, free):
        return tuple(g for g in free if g in ("pose", "joints"))

    def rig_vertices(self, free=()):
        template = self.models.expressions.template
        grow = self.grow if "joints" in free else self.grow.detach()
        stretch = torch.stack([torch.ones_like(grow), 1.0 + grow, torch.ones_like(grow)])
        return self.centre + stretch * (template - self.centre)

    def prior_terms(self, weights, **_):
        return ()

    def finish(self) -> dict:
        return {}


def test_a_registered_head_model_is_fitted_by_fit_scan_without_other_code(asset):
    register_scan_state(StretchedTemplate)
    try:
        assert scan_state_class("test_stretched") is StretchedTemplate
        truth_grow, rotation, translation = 0.08, head_rotation(12.0, -8.0, 3.0), np.array([4.0, -7.0, 30.0])
        centre = asset.vertices.mean(0)
        head = centre + np.array([1.0, 1.0 + truth_grow, 1.0]) * (asset.vertices - centre)
        rng = np.random.default_rng(0)
        points = head[rng.choice(len(head), 3000, replace=False)] @ rotation.T + translation
        config = FitScanConfig(skinning="test_stretched", use_neural=False)
        fit = fit_scan(validate_points(points), config)

        def aspect(v):  # height over width: what a uniform scale does not change
            extent = v.max(0) - v.min(0)
            return extent[1] / extent[0]

        assert abs(aspect(fit.rig_vertices) / aspect(asset.vertices) - (1.0 + truth_grow)) < 0.01
        assert np.degrees(np.arccos(np.clip((np.trace(fit.rotation.T @ rotation) - 1) / 2, -1, 1))) < 2.0
        assert np.linalg.norm(fit.vertices - (head @ rotation.T + translation), axis=1).mean() < 1.0
    finally:
        SCAN_STATES.pop("test_stretched", None)


@pytest.mark.slow  # 8 s: two scan fits
def test_a_head_model_registered_only_as_a_head_model_is_fitted_by_fit_scan(stretched_model, asset, tmp_path):
    """No scan state of its own: the generic state over its groups (pipeline.fitting.model_state)."""
    truth_grow, rotation, translation = -0.06, head_rotation(-10.0, 6.0, -2.0), np.array([-3.0, 5.0, 40.0])
    centre = asset.vertices.mean(0)
    head = centre + np.array([1.0, 1.0 + truth_grow, 1.0]) * (asset.vertices - centre)
    rng = np.random.default_rng(1)
    points = 1.05 * head[rng.choice(len(head), 3000, replace=False)] @ rotation.T + translation
    fit = fit_scan(validate_points(points), FitScanConfig(skinning=stretched_model.kind, use_neural=False))
    assert fit.head.kind == stretched_model.kind and abs(fit.head["joints"][0] - truth_grow) < 0.01
    assert abs(fit.scale - 1.05) < 0.01
    assert np.linalg.norm(fit.vertices - (1.05 * head @ rotation.T + translation), axis=1).mean() < 1.0
    # and by the command, every output written
    np.savetxt(tmp_path / "scan.xyz", points)
    out = tmp_path / "out"
    code = main(
        ["fit-scan", str(tmp_path / "scan.xyz"), "--out", str(out), "--set", f"skinning={stretched_model.kind}"]
    )
    assert code == 0
    params = json.loads((out / "params.json").read_text())
    assert params["model"] == stretched_model.kind and abs(params["grow"] - truth_grow) < 0.01
