"""The ICT Face Model copy, its correspondence with the template and the template built from it (issue 25)."""

from __future__ import annotations

import numpy as np
import pytest

from rig.asset import DEFAULT_ASSET, build_asset, load_asset, read_asset
from rig.geometry import closest_surface_points
from rig.ict.data import COMPACT_PATH, MAX_STORAGE_ERROR_MM, NUM_IDENTITY_MODES, SKIN_VERTICES, load_ict
from rig.ict.modes import expression_shapes, identity_modes, transfer_of
from rig.ict.transfer import boundary_loops, ict_rims
from rig.template import REGION_NAMES, build_makehuman_template

ZERO_PARAMETER_BOUND_MM = 0.25
"""Measured (benchmarks/bench_ict_transfer.py): the committed template's covered vertices lie within 0.18 mm
(max, at the eyelid rims; mean < 0.006 mm in every region) of the ICT mean's surface: the mirror
symmetrisation moves them (the storage error is < 0.001 mm)."""
FACE_TRANSFER_BOUND_MM = 0.3
SKIN_TRANSFER_BOUND_MM = 0.8
"""Measured (benchmarks/bench_ict_transfer.py, 3 test identities): the transferred head's vertices lie
0.09-0.15 mm (mean per face region) and 0.43 mm (mean over all vertices; scalp 0.57, neck 0.92, ears 1.9) from
the surface of the same head registered directly; vertex to vertex they differ more (face 1.5 mm, scalp 6 mm),
as the direct registration slides along smooth skin (docs/capacity.md)."""


@pytest.fixture(scope="module")
def ict():
    return load_ict()


def test_compact_copy_is_small_licensed_and_complete(ict):
    assert COMPACT_PATH.stat().st_size < 15e6
    licence = (COMPACT_PATH.parent / "LICENSE").read_text()
    assert "MIT" in licence and "Permission is hereby granted" in licence
    assert ict.neutral.shape == (SKIN_VERTICES, 3)
    assert ict.identity.shape == (NUM_IDENTITY_MODES, SKIN_VERTICES, 3)
    assert ict.expression.shape == (53, SKIN_VERTICES, 3)
    assert len(ict.expression_names) == 53 and "jawOpen" in ict.expression_names
    assert ict.landmarks68.shape == (68,) and ict.landmarks68.max() < SKIN_VERTICES
    assert ict.triangles.max() < SKIN_VERTICES and len(np.unique(ict.triangles)) == SKIN_VERTICES
    # a real face's size (ICT's source is in cm; the copy is in mm): the jaw ~13-15 cm wide at the ears
    # (iBUG landmarks 1 and 17), nasion to menton ~11-13 cm (28 and 9), the eyes ~6 cm apart
    lm = ict.neutral[ict.landmarks68]
    assert 125 < np.linalg.norm(lm[0] - lm[16]) < 155
    assert 105 < np.linalg.norm(lm[27] - lm[8]) < 135
    assert 55 < ict.eye_centres[0, 0] - ict.eye_centres[1, 0] < 70
    # ICT's own statement: the first 10 modes hold 88 % of the variance (of N(0, I) identities)
    energy = (ict.identity.astype(float) ** 2).sum((1, 2))
    assert energy[:10].sum() / energy.sum() == pytest.approx(0.88, abs=0.02)
    assert MAX_STORAGE_ERROR_MM["identity"] < 1e-3


def test_skin_has_the_eye_mouth_and_neck_rims(ict):
    loops = boundary_loops(ict.triangles)
    assert len(loops) == 4
    centres = np.array([ict.neutral[lp].mean(0) for lp in loops])
    assert (np.sort(np.sign(np.round(centres[:, 0]))) == [-1, 0, 0, 1]).all()


def test_lip_rim_is_icts_contact_line_not_its_skin_boundary(ict):
    """ICT's skin ends deep in the mouth, its lips ~11 mm apart there; the template's lip rim (lips 1.4 mm
    apart on MakeHuman's shape) goes to ICT's lip contact line, so the committed template's lips meet."""
    rims = ict_rims(ict)
    mouth = next(lp for lp in boundary_loops(ict.triangles) if abs(ict.neutral[lp, 0].mean()) < 1 and lp.size < 200)
    v = ict.neutral
    loops = (("boundary", mouth), ("contact", rims.mouth))
    gap = {name: float(np.ptp(v[lp][np.abs(v[lp, 0]) < 1.0, 1])) for name, lp in loops}
    assert gap["boundary"] > 8.0 and gap["contact"] < 1.5
    # the contact line lies between the outer lips' landmarks (iBUG 51 above, 57 below) and the mouth's end
    y = v[rims.mouth][np.abs(v[rims.mouth, 0]) < 1.0, 1]
    assert v[ict.landmarks68[57], 1] < y.min() and y.max() < v[ict.landmarks68[51], 1]
    assert 0 < rims.inner.sum() < 0.1 * len(ict.triangles)
    # the committed template: its upper and lower lip rims nearly touch at the midline
    asset = load_asset()
    loop = asset.mouth_loop
    mid = loop[np.abs(asset.vertices[loop, 0]) < 1.0]
    assert np.ptp(asset.vertices[mid, 1]) < 2.0


@pytest.mark.slow  # a whole asset rebuild (14 s): in `make test-slow`, which CI runs, so the suite stays under 6 min
def test_committed_asset_is_rebuilt_from_the_vendored_data_bit_for_bit():
    built, committed = build_asset(), read_asset(DEFAULT_ASSET)
    for name in type(built).__dataclass_fields__:
        assert np.array_equal(np.asarray(getattr(built, name)), np.asarray(getattr(committed, name))), name


def test_zero_parameters_give_the_ict_mean(ict):
    asset = load_asset()
    surface = ict.neutral @ asset.ict_rotation.T + asset.ict_translation
    found = closest_surface_points(asset.vertices[asset.ict_covered], surface, ict.triangles)
    assert found.distance.max() < ZERO_PARAMETER_BOUND_MM and found.distance.mean() < 0.01
    # the face is covered (the ears and the hidden parts are continued)
    face = asset.region_mask("forehead", "brows", "eyelids", "nose", "cheeks", "lips", "chin")
    assert np.isin(np.flatnonzero(face), asset.ict_covered).mean() > 0.95
    assert not np.isin(np.flatnonzero(asset.region_mask("eyeballs", "teeth", "ears")), asset.ict_covered).any()
    # exactly mirror-symmetric, eyeball centres placed by the template's rule
    mirrored = asset.vertices[asset.mirror] * np.array([-1.0, 1.0, 1.0])
    assert np.abs(mirrored - asset.vertices).max() < 1e-9
    eyes = asset.vertices[asset.region_mask("eyeballs")].mean(0)
    assert np.allclose(eyes[1:], [5.0, 58.0], atol=0.005 + 1e-9)  # the placement is rounded to 0.01 mm


def test_template_shape_changed_from_makehuman_but_keeps_its_topology():
    asset, makehuman = load_asset(), build_makehuman_template()
    assert np.array_equal(asset.faces, makehuman.faces) and np.array_equal(asset.regions, makehuman.regions)
    moved = np.linalg.norm(asset.vertices - makehuman.vertices, axis=1)
    assert moved[asset.region_mask("nose", "cheeks")].mean() > 1.0  # a different face, not a copy


def test_transfer_is_linear_and_exact_at_covered_vertices(ict):
    asset = load_asset()
    transfer = transfer_of(asset)
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, SKIN_VERTICES, 3))
    ta, tb, tab = transfer.apply(a), transfer.apply(b), transfer.apply(2.0 * a - b)
    assert np.allclose(tab, 2.0 * ta - tb, atol=1e-9)
    # a covered vertex takes the field interpolated at its ICT surface point: a field that is affine in ICT
    # positions transfers to the same affine function of the covered vertices' ICT points
    m = np.array([[0.3, -0.2, 0.1], [0.0, 0.5, 0.2], [0.1, 0.0, -0.4]])
    field = ict.neutral @ m.T
    d = transfer.apply(field)
    points = (ict.neutral[ict.triangles[asset.ict_triangle]] * asset.ict_barycentric[:, :, None]).sum(1)
    assert np.allclose(d[asset.ict_covered], points @ m.T, atol=1e-9)
    # a constant field moves every vertex (continued ones and rigid pieces too) by that constant
    const = transfer.apply(np.broadcast_to([1.0, -2.0, 3.0], (SKIN_VERTICES, 3)))
    assert np.allclose(const, [1.0, -2.0, 3.0], atol=1e-9)


def test_identity_modes_and_expressions_on_the_template():
    asset = load_asset()
    modes = identity_modes(asset)
    assert modes.shape == (NUM_IDENTITY_MODES, len(asset.vertices), 3) and not modes.flags.writeable
    rms = np.sqrt((modes**2).sum(-1).mean(-1))
    assert rms[0] > rms[50] > 0  # principal components: the first mode moves most
    names, shapes = expression_shapes(asset)
    jaw = shapes[names.index("jawOpen")]
    chin = asset.region_mask("chin")
    assert jaw[chin, 1].mean() < -5.0  # the chin goes down
    assert np.linalg.norm(jaw[asset.region_mask("forehead")], axis=1).mean() < 0.2  # the forehead stays
    blink = shapes[names.index("eyeBlink_L")]
    lids = asset.region_mask("eyelids") & (asset.vertices[:, 0] > 0)
    assert blink[lids, 1].min() < -3.0  # the left upper lid comes down
    assert np.abs(blink[asset.region_mask("eyeballs")]).max() < 1.0  # the eyeball stays


@pytest.mark.slow
def test_transfer_matches_a_direct_registration(ict):
    from pipeline.synthetic.population import ict_coefficients, split_seeds
    from rig.ict.mean import on_template

    base = build_makehuman_template()
    mean, reg = on_template(base, ict)
    transfer = transfer_of(load_asset())
    c = ict_coefficients(int(split_seeds("test")[0]))
    transferred = mean + transfer.apply(np.tensordot(c, ict.identity.astype(float), axes=1) @ reg.rotation.T)
    direct, _ = on_template(base, ict, ict.head(c))
    skin = ~np.isin(base.regions, [REGION_NAMES.index(r) for r in ("eyeballs", "teeth", "tongue")])
    dist = np.full(len(base.vertices), np.nan)
    dist[skin] = closest_surface_points(transferred[skin], direct, base.faces[skin[base.faces].all(1)]).distance
    face = np.isin(base.regions, [REGION_NAMES.index(r) for r in ("forehead", "nose", "cheeks", "lips", "chin")])
    assert dist[face].mean() < FACE_TRANSFER_BOUND_MM
    assert np.nanmean(dist) < SKIN_TRANSFER_BOUND_MM
    # the same correspondence where ICT's surface is: the lips and eyelid rims, vertex to vertex
    assert np.linalg.norm(transferred - direct, axis=1)[base.mouth_loop].mean() < 0.5
