import numpy as np
import pytest
import torch

from rig.joints import JOINT_MIRROR, JOINT_NAMES, PARENTS
from rig.parameters import CHANNELS, mirror_theta, params_to_theta, random_theta


def test_initial_weights_are_sparse_normalised_symmetric(asset):
    w = asset.weights
    assert (w >= 0).all()
    assert np.abs(w.sum(1) - 1).max() < 1e-12
    assert (w > 0).sum(1).max() <= 4
    assert np.abs(w[asset.mirror][:, list(JOINT_MIRROR)] - w).max() < 1e-12
    assert 5000 <= len(asset.weight_free) <= 10000  # JNR: 8,990 free floats (ours: 5,757 on 4,874 vertices)
    assert len(asset.weight_rows) > 1.8 * len(asset.weight_free)  # symmetry shares most floats


def test_mirrored_parameters_give_mirrored_mesh(rig64):
    theta = random_theta(torch.Generator().manual_seed(11), 3, spread=0.6, dtype=torch.float64)
    out = rig64(theta).vertices
    mirrored = rig64(mirror_theta(theta)).vertices
    assert torch.abs(rig64.mirror_vertices(out) - mirrored).max() < 1e-9
    # and an asymmetric edit really is asymmetric
    assert torch.abs(out - rig64.mirror_vertices(out)).max() > 1.0


def _subtree(k):
    out = {k}
    for j, p in enumerate(PARENTS):
        if p in out:
            out.add(j)
    return out


# The region each joint paints (where Table 1 gives it a channel).
EXPECTED_REGION = {
    "neck": {"neck"},
    "crown": {"scalp"},
    "brow_center": {"brows", "forehead", "nose"},
    "left_brow_outer": {"brows", "forehead", "eyelids"},
    "left_eye_socket": {"eyelids", "eyeballs", "eye_pockets"},
    "left_upper_eyelid": {"eyelids"},
    "left_lower_eyelid": {"eyelids"},
    "left_cheek_bone": {"cheeks"},
    "nose_root_a": {"nose", "brows"},
    "nose_bridge": {"nose"},
    "nose_ridge_a": {"nose"},
    "nose_ridge_b": {"nose"},
    "left_ear_position": {"ears", "scalp"},
    "left_ear_rotate_scale": {"ears"},
    "nose_tip": {"nose"},
    "nose_nostril": {"nose"},
    "mouth_left_corner": {"lips", "cheeks"},
    "chin": {"chin"},
    "top_lip": {"lips"},
    "bottom_lip": {"lips"},
    "left_cheek": {"cheeks"},
    "left_chin": {"chin"},
    "left_jaw_root": {"jaw", "neck", "cheeks"},
}


@pytest.mark.parametrize("channel", [c.name for c in CHANNELS])
def test_each_channel_moves_its_own_region_only(rig64, asset, channel):
    c = CHANNELS[[x.name for x in CHANNELS].index(channel)]
    value = c.high if abs(c.high - (1.0 if c.is_scale else 0.0)) >= abs(c.low - (1.0 if c.is_scale else 0.0)) else c.low
    theta = params_to_theta({channel: value}, dtype=torch.float64)[None]
    moved = torch.linalg.norm(rig64(theta).vertices[0] - rig64.template, dim=-1).numpy()
    assert moved.max() > 0.2, f"{channel} moves nothing"
    # Vertices without weight on the joint or its descendants do not move at all.
    subtree = sorted(_subtree(c.joint))
    untouched = asset.weights[:, subtree].sum(1) == 0
    assert moved[untouched].max() < 1e-9
    name = JOINT_NAMES[c.joint]
    if name in EXPECTED_REGION:
        # The joint paints its own region: its 10 heaviest vertices lie there.
        top = np.argsort(-asset.weights[:, c.joint], kind="stable")[:10]
        regions = {asset.region_names[r] for r in asset.regions[top]}
        assert regions & EXPECTED_REGION[name], (channel, regions)
    if name.startswith("nose"):
        assert moved[asset.region_mask("ears", "neck", "scalp")].max() < 1e-9
    if name.startswith("left_") and name not in ("left_crown_outer",):
        right = asset.vertices[:, 0] < -20
        assert moved[right].max() < 1e-9


def test_limits_loss_enforces_limits():
    from rig.losses import limit_loss
    from rig.parameters import theta_limits

    low, high = theta_limits(torch.float64)
    inside = random_theta(torch.Generator().manual_seed(1), 4, spread=1.0, dtype=torch.float64)
    assert torch.all(limit_loss(inside, low, high) == 0)
    outside = inside.clone()
    outside[:, 0] = high[0] + 2.0
    assert torch.allclose(limit_loss(outside, low, high), torch.full((4,), 2.0 / 52, dtype=torch.float64))
