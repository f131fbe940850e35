"""rig.disk_cache: arrays built once are read back bit for bit, keyed by their inputs; an unusable cache is
skipped; the expression shapes read from the cache equal the built ones."""

import numpy as np
import pytest

from rig.disk_cache import CACHE_ENV, cache_dir, cache_key, disk_cached


def _builder(calls: list):
    def build():
        calls.append(1)
        rng = np.random.default_rng(len(calls))
        return {"a": rng.normal(size=(4, 3)), "b": np.arange(5)}

    return build


def test_built_once_then_read_bit_for_bit(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    calls: list = []
    first = disk_cached("thing", [np.ones(3), "x"], _builder(calls))
    again = disk_cached("thing", [np.ones(3), "x"], _builder(calls))
    assert len(calls) == 1
    for key in ("a", "b"):
        assert again[key].dtype == first[key].dtype and np.array_equal(again[key], first[key])
    # other inputs: another key, built again
    disk_cached("thing", [np.ones(3) * 2, "x"], _builder(calls))
    disk_cached("thing", [np.ones(3, np.float32), "x"], _builder(calls))  # same values, another dtype
    assert len(calls) == 3
    assert len(list((tmp_path / "cache").glob("thing-*.npz"))) == 3


def test_off_unwritable_and_corrupt_caches_are_skipped(tmp_path, monkeypatch):
    calls: list = []
    monkeypatch.setenv(CACHE_ENV, "off")
    assert cache_dir() is None
    disk_cached("thing", ["x"], _builder(calls))
    disk_cached("thing", ["x"], _builder(calls))
    assert len(calls) == 2
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv(CACHE_ENV, str(blocker / "cache"))  # cannot be made: built, no error
    assert disk_cached("thing", ["x"], _builder(calls))["b"].tolist() == [0, 1, 2, 3, 4]
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "c"))
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / f"thing-{cache_key(['x'])}.npz").write_bytes(b"garbage")
    n = len(calls)
    disk_cached("thing", ["x"], _builder(calls))
    assert len(calls) == n + 1  # rebuilt over the corrupt file
    disk_cached("thing", ["x"], _builder(calls))
    assert len(calls) == n + 1  # and that one is read


def test_expression_basis_from_the_cache_equals_the_build(tmp_path, monkeypatch):
    from rig.asset import load_asset
    from rig.expressions import _cached, build_expression_basis

    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    asset = load_asset()
    basis, weight = build_expression_basis(asset)
    _cached.__wrapped__(asset)  # writes the cache file
    assert len(list(tmp_path.glob("expression_basis-*.npz"))) == 1
    cached_basis, cached_weight = _cached.__wrapped__(asset)  # reads it
    assert np.array_equal(cached_basis, basis) and np.array_equal(cached_weight, weight)


@pytest.mark.parametrize("value", ["", None])
def test_default_folder(monkeypatch, tmp_path, value):
    monkeypatch.delenv(CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    if value is not None:
        monkeypatch.setenv(CACHE_ENV, value)
    assert cache_dir() == tmp_path / "jnr"
