"""pipeline.synthetic.population: seeded MakeHuman identity heads in the template's topology (the MakeHuman
population, :func:`makehuman_split`, built on MakeHuman's average head) and the population on disk (ICT and
MakeHuman splits). The ICT splits themselves: ``test_ict_population.py``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.synthetic import population as pop
from pipeline.synthetic.population import (
    FEATURE_NAMES,
    FEATURES,
    MAKEHUMAN_SPLIT_SIZES,
    MODE_NAMES,
    PHENOTYPE_NAMES,
    SPLIT_SIZES,
    build_basis,
    default_phenotype,
    feature_basis,
    feature_mask,
    flipped_skin_faces,
    makehuman_split,
    mirror_coefficients,
    phenotype_displacements,
    phenotype_of,
    population_split,
    read_population,
    sample_coefficients,
    sample_head,
    sample_phenotypes,
    split_seeds,
    synthesize_heads,
    write_population,
)
from pipeline.synthetic.population.files import READABLE_VERSIONS, SPLIT_KINDS, _mesh_bytes
from rig.makehuman.base_mesh import data_dir
from rig.makehuman.head import head_mesh
from rig.makehuman.phenotype import Phenotype, phenotype_offsets
from rig.makehuman.targets import target_on_head
from rig.template import HIDDEN_REGIONS, makehuman_vertices

MIRROR_X = np.array([-1.0, 1.0, 1.0])
ASYMMETRIC = ("antisymmetric", "mirror_negated")


@pytest.fixture(scope="module")
def basis(asset):
    return feature_basis(asset)


@pytest.fixture(scope="module")
def splits(asset):
    """The MakeHuman population's splits (train, val, test and the shifted heldout)."""
    return {name: makehuman_split(name, seed=0, asset=asset) for name in MAKEHUMAN_SPLIT_SIZES}


@pytest.fixture(scope="module")
def mh_base():
    """MakeHuman's average head: what the MakeHuman heads are built on (not the template, the ICT mean)."""
    return makehuman_vertices()


def _mirror(v, asset):
    return v[..., asset.mirror, :] * MIRROR_X


def _rms(d) -> float:
    return float(np.sqrt((np.asarray(d) ** 2).sum(-1).mean()))


def _symmetric_part(coefficients):
    """The coefficients with every asymmetric term removed: right = left, the rest of the asymmetric ones 0."""
    c = np.array(coefficients, float)
    for i, f in enumerate(FEATURES):
        if f.symmetry in ASYMMETRIC:
            c[..., i] = 0.0
        elif f.symmetry == "right":
            c[..., i] = c[..., FEATURE_NAMES.index(f.mirror)]
    return c


def _skin_normal_dots(heads, asset, reference):
    """Cosine between every skin triangle's normal and the reference head's, ``(n, F_skin)``."""
    faces = asset.faces[~asset.region_mask(*HIDDEN_REGIONS)[asset.faces].any(1)]

    def normals(v):
        t = v[..., faces, :]
        n = np.cross(t[..., 1, :] - t[..., 0, :], t[..., 2, :] - t[..., 0, :])
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    return (normals(heads) * normals(reference)).sum(-1)


# ----------------------------------------------------------------------------------------------------
# The feature table and basis
# ----------------------------------------------------------------------------------------------------


def test_feature_table():
    assert FEATURE_NAMES == tuple(f.name for f in FEATURES) and len(set(FEATURE_NAMES)) == len(FEATURES) == 170
    kinds = {k: int(feature_mask(k).sum()) for k in pop.KINDS}
    assert kinds == {"local": 134, "asym": 29, "head_shape": 7}
    local = [f for f in FEATURES if f.kind == "local"]
    assert {g: sum(f.group == g for f in local) for g in pop.LOCAL_GROUPS} == {
        "cheek": 8,
        "chin": 7,
        "ears": 22,
        "eyebrows": 3,
        "eyes": 32,
        "forehead": 4,
        "head": 7,
        "mouth": 22,
        "neck": 8,
        "nose": 21,
    }  # as counted in the MakeHuman note
    assert not {f.name.removeprefix("l-").removeprefix("r-") for f in FEATURES} & set(pop.TRANSLATING_TARGETS)
    assert {f.name for f in FEATURES if f.symmetry == "antisymmetric"} == set(pop.ANTISYMMETRIC_TARGETS)
    assert {f.name for f in FEATURES if f.kind == "head_shape"} == set(pop.HEAD_SHAPES)
    by_name = {f.name: f for f in FEATURES}
    for f in FEATURES:
        partner = by_name[f.mirror]
        assert partner.mirror == f.name and partner.kind == f.kind
        assert (f.mirror != f.name) == (f.symmetry in ("left", "right"))
        if f.symmetry == "left":
            assert f.name.startswith("l-") and partner.symmetry == "right"
        assert (f.low, f.high) == ((0.0, 1.0) if f.kind == "head_shape" else (-1.0, 1.0))
        assert (f.negative is None) == (f.kind == "head_shape")
    assert by_name["asym-eye-1"].positive == "asym/asym-eye-1-r.target.gz"  # c < 0: the -l file, c > 0: -r
    assert by_name["asym-eye-1"].negative == "asym/asym-eye-1-l.target.gz"
    assert by_name["l-cheek-volume-decr-incr"].positive == "cheek/l-cheek-volume-incr.target.gz"


def test_basis_is_cached_read_only_and_reproducible(asset, basis):
    assert feature_basis(asset) is basis
    assert basis.names == FEATURE_NAMES
    # the MakeHuman heads are built on MakeHuman's own average head, which is not the template (the ICT mean)
    assert np.array_equal(basis.template, makehuman_vertices()) and not basis.template.flags.writeable
    assert np.abs(basis.template - asset.vertices).max() > 5.0
    assert basis.positive.shape == basis.negative.shape == (len(FEATURES), len(asset.vertices), 3)
    assert np.array_equal(build_basis(asset).positive, basis.positive)
    with pytest.raises(ValueError):
        basis.positive[0, 0, 0] = 1.0
    assert not basis.negative[feature_mask("head_shape")].any()
    peak = np.linalg.norm(basis.positive, axis=2).max(1)
    assert (peak > 0.05).all() and (peak < 60.0).all()  # every target moves the head, none absurdly


def test_fields_are_exactly_mirror_consistent(asset, basis):
    index = {n: i for i, n in enumerate(FEATURE_NAMES)}
    for i, f in enumerate(FEATURES):
        pos, neg = basis.positive[i], basis.negative[i]
        if f.symmetry == "symmetric":
            assert np.abs(_mirror(pos, asset) - pos).max() < 1e-12, f.name
            assert np.abs(_mirror(neg, asset) - neg).max() < 1e-12, f.name
        elif f.symmetry == "antisymmetric":
            assert np.abs(_mirror(pos, asset) + pos).max() < 1e-12 and np.array_equal(neg, -pos), f.name
        elif f.symmetry == "mirror_negated":
            assert np.abs(_mirror(pos, asset) - neg).max() < 1e-12, f.name
        else:
            j = index[f.mirror]
            assert np.abs(_mirror(pos, asset) - basis.positive[j]).max() < 1e-12, f.name
            assert np.abs(_mirror(neg, asset) - basis.negative[j]).max() < 1e-12, f.name
    # a left target is on the left
    left = basis.template[:, 0] > 0
    for i, f in enumerate(FEATURES):
        if f.symmetry == "left" and f.group != "head":
            d = np.linalg.norm(basis.positive[i], axis=1)
            assert d[left].sum() > 0.9 * d.sum(), f.name


def test_symmetrisation_of_makehuman_pairs(asset, basis):
    """L' = (L + mirror(R)) / 2, and MakeHuman's own pairs were close to mirror images already."""
    head, folder = head_mesh(), data_dir() / "mpfb2" / "targets"
    i = FEATURE_NAMES.index("l-eye-height1-decr-incr")  # the least symmetric pair (7 %)
    f, g = FEATURES[i], FEATURES[FEATURE_NAMES.index("r-eye-height1-decr-incr")]
    left, right = target_on_head(folder / f.negative, head), target_on_head(folder / g.negative, head)
    expected = 0.5 * (left + _mirror(right, asset))
    assert np.abs(basis.negative[i] - expected).max() < 1e-12
    assert 0.0 < _rms(basis.negative[i] - left) < 0.1 * _rms(left)
    asym = FEATURE_NAMES.index("asym-nose-2")
    raw_l = target_on_head(folder / FEATURES[asym].negative, head)
    raw_r = target_on_head(folder / FEATURES[asym].positive, head)
    assert np.abs(basis.negative[asym] - 0.5 * (raw_l + _mirror(raw_r, asset))).max() < 1e-12
    assert _rms(raw_l - _mirror(raw_r, asset)) < 0.2 * _rms(raw_l)
    # an antisymmetric target really is (nearly) antisymmetric in MakeHuman's file
    nose = target_on_head(folder / FEATURES[FEATURE_NAMES.index("nose-trans-in-out")].positive, head)
    assert _rms(nose + _mirror(nose, asset)) < 0.01 * _rms(nose)


# ----------------------------------------------------------------------------------------------------
# Phenotypes
# ----------------------------------------------------------------------------------------------------


def test_sample_phenotypes():
    p = sample_phenotypes(np.random.default_rng(3), 3000)
    assert p.shape == (3000, len(PHENOTYPE_NAMES)) and PHENOTYPE_NAMES[:2] == ("gender", "age")
    col = {n: p[:, i] for i, n in enumerate(PHENOTYPE_NAMES)}
    assert 0.0 <= col["gender"].min() < 0.02 and 0.98 < col["gender"].max() <= 1.0
    assert col["age"].min() >= Phenotype.age_value(18) and col["age"].max() <= Phenotype.age_value(80)
    assert abs(np.median(col["age"]) - Phenotype.age_value(49)) < 0.02
    for name in ("muscle", "weight"):
        assert 0.3 <= col[name].min() and col[name].max() <= 0.7 and 0.09 < col[name].std() < 0.11
    assert 0.25 <= col["height"].min() and col["height"].max() <= 0.75
    assert (col["proportions"] == 0.5).all()
    race = p[:, -3:]
    assert np.abs(race.sum(1) - 1.0).max() < 1e-12 and (race > 0).all()
    assert np.abs(race.mean(0) - 1 / 3).max() < 0.02  # uniform on the simplex
    assert np.array_equal(p, sample_phenotypes(np.random.default_rng(3), 3000))
    assert sample_phenotypes(0, 0).shape == (0, len(PHENOTYPE_NAMES))
    phenotype_of(p[0])  # a valid rig.makehuman.Phenotype
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError):
            sample_phenotypes(0, bad)


def test_phenotype_part(asset, basis):
    p = np.array([0.9, Phenotype.age_value(70), 0.6, 0.4, 0.7, 0.5, 0.1, 0.7, 0.2])
    d = phenotype_displacements(p, asset)
    raw = phenotype_offsets(phenotype_of(p)) - phenotype_offsets()  # rig.makehuman's own mixing
    raw = 0.5 * (raw + _mirror(raw, asset))
    eyes = asset.region_mask("eyeballs")
    shift = raw[eyes].mean(0)
    assert abs(shift[1]) > 10.0  # the macro targets do move the head with the body ...
    assert np.abs(d - (raw - [0.0, shift[1], shift[2]])).max() < 1e-9  # ... and that is taken out
    assert np.abs(d[eyes].mean(0)).max() < 1e-9
    assert np.abs(_mirror(d, asset) - d).max() < 1e-9
    assert 2.0 < _rms(d - d.mean(0)) < 15.0
    assert not phenotype_displacements(default_phenotype(), asset).any()
    heads = synthesize_heads(np.zeros((2, len(FEATURES))), np.stack([default_phenotype(), p]), asset)
    assert np.array_equal(heads[0], basis.template) and np.abs(heads[1] - basis.template - d).max() < 1e-12
    with pytest.raises(ValueError, match="phenotypes must have shape"):
        synthesize_heads(np.zeros(len(FEATURES)), np.zeros(4), asset)
    with pytest.raises(ValueError, match="within"):
        phenotype_displacements(np.full(len(PHENOTYPE_NAMES), 1.5), asset)


# ----------------------------------------------------------------------------------------------------
# Feature coefficients and synthesis
# ----------------------------------------------------------------------------------------------------


def test_sample_coefficients():
    c = sample_coefficients(np.random.default_rng(5), 4000)
    assert c.shape == (4000, len(FEATURES))
    low, high = np.array([f.low for f in FEATURES]), np.array([f.high for f in FEATURES])
    assert (c >= low).all() and (c <= high).all()
    assert not c[:, ~feature_mask("local")].any()  # the unshifted distribution never uses asym / head shapes
    sd = c.std(0)
    sym = np.array([f.symmetry == "symmetric" and f.kind == "local" for f in FEATURES])
    anti = np.array([f.symmetry == "antisymmetric" for f in FEATURES])
    assert np.abs(sd[sym] - pop.LOCAL_SD).max() < 0.02 and np.abs(sd[anti] - pop.ASYM_NOISE_SD).max() < 0.005
    for i, f in enumerate(FEATURES):
        if f.symmetry == "left":  # tied: a shared value plus a little noise per side
            diff = c[:, i] - c[:, FEATURE_NAMES.index(f.mirror)]
            assert abs(diff.std() - np.sqrt(2) * pop.ASYM_NOISE_SD) < 0.005, f.name
            assert np.corrcoef(c[:, i], c[:, FEATURE_NAMES.index(f.mirror)])[0, 1] > 0.9
    shifted = sample_coefficients(np.random.default_rng(5), 4000, shifted=True)
    asym, shapes = feature_mask("asym"), feature_mask("head_shape")
    assert (shifted[:, asym] != 0).all() and np.abs(shifted[:, asym].std(0) - pop.ASYM_SLIDER_SD).max() < 0.02
    assert (shifted[:, shapes] >= 0).all() and (shifted[:, shapes] <= 1).all()
    assert np.abs(shifted[:, shapes].mean(0) - pop.HEAD_SHAPE_SD * np.sqrt(2 / np.pi)).max() < 0.02
    assert np.array_equal(sample_coefficients(7, 3), sample_coefficients(np.random.default_rng(7), 3))
    assert sample_coefficients(0, 0).shape == (0, len(FEATURES))
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError):
            sample_coefficients(0, bad)
    with pytest.raises(ValueError):
        sample_coefficients("seed", 2)


def test_synthesis_is_piecewise_linear_in_the_coefficients(asset, basis):
    assert np.array_equal(synthesize_heads(np.zeros(len(FEATURES)), asset=asset), basis.template)
    c = sample_coefficients(np.random.default_rng(1), 3, shifted=True)
    heads = synthesize_heads(c, asset=asset)
    assert heads.shape == (3, len(asset.vertices), 3) and heads.dtype == np.float64
    expected = (
        basis.template
        + np.tensordot(np.maximum(c, 0), basis.positive, 1)
        + np.tensordot(np.maximum(-c, 0), basis.negative, 1)
    )
    assert np.abs(heads - expected).max() < 1e-9
    assert np.abs(synthesize_heads(c[1], asset=asset) - heads[1]).max() < 1e-12
    i = FEATURE_NAMES.index("chin-height-decr-incr")  # MakeHuman's two files differ: not an odd function
    one = np.zeros(len(FEATURES))
    one[i] = 0.5
    up = synthesize_heads(one, asset=asset) - basis.template
    down = synthesize_heads(-one, asset=asset) - basis.template
    assert np.abs(up - 0.5 * basis.positive[i]).max() < 1e-12 and np.abs(down - 0.5 * basis.negative[i]).max() < 1e-12
    assert _rms(up + down) > 0.1 * _rms(up)
    with pytest.raises(ValueError, match="coefficients must have shape"):
        synthesize_heads(np.zeros((2, len(FEATURES) + 1)), asset=asset)
    with pytest.raises(ValueError, match="finite"):
        synthesize_heads(np.full(len(FEATURES), np.nan), asset=asset)


def test_a_head_without_asymmetric_terms_is_exactly_symmetric(asset):
    for seed in (1, 2):
        phenotype, c = sample_head(seed, shifted=True, asset=asset)  # any phenotype, head shapes included
        head = synthesize_heads(_symmetric_part(c), phenotype, asset)
        assert np.abs(_mirror(head, asset) - head).max() < 1e-9
        full = synthesize_heads(c, phenotype, asset)
        assert _rms(_mirror(full, asset) - full) > 0.2  # the asymmetric terms do break the symmetry
        # and the mirror image of any head is the head of the mirrored coefficients
        mirrored = synthesize_heads(mirror_coefficients(c), phenotype, asset)
        assert np.abs(mirrored - _mirror(full, asset)).max() < 1e-9
    assert np.array_equal(mirror_coefficients(mirror_coefficients(c)), c)


def test_flipped_skin_faces_counts_turned_triangles(asset, mh_base):
    """Counted against MakeHuman's average head (the MakeHuman heads' base), not the template."""
    assert flipped_skin_faces(mh_base, asset) == 0
    head = mh_base.copy()
    skin = ~asset.region_mask(*HIDDEN_REGIONS)[asset.faces].any(1)
    a, b, c = asset.faces[np.where(skin)[0][100]]
    head[a] = head[b] + head[c] - head[a]  # reflect one corner across the opposite edge: that face turns over
    assert flipped_skin_faces(np.stack([mh_base, head]), asset).tolist()[0] == 0
    assert flipped_skin_faces(head, asset) >= 1
    # a hidden triangle (an eyeball's) turned over is not counted
    hidden = np.where(asset.region_mask("eyeballs")[asset.faces].all(1))[0]
    a, b, c = asset.faces[hidden[0]]
    inner = mh_base.copy()
    inner[a] = inner[b] + inner[c] - inner[a]
    assert flipped_skin_faces(inner, asset) == 0


# ----------------------------------------------------------------------------------------------------
# The MakeHuman population's splits (makehuman_split)
# ----------------------------------------------------------------------------------------------------


def test_split_sizes_and_names(splits):
    assert MAKEHUMAN_SPLIT_SIZES == {"train": 85, "val": 2, "test": 7, "heldout": 100}
    assert {k: len(v) for k, v in splits.items()} == MAKEHUMAN_SPLIT_SIZES
    names = [n for p in splits.values() for n in p.names]
    assert len(names) == len(set(names)) == 194
    assert splits["train"].names[0] == "train_000" and splits["heldout"].names[-1] == "heldout_099"
    for name, p in splits.items():
        assert p.split == name and p.expression == "neutral" and p.shifted == (name == "heldout")
        assert p.feature_names == FEATURE_NAMES and p.phenotype_names == PHENOTYPE_NAMES
        assert p.coefficients.shape == (len(p), len(FEATURES)) and p.phenotypes.shape == (len(p), 9)
        assert p.vertices.shape[0] == len(p) and p.vertices.dtype == np.float64


def test_heads_are_reproducible_from_their_seeds(asset, splits):
    for name in ("val", "heldout"):
        p = splits[name]
        for i in (0, len(p) - 1):
            phenotype, c = sample_head(int(p.seeds[i]), shifted=p.shifted, asset=asset)
            assert np.array_equal(phenotype, p.phenotypes[i]) and np.array_equal(c, p.coefficients[i])
            assert np.array_equal(synthesize_heads(c, phenotype, asset), p.vertices[i])
    for name, p in splits.items():  # the MakeHuman streams are the ones from before issue 25
        assert np.array_equal(p.seeds, split_seeds(name, 0, stream="makehuman"))
        assert not np.isin(p.seeds, split_seeds(name, 0)).any()  # and not the ICT split's of the same name
    again = makehuman_split("test", seed=0, asset=asset)
    assert np.array_equal(again.vertices, splits["test"].vertices)
    assert np.array_equal(again.seeds, splits["test"].seeds)
    other = makehuman_split("test", seed=1, asset=asset)
    assert np.abs(other.vertices - splits["test"].vertices).max() > 1.0
    # no two heads in different splits are alike
    all_c = np.concatenate([p.coefficients for p in splits.values()])
    d = np.linalg.norm(all_c[:, None] - all_c[None], axis=-1) + np.eye(len(all_c)) * 1e9
    assert d.min() > 0.5
    for bad_name, bad_seed in (("training", 0), ("makehuman", 0), ("val", -1), ("val", 1.5)):
        with pytest.raises(ValueError):
            makehuman_split(bad_name, seed=bad_seed, asset=asset)
    for bad_name, bad_seed in (("training", 0), ("val", -1), ("val", 1.5)):
        with pytest.raises(ValueError):
            population_split(bad_name, seed=bad_seed, asset=asset)


def test_first_heads_of_a_split_are_the_splits_first_heads(asset, splits):
    head = makehuman_split("heldout", seed=0, asset=asset, first=3)
    assert head.names == splits["heldout"].names[:3] and np.array_equal(head.seeds, splits["heldout"].seeds[:3])
    assert np.array_equal(head.vertices, splits["heldout"].vertices[:3])
    assert np.array_equal(head.coefficients, splits["heldout"].coefficients[:3])
    assert len(makehuman_split("val", asset=asset, first=10)) == 2
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="first"):
            makehuman_split("val", asset=asset, first=bad)


def test_heldout_is_shifted(asset, splits):
    extra = ~feature_mask("local")
    for name in ("train", "val", "test"):
        assert not splits[name].coefficients[:, extra].any(), name
    held = splits["heldout"].coefficients
    assert (held[:, feature_mask("asym")] != 0).all() and (held[:, feature_mask("head_shape")] > 0).mean() > 0.95
    assert splits["heldout"].coefficients[:, feature_mask("asym")].std() > 0.2

    def asymmetry(p):
        return np.sqrt(((_mirror(p.vertices, asset) - p.vertices) ** 2).sum(-1).mean(-1)) / 2

    train, heldout = asymmetry(splits["train"]), asymmetry(splits["heldout"])
    assert 0.1 < np.median(train) < 1.0 and np.median(heldout) > 2.0 * np.median(train)


def test_population_spread(asset, splits, mh_base):
    """~7 mm RMS around the mean head (the MakeHuman note's figure for N(0, 0.25) plus phenotypes)."""
    for name in ("train", "heldout"):
        v = splits[name].vertices
        spread = _rms(v - v.mean(0))
        assert 5.5 < spread < 9.5, (name, spread)
        per_head = np.sqrt(((v - mh_base) ** 2).sum(-1).mean(-1))  # from the head they are built on
        assert per_head.min() > 2.0 and per_head.max() < 20.0
    train, held = splits["train"].vertices, splits["heldout"].vertices
    assert _rms(held - held.mean(0)) > _rms(train - train.mean(0))  # the extra terms add variation
    heads = np.concatenate([p.vertices for p in splits.values()])
    width = 2 * np.abs(heads[:, ~asset.region_mask("neck", "ears"), 0]).max(1)
    assert width.min() > 110 and width.max() < 190 and width.std() > 4.0
    front = asset.regions[np.argmax(heads[:, :, 2], axis=1)]
    assert np.isin(front, [asset.region_names.index(r) for r in ("nose", "lips")]).all()


def test_no_flipped_faces_on_the_skin(asset, splits, mh_base):
    heads = np.concatenate([splits["train"].vertices[:10], splits["heldout"].vertices[:10]])
    dots = _skin_normal_dots(heads, asset, mh_base)
    assert dots.min() > 0.0  # every skin triangle within 90 degrees of MakeHuman's average head's
    assert (flipped_skin_faces(heads, asset) == 0).all()
    # the rejection is needed (MakeHuman's creases fold under about half of the raw draws), not a formality
    rng = np.random.default_rng(11)
    raw = synthesize_heads(sample_coefficients(rng, 40), sample_phenotypes(rng, 40), asset)
    folded = (_skin_normal_dots(raw, asset, mh_base) <= 0).any(1)
    assert 0.2 < folded.mean() < 0.8
    assert np.array_equal(folded, flipped_skin_faces(raw, asset) > 0)


# ----------------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ict_splits(asset):
    return {name: population_split(name, seed=0, asset=asset) for name in ("val", "test")}


def test_write_and_read_round_trip(tmp_path, asset, ict_splits):
    out = tmp_path / "population"
    calls = []
    manifest_path = write_population(
        out, seed=0, splits=("val", "test"), progress=lambda stage, done, total: calls.append((done, total))
    )
    assert manifest_path == out / "manifest.json"
    assert calls[0] == (0, 9) and calls[-1] == (9, 9) and len(calls) == 10
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "test", "val"]
    assert len(list((out / "test").glob("*.ply"))) == 7
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left

    manifest = json.loads(manifest_path.read_text())
    assert manifest["units"] == "mm" and manifest["generator_version"] == pop.GENERATOR_VERSION == 3
    assert manifest["coordinates"]["up"] == "+Y" and manifest["shifted_splits"] == ["heldout", "makehuman"]
    assert manifest["split_sizes"] == {"val": 2, "test": 7} and list(manifest["splits"]) == ["val", "test"]
    for name, entry in manifest["splits"].items():
        assert entry["kind"] == "ict" and entry["size"] == SPLIT_SIZES[name] and entry["shifted"] is False
        assert entry["feature_names"] == list(MODE_NAMES) and entry["phenotype_names"] == []
        assert "ict_coefficients(seed, shifted=False)" in entry["head"] and "ict_heads" in entry["head"]
        assert f"crc32('ict-{name}')" in entry["seed_derivation"] and "features" not in entry
    dist = manifest["distributions"]
    assert dist["ict"]["mode_sd"] == [1.0] * 100
    assert dist["ict"]["shifted_mode_sd"] == [1.25] * 30 + [1.5] * 70
    assert "modes 1-30: normal(0, 1.25^2), modes 31-100: normal(0, 1.5^2)" in dist["ict"]["coefficients"]
    assert {"phenotype", "local", "asym", "head_shape"} <= set(dist["makehuman"])
    head = manifest["heads"][0]
    assert head["split"] == "val" and head["name"] == "val_000" and head["file"] == "val/val_000.ply"
    assert head["vertex_count"] == len(asset.vertices) and list(head["coefficients"]) == list(MODE_NAMES)
    assert "phenotype" not in head and "age_years" not in head  # ICT identities have neither
    assert isinstance(head["seed"], int)

    loaded = read_population(manifest_path)
    assert list(loaded) == ["val", "test"]
    for name, p in loaded.items():
        assert p.names == ict_splits[name].names and p.feature_names == MODE_NAMES and p.phenotype_names == ()
        assert np.abs(p.vertices - ict_splits[name].vertices).max() < 1e-5  # float32 PLY
        assert np.array_equal(p.coefficients, ict_splits[name].coefficients)
        assert p.phenotypes.shape == (len(p), 0)
        assert np.array_equal(p.seeds, ict_splits[name].seeds)
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
    assert np.array_equal(again.coefficients, expected.coefficients)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]

    # a manifest of another generator version is refused (its heads are other heads)
    manifest = json.loads((out / "manifest.json").read_text())
    manifest["generator_version"] = 1
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="version 1"):
        read_population(out)
    # and so is one whose split has no (or an unknown) kind
    manifest["generator_version"] = 3
    manifest["splits"]["val"]["kind"] = "scan"
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="unknown kind"):
        read_population(out)
    del manifest["splits"]["val"]
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="not described"):
        read_population(out)


def test_write_and_read_the_makehuman_split(tmp_path, asset):
    """The out-of-distribution split: MakeHuman heads with phenotypes and ages, from its own stream."""
    out = tmp_path / "population"
    write_population(out, seed=0, splits=("makehuman", "val"))
    manifest = json.loads((out / "manifest.json").read_text())
    assert SPLIT_KINDS == {"train": "ict", "val": "ict", "test": "ict", "heldout": "ict", "makehuman": "makehuman"}
    entry = manifest["splits"]["makehuman"]
    assert entry["kind"] == "makehuman" and entry["size"] == 100 and entry["shifted"] is True
    assert entry["feature_names"] == list(FEATURE_NAMES) and entry["phenotype_names"] == list(PHENOTYPE_NAMES)
    assert [f["name"] for f in entry["features"]] == list(FEATURE_NAMES)
    assert "sample_head(seed, shifted=True)" in entry["head"] and "crc32('ict-makehuman')" in entry["seed_derivation"]
    assert manifest["splits"]["val"]["kind"] == "ict"
    rows = [h for h in manifest["heads"] if h["split"] == "makehuman"]
    assert len(rows) == 100 and rows[0]["file"] == "makehuman/makehuman_000.ply"
    assert set(rows[0]["coefficients"]) == set(FEATURE_NAMES) and set(rows[0]["phenotype"]) == set(PHENOTYPE_NAMES)
    ages = [h["age_years"] for h in rows]
    assert 18.0 <= min(ages) and max(ages) <= 80.0 and max(ages) - min(ages) > 30.0

    loaded = read_population(out)
    assert list(loaded) == ["makehuman", "val"]
    p, expected = loaded["makehuman"], population_split("makehuman", seed=0, asset=asset)
    assert p.feature_names == FEATURE_NAMES and p.phenotype_names == PHENOTYPE_NAMES and p.shifted
    assert np.array_equal(p.seeds, expected.seeds) and np.array_equal(p.seeds, split_seeds("makehuman", 0))
    assert np.array_equal(p.coefficients, expected.coefficients) and np.array_equal(p.phenotypes, expected.phenotypes)
    assert np.abs(p.vertices - expected.vertices).max() < 1e-5
    # the manifest is enough to make a head again
    for i in (0, 99):
        phenotype, c = sample_head(int(p.seeds[i]), shifted=True, asset=asset)
        assert np.array_equal(c, p.coefficients[i]) and np.array_equal(phenotype, p.phenotypes[i])
    assert loaded["val"].phenotypes.shape == (2, 0) and loaded["val"].feature_names == MODE_NAMES


def test_version_2_manifests_are_read_as_before(tmp_path, asset, splits):
    """A manifest of generator version 2 (every split MakeHuman, feature and phenotype names at the top
    level; written before issue 25) reads back as it did (the heads of such a manifest are ``makehuman_split``'s)."""
    assert READABLE_VERSIONS == (2, 3)
    val = splits["val"]
    (tmp_path / "val").mkdir()
    heads = []
    for i, name in enumerate(val.names):
        (tmp_path / f"val/{name}.ply").write_bytes(_mesh_bytes(val.vertices[i], asset.faces, "ply"))
        phenotype = dict(zip(PHENOTYPE_NAMES, map(float, val.phenotypes[i])))
        heads.append(
            {
                "split": "val",
                "name": name,
                "file": f"val/{name}.ply",
                "seed": int(val.seeds[i]),
                "vertex_count": len(asset.vertices),
                "expression": "neutral",
                "phenotype": phenotype,
                "age_years": 40.0,
                "coefficients": dict(zip(FEATURE_NAMES, map(float, val.coefficients[i]))),
            }
        )
    manifest = {
        "generator": "pipeline.synthetic.population",
        "generator_version": 2,
        "split_sizes": {"val": 2},
        "shifted_splits": ["heldout"],
        "phenotype_names": list(PHENOTYPE_NAMES),
        "feature_names": list(FEATURE_NAMES),
        "heads": heads,
    }
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    loaded = read_population(tmp_path)["val"]
    assert loaded.names == val.names and loaded.feature_names == FEATURE_NAMES
    assert loaded.phenotype_names == PHENOTYPE_NAMES and np.array_equal(loaded.phenotypes, val.phenotypes)
    assert np.array_equal(loaded.coefficients, val.coefficients) and np.array_equal(loaded.seeds, val.seeds)
    assert np.abs(loaded.vertices - val.vertices).max() < 1e-5
    # its names are at the top level: without them it is not a population manifest
    del manifest["feature_names"]
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="not a population manifest"):
        read_population(tmp_path)


def test_cli_splits_are_the_population_splits():
    from pipeline.cli.data import SPLITS

    assert SPLITS == tuple(SPLIT_SIZES)


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


def test_similarity_normalised_undoes_a_known_similarity():
    from scipy.spatial.transform import Rotation

    from pipeline.synthetic.population import similarity_normalised
    from rig.asset import load_asset

    template = load_asset().vertices
    rot = Rotation.from_euler("xyz", [4.0, -7.0, 3.0], degrees=True).as_matrix()
    moved = 1.08 * template @ rot.T + np.array([3.0, -12.0, 40.0])
    out = similarity_normalised(np.stack([moved, template]), template)
    np.testing.assert_allclose(out[0], template, atol=1e-9)
    np.testing.assert_allclose(out[1], template, atol=1e-9)
