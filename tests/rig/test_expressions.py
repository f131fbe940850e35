"""rig.expressions: the 52 ARKit face units on the MakeHuman template."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rig.expressions import (
    EXPRESSION_NAMES,
    EXPRESSIONS,
    JAW_ANGLE_DEG,
    JAW_INDEX,
    ExpressionError,
    ExpressionModel,
    build_expression_basis,
    coefficients_from_dict,
    expression_limits,
    jaw_summary,
    lid_factor,
    mirror_coefficients,
    peak_displacements,
)
from rig.makehuman.face_units import ARKIT_NAMES, arkit_offsets
from rig.model import JointRig
from rig.template import makehuman_vertices, rim_halves

MIRROR_X = np.array([-1.0, 1.0, 1.0])

# Apple's ARFaceAnchor.BlendShapeLocation names, written out here independently of rig.makehuman.
APPLE_NAMES = """eyeBlinkLeft eyeLookDownLeft eyeLookInLeft eyeLookOutLeft eyeLookUpLeft eyeSquintLeft eyeWideLeft
eyeBlinkRight eyeLookDownRight eyeLookInRight eyeLookOutRight eyeLookUpRight eyeSquintRight eyeWideRight jawForward
jawLeft jawRight jawOpen mouthClose mouthFunnel mouthPucker mouthLeft mouthRight mouthSmileLeft mouthSmileRight
mouthFrownLeft mouthFrownRight mouthDimpleLeft mouthDimpleRight mouthStretchLeft mouthStretchRight mouthRollLower
mouthRollUpper mouthShrugLower mouthShrugUpper mouthPressLeft mouthPressRight mouthLowerDownLeft mouthLowerDownRight
mouthUpperUpLeft mouthUpperUpRight browDownLeft browDownRight browInnerUp browOuterUpLeft browOuterUpRight cheekPuff
cheekSquintLeft cheekSquintRight noseSneerLeft noseSneerRight tongueOut""".split()

# Where each shape's largest displacement lies (by name prefix).
OWN_REGIONS = {
    "eyeLook": ("eyeballs",),
    "eye": ("eyelids", "cheeks"),
    "jaw": ("chin", "jaw", "lips", "teeth", "tongue", "neck", "mouth_interior", "cheeks"),
    "mouth": ("lips", "cheeks", "mouth_interior", "chin"),
    "brow": ("brows", "forehead"),
    "cheek": ("cheeks", "jaw"),
    "nose": ("nose", "brows"),
    "tongue": ("tongue",),
}


def _own(name):
    return next(v for k, v in OWN_REGIONS.items() if name.startswith(k))


@pytest.fixture(scope="module")
def model(asset):
    return ExpressionModel(asset, dtype=torch.float64)


@pytest.fixture(scope="module")
def shapes(model):
    """Offsets ``(E, V, 3)`` of every shape alone at 1 (through the model)."""
    with torch.no_grad():
        return model(torch.eye(len(EXPRESSION_NAMES), dtype=torch.float64)).numpy()


def _offset(model, name, value=1.0):
    c = coefficients_from_dict({name: value}, dtype=torch.float64)[None]
    with torch.no_grad():
        return model(c)[0].numpy()


def test_names_are_arkits():
    assert EXPRESSION_NAMES == tuple(APPLE_NAMES) == ARKIT_NAMES and len(EXPRESSIONS) == 52
    for spec in EXPRESSIONS:
        assert (spec.low, spec.high) == (0.0, 1.0)
        assert spec.side == (
            "left" if spec.name.endswith("Left") else "right" if spec.name.endswith("Right") else "center"
        )


def _gradients(rest, offsets, faces):
    from rig.geometry import _triangle_frames

    return _triangle_frames(rest + offsets, faces) @ np.linalg.inv(_triangle_frames(rest, faces))


def test_model_is_the_artists_shapes_carried_onto_the_template(asset, shapes):
    """At coefficient 1 every shape deforms the template's triangles as the data's shape deforms MakeHuman's
    (deformation transfer; jawOpen too: rotation + corrective), with the same size; the lid shapes are the
    data's offsets with the lid travel fitted to the template's eyes; the strays removed."""
    raw = arkit_offsets().copy()
    makehuman = makehuman_vertices()
    stray = asset.region_mask("mouth_interior", "teeth", "tongue")
    lid = lid_factor(asset)
    for i, name in enumerate(EXPRESSION_NAMES):
        if name.startswith(("eyeBlink", "eyeSquint", "eyeWide")):  # the data's offsets, lid travel adapted
            raw[i, :, 1] *= lid
            diff = np.linalg.norm(shapes[i] - raw[i], axis=1)[~stray]
            assert diff.max() < 1.5, (name, diff.max())  # the data's pairs differ by <= 1.3 mm
            continue
        source = _gradients(makehuman, raw[i], asset.faces)
        moving = np.linalg.norm(source - np.eye(3), axis=(1, 2)) > 0.05
        if not moving.any():  # tongueOut moves the tongue rigidly
            np.testing.assert_allclose(shapes[i], raw[i], atol=1e-6)
            continue
        # measured: median 0.007-0.048, 90th percentile 0.045-0.234 (the data's pairs are not symmetric)
        mismatch = np.linalg.norm(_gradients(asset.vertices, shapes[i], asset.faces) - source, axis=(1, 2))[moving]
        assert np.median(mismatch) < 0.05 and np.percentile(mismatch, 90) < 0.25, name
        size = np.sqrt((shapes[i] ** 2).sum(1).mean() / (raw[i] ** 2).sum(1).mean())
        assert 0.9 < size < 1.15, (name, size)  # measured 0.967-1.092 (the ICT mean is the larger head)
        if name.startswith(("eye", "brow")):
            assert np.abs(shapes[i][stray]).max() == 0.0
    np.testing.assert_array_equal(build_expression_basis(asset)[0], build_expression_basis(asset)[0])


def test_zero_coefficients(model):
    out = model(torch.zeros(3, 52, dtype=torch.float64))
    assert out.shape == (3, model.template.shape[0], 3)
    assert torch.count_nonzero(out) == 0


def test_each_shape_moves_its_own_region(asset, shapes):
    still = asset.region_mask("ears", "scalp")
    for i, name in enumerate(EXPRESSION_NAMES):
        d = np.linalg.norm(shapes[i], axis=1)
        top = asset.region_names[asset.regions[d.argmax()]]
        assert top in _own(name), (name, top)
        assert d[still].max() < 1.0, (name, d[still].max())
        if name.startswith(("eye", "brow")):
            assert d[asset.region_mask("mouth_interior", "teeth", "tongue", "lips")].max() < 0.5, name
        if not name.startswith("eyeLook"):
            assert d[asset.region_mask("eyeballs")].max() < 0.05, name


def test_peaks_plausible(asset):
    peaks = peak_displacements(asset)
    for name, peak in peaks.items():
        assert 2.0 <= peak <= (45.0 if name in ("jawOpen", "mouthClose", "tongueOut") else 20.0), (name, peak)


def test_left_right_mirror_exactly(asset, shapes):
    for i, name in enumerate(EXPRESSION_NAMES):
        twin = name[:-4] + "Right" if name.endswith("Left") else name[:-5] + "Left" if name.endswith("Right") else name
        j = EXPRESSION_NAMES.index(twin)
        np.testing.assert_allclose(shapes[j][asset.mirror] * MIRROR_X, shapes[i], atol=1e-9, err_msg=name)


def test_mirror_coefficients(asset, model):
    c = torch.rand(2, 52, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        a, b = model(c), model(mirror_coefficients(c))
    np.testing.assert_allclose(b.numpy()[:, asset.mirror] * MIRROR_X, a.numpy(), atol=1e-9)
    np.testing.assert_array_equal(mirror_coefficients(mirror_coefficients(c.numpy())), c.numpy())


def test_blink_closes_the_left_eye_only(asset, model):
    v = asset.vertices + _offset(model, "eyeBlinkLeft")
    for loop in asset.eye_loops:
        upper, lower = rim_halves(asset.vertices, loop)
        rest_gap = asset.vertices[upper[1:-1], 1].mean() - asset.vertices[lower[1:-1], 1].mean()
        gap = v[upper[1:-1], 1].mean() - v[lower[1:-1], 1].mean()
        if asset.vertices[loop[0], 0] > 0:  # the left eye closes
            assert gap < 0.25 * rest_gap, (gap, rest_gap)
        else:
            assert gap == pytest.approx(rest_gap)


def test_jaw_opens_by_rotation_without_tearing(asset, model):
    v0 = asset.vertices
    upper, lower = rim_halves(v0, asset.mouth_loop)
    mid = asset.mirror == np.arange(len(v0))
    u, lo = upper[mid[upper]][0], lower[mid[lower]][0]
    v1 = v0 + _offset(model, "jawOpen", 1.0)
    assert v1[u, 1] - v1[lo, 1] > 25.0  # the lips part by more than 25 mm at the open limit
    f = asset.faces
    n0 = np.cross(v0[f[:, 1]] - v0[f[:, 0]], v0[f[:, 2]] - v0[f[:, 0]])
    for c in (0.25, 0.5, 0.75, 1.0):
        v = v0 + _offset(model, "jawOpen", c)
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        assert ((n * n0).sum(1) > 0).all(), c  # no triangle inverted
    # half-way is the exact rotation by 11 degrees plus half the corrective (not the chord)
    half = _offset(model, "jawOpen", 0.5)
    assert 0.0 < -half[lo, 1] < -_offset(model, "jawOpen", 1.0)[lo, 1]
    summary = jaw_summary(asset)
    assert summary["corrective_rms_mm"] < 0.2 * summary["artist_rms_mm"]  # the rotation carries most of it
    assert JAW_ANGLE_DEG == 22.0 and JAW_INDEX == EXPRESSION_NAMES.index("jawOpen")


def test_composes_with_rig(asset):
    rig = JointRig(asset)
    expr = ExpressionModel(asset)
    c = torch.zeros(2, 52)
    c[0, EXPRESSION_NAMES.index("jawOpen")] = 0.7
    c[1, EXPRESSION_NAMES.index("mouthSmileLeft")] = 1.0
    c.requires_grad_(True)
    theta = torch.zeros(2, rig.num_parameters)
    out = rig(theta, vertices=rig.template + expr(c)).vertices
    assert out.shape == (2, rig.num_vertices, 3) and torch.isfinite(out).all()
    torch.testing.assert_close(out, rig.template + expr(c), atol=1e-3, rtol=0)  # rest pose: no change
    out.sum().backward()
    assert c.grad is not None and torch.isfinite(c.grad).all()


def test_coefficients_from_dict():
    c = coefficients_from_dict({"jawOpen": 0.5, "mouthSmileLeft": 0.25}, dtype=torch.float64)
    assert c.shape == (52,) and c[EXPRESSION_NAMES.index("jawOpen")] == 0.5
    with pytest.raises(ExpressionError, match="ARKit"):
        coefficients_from_dict({"jaw_open": 1.0})
    with pytest.raises(ValueError):
        coefficients_from_dict({"jawOpen": 1.5})
    with pytest.raises(ExpressionError):
        coefficients_from_dict({"jawOpen": -0.1})
    with pytest.raises(ExpressionError):
        coefficients_from_dict({"jawOpen": float("nan")})
    with pytest.warns(UserWarning):
        c = coefficients_from_dict({"jawOpen": 1.5, "cheekPuff": -3.0}, clamp=True)
    assert c[EXPRESSION_NAMES.index("jawOpen")] == 1.0 and c[EXPRESSION_NAMES.index("cheekPuff")] == 0.0


def test_bad_shape(model):
    with pytest.raises(ExpressionError):
        model(torch.zeros(2, 24))
    low, high = expression_limits(torch.float32)
    assert low.shape == high.shape == (52,) and (low == 0).all() and (high == 1).all()
