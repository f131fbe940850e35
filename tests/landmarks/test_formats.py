import json

import numpy as np
import pytest

from landmarks.formats import LandmarkFileError, read_landmarks, write_landmarks


@pytest.fixture
def points(rng):
    return rng.uniform(0, 640, size=(68, 2))


@pytest.mark.parametrize("ext", [".pts", ".json", ".csv"])
def test_round_trip(tmp_path, points, ext):
    path = tmp_path / f"face{ext}"
    write_landmarks(path, points)
    back = read_landmarks(path)
    assert back.shape == (68, 2) and back.dtype == np.float64
    np.testing.assert_allclose(back, points, rtol=0, atol=1e-9)


def test_pts_is_one_based_on_disk(tmp_path):
    path = tmp_path / "a.pts"
    path.write_text("version: 1\nn_points: 68\n{\n" + "1 1\n" * 67 + "10.5 20.25\n}\n")
    pts = read_landmarks(path)
    np.testing.assert_array_equal(pts[0], [0.0, 0.0])  # Matlab pixel (1, 1) is OpenCV pixel (0, 0)
    np.testing.assert_array_equal(pts[67], [9.5, 19.25])
    write_landmarks(path, np.zeros((68, 2)))
    text = path.read_text().splitlines()
    assert text[:3] == ["version: 1", "n_points: 68", "{"] and text[3] == "1.0 1.0" and text[-1] == "}"


def test_json_and_csv_layout(tmp_path, points):
    write_landmarks(tmp_path / "a.json", points)
    data = json.loads((tmp_path / "a.json").read_text())
    assert data["convention"] == "ibug68" and data["pixel_origin"] == "opencv" and len(data["landmarks"]) == 68
    write_landmarks(tmp_path / "a.csv", points)
    lines = (tmp_path / "a.csv").read_text().splitlines()
    assert lines[0] == "index,x,y" and lines[1].startswith("0,") and len(lines) == 69
    data["pixel_origin"] = "matlab"
    (tmp_path / "m.json").write_text(json.dumps(data))
    np.testing.assert_allclose(read_landmarks(tmp_path / "m.json"), points - 1.0)


def test_missing_file_and_unknown_extension(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.pts"):
        read_landmarks(tmp_path / "nope.pts")
    with pytest.raises(LandmarkFileError, match="unknown landmark format"):
        read_landmarks(tmp_path / "a.txt")


def _pts(lines, n=68):
    return f"version: 1\nn_points: {n}\n{{\n" + "\n".join(lines) + "\n}\n"


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("count.pts", _pts(["1 2"] * 67, 67), "expected 68 landmarks, got 67"),
        ("declared.pts", _pts(["1 2"] * 67), "n_points says 68 but the file lists 67"),
        ("nan.pts", _pts(["1 2"] * 10 + ["nan 3"] + ["1 2"] * 57), r"line 14: non-finite"),
        ("word.pts", _pts(["1 2"] * 5 + ["1 x"] + ["1 2"] * 62), r"line 9: not a number: 'x'"),
        ("three.pts", _pts(["1 2 3"] + ["1 2"] * 67), r"line 4: expected 'x y'"),
        ("open.pts", "version: 1\nn_points: 68\n{\n" + "1 2\n" * 68, "no '}'"),
        ("count.csv", "index,x,y\n" + "".join(f"{i},1,2\n" for i in range(60)), "expected 68 landmarks, got 60"),
        ("header.csv", "i,x,y\n0,1,2\n", "line 1: expected the header"),
        (
            "inf.csv",
            "index,x,y\n" + "".join(f"{i},{'inf' if i == 3 else 1},2\n" for i in range(68)),
            "line 5: non-finite",
        ),
        ("index.csv", "index,x,y\n0,1,2\n2,1,2\n", "line 3: expected index 1"),
        ("short.csv", "index,x,y\n0,1\n", "line 2: expected 'index,x,y'"),
        ("count.json", json.dumps({"landmarks": [[1, 2]] * 5}), "expected 68 landmarks, got 5"),
        ("bad.json", '{"landmarks": [', "invalid JSON"),
        ("row.json", json.dumps({"landmarks": [[1, 2]] * 3 + [[1, "a"]] + [[1, 2]] * 64}), "landmark 3"),
        ("conv.json", json.dumps({"landmarks": [[1, 2]] * 68, "convention": "mp468"}), "unsupported convention"),
    ],
)
def test_bad_files_raise_with_file_and_line(tmp_path, name, text, message):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(LandmarkFileError, match=message) as info:
        read_landmarks(path)
    assert name in str(info.value)


def test_write_rejects_bad_points(tmp_path):
    with pytest.raises(ValueError, match="shape"):
        write_landmarks(tmp_path / "a.csv", np.zeros((68, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        write_landmarks(tmp_path / "a.csv", np.full((68, 2), np.nan))


def test_write_landmarks_never_leaves_a_half_written_file(tmp_path, monkeypatch):
    import os

    path = tmp_path / "face.pts"
    first = np.arange(136, dtype=float).reshape(68, 2)
    write_landmarks(path, first)
    before = path.read_bytes()

    def fail(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", fail)
    with pytest.raises(OSError, match="No space"):
        write_landmarks(path, first + 1.0)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["face.pts"]
    np.testing.assert_allclose(read_landmarks(path), first)


@pytest.mark.parametrize("suffix", [".pts", ".json", ".csv"])
@pytest.mark.parametrize("count", [468, 478])
def test_mediapipe_point_files_round_trip(tmp_path, suffix, count):
    points = np.random.default_rng(count).uniform(10.0, 500.0, (count, 2))
    path = tmp_path / f"mesh{suffix}"
    write_landmarks(path, points)
    np.testing.assert_allclose(read_landmarks(path, (68, 468, 478)), points, atol=1e-9)
    with pytest.raises(LandmarkFileError, match=f"expected 68 landmarks, got {count}"):
        read_landmarks(path)  # an iBUG-68 reader refuses them
    if suffix == ".json":
        assert json.loads(path.read_text())["convention"] == "mediapipe"


def test_json_convention_must_match_the_count(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"landmarks": [[1.0, 2.0]] * 478, "convention": "ibug68"}))
    with pytest.raises(LandmarkFileError, match="478 landmarks do not match the convention 'ibug68'"):
        read_landmarks(path, (68, 478))
    path.write_text(json.dumps({"landmarks": [[1.0, 2.0]] * 68, "convention": "dlib"}))
    with pytest.raises(LandmarkFileError, match="unsupported convention 'dlib'"):
        read_landmarks(path, (68, 478))


@pytest.mark.parametrize("count", [68, 468, 478])
def test_a_json_file_without_a_convention_is_read_by_its_count(tmp_path, count):
    """Issue 38: 468/478-point JSON files without ``"convention": "mediapipe"`` were refused with a message
    about the convention; the count tells the layout (an explicit convention must still match)."""
    points = np.random.default_rng(count).uniform(10.0, 500.0, (count, 2))
    path = tmp_path / "points.json"
    path.write_text(json.dumps({"landmarks": points.tolist()}))
    np.testing.assert_allclose(read_landmarks(path, (68, 468, 478)), points)


def test_an_index_in_a_message_says_it_is_0_based(tmp_path):
    """Issue 38: messages gave numpy's 0-based index without saying so (a user counts from 1)."""
    path = tmp_path / "p.json"
    rows = [[1.0, 2.0]] * 68
    rows[3] = [1.0, "x"]
    path.write_text(json.dumps({"landmarks": rows}))
    with pytest.raises(LandmarkFileError, match=r"landmark 3 \(0-based\): expected \[x, y\] numbers"):
        read_landmarks(path)


def test_a_json_landmark_file_with_a_key_twice_is_refused(tmp_path):
    """Issue 38: a duplicate key was accepted silently (json keeps the last one)."""
    path = tmp_path / "p.json"
    points = json.dumps([[1.0, 2.0]] * 68)
    path.write_text(f'{{"landmarks": {points}, "landmarks": {points}}}')
    with pytest.raises(LandmarkFileError, match="'landmarks' appears twice"):
        read_landmarks(path)
