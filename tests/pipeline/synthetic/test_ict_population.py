"""pipeline.synthetic.population: the ICT identity splits of :func:`population_split` (``train``, ``val``,
``test``, the shifted ``heldout``) and the out-of-distribution ``makehuman`` split (issue 25)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.synthetic.population import (
    ASYM_SLIDER_SD,
    FEATURE_NAMES,
    MAKEHUMAN_SPLIT_SIZES,
    MODE_NAMES,
    MODE_SD,
    PHENOTYPE_NAMES,
    SHIFTED_MODE_SD,
    SHIFTED_SPLITS,
    SPLIT_SIZES,
    feature_mask,
    ict_coefficients,
    ict_heads,
    makehuman_split,
    population_split,
    sample_head,
    split_seeds,
    synthesize_heads,
)
from pipeline.synthetic.population.heads import flipped_against
from pipeline.synthetic.population.ict import MAX_DRAWS
from rig.asset import load_asset
from rig.errors import InputError
from rig.geometry import face_normals
from rig.template import HIDDEN_REGIONS

ICT_SPLITS = ("train", "val", "test", "heldout")


@pytest.fixture(scope="module")
def template(asset):
    return asset.vertices


@pytest.fixture(scope="module")
def splits(asset):
    """The four ICT splits, base seed 0."""
    return {name: population_split(name, seed=0, asset=asset) for name in ICT_SPLITS}


@pytest.fixture(scope="module")
def makehuman_heads(asset):
    """The first 20 heads of the ``makehuman`` split."""
    return population_split("makehuman", seed=0, asset=asset, first=20)


def _skin_faces(asset):
    """Triangles with no vertex in a hidden region (the skin a scanner sees)."""
    return asset.faces[~asset.region_mask(*HIDDEN_REGIONS)[asset.faces].any(1)]


def test_the_splits_and_their_sizes(splits):
    assert SPLIT_SIZES == {"train": 85, "val": 2, "test": 7, "heldout": 100, "makehuman": 100}
    assert SHIFTED_SPLITS == ("heldout", "makehuman")
    assert len(MODE_NAMES) == 100 and MODE_NAMES[0] == "ict_identity_000" and MODE_NAMES[-1] == "ict_identity_099"
    for name, p in splits.items():
        n = SPLIT_SIZES[name]
        assert p.split == name and len(p) == n and p.expression == "neutral" and p.shifted == (name == "heldout")
        assert p.names == tuple(f"{name}_{i:03d}" for i in range(n))
        assert p.feature_names == MODE_NAMES and p.coefficients.shape == (n, 100)
        assert p.phenotype_names == () and p.phenotypes.shape == (n, 0)
        assert p.vertices.shape == (n, len(load_asset().vertices), 3) and p.vertices.dtype == np.float64
        assert np.isfinite(p.vertices).all() and p.seeds.shape == (n,) and p.seeds.dtype == np.int64


def test_seeds_are_disjoint_across_the_five_splits(splits, makehuman_heads):
    seeds = {name: split_seeds(name, 0) for name in SPLIT_SIZES}
    for name, p in splits.items():
        assert np.array_equal(p.seeds, seeds[name])
    assert np.array_equal(makehuman_heads.seeds, seeds["makehuman"][:20])
    every = np.concatenate(list(seeds.values()))
    assert len(every) == sum(SPLIT_SIZES.values()) == 294
    assert len(np.unique(every)) == len(every)  # no seed twice, within a split or across splits
    names = list(seeds)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            assert not np.intersect1d(seeds[a], seeds[b]).size, (a, b)
    # nor shared with the MakeHuman population's own streams
    makehuman = np.concatenate([split_seeds(n, 0, stream="makehuman") for n in MAKEHUMAN_SPLIT_SIZES])
    assert not np.intersect1d(every, makehuman).size


def test_same_seed_same_heads_other_seed_other_heads(asset, splits):
    for name in ("val", "test"):
        again = population_split(name, seed=0, asset=asset)
        assert np.array_equal(again.vertices, splits[name].vertices)
        assert np.array_equal(again.coefficients, splits[name].coefficients)
        assert np.array_equal(again.seeds, splits[name].seeds)
        other = population_split(name, seed=1, asset=asset)
        assert not np.intersect1d(other.seeds, splits[name].seeds).size
        assert not np.isin(other.coefficients, splits[name].coefficients).any()
        per_head = np.sqrt(((other.vertices - splits[name].vertices) ** 2).sum(-1).mean(-1))
        assert per_head.min() > 1.0  # mm RMS: every head is another head
    for bad_name, bad_seed in (("training", 0), ("val", -1), ("val", 1.5), ("val", True)):
        with pytest.raises(ValueError):
            population_split(bad_name, seed=bad_seed, asset=asset)


def test_first_k_heads_are_the_splits_first_k(asset, splits):
    for name, k in (("train", 5), ("heldout", 3), ("val", 0)):
        head = population_split(name, seed=0, asset=asset, first=k)
        whole = splits[name]
        assert len(head) == k and head.names == whole.names[:k]
        assert np.array_equal(head.seeds, whole.seeds[:k]) and np.array_equal(head.coefficients, whole.coefficients[:k])
        assert np.abs(head.vertices - whole.vertices[:k]).max(initial=0.0) < 1e-9
    assert len(population_split("val", asset=asset, first=10)) == 2
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="first"):
            population_split("test", asset=asset, first=bad)


def test_each_head_is_made_from_its_seed(asset, splits):
    for p in splits.values():
        for i in sorted({0, len(p) // 2, len(p) - 1}):
            c = ict_coefficients(int(p.seeds[i]), shifted=p.shifted, asset=asset)
            assert np.array_equal(c, p.coefficients[i])
            # one of the draws of the head's own stream (the first one that does not fold the skin)
            rng = np.random.default_rng(int(p.seeds[i]))
            sd = SHIFTED_MODE_SD if p.shifted else MODE_SD
            draws = [rng.standard_normal(100) * sd for _ in range(MAX_DRAWS)]
            first = next(k for k, d in enumerate(draws) if np.array_equal(d, c))
            assert all(flipped_against(ict_heads(d, asset), asset.vertices, asset) > 0 for d in draws[:first])
            assert np.abs(ict_heads(c, asset) - p.vertices[i]).max() < 1e-9


def test_zero_coefficients_give_the_template(asset, template):
    assert np.array_equal(ict_heads(np.zeros(100), asset), template)
    assert np.array_equal(ict_heads(np.zeros((3, 7)), asset), np.broadcast_to(template, (3, *template.shape)))
    assert np.array_equal(ict_heads(np.zeros(100)), load_asset().vertices)  # the default asset


def test_heads_are_linear_in_the_coefficients(asset, template):
    """head(c) - template is linear in c: the modes' sum, and the eyeball re-placement (the displacement minus
    its mean over the eyeball vertices) is linear too."""
    rng = np.random.default_rng(4)
    a, b = rng.standard_normal(100), 2.0 * rng.standard_normal(100)
    da, db, dab = (ict_heads(c, asset) - template for c in (a, b, a + b))
    assert np.abs(dab - (da + db)).max() < 1e-9
    assert np.abs(ict_heads(-1.5 * a, asset) - template + 1.5 * da).max() < 1e-9
    assert np.abs(da).max() > 1.0  # not trivially linear: the head does move
    # k < 100 coefficients are the first k modes
    assert np.abs(ict_heads(a[:10], asset) - ict_heads(np.r_[a[:10], np.zeros(90)], asset)).max() < 1e-9
    with pytest.raises(ValueError, match="finite"):
        ict_heads(np.full(100, np.nan), asset)
    with pytest.raises(ValueError):
        ict_heads(np.zeros(101), asset)


def test_heldout_has_a_wider_spread(splits):
    assert np.array_equal(MODE_SD, np.ones(100))
    assert np.array_equal(SHIFTED_MODE_SD, np.r_[np.full(30, 1.25), np.full(70, 1.5)])
    train, held = splits["train"].coefficients, splits["heldout"].coefficients
    fine_train, fine_held = train[:, 30:].std(ddof=1), held[:, 30:].std(ddof=1)
    assert 0.9 < fine_train < 1.1 and 1.35 < fine_held < 1.65 and fine_held > 1.3 * fine_train
    coarse_train, coarse_held = train[:, :30].std(ddof=1), held[:, :30].std(ddof=1)
    assert 0.85 < coarse_train < 1.15 and 1.1 < coarse_held < 1.4
    for name in ("train", "val", "test"):
        assert not splits[name].shifted

    def spread(p):
        v = p.vertices
        return float(np.sqrt(((v - v.mean(0)) ** 2).sum(-1).mean()))

    assert spread(splits["heldout"]) > 1.1 * spread(splits["train"])  # mm: the heads vary more too


def test_a_wider_spread_scales_the_same_draws(asset):
    """``spread`` multiplies each draw of the head's own stream (the identity regressor's wide training heads);
    a spread that is not a positive number is refused."""
    for seed in (3, 11):
        c = ict_coefficients(seed, asset=asset, spread=1.5)
        rng = np.random.default_rng(seed)
        draws = [rng.standard_normal(100) * 1.5 for _ in range(MAX_DRAWS)]
        assert any(np.array_equal(d, c) for d in draws)
        assert np.array_equal(ict_coefficients(seed, asset=asset, spread=1.0), ict_coefficients(seed, asset=asset))
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="spread"):
            ict_coefficients(3, asset=asset, spread=bad)


def test_the_eyeball_centre_stays_where_the_templates_is(asset, template, splits):
    """The eyeballs' centre (mean of both eyeballs' vertices) is the template's in every head; each eyeball
    moves rigidly (the modes change the distance between the eyes, which is identity)."""
    eyes = asset.region_mask("eyeballs")
    left, right = eyes & (template[:, 0] > 0), eyes & (template[:, 0] < 0)
    assert left.sum() == right.sum() > 0
    heads = np.concatenate([p.vertices for p in splits.values()])
    assert np.abs(heads[:, eyes].mean(1) - template[eyes].mean(0)).max() < 1e-9
    for side in (left, right):
        d = heads[:, side] - template[side]
        assert np.abs(d - d.mean(1, keepdims=True)).max() < 1e-9
    apart = heads[:, left].mean(1)[:, 0] - heads[:, right].mean(1)[:, 0]
    assert apart.std() > 0.5  # mm: the eye distance does vary between identities


def test_no_skin_triangle_turns_over(asset, template, splits):
    faces = _skin_faces(asset)
    n0 = face_normals(template, faces)
    for name, p in splits.items():
        turned = ((face_normals(p.vertices, faces) * n0).sum(-1) <= 0.0).sum(1)
        assert (turned == 0).all(), (name, int((turned > 0).sum()), int(turned.max()))


def test_skin_on_the_ict_surface_keeps_its_orientation_in_the_unshifted_splits(asset, template, splits):
    """Where every corner of a skin triangle lies on ICT's surface (the asset's ``ict_covered``), the
    unshifted heads keep it with a margin (no triangle turned by more than 90 degrees)."""
    faces = _skin_faces(asset)
    covered = np.zeros(len(template), bool)
    covered[asset.ict_covered] = True
    faces = faces[covered[faces].all(1)]
    assert len(faces) > 0.7 * len(_skin_faces(asset))
    n0 = face_normals(template, faces)
    n0 = n0 / np.linalg.norm(n0, axis=-1, keepdims=True)
    for name in ("train", "val", "test"):
        n = face_normals(splits[name].vertices, faces)
        cos = (n * n0).sum(-1) / np.linalg.norm(n, axis=-1)
        assert cos.min() > 0.0, name


def test_the_makehuman_split_is_the_shifted_makehuman_distribution_from_its_own_stream(asset, makehuman_heads):
    p = makehuman_heads
    assert p.split == "makehuman" and p.shifted and p.names[0] == "makehuman_000"
    assert p.feature_names == FEATURE_NAMES and p.phenotype_names == PHENOTYPE_NAMES
    assert p.coefficients.shape == (20, len(FEATURE_NAMES)) and p.phenotypes.shape == (20, len(PHENOTYPE_NAMES))
    # its own seeds: not those of the MakeHuman population's heldout split ...
    heldout = makehuman_split("heldout", seed=0, asset=asset, first=20)
    assert not np.intersect1d(p.seeds, split_seeds("heldout", 0, stream="makehuman")).size
    assert np.abs(p.vertices - heldout.vertices).max() > 1.0
    # ... but drawn as that split draws its heads (sample_head, shifted), so each head is made from its seed
    for i in (0, 19):
        phenotype, c = sample_head(int(p.seeds[i]), shifted=True, asset=asset)
        assert np.array_equal(c, p.coefficients[i]) and np.array_equal(phenotype, p.phenotypes[i])
        assert np.array_equal(synthesize_heads(c, phenotype, asset), p.vertices[i])
    # the shifted distribution: the asym sliders and the head shapes are in use, as in the heldout split
    asym, shapes = feature_mask("asym"), feature_mask("head_shape")
    for q in (p, heldout):
        assert (q.coefficients[:, asym] != 0).all()
        assert abs(q.coefficients[:, asym].std() - ASYM_SLIDER_SD) < 0.05
        assert (q.coefficients[:, shapes] > 0).mean() > 0.95
