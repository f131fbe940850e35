import json
from pathlib import Path

import pytest
import torch

from pipeline.cli import main
from pipeline.synthetic.population import population_split
from pipeline.train import TrainConfig, load_config
from rig.parameters import random_theta
from rig.skinning.joint_fit import fit_joints

RESULTS = Path(__file__).resolve().parents[3] / "benchmarks" / "results"


@pytest.mark.slow  # 5 s: make test-slow
def test_population_is_not_the_rigs_own_span(rig32):
    """The best joint fit with the initial weights leaves a clearly non-zero error on synthetic heads,
    while heads made by the rig itself are recovered (the control)."""
    heads = torch.as_tensor(population_split("train").vertices[:4], dtype=torch.float32)
    with torch.no_grad():
        own = rig32(random_theta(torch.Generator().manual_seed(0), 4, spread=0.2)).vertices
    fit = fit_joints(rig32, torch.cat([heads, own]), iterations=400)
    with torch.no_grad():
        err = (rig32(fit.theta).vertices - torch.cat([heads, own])).norm(dim=-1).mean(-1)
    assert (err[:4] > 0.25).all(), err
    assert (err[4:] < 0.15).all(), err


def test_config_rejects_unknown_keys(tmp_path):
    (tmp_path / "c.yaml").write_text("cycles: 2\nbogus: 1\n")
    with pytest.raises(ValueError, match="bogus"):
        load_config(tmp_path / "c.yaml")
    (tmp_path / "c.yaml").write_text("cycles: 2\n")
    assert load_config(tmp_path / "c.yaml", {"seed": 3}) == TrainConfig(cycles=2, seed=3)


@pytest.mark.slow  # a training run (11 s): in `make test-slow`, which CI runs
def test_tiny_training_run_through_the_cli(tmp_path, capsys):
    out = tmp_path / "skinning.npz"
    code = main(
        [
            "train",
            "--out",
            str(out),
            "--quiet",
            "--set",
            "joint_iterations=40",
            "--set",
            "weight_iterations=30",
            "--set",
            "cycles=1",
            "--set",
            "autoencoder_epochs=2",
            "--set",
            "wgan_iterations=3",
            "--set",
            "max_training_sets=200",
        ]
    )
    assert code == 0, capsys.readouterr().err
    log = json.loads(out.with_suffix(".log.json").read_text())
    rmse = log["rmse_train_mm"]["per_joint_fit"]
    assert rmse[1] < rmse[0]  # learned linear weights fit the training heads better than the initial ones
    assert log["counts"]["weight_training_sets"] > 100
    code = main(["train", "--out", str(out), "--quiet", "--set", "nonsense=1"])
    assert code == 2 and "nonsense" in capsys.readouterr().err


def test_data_synth_writes_meshes_and_manifest(tmp_path, capsys):
    out = tmp_path / "pop"
    assert main(["data", "synth", "--out", str(out), "--splits", "val", "test", "--quiet"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    text = json.dumps(manifest)
    assert "val_000" in text and "test_006" in text
    assert main(["data", "synth", "--out", str(out), "--splits", "val", "--quiet"]) == 2
    assert "--force" in capsys.readouterr().err


@pytest.mark.skipif(not (RESULTS / "capacity_ict.json").exists(), reason="no committed capacity table yet")
@pytest.mark.slow
def test_committed_artifacts_reproduce_the_committed_table():
    from pipeline.evaluation.capacity import CapacitySettings, evaluate_capacity

    table = json.loads((RESULTS / "capacity_ict.json").read_text())  # issue 25: the ICT identities
    settings = CapacitySettings(**table["settings"])
    result = evaluate_capacity(("test",), settings, models=("jnr",))
    for name in ("initial", "learned_linear", "neural"):
        ours, committed = result["splits"]["test"][name]["mean_mm"], table["splits"]["test"][name]["mean_mm"]
        assert abs(ours - committed) <= 0.02 + 0.05 * committed, (name, ours, committed)


def test_configs_train_yaml_is_the_committed_schedule():
    root = Path(__file__).resolve().parents[3]
    assert load_config(root / "configs" / "train.yaml") == TrainConfig()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--identity-regressor", "--set", "heads=10"], "--identity-regressor takes only --out, --cache"),
        (["--identity-regressor", "--identity-prior"], "takes only"),
        (["--identity-prior", "--cache", "x"], "--identity-prior takes only --out, --force"),
        (["--cache", "x"], "--cache applies to --identity-regressor only"),
    ],
)
def test_train_options_that_do_not_go_together_are_refused(tmp_path, capsys, args, message):
    """``jnr train``: each artifact option takes only its own options; nothing is written."""
    out = tmp_path / "out.npz"
    code = main(["train", "--out", str(out), "--quiet", *args])
    assert code == 2 and message in capsys.readouterr().err
    assert not out.exists()
