"""A seeded fuzz of jnr's file readers (issue 29): valid files of every kind, mangled at random (bytes
flipped, cut short, spliced with random bytes or text), must be read or refused with an ``InputError`` (one
line, exit 2 on the command line): never another exception, a hang or a crash. Deterministic: the seed
makes the same 240 files every run, in a few seconds."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from rig.errors import InputError

CASES = 40


def _mutations(data: bytes, seed: int, n: int = CASES):
    """``n`` mangled copies of ``data``: flips, truncations, random insertions, swapped text tokens."""
    rng = np.random.default_rng(seed)
    tokens = [b"nan", b"inf", b"-1e308", b"1e400", b"true", b'"x"', b"[", b"{", b"\x00", b"\xff\xfe", b"\n", b","]
    for i in range(n):
        b = bytearray(data)
        kind = i % 4
        if kind == 0 and b:  # flip a few bytes
            for j in rng.integers(0, len(b), size=int(rng.integers(1, 8))):
                b[j] = int(rng.integers(0, 256))
        elif kind == 1:  # cut short
            b = b[: int(rng.integers(0, max(1, len(b))))]
        elif kind == 2:  # random bytes spliced in
            at = int(rng.integers(0, len(b) + 1))
            b[at:at] = rng.integers(0, 256, size=int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
        else:  # a hostile token in place of a few bytes
            at = int(rng.integers(0, len(b) + 1))
            b[at : at + int(rng.integers(0, 4))] = tokens[int(rng.integers(0, len(tokens)))]
        yield bytes(b)


def _read_all(tmp_path, name: str, data: bytes, read, seed: int) -> dict:
    """Read every mangled copy; count the outcomes (an exception of another kind fails the test)."""
    outcomes = {"read": 0, "refused": 0}
    for i, mangled in enumerate(_mutations(data, seed)):
        path = tmp_path / f"{i}_{name}"
        path.write_bytes(mangled)
        try:
            read(path)
        except InputError as exc:
            assert "\n" not in str(exc).strip(), str(exc)
            outcomes["refused"] += 1
        else:
            outcomes["read"] += 1
    return outcomes


def _head_cloud() -> np.ndarray:
    rng = np.random.default_rng(0)
    d = rng.normal(size=(800, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * [75.0, 100.0, 90.0]


def test_mangled_point_clouds_are_read_or_refused(tmp_path, recwarn):
    from pipeline.scan.pointcloud.read import read_point_cloud
    from pipeline.scan.pointcloud.write import write_point_cloud_ply

    points = _head_cloud()
    write_point_cloud_ply(tmp_path / "seed.ply", points, normals=points / np.linalg.norm(points, axis=1, keepdims=True))
    buffer = io.BytesIO()
    np.save(buffer, points)
    seeds = {
        "c.ply": (tmp_path / "seed.ply").read_bytes(),
        "c.xyz": "\n".join(" ".join(f"{v:.4f}" for v in p) for p in points).encode(),
        "c.obj": "\n".join("v " + " ".join(f"{v:.4f}" for v in p) for p in points).encode(),
        "c.npy": buffer.getvalue(),
    }
    for k, (name, data) in enumerate(seeds.items()):
        outcomes = _read_all(tmp_path, name, data, read_point_cloud, seed=k)
        assert outcomes["refused"] > 0, (name, outcomes)  # the fuzz does reach the checks


def test_mangled_parameter_files_are_read_or_refused(tmp_path):
    from pipeline.head.params import load_params_file
    from rig.head_model import create
    from rig.io.params import load_params_json

    model = create("jnr")
    params = model.params(np.zeros(107), np.zeros(50), np.zeros(52))

    def read_fit(path):
        return model.from_dict(load_params_file(path).data)

    data = json.dumps({"format": "jnr-params/2", "fit": "photo", "model": "jnr", **model.to_dict(params)}).encode()
    assert _read_all(tmp_path, "params.json", data, read_fit, seed=10)["refused"] > 0
    joints = json.dumps({"joints": {"nose_tip.translate_y": 2.0, "neck.scale": 1.1, "jaw.rotate_x": 5.0}}).encode()
    assert _read_all(tmp_path, "joints.json", joints, load_params_json, seed=11)["refused"] > 0


def test_mangled_curves_are_read_or_refused(tmp_path):
    from pipeline.head.curves import read_curves

    rows = ["time,jawOpen,eyeBlinkLeft,mouthSmileRight"]
    rows += [f"{i / 30:.4f},{(i % 10) / 10},{(i % 7) / 7},{(i % 5) / 5}" for i in range(60)]
    outcomes = _read_all(tmp_path, "c.csv", "\n".join(rows).encode(), read_curves, seed=20)
    assert outcomes["refused"] > 0 and outcomes["read"] > 0


@pytest.mark.filterwarnings("ignore")
def test_mangled_photos_and_landmarks_are_read_or_refused(tmp_path):
    from PIL import Image

    from landmarks.formats import read_landmarks
    from landmarks.images import load_working_image

    rng = np.random.default_rng(3)
    picture = rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8)
    for k, fmt in enumerate(("png", "jpeg")):
        buffer = io.BytesIO()
        Image.fromarray(picture).save(buffer, format=fmt)
        outcomes = _read_all(
            tmp_path, f"p.{'jpg' if fmt == 'jpeg' else fmt}", buffer.getvalue(), load_working_image, 30 + k
        )
        assert outcomes["refused"] > 0, outcomes
    pts = "version: 1\nn_points: 68\n{\n" + "\n".join(f"{100 + i} {200 + (i * 7) % 50}" for i in range(68)) + "\n}\n"
    assert _read_all(tmp_path, "l.pts", pts.encode(), read_landmarks, seed=40)["refused"] > 0
