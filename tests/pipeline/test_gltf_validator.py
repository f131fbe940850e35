"""Our glTF files through Khronos' glTF validator (npm ``gltf-validator``, installed by ``make venv``'s
``npm ci`` beside three.js): a fit's skinned head with its texture, an accessory and an animation must give
no error and no warning.

Skipped where Node.js or the validator is missing, unless ``JNR_REQUIRE_BROWSER=1`` (CI), which makes the
missing tool a failure.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import trimesh

from tests.conftest import needs_tool

ROOT = Path(__file__).resolve().parents[2]
VALIDATOR = ROOT / "node_modules" / "gltf-validator"
SCRIPT = """
const validator = require(process.argv[1]);
const fs = require('fs');
(async () => {
  const out = {};
  for (const file of process.argv.slice(2)) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)));
    out[file] = {errors: report.issues.numErrors, warnings: report.issues.numWarnings,
                 messages: report.issues.messages.filter(m => m.severity <= 1).slice(0, 5)};
  }
  console.log(JSON.stringify(out));
})();
"""


NODE = shutil.which("node")
MISSING = "Node.js or node_modules/gltf-validator missing (make venv runs npm ci)"


@needs_tool(NODE is not None and VALIDATOR.is_dir(), MISSING)
def test_our_gltf_files_pass_the_khronos_validator(tmp_path):
    assert NODE is not None and VALIDATOR.is_dir(), MISSING
    node = NODE
    import torch

    from pipeline.animation import curve_keyframes, example_curves, load_fit_head
    from pipeline.head.skinned import write_skinned_head
    from rig.asset import load_asset
    from rig.io.gltf import GltfAttachment
    from rig.parameters import random_theta, theta_to_params

    generator = torch.Generator().manual_seed(2)
    params = {
        "joints": theta_to_params(random_theta(generator, 1)[0].double()),
        "latent_z": [0.1] * 50,
        "expressions": {"jawOpen": 0.3},
    }
    fit = tmp_path / "fit"
    fit.mkdir()
    (fit / "params.json").write_text(json.dumps(params))
    import io

    from PIL import Image

    png = io.BytesIO()
    Image.fromarray(np.full((16, 16, 3), 180, np.uint8)).save(png, format="PNG")
    (fit / "texture.png").write_bytes(png.getvalue())
    head = load_fit_head(fit)
    asset = load_asset()
    box = trimesh.creation.box(extents=(60.0, 20.0, 20.0))
    weights = np.zeros((len(box.vertices), len(asset.joint_names)))
    weights[:, list(asset.joint_names).index("crown")] = 1.0
    hat = GltfAttachment(
        "hat",
        np.asarray(box.vertices) + [0.0, 110.0, 0.0],
        np.asarray(box.faces),
        weights,
        np.zeros((52, len(box.vertices), 3)),
        (0.1, 0.2, 0.6),
    )
    files = {
        "head.glb": {},
        "head.gltf": {},
        "head_keys.glb": {"expression": "keys"},  # mesh_keys.glb's layout (issue 38)
        "animated_with_hat.glb": {"attachments": [hat], "animation": curve_keyframes(head, example_curves())},
    }
    for name, extra in files.items():
        write_skinned_head(
            tmp_path / name, asset, head.weights, head.tau, head.expressions, base_color_texture=head.texture, **extra
        )
    run = subprocess.run(
        [node, "-e", SCRIPT, str(VALIDATOR), *(str(tmp_path / n) for n in files)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    reports = json.loads(run.stdout)
    for name in files:
        report = reports[str(tmp_path / name)]
        assert report["errors"] == 0 and report["warnings"] == 0, (name, report["messages"])
