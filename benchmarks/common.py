"""What the benchmarks share: the models on 2 torch threads, and how a run ends (the command, the JSON)."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import torch


def load_models():
    """``(rig, neural)``: the committed rig (float32) and its learned skinning, torch on 2 threads (the
    machine the README's figures were measured on)."""
    from rig.model import JointRig
    from rig.skinning.neural import load_neural

    torch.set_num_threads(2)
    rig = JointRig()
    neural, _ = load_neural(rig)
    return rig, neural


def finish(payload: dict, json_path: Path | None) -> None:
    """Print the command that made the figures and, with ``json_path``, write ``payload`` and the command."""
    print("command: " + " ".join(shlex.quote(a) for a in [sys.executable, *sys.argv]))
    if json_path:
        json_path.write_text(json.dumps({**payload, "command": sys.argv}, indent=1, default=str))
