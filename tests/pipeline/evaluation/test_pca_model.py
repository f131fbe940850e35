"""The PCA shape model (pipeline/evaluation/pca_model.py), the "3DMM reference" of ``jnr eval capacity``:
against a naive least-squares solve, on the 85 training heads and held-out heads, and through the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from pipeline.cli import main
from pipeline.evaluation.capacity import ASM_ROWS, PCA_ROWS, evaluate_capacity, pca_training_heads
from pipeline.evaluation.pca_model import PcaShapeModel, train_pca
from pipeline.metrics import mean_vertex_error
from rig.errors import InputError, SetupError, ShapeError


@pytest.fixture(scope="module")
def heads():
    """The training heads and the 7 test heads, similarity-normalised onto the template exactly as
    ``jnr eval capacity`` does: ``(85, V, 3)``, ``(7, V, 3)`` mm."""
    from pipeline.synthetic.population import population_split, similarity_normalised
    from rig.asset import load_asset

    train = pca_training_heads(0)  # cached: the CLI test below reuses it
    assert train.shape[0] == 85
    heldout = similarity_normalised(population_split("test").vertices, load_asset().vertices)
    return torch.as_tensor(train.copy()), torch.as_tensor(heldout)


@pytest.fixture(scope="module")
def full(heads):
    return train_pca(heads[0], heads[0].shape[0] - 1)


def test_smoke_shapes_and_floats(full):
    V = full.num_vertices
    model = full.truncated(10)
    assert isinstance(model, PcaShapeModel)
    assert model.mean.shape == (V, 3) and model.components.shape == (10, 3 * V) and model.stddev.shape == (10,)
    assert model.fit(full.mean[None].float()).shape == (1, V, 3)
    assert model.num_floats() == {"mean": 3 * V, "components": 30 * V, "coefficients": 10}
    assert torch.all(full.stddev[:-1] >= full.stddev[1:]) and torch.all(full.stddev > 0)
    with pytest.raises(AttributeError):  # frozen
        model.mean = model.mean


def test_k_n_minus_1_reproduces_every_training_head(heads, full):
    train, _ = heads
    assert full.k == 84
    err = (full.fit(train) - train).norm(dim=-1).max()
    assert err < 1e-4, err


def test_components_are_orthonormal(full):
    gram = full.components @ full.components.T
    assert torch.allclose(gram, torch.eye(full.k, dtype=gram.dtype), atol=1e-10)


def test_truncated_is_training_with_fewer_components(heads, full):
    train, heldout = heads
    small = train_pca(train[:30], 10)
    cut = train_pca(train[:30], 29).truncated(10)
    assert torch.allclose(cut.mean, small.mean) and torch.allclose(cut.stddev, small.stddev)
    assert torch.allclose(cut.fit(heldout), small.fit(heldout), atol=1e-6)  # components up to sign
    with pytest.raises(InputError, match=r"truncated: k must be an integer in \[1, 84\]"):
        full.truncated(85)


def test_heldout_error_decreases_monotonically_with_k(heads, full):
    _, heldout = heads
    errors = [
        float(mean_vertex_error(full.truncated(k).fit(heldout).numpy(), heldout.numpy()).mean())
        for k in (1, 2, 5, 10, 20, 30, 50, 70, 84)
    ]
    assert all(a > b for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] > 0.1  # held-out heads are not in the span of the training heads


def test_projection_equals_naive_least_squares(heads, full):
    """``fit`` = ``mean + C^T a`` with ``a = argmin |C^T a - (x - mean)|`` solved by torch.linalg.lstsq."""
    train, heldout = heads
    model = full.truncated(20)
    targets = torch.cat([heldout[:3], train[:1] + torch.randn_like(train[:1])])
    d = (targets - model.mean).reshape(targets.shape[0], -1)
    naive = torch.linalg.lstsq(model.components.T, d.T).solution.T  # (B, k)
    assert torch.allclose(model.coefficients(targets), naive, atol=1e-8)
    expected = model.mean + (naive @ model.components).reshape(targets.shape)
    assert torch.allclose(model.fit(targets), expected, atol=1e-8)


def test_ridge_shrinks_towards_the_mean(heads, full):
    _, heldout = heads
    model = full.truncated(10)
    plain = model.coefficients(heldout[:2])
    assert torch.equal(model.coefficients(heldout[:2], ridge=0.0), plain)
    shrunk = model.coefficients(heldout[:2], ridge=model.stddev[0].item() ** 2)
    assert torch.all(shrunk.abs() < plain.abs())
    with pytest.raises(InputError, match="ridge"):
        model.fit(heldout[:1], ridge=-1.0)


@pytest.mark.parametrize("k", [0, -1, 6, 7, 2.5, True, "3"])
def test_bad_k_raises_value_error(k):
    with pytest.raises(ValueError, match=r"train_pca: k must be .*\[1, 5\]"):
        train_pca(np.random.default_rng(0).normal(size=(6, 4, 3)), k)


def test_bad_shapes_raise():
    with pytest.raises(ShapeError, match=r"train_pca: vertices must have shape \(N, V, 3\), got \(6, 12\)"):
        train_pca(np.zeros((6, 12)), 2)
    model = train_pca(np.random.default_rng(0).normal(size=(6, 4, 3)), 2)
    with pytest.raises(ShapeError, match=r"targets must have shape \(N, 4, 3\), got \(1, 5, 3\)"):
        model.fit(np.zeros((1, 5, 3)))
    with pytest.raises(InputError, match="finite"):
        model.fit(np.full((1, 4, 3), np.nan))


def test_capacity_rejects_unknown_models_and_lonely_oracle():
    with pytest.raises(InputError, match="models"):
        evaluate_capacity(("test",), models=("pca", "bfm"))
    with pytest.raises(InputError, match="oracle"):
        evaluate_capacity(("test",), models=("pca",), oracle=True)


def test_cli_capacity_pca_rows(capsys, tmp_path):
    from pipeline.cli.evaluate import capacity_table

    out = tmp_path / "capacity.json"
    code = main(["eval", "capacity", "--models", "pca", "--limit", "2", "--json", "--quiet", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    result = json.loads(captured.out)
    assert result == json.loads(out.read_text())
    assert result["models"] == ["pca"] and result["training"]["pca_train_heads"] == 85
    for split in ("test", "heldout"):
        row = result["splits"][split]
        assert [n for n in row if n != "seconds"] == list(PCA_ROWS)
        for name in PCA_ROWS:
            r = row[name]
            assert r["heads"] == 2 and r["seconds_per_head"] >= 0.0 and 0.0 < r["mean_mm"] < 5.0
            assert r["model_floats"] == sum(result["model_floats"][name].values())
        assert row["pca_k10"]["mean_mm"] > row["pca_k84"]["mean_mm"]
    table = capacity_table(result).splitlines()
    assert table[0].split()[:3] == ["split", "row", "mean"] and "s/head" in table[0] and "model floats" in table[0]
    assert len(table) == 1 + 2 * len(PCA_ROWS) and table[1].split()[:2] == ["test", "pca_k10"]


def test_cli_capacity_bad_models_are_usage_errors(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["eval", "capacity", "--quiet", "--models", "pca,bfm"])
    assert exit_.value.code == 2 and "--models: expected a comma-separated subset" in capsys.readouterr().err
    assert main(["eval", "capacity", "--quiet", "--models", "pca", "--oracle"]) == 2
    assert "--oracle" in capsys.readouterr().err


# ------------------------------------------------------------------------------------ the ASM rows' wiring


class _FakeAsm:
    """``rig.skinning.asm``'s API as ``jnr eval capacity`` uses it: every fit is the target moved by
    ``K`` mm along x, plus 1 mm with dynamic binding, so each row's error says which model and variant
    were fitted."""

    from dataclasses import dataclass

    @dataclass(frozen=True)
    class AsmVariant:
        dynamic_binding: bool = True
        gmm_weights: bool = True

    class AdaptiveSkinning:
        def __init__(self, rig, components=2):
            self.components = components

        def num_floats(self, variant):
            return {"fixed": 1000 * self.components, "per_head": 10 + variant.gmm_weights, "static_vertices": 7}

    @dataclass(frozen=True)
    class AsmFit:
        vertices: torch.Tensor
        seconds: float

    @staticmethod
    def fit_asm(model, targets, *, variant, iterations=400, progress=None):
        shift = (model.components if variant.gmm_weights else 0.0) + (1.0 if variant.dynamic_binding else 0.0)
        moved = targets.clone()
        moved[..., 0] += shift
        if shift == 3.0:  # asm_dynamic + gmm with K = 2: one failed fit
            moved[0] = float("nan")
        return _FakeAsm.AsmFit(vertices=moved, seconds=0.0)


def test_asm_rows_call_the_asm_api(monkeypatch):
    import types

    fake = types.ModuleType("rig.skinning.asm")
    for name in ("AsmVariant", "AdaptiveSkinning", "fit_asm"):
        setattr(fake, name, getattr(_FakeAsm, name))
    monkeypatch.setitem(__import__("sys").modules, "rig.skinning.asm", fake)
    with pytest.warns(RuntimeWarning, match="test: asm_k2: 1 of 2 fits returned non-finite vertices"):
        result = evaluate_capacity(("test",), limit=2, models=("asm",))
    row = result["splits"]["test"]
    assert [n for n in row if n != "seconds"] == list(ASM_ROWS)
    expected = {"asm_static": 0.0, "asm_dynamic_binding": 1.0, "asm_gmm_k2": 2.0, "asm_gmm_k5": 5.0, "asm_k5": 6.0}
    for name, shift in expected.items():
        assert row[name]["mean_mm"] == pytest.approx(shift, abs=1e-4) and row[name]["heads"] == 2
        assert "nonfinite_heads" not in row[name]
    assert np.isnan(row["asm_k2"]["mean_mm"]) and row["asm_k2"]["nonfinite_heads"] == 1
    assert result["model_floats"]["asm_k5"] == {"fixed": 5000, "per_head": 11, "static_vertices": 7}
    assert row["asm_k5"]["model_floats"] == 5011 and row["asm_static"]["model_floats"] == 2010  # not the vertex count


def test_missing_asm_module_is_a_clear_error(monkeypatch, capsys):
    monkeypatch.setitem(__import__("sys").modules, "rig.skinning.asm", None)  # import fails
    with pytest.raises(SetupError, match=r"rig.skinning.asm .* --models jnr,pca"):
        evaluate_capacity(("test",), models=("pca", "asm"))
    assert main(["eval", "capacity", "--quiet", "--models", "asm"]) == 1
    assert "--models jnr,pca" in capsys.readouterr().err
