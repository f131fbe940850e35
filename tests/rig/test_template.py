"""rig.template / rig.asset: MakeHuman's head placed, labelled and rigged; the committed asset rebuilds."""

import numpy as np
import pytest
import trimesh

from rig.asset import build_asset
from rig.template import EYE_DEPTH_MM, EYE_HEIGHT_MM, REGION_NAMES, rim_halves


def test_template_is_the_symmetric_makehuman_head(asset):
    assert 4500 <= len(asset.vertices) <= 5500  # JNR: 5,236
    m = asset.mirror
    assert np.array_equal(m[m], np.arange(len(m)))
    assert np.abs(asset.vertices[m] * [-1, 1, 1] - asset.vertices).max() == 0.0
    assert np.array_equal(asset.regions[m], asset.regions)
    # the triangulation is mirror-symmetric too: mirrored faces are the same set
    faces = {tuple(sorted(f)) for f in asset.faces.tolist()}
    assert faces == {tuple(sorted(m[f])) for f in asset.faces.tolist()}
    skin = ~asset.region_mask("eyeballs", "teeth", "tongue")
    mesh = trimesh.Trimesh(asset.vertices, asset.faces[skin[asset.faces].all(1)], process=False)
    assert mesh.is_winding_consistent
    # one open boundary: the neck cut (eye pockets and mouth bag are closed)
    boundary = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
    loops = trimesh.graph.connected_components(mesh.edges_sorted[boundary])
    assert len(loops) == 1 and asset.vertices[np.concatenate(loops), 1].max() < -120.0


def test_placed_by_the_eyes_and_adult_proportions_in_mm(asset):
    v = asset.vertices
    eyes = v[asset.region_mask("eyeballs")]
    np.testing.assert_allclose(eyes.mean(0)[1:], [EYE_HEIGHT_MM, EYE_DEPTH_MM], atol=0.01)
    head = ~asset.region_mask("neck", "ears")
    width = 2 * np.abs(v[head, 0]).max()
    menton_to_crown = v[:, 1].max() - v[asset.region_mask("chin"), 1].min()
    assert 140 <= width <= 165, width
    assert 200 <= menton_to_crown <= 240, menton_to_crown
    # face towards +Z: the nose tip is the front-most point; +Y is up
    assert asset.regions[np.argmax(v[:, 2])] == REGION_NAMES.index("nose")
    assert asset.regions[np.argmax(v[:, 1])] == REGION_NAMES.index("scalp")


def test_every_region_is_present_and_sensible(asset):
    v = asset.vertices
    for name in REGION_NAMES:
        assert asset.region_mask(name).sum() >= 10, name
    assert v[asset.region_mask("neck"), 1].mean() < v[asset.region_mask("chin"), 1].mean()
    assert v[asset.region_mask("brows"), 1].mean() > v[asset.region_mask("eyelids"), 1].mean()
    assert v[asset.region_mask("lips"), 1].mean() < v[asset.region_mask("nose"), 1].mean()
    assert np.abs(v[asset.region_mask("ears"), 0]).min() > 60
    # the hidden pieces lie behind the face
    for hidden in ("teeth", "tongue", "mouth_interior", "eye_pockets"):
        assert v[asset.region_mask(hidden), 2].max() < v[asset.region_mask("lips", "eyelids"), 2].max(), hidden


def test_eye_openings_and_mouth_slit(asset):
    v = asset.vertices
    for loop in asset.eye_loops:
        upper, lower = rim_halves(v, loop)
        assert upper[0] == lower[0] and upper[-1] == lower[-1]
        inner, outer = v[upper[0]], v[upper[-1]]
        assert abs(inner[0]) < abs(outer[0]) and 18 < np.linalg.norm(outer - inner) < 32  # an adult eye fissure
        assert v[upper[1:-1], 1].max() - v[lower[1:-1], 1].min() > 6.0  # an open almond between the lids
    upper, lower = rim_halves(v, asset.mouth_loop)
    assert len(set(upper[1:-1]) & set(lower[1:-1])) == 0  # lips are separate vertices: the jaw can open
    mid = asset.mirror == np.arange(len(v))
    assert v[upper[mid[upper]], 1].min() > v[lower[mid[lower]], 1].max()  # upper lip above the lower lip
    assert 40 < v[upper[-1], 0] - v[upper[0], 0] < 55  # mouth width, mm


def test_uvs_are_makehumans_atlas(asset):
    uv = asset.face_uvs
    assert uv.shape == (len(asset.faces), 3, 2)
    assert uv.min() >= 0 and uv.max() <= 1
    spread = (uv.max(axis=1) - uv.min(axis=1)).max(axis=0)
    assert spread[0] < 0.1 and spread[1] < 0.1  # no face stretched across a seam


@pytest.mark.slow  # 18 s of the fast suite's 6 minutes: CI's make test-slow runs it
def test_asset_rebuilds_bit_for_bit(asset):
    rebuilt = build_asset()
    np.testing.assert_array_equal(rebuilt.vertices, asset.vertices)
    np.testing.assert_array_equal(rebuilt.faces, asset.faces)
    np.testing.assert_array_equal(rebuilt.face_uvs, asset.face_uvs)
    np.testing.assert_array_equal(rebuilt.weight_rows, asset.weight_rows)
    np.testing.assert_array_equal(rebuilt.weight_cols, asset.weight_cols)
    np.testing.assert_array_equal(rebuilt.weight_free, asset.weight_free)
    np.testing.assert_array_equal(rebuilt.regions, asset.regions)
    np.testing.assert_array_equal(rebuilt.joint_positions, asset.joint_positions)
