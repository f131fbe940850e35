import numpy as np
import trimesh

from rig.asset import build_asset
from rig.template import REGION_NAMES


def test_template_is_a_closed_symmetric_head(asset):
    mesh = trimesh.Trimesh(asset.vertices, asset.faces, process=False)
    assert 4500 <= len(asset.vertices) <= 5500  # JNR: 5,236
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.euler_number == 2  # genus 0: eye and mouth openings lead into closed caps
    assert mesh.volume > 0  # outward normals
    m = asset.mirror
    assert np.array_equal(m[m], np.arange(len(m)))
    assert np.abs(asset.vertices[m] * [-1, 1, 1] - asset.vertices).max() == 0.0
    assert np.array_equal(asset.regions[m], asset.regions)


def test_adult_proportions_in_mm(asset):
    v = asset.vertices
    head = ~asset.region_mask("neck", "ears")
    width = 2 * np.abs(v[head, 0]).max()
    chin_to_crown = v[:, 1].max() - v[asset.region_mask("chin"), 1].min()
    assert 140 <= width <= 165, width
    assert 220 <= chin_to_crown <= 240, chin_to_crown
    # Face towards +Z: the nose tip is the front-most point, +Y is up.
    assert asset.regions[np.argmax(v[:, 2])] == REGION_NAMES.index("nose")
    assert asset.regions[np.argmax(v[:, 1])] == REGION_NAMES.index("scalp")


def test_every_region_is_present_and_sensible(asset):
    v = asset.vertices
    for name in REGION_NAMES:
        assert asset.region_mask(name).sum() >= 10, name
    assert v[asset.region_mask("neck"), 1].mean() < v[asset.region_mask("chin"), 1].mean()
    assert v[asset.region_mask("brows"), 1].mean() > v[asset.region_mask("eyelids"), 1].mean()
    assert np.abs(v[asset.region_mask("ears"), 0]).min() > 60


def test_eye_openings_and_mouth_slit(asset):
    v = asset.vertices
    for loop in asset.eye_loops:
        n = (len(loop) - 2) // 2
        upper, lower = loop[1:1 + n], loop[2 + n:][::-1]
        gap = v[upper, 1] - v[lower, 1]
        assert gap.max() > 6.0 and (gap > 0).all()  # an open almond between the eyelids
    loop = asset.mouth_loop
    n = (len(loop) - 2) // 2
    upper, lower = loop[1:1 + n], loop[2 + n:][::-1]
    assert len(set(upper) & set(lower)) == 0  # lips are separate vertices: the jaw can open
    assert ((v[upper, 1] - v[lower, 1]) > 0).all()
    eyeballs = asset.region_mask("eyeballs")
    assert eyeballs.sum() > 20 and v[eyeballs, 2].max() < v[asset.region_mask("eyelids"), 2].max()


def test_uvs_are_in_range_and_seam_is_cut(asset):
    uv = asset.face_uvs
    assert uv.shape == (len(asset.faces), 3, 2)
    assert uv.min() >= 0 and uv.max() <= 1
    spread = (uv.max(axis=1) - uv.min(axis=1)).max(axis=0)
    assert spread[0] < 0.2 and spread[1] < 0.2  # no face stretched across the seam


def test_asset_rebuilds_identically(asset):
    rebuilt = build_asset()
    assert np.abs(rebuilt.vertices - asset.vertices).max() <= 1e-6
    assert np.array_equal(rebuilt.faces, asset.faces)
    assert np.array_equal(rebuilt.weight_rows, asset.weight_rows)
    assert np.array_equal(rebuilt.weight_cols, asset.weight_cols)
    assert np.abs(rebuilt.weight_free - asset.weight_free).max() <= 1e-9
    assert np.array_equal(rebuilt.regions, asset.regions)
