import os

import numpy as np
import pytest
import torch

from rig.asset import load_asset
from rig.model import JointRig


@pytest.fixture(scope="session")
def asset():
    return load_asset()


@pytest.fixture(scope="session")
def rig64(asset):
    return JointRig(asset, dtype=torch.float64)


@pytest.fixture(scope="session")
def rig32(asset):
    return JointRig(asset, dtype=torch.float32)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


REQUIRE_TOOLS = os.environ.get("JNR_REQUIRE_BROWSER") == "1"
"""CI (``.ci/run``) sets ``JNR_REQUIRE_BROWSER=1``: tests that need Chromium, three.js or Node.js then run and
fail on a missing tool instead of being skipped."""


def needs_tool(available: bool, why: str):
    """A ``skipif`` marker for tests that need an outside tool: skipped where it is missing (a developer
    machine without ``make venv``/``make browser``), run anyway under :data:`REQUIRE_TOOLS`, where the test's
    own check of the tool fails with ``why``."""
    return pytest.mark.skipif(not available and not REQUIRE_TOOLS, reason=why)
