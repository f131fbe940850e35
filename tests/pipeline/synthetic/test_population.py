"""pipeline.synthetic.population: seeded synthetic identity heads in the template's topology."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import cKDTree

from pipeline.synthetic import population as pop
from pipeline.synthetic.population import (
    FEATURE_NAMES,
    FEATURES,
    SPLIT_SIZES,
    build_basis,
    feature_basis,
    population_split,
    read_population,
    sample_coefficients,
    synthesize_heads,
    write_population,
)

MIRROR_X = np.array([-1.0, 1.0, 1.0])

# For every symmetric feature: the regions it must move most (the largest displacement is in one of
# them) and regions that must stay still (< 0.05 mm at the extreme of the feature's range).
_FACE_NOT_NOSE = ("ears", "neck", "scalp", "eyeballs", "chin", "jaw", "forehead")
LOCALITY = {
    "nose_length": (("nose",), _FACE_NOT_NOSE + ("lips", "mouth_interior")),
    "nose_width": (("nose",), _FACE_NOT_NOSE + ("lips", "mouth_interior")),
    "nose_hump": (("nose",), _FACE_NOT_NOSE + ("lips", "mouth_interior")),
    "nostril_flare": (("nose",), _FACE_NOT_NOSE + ("lips", "mouth_interior")),
    "lip_volume_upper": (("lips", "mouth_interior"), ("ears", "neck", "scalp", "eyeballs", "eyelids", "nose")),
    "lip_volume_lower": (("lips", "mouth_interior"), ("ears", "neck", "scalp", "eyeballs", "eyelids", "nose")),
    "mouth_width": (("lips", "mouth_interior"), ("ears", "neck", "scalp", "eyeballs", "eyelids", "nose")),
    "cheek_fullness": (("cheeks",), ("ears", "neck", "scalp", "eyeballs", "nose", "lips")),
    "cheekbone": (("cheeks",), ("ears", "neck", "scalp", "eyeballs", "nose", "lips")),
    "brow_ridge": (("brows",), ("ears", "neck", "scalp", "eyeballs", "nose", "lips", "chin")),
    "chin_projection": (("chin",), ("ears", "scalp", "eyeballs", "eyelids", "nose", "neck")),
    "chin_width": (("chin",), ("ears", "scalp", "eyeballs", "eyelids", "nose", "lips")),
    "jaw_angle_width": (("jaw",), ("ears", "scalp", "eyeballs", "eyelids", "nose", "lips", "chin")),
    "forehead_slope": (("forehead", "scalp"), ("ears", "eyeballs", "eyelids", "nose", "lips", "chin", "neck")),
    "ear_size": (("ears",), ("nose", "eyeballs", "eyelids", "lips", "chin", "neck", "scalp", "forehead")),
    "ear_angle": (("ears",), ("nose", "eyeballs", "eyelids", "lips", "chin", "neck", "scalp", "forehead")),
    "ear_shape": (("ears",), ("nose", "eyeballs", "eyelids", "lips", "chin", "neck", "scalp", "forehead")),
    "eye_size": (("eyelids", "eyeballs"), ("ears", "neck", "scalp", "nose", "lips", "chin")),
    "eye_spacing": (("eyelids", "eyeballs"), ("ears", "neck", "scalp", "nose", "lips", "chin")),
    "skull_width": (("scalp",), ("nose", "eyeballs", "eyelids", "lips", "chin", "neck")),
    "occiput_projection": (("scalp",), ("nose", "eyeballs", "eyelids", "lips", "chin", "ears", "forehead")),
    "face_length": (("chin", "lips", "jaw", "cheeks", "neck", "mouth_interior"), ("ears", "forehead", "brows")),
}


@pytest.fixture(scope="module")
def basis(asset):
    return feature_basis(asset)


@pytest.fixture(scope="module")
def splits(asset):
    return {name: population_split(name, seed=0, asset=asset) for name in SPLIT_SIZES}


@pytest.fixture(scope="module")
def samples(asset, splits):
    """20 heads from the training split and 20 from the held-out set."""
    return np.concatenate([splits["train"].vertices[:20], splits["heldout"].vertices[:20]])


@pytest.fixture(scope="module")
def adjacency(asset):
    f = asset.faces
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    n = len(asset.vertices)
    a = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    return a.tocsr()


def _uniform_laplacian(adjacency, d):
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    return d - (adjacency @ d) / degree[:, None]


def _face_normals(v, faces):
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


# ----------------------------------------------------------------------------------------------------
# The feature table and basis
# ----------------------------------------------------------------------------------------------------

def test_feature_table(basis, asset):
    assert basis.names == FEATURE_NAMES == tuple(f.name for f in FEATURES)
    assert len(set(FEATURE_NAMES)) == len(FEATURE_NAMES)
    symmetric = [f for f in FEATURES if f.symmetry == "symmetric"]
    assert len(symmetric) >= 14
    assert set(LOCALITY) == {f.name for f in symmetric}
    assert any(f.symmetry == "antisymmetric" for f in FEATURES)
    for f in FEATURES:
        assert f.unit in ("mm", "deg") and f.low < 0.0 < f.high and f.sd > 0 and 0 < f.p_active <= 1, f
    assert basis.fields.shape == (len(FEATURES), len(asset.vertices), 3)
    assert basis.fields.dtype == np.float64 and np.isfinite(basis.fields).all()
    # mm features are normalised: coefficient = peak displacement
    for f, field in zip(FEATURES, basis.fields):
        peak = np.linalg.norm(field, axis=1).max()
        partner = f.name.startswith("asym_") and f.name[5:] in FEATURE_NAMES  # scaled like its feature
        if f.unit == "mm" and not partner:
            assert peak == pytest.approx(1.0), f.name
        else:
            assert 0.0 < peak < 2.0, f.name


def test_basis_is_cached_and_reproducible(asset, basis):
    assert feature_basis(asset) is basis
    fresh = build_basis(asset)
    assert np.array_equal(fresh.fields, basis.fields)
    with pytest.raises(ValueError):
        basis.fields[0, 0, 0] = 1.0  # read-only


def test_symmetric_and_antisymmetric_fields(basis, asset):
    m = asset.mirror
    for f, field in zip(FEATURES, basis.fields):
        mirrored = field[m] * MIRROR_X
        if f.symmetry == "symmetric":
            assert np.abs(mirrored - field).max() <= 1e-9, f.name
        else:
            assert np.abs(mirrored + field).max() <= 1e-9, f.name  # antisymmetric ...
            assert np.abs(mirrored - field).max() > 0.1, f.name  # ... hence not symmetric


def test_features_are_local(basis, asset):
    for f, field in zip(FEATURES, basis.fields):
        if f.symmetry != "symmetric":
            continue
        moves, still = LOCALITY[f.name]
        d = np.linalg.norm(field, axis=1) * max(abs(f.low), abs(f.high))
        assert d[asset.region_mask(*moves)].max() >= 0.9 * d.max(), f.name
        assert d[asset.region_mask(*still)].max() < 0.05, (f.name, d[asset.region_mask(*still)].max())
    # and the partners of paired features stay where their feature is
    for f, field in zip(FEATURES, basis.fields):
        if f.name.startswith("asym_") and f.name[5:] in LOCALITY:
            d = np.linalg.norm(field, axis=1) * max(abs(f.low), abs(f.high))
            assert d[asset.region_mask(*LOCALITY[f.name[5:]][1])].max() < 0.05, f.name


def test_paired_partner_gives_left_and_right_coefficients(basis, asset):
    i, j = FEATURE_NAMES.index("ear_angle"), FEATURE_NAMES.index("asym_ear_angle")
    c = np.zeros(len(FEATURES))
    c[i], c[j] = 6.0, 2.0  # left ear 8 degrees, right ear 4
    d = synthesize_heads(c, asset) - asset.vertices
    left = asset.region_mask("ears") & (asset.vertices[:, 0] > 0)
    right_of_left = asset.mirror[left]
    ratio = np.linalg.norm(d[left], axis=1).sum() / np.linalg.norm(d[right_of_left], axis=1).sum()
    assert ratio == pytest.approx(2.0, rel=1e-9)


# ----------------------------------------------------------------------------------------------------
# Sampling, synthesis and the splits
# ----------------------------------------------------------------------------------------------------

def test_sample_coefficients():
    c = sample_coefficients(np.random.default_rng(5), 2000)
    assert c.shape == (2000, len(FEATURES))
    low = np.array([f.low for f in FEATURES])
    high = np.array([f.high for f in FEATURES])
    assert (c >= low).all() and (c <= high).all()
    active = (c != 0).mean(axis=0)
    p = np.array([f.p_active for f in FEATURES])
    assert np.abs(active - p).max() < 0.05
    assert (p < 1).any()  # some features are sparse
    assert np.array_equal(c, sample_coefficients(np.random.default_rng(5), 2000))
    assert np.array_equal(sample_coefficients(7, 3), sample_coefficients(np.random.default_rng(7), 3))
    assert sample_coefficients(np.random.default_rng(0), 0).shape == (0, len(FEATURES))
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError):
            sample_coefficients(np.random.default_rng(0), bad)
    with pytest.raises(ValueError):
        sample_coefficients("seed", 2)


def test_synthesize_heads_is_linear_in_the_coefficients(asset, basis):
    assert np.array_equal(synthesize_heads(np.zeros(len(FEATURES)), asset), asset.vertices)
    c = sample_coefficients(np.random.default_rng(1), 3)
    heads = synthesize_heads(c, asset)
    assert heads.shape == (3, len(asset.vertices), 3) and heads.dtype == np.float64
    expected = asset.vertices + np.tensordot(c, basis.fields, axes=1)
    assert np.abs(heads - expected).max() < 1e-9
    assert np.abs(synthesize_heads(c[1], asset) - heads[1]).max() < 1e-12
    assert np.abs(basis.displacements(c) - (heads - asset.vertices)).max() < 1e-9
    with pytest.raises(ValueError, match="coefficients must have shape"):
        synthesize_heads(np.zeros((2, len(FEATURES) + 1)), asset)
    with pytest.raises(ValueError, match="finite"):
        synthesize_heads(np.full(len(FEATURES), np.nan), asset)


def test_split_sizes_and_names(splits):
    assert {k: len(v) for k, v in splits.items()} == {"train": 85, "val": 2, "test": 7, "heldout": 100}
    names = [n for p in splits.values() for n in p.names]
    assert len(names) == len(set(names)) == 194
    assert splits["train"].names[0] == "train_000" and splits["heldout"].names[-1] == "heldout_099"
    for name, p in splits.items():
        assert p.split == name and p.expression == "neutral"
        assert p.feature_names == FEATURE_NAMES
        assert p.coefficients.shape == (len(p), len(FEATURES))
        assert p.vertices.shape[0] == len(p) and p.vertices.dtype == np.float64
        for seed, coefficients in zip(p.seeds[:3], p.coefficients[:3]):  # per-head seeds reproduce the head
            assert np.array_equal(sample_coefficients(np.random.default_rng(int(seed)), 1)[0], coefficients)


def test_determinism_and_independent_splits(asset, splits):
    again = population_split("test", seed=0, asset=asset)
    assert np.array_equal(again.vertices, splits["test"].vertices)
    assert np.array_equal(again.coefficients, splits["test"].coefficients)
    other_seed = population_split("test", seed=1, asset=asset)
    assert not np.allclose(other_seed.vertices, splits["test"].vertices)
    # no two heads in different splits are alike
    all_c = np.concatenate([p.coefficients for p in splits.values()])
    d = np.linalg.norm(all_c[:, None] - all_c[None], axis=-1) + np.eye(len(all_c)) * 1e9
    assert d.min() > 1.0
    assert not np.allclose(splits["val"].vertices[0], splits["test"].vertices[0])
    for bad_name, bad_seed in (("training", 0), ("val", -1), ("val", 1.5)):
        with pytest.raises(ValueError):
            population_split(bad_name, seed=bad_seed, asset=asset)


# ----------------------------------------------------------------------------------------------------
# Quality of the heads
# ----------------------------------------------------------------------------------------------------

def test_heads_are_smooth_and_unflipped(asset, samples, adjacency):
    n0 = _face_normals(asset.vertices, asset.faces)
    for head in samples:
        d = head - asset.vertices
        lap = np.linalg.norm(_uniform_laplacian(adjacency, d), axis=1)
        nd = np.linalg.norm(d, axis=1)
        assert np.sqrt((lap ** 2).mean() / (nd ** 2).mean()) < 0.4  # a noise field gives ~1.1
        assert lap.max() < 0.75 * nd.max()  # a one-vertex spike gives 1.0
        dots = (_face_normals(head, asset.faces) * n0).sum(axis=1)
        assert dots.min() > 0.3  # no face flips (or even turns steeply)
    # the measure does tell a spike from a smooth field
    spike = np.zeros_like(asset.vertices)
    spike[1000] = (0.0, 0.0, 3.0)
    assert np.linalg.norm(_uniform_laplacian(adjacency, spike), axis=1).max() == pytest.approx(3.0)


def test_nearby_surfaces_never_collapse(asset, samples):
    """Vertices within 8 mm (across the mouth slit, eyelids over the eyeballs, ears and skull) keep apart."""
    v = asset.vertices
    pairs = np.array(sorted(cKDTree(v).query_pairs(8.0)))
    d0 = np.linalg.norm(v[pairs[:, 0]] - v[pairs[:, 1]], axis=1)
    inner = asset.region_mask("eyeballs", "mouth_interior")
    across = inner[pairs[:, 0]] != inner[pairs[:, 1]]  # interior vertex next to skin (lids, lips)
    assert across.sum() > 50
    for head in samples:
        ratio = np.linalg.norm(head[pairs[:, 0]] - head[pairs[:, 1]], axis=1) / d0
        assert ratio.min() > 0.35
        assert ratio[across].min() > 0.5


def test_plausible_magnitudes_and_proportions(asset, splits):
    heads = np.concatenate([p.vertices for p in splits.values()])
    d = np.linalg.norm(heads - asset.vertices, axis=2)
    assert (d.max(axis=1) > 1.0).all() and (d.max(axis=1) < 20.0).all()
    assert 3.0 < np.median(d.max(axis=1)) < 10.0
    mean = d.mean(axis=1)
    assert (mean > 0.2).all() and (mean < 5.0).all()
    head = ~asset.region_mask("neck", "ears")
    chin = asset.region_mask("chin")
    width = 2 * np.abs(heads[:, head, 0]).max(axis=1)
    height = heads[:, :, 1].max(axis=1) - heads[:, chin, 1].min(axis=1)
    assert (width > 135).all() and (width < 175).all()
    assert (height > 215).all() and (height < 250).all()
    assert width.std() > 2.0 and height.std() > 1.0  # the population varies
    # the face still points forward: the nose tip is the front-most point
    tip = np.argmax(heads[:, :, 2], axis=1)
    assert (asset.regions[tip] == asset.region_names.index("nose")).all()


# ----------------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------------

def test_write_and_read_round_trip(tmp_path, asset, splits):
    out = tmp_path / "population"
    calls = []
    manifest_path = write_population(out, seed=0, splits=("val", "test"),
                                     progress=lambda stage, done, total: calls.append((done, total)))
    assert manifest_path == out / "manifest.json"
    assert calls[0] == (0, 9) and calls[-1] == (9, 9) and len(calls) == 10
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "test", "val"]
    assert len(list((out / "test").glob("*.ply"))) == 7
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left

    manifest = json.loads(manifest_path.read_text())
    assert manifest["units"] == "mm" and manifest["generator_version"] == pop.GENERATOR_VERSION
    assert manifest["coordinates"]["up"] == "+Y" and manifest["feature_names"] == list(FEATURE_NAMES)
    head = manifest["heads"][0]
    assert head["split"] == "val" and head["name"] == "val_000" and head["file"] == "val/val_000.ply"
    assert head["vertex_count"] == len(asset.vertices) and set(head["coefficients"]) == set(FEATURE_NAMES)
    assert isinstance(head["seed"], int)

    loaded = read_population(manifest_path)
    assert list(loaded) == ["val", "test"]
    for name, p in loaded.items():
        assert p.names == splits[name].names
        assert np.abs(p.vertices - splits[name].vertices).max() < 1e-5
        assert np.array_equal(p.coefficients, splits[name].coefficients)
        assert np.array_equal(p.seeds, splits[name].seeds)
    assert read_population(out)["val"].names == ("val_000", "val_001")  # the directory works too

    # A second call without overwrite refuses and leaves the first output intact.
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with pytest.raises(FileExistsError, match="--force"):
        write_population(out, seed=1, splits=("val",))
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before

    # overwrite replaces it
    write_population(out, seed=1, splits=("val",), file_format="obj", overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "val"]
    again = read_population(out / "manifest.json")["val"]
    expected = population_split("val", seed=1, asset=asset)
    assert np.abs(again.vertices - expected.vertices).max() < 1e-5
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_failed_write_leaves_nothing(tmp_path):
    out = tmp_path / "population"

    def fail(stage, done, total):
        if done == 3:
            raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError, match="interrupted"):
        write_population(out, splits=("test",), progress=fail)
    assert list(tmp_path.iterdir()) == []
    # an existing empty directory is fine without overwrite
    out.mkdir()
    write_population(out, splits=("val",))
    assert (out / "val" / "val_001.ply").is_file()


def test_write_population_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="file_format"):
        write_population(tmp_path / "a", splits=("val",), file_format="stl")
    with pytest.raises(ValueError, match="unknown split"):
        write_population(tmp_path / "a", splits=("validation",))
    with pytest.raises(ValueError, match="duplicates"):
        write_population(tmp_path / "a", splits=("val", "val"))
    (tmp_path / "file").write_text("x")
    with pytest.raises(FileExistsError):
        write_population(tmp_path / "file", splits=("val",))
    with pytest.raises(FileNotFoundError):
        read_population(tmp_path / "missing.json")
