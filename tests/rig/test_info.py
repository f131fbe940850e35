import subprocess
import sys

from rig.info import rig_info
from rig.parameters import NUM_PARAMETERS


def test_rig_info_counts_the_asset(asset):
    info = rig_info(asset)
    assert list(info) == [
        "vertices",
        "faces",
        "joints",
        "free_parameters",
        "free_parameters_symmetric",
        "skinning_floats",
        "skinning_nonzeros",
        "max_influences",
        "model_floats",
        "expressions",
        "expression_names",
        "regions",
        "units",
        "asset_version",
        "asm_parameters_per_bone",
        "asm_parameters",
        "asm_gmm_vertices",
    ]
    assert (info["vertices"], info["faces"], info["joints"]) == (len(asset.vertices), len(asset.faces), 52)
    assert info["free_parameters"] == NUM_PARAMETERS and 0 < info["free_parameters_symmetric"] < NUM_PARAMETERS
    assert info["skinning_floats"] == len(asset.weight_free) and info["skinning_nonzeros"] == len(asset.weight_rows)
    assert 1 <= info["max_influences"] <= 52
    assert info["model_floats"] == asset.vertices.size + asset.joint_positions.size + len(asset.weight_free)
    assert info["regions"] == list(asset.region_names) and info["units"] == "mm"
    assert info["expressions"] == 52 and info["expression_names"][:2] == ["eyeBlinkLeft", "eyeLookDownLeft"]
    assert 4500 <= info["vertices"] <= 5500
    # ASM Table 1: 11 + 6K floats per bone, on the rig's 52 joints
    assert info["asm_parameters_per_bone"] == {"K=2": 23, "K=3": 29, "K=5": 41}
    assert info["asm_parameters"]["K=2"] == 52 * 23 == 1196
    assert 3000 < info["asm_gmm_vertices"] < info["vertices"]
    assert rig_info() == info  # the committed asset by default


def test_rig_info_imports_nothing_outside_rig():
    code = (
        "import sys, rig.info; bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('pipeline', 'landmarks', 'render')); print(bad); sys.exit(bool(bad))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_a_reader_that_goes_away_is_not_an_error():
    """``jnr rig info --json | head``: when the pipe's reader has gone, jnr stops quietly (exit 141, as a
    process ended by SIGPIPE), not with "jnr: error: [Errno 32] Broken pipe"."""
    import os

    read, write = os.pipe()
    os.close(read)  # the reader is gone before jnr writes
    proc = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "rig", "info", "--json"],
        stdout=write,
        stderr=subprocess.PIPE,
        text=True,
        timeout=120,
    )
    os.close(write)
    assert proc.returncode == 141 and proc.stderr == "", (proc.returncode, proc.stderr)
