"""The pose error of the photo evaluation (pipeline.evaluation.photos.pose_error_angles) on known rotations."""

import numpy as np
import pytest

from pipeline.evaluation.photos import pose_error_angles, pose_error_deg
from rig.asset import load_asset
from rig.geometry import head_rotation


@pytest.mark.parametrize("yaw,pitch,roll", [(0.0, 4.0, 0.0), (-3.0, 0.0, 0.0), (2.0, -1.5, 1.0)])
def test_a_known_extra_rotation_is_the_pose_error(yaw, pitch, roll):
    """The same head, posed with a rotation that differs by a known rotation in the camera's axes (written in rig
    axes: the fitted pose turned further by ``correction`` is the true one): the error is that rotation's angle,
    its signed angles are the correction's, whatever the translation (the alignment is about the centroids)."""
    asset = load_asset()
    head = asset.vertices
    true_rotation, translation = head_rotation(20.0, -5.0, 2.0), np.array([10.0, -5.0, 650.0])
    correction = head_rotation(yaw, pitch, roll)
    fitted_rotation = correction.T @ true_rotation
    fitted_translation = translation + np.array([3.0, -2.0, 15.0])
    angle, y, p, r = pose_error_angles(
        head, fitted_rotation, fitted_translation, head, true_rotation, translation, asset
    )
    expected = np.degrees(np.arccos((np.trace(correction) - 1) / 2))
    assert angle == pytest.approx(expected, abs=1e-6)
    assert pose_error_deg(
        head, fitted_rotation, fitted_translation, head, true_rotation, translation, asset
    ) == pytest.approx(angle)
    np.testing.assert_allclose((y, p, r), (yaw, pitch, roll), atol=1e-6)


def test_no_error_for_the_true_pose():
    asset = load_asset()
    rotation = head_rotation(-15.0, 3.0, 0.0)
    angle = pose_error_deg(
        asset.vertices, rotation, np.array([0, 0, 700.0]), asset.vertices, rotation, np.array([0, 0, 700.0]), asset
    )
    assert angle == pytest.approx(0.0, abs=1e-5)
