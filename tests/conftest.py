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
