"""Training the identity regressor (issue 37): its heads are none of the splits', the coefficient map is
recovered, the photos are cached and resumed."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import identity_training as it
from pipeline.synthetic.population import split_seeds
from rig.errors import InputError


def test_training_heads_are_their_own_and_do_not_depend_on_how_many():
    seeds = it.training_seeds(500)
    used = set().union(*(set(split_seeds(s, 0).tolist()) for s in ("train", "val", "test", "heldout")))
    assert len(set(seeds.tolist())) == 500 and not used & set(seeds.tolist())
    assert np.array_equal(it.training_seeds(40), seeds[:40])  # a cache of a smaller run is reused
    assert not np.array_equal(it.training_seeds(40, seed=1), seeds[:40])


def test_the_coefficient_map_recovers_a_known_linear_map():
    rng = np.random.default_rng(0)
    c = rng.normal(size=(1000, 100))
    a, b = rng.normal(size=(100, 7)), rng.normal(size=7)
    theta = c @ a + b + rng.normal(0, 0.01, (1000, 7))
    a_fit, b_fit = it.coefficient_map(c, theta)
    assert np.abs(a_fit - a).max() < 0.02 and np.abs(b_fit - b).max() < 0.02
    resid = it.coefficient_map_residuals(c, theta)
    assert 0.005 < resid.std() < 0.02  # held-out residuals: the noise, a little more


def test_training_photos_are_read_and_cached(tmp_path, monkeypatch):
    """Two chunks of one photo each (spp 2): MediaPipe reads both faces, the second expressive; a second call
    reads the cache instead of rendering."""
    monkeypatch.setattr(it, "CHUNK", 1)
    data = it.training_photos(2, tmp_path, spp=2)
    assert data["points"].shape == (2, 478, 3) and data["found"].all()
    assert data["expressive"].tolist() == [False, True]
    assert np.isfinite(data["points"]).all() and data["coefficients"].shape == (2, 100)
    assert data["seconds"].shape == (2,) and (data["seconds"] > 0).all()  # each photo's render + detection
    assert len(list(tmp_path.glob("*.npz"))) == 2

    def no_render(*args):
        raise AssertionError("rendered again")

    monkeypatch.setattr(it, "render_chunk", no_render)
    again = it.training_photos(2, tmp_path, spp=2)
    assert np.array_equal(again["points"], data["points"])


def _stand_in_render(calls: list, points_of):
    """A stand-in for :func:`identity_training.render_chunk`: the heads' real coefficients, every face found,
    ``points_of(coefficients, rng)`` as its points, 0.5 s a photo; each call's ``(seed, spread)`` kept in ``calls``."""

    def render(seeds, first, seed, spp, spread=1.0):
        calls.append((seed, spread))
        c = np.stack([it.ict_coefficients(int(s), spread=spread) for s in seeds])
        noise = np.random.default_rng(first + 1000 * seed)
        return {
            "coefficients": c,
            "expressive": np.zeros(len(c), bool),
            "found": np.ones(len(c), bool),
            "points": np.stack([points_of(x, noise) for x in c]),
            "seconds": np.full(len(c), 0.5),
        }

    return render


def test_wide_training_heads_have_their_own_stream_and_files(tmp_path, monkeypatch):
    """A wider spread draws the stream's heads wider and keeps its chunks apart from the N(0, I) ones."""
    calls = []
    monkeypatch.setattr(it, "render_chunk", _stand_in_render(calls, lambda c, rng: np.zeros((478, 3))))
    plain = it.training_photos(3, tmp_path, seed=1)
    wide = it.training_photos(3, tmp_path, seed=1, spread=1.5)
    assert calls == [(1, 1.0), (1, 1.5)]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "photos_s1_sd1.5_spp64_000000.npz",
        "photos_s1_spp64_000000.npz",
    ]
    assert not np.array_equal(plain["coefficients"], wide["coefficients"])
    assert wide["coefficients"].std() > 1.2 * plain["coefficients"].std()
    for bad in (0.0, float("nan")):
        with pytest.raises(InputError, match="spread"):
            it.training_photos(3, tmp_path / "bad", spread=bad)
    assert not (tmp_path / "bad").exists()


def test_a_cache_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        it.training_photos(2, tmp_path / "f")
    assert (tmp_path / "f").read_text() == "x"


def test_the_map_is_learned_from_both_head_sets_and_reads_a_new_head(tmp_path, monkeypatch):
    """The whole training on stand-ins for the renders and the rig fits: points linear in the ICT coefficients
    (plus noise), channels linear in the heads. The wide set comes from stream ``seed + 1`` at ``wide_spread``,
    the coefficient map recovers the channels, and the learned map reads a head of neither set."""
    import pipeline.train

    rng = np.random.default_rng(0)
    basis = rng.normal(0, 0.05, (100, 478 * 3))
    shape = rng.normal(0, 1.0, (478, 3))
    calls = []

    def points_of(c, noise_rng):
        return shape + (c @ basis).reshape(478, 3) + noise_rng.normal(0, 0.002, (478, 3))

    span = it.parameter_span().numpy()
    template = it.ict_heads(np.zeros(100))
    pick = rng.choice(template.size, len(span), replace=False)

    def fake_fit(vertices, iterations=400, progress=None):  # channels: a fixed linear read of the head
        return (vertices.reshape(len(vertices), -1) - template.reshape(-1))[:, pick] * 0.1 * span

    monkeypatch.setattr(it, "render_chunk", _stand_in_render(calls, points_of))
    monkeypatch.setattr(it, "clip_to_limits", lambda theta: theta)
    monkeypatch.setattr(pipeline.train, "fit_population_joints", fake_fit)
    reg = it.train_identity_regressor(
        tmp_path / "map.npz", heads=200, map_heads=160, seed=3, cache=tmp_path / "c", mirror=False
    )
    assert sorted(set(calls)) == [(3, 1.0), (4, it.WIDE_SPREAD)]
    # as many wide heads as heads by default
    assert reg.meta["photos"] == 400 and reg.meta["wide_heads"] == 200 and reg.meta["seconds"]["photos"] == 200.0
    assert reg.meta["cv_explained"] > 0.9
    c = it.ict_coefficients(123456, spread=1.5)
    truth = fake_fit(it.ict_heads(c)[None])[0]
    err = np.abs(reg.predict(points_of(c, np.random.default_rng(9))) - truth) / span
    assert np.sqrt((err**2).mean()) < 0.1 * np.sqrt(((truth / span) ** 2).mean())
    with pytest.raises(InputError, match="wide_heads"):
        it.train_identity_regressor(tmp_path / "bad.npz", heads=200, wide_heads=-1, cache=tmp_path / "c")
    calls.clear()
    with pytest.raises(InputError, match="wide_spread"):  # refused before any photo is rendered
        it.train_identity_regressor(
            tmp_path / "bad.npz", heads=200, map_heads=160, wide_spread=0.0, cache=tmp_path / "new"
        )
    assert not (tmp_path / "bad.npz").exists() and calls == []
