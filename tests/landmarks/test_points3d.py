import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from landmarks.points3d import (
    LANDMARK_NAMES_3D,
    MAX_CLOUD_DISTANCE_MM,
    MAX_SHAPE_RESIDUAL,
    LandmarkError,
    check_landmarks_3d,
    fit_similarity,
    landmark_vertices,
    match_landmarks,
)
from rig.geometry import Similarity

GOLDEN = {
    "left_eye_outer": 3240,
    "left_eye_inner": 3254,
    "right_eye_inner": 1104,
    "right_eye_outer": 1090,
    "nose_tip": 294,
    "mouth_left": 2730,
    "mouth_right": 527,
    "chin": 991,
}


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
    assert names == ("nose_tip", "mouth_left", "chin") and ids.tolist() == [294, 2730, 991]
    np.testing.assert_array_equal(pos[0], [1, 2, 3])
    with pytest.raises(LandmarkError, match="unknown"):
        match_landmarks({"nose": [0, 0, 0]}, asset)
    with pytest.raises(LandmarkError, match="at least 3"):
        match_landmarks({"chin": [0, 0, 0]}, asset)


# ------------------------------------------------------------------------------------------ plausibility


@pytest.fixture(scope="module")
def template_marks(asset):
    """The 8 landmarks of the template (rig space, mm) and the template's front as a cloud."""
    ids = landmark_vertices(asset)
    front = asset.vertices[asset.vertices[:, 2] > 20.0]
    return np.array([asset.vertices[i] for i in ids.values()]), list(ids), front


def _placed(points, seed=0, scale=1.1):
    """A random rotation, the scale and a translation (the same for landmarks and their cloud)."""
    rot = Rotation.random(random_state=seed).as_matrix()
    return Similarity(rot, np.array([30.0, -200.0, 650.0]), scale).apply(points), rot


def test_fit_similarity_equals_the_similarity_fit_and_sees_reflections(rng):
    for _ in range(5):
        a, b = rng.normal(size=(6, 3)) * 50.0, rng.normal(size=(6, 3)) * 40.0
        scale, rot, proper, improper = fit_similarity(a, b)
        best = Similarity.fit(a, b, with_scale=True)
        assert scale == pytest.approx(best.scale, rel=1e-12) and np.allclose(rot, best.rotation, atol=1e-10)
        assert proper == pytest.approx(np.sqrt(((best.apply(a) - b) ** 2).sum(1).mean()), rel=1e-9)
        mirrored = a * [-1.0, 1.0, 1.0]  # the best improper fit is the best proper fit of the mirror image
        best = Similarity.fit(mirrored, b, with_scale=True)
        assert improper == pytest.approx(np.sqrt(((best.apply(mirrored) - b) ** 2).sum(1).mean()), rel=1e-9)


def test_plausible_landmarks_are_accepted(template_marks, rng):
    marks, names, front = template_marks
    placed, rot = _placed(marks, seed=1, scale=1.1)
    noisy = placed + rng.normal(0.0, 2.0, placed.shape)
    cloud, _ = _placed(front, seed=1, scale=1.1)
    check = check_landmarks_3d(noisy, names, cloud=cloud, view_direction=rot[:, 2])
    assert check.scale == pytest.approx(1.1, abs=0.05) and check.shape_residual < 0.1
    assert check.mirrored_residual > MAX_SHAPE_RESIDUAL  # all 8: a reflection does not fit
    assert check.facing > 0.95 and check.cloud_distance_mm.max() < 10.0
    assert check_landmarks_3d(placed[[4, 5, 7]], [names[i] for i in (4, 5, 7)]).min_separation_mm > 40  # 3 suffice


@pytest.mark.parametrize(
    "case, message",
    [
        ("coincident", "0 mm apart"),
        ("metres", r"are 0\.0011 x the size of the template's \(accepted 0\.5-2\)"),
        ("ten_times", r"are 11 x the size"),
        ("mirrored", "look mirrored"),
        ("shuffled", "not face-like"),
        ("swapped_flat", "away from the scanner"),
        ("far", r"'chin' is \d+(\.\d+)? mm from the nearest cloud point \(at most 75 mm accepted\)"),
    ],
)
def test_implausible_landmarks_are_rejected_with_what_was_wrong(template_marks, case, message):
    marks, names, front = template_marks
    placed, rot = _placed(marks)
    cloud, _ = _placed(front)
    view = rot[:, 2]  # the template's face direction, placed: the scanner looks at the face
    if case == "coincident":
        placed, names = np.repeat(placed[:1], 3, axis=0), names[:3]
    elif case == "metres":
        placed = placed / 1000.0
    elif case == "ten_times":
        placed = placed * 10.0
    elif case == "mirrored":  # x negated in the template's frame: every left/right label swapped
        placed, _ = _placed(marks * [-1.0, 1.0, 1.0])
    elif case == "shuffled":
        placed = placed[[0, 1, 2, 3, 7, 5, 6, 4]]  # nose tip and chin swapped
    elif case == "swapped_flat":  # eyes and mouth corners only (nearly coplanar), left and right swapped
        flat = [0, 1, 2, 3, 5, 6]
        placed, names = placed[[3, 2, 1, 0, 6, 5]], [names[i] for i in flat]
    elif case == "far":  # a hole of 85 mm around the chin: the chin is off the cloud, the others are not
        cloud = cloud[np.linalg.norm(cloud - placed[7], axis=1) > MAX_CLOUD_DISTANCE_MM + 10.0]
    with pytest.raises(LandmarkError, match=message) as info:
        check_landmarks_3d(placed, names, cloud=cloud, view_direction=view, source="marks.json")
    assert str(info.value).startswith("marks.json: ") and "\n" not in str(info.value)
