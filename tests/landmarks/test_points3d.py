import numpy as np
import pytest

from landmarks.points3d import LANDMARK_NAMES_3D, LandmarkError, landmark_vertices, match_landmarks

GOLDEN = {"left_eye_outer": 1735, "left_eye_inner": 1727, "right_eye_inner": 1717, "right_eye_outer": 1709,
          "nose_tip": 2730, "mouth_left": 3576, "mouth_right": 3564, "chin": 4242}


def test_landmark_order_and_vertices_are_pinned(asset):
    ids = landmark_vertices(asset)
    assert tuple(ids) == LANDMARK_NAMES_3D
    assert ids == GOLDEN


def test_landmarks_sit_where_their_names_say(asset):
    v = asset.vertices[list(landmark_vertices(asset).values())]
    p = dict(zip(LANDMARK_NAMES_3D, v))
    assert p["left_eye_outer"][0] > p["left_eye_inner"][0] > 0 > p["right_eye_inner"][0] > p["right_eye_outer"][0]
    np.testing.assert_allclose(p["left_eye_outer"] * [-1, 1, 1], p["right_eye_outer"], atol=1e-6)  # mirror pair
    assert p["nose_tip"][2] == asset.vertices[asset.region_mask("nose"), 2].max()
    assert p["mouth_left"][1] < p["nose_tip"][1] and p["chin"][1] < p["mouth_left"][1]


def test_match_landmarks_checks_names_and_count(asset):
    ids, pos, names = match_landmarks({"chin": [0, 0, 0], "nose_tip": [1, 2, 3], "mouth_left": [4, 5, 6]}, asset)
    assert names == ("nose_tip", "mouth_left", "chin") and ids.tolist() == [2730, 3576, 4242]
    np.testing.assert_array_equal(pos[0], [1, 2, 3])
    with pytest.raises(LandmarkError, match="unknown"):
        match_landmarks({"nose": [0, 0, 0]}, asset)
    with pytest.raises(LandmarkError, match="at least 3"):
        match_landmarks({"chin": [0, 0, 0]}, asset)
