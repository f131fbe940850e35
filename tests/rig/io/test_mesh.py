"""Round trips of rig.io.mesh: OBJ / PLY through trimesh."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from rig.io.mesh import export_mesh, split_uv_seams, write_mtl
from tests.rig.io.conftest import merge_duplicates


def _hidden_files(directory: Path) -> list[str]:
    """Temporary files are hidden (``.name...``): none may be left behind."""
    return [p.name for p in directory.iterdir() if p.name.startswith(".")]


# ----------------------------------------------------------------------------------------------
# OBJ / PLY
# ----------------------------------------------------------------------------------------------


def test_obj_round_trip_with_uv_seam(sphere, tmp_path):
    v, f, uv = sphere["vertices"], sphere["faces"], sphere["face_uvs"]
    path = tmp_path / "head.obj"
    export_mesh(path, v, f, face_uvs=uv)

    loaded = trimesh.load(path, process=False)
    assert isinstance(loaded, trimesh.Trimesh)
    n = len(v)
    assert len(loaded.vertices) > n  # the seam was split
    np.testing.assert_allclose(loaded.vertices[:n], v, rtol=0, atol=1e-5)
    np.testing.assert_array_equal(merge_duplicates(loaded.vertices, loaded.faces, v), f)
    assert loaded.visual.uv is not None and loaded.visual.uv.shape == (len(loaded.vertices), 2)
    np.testing.assert_allclose(loaded.visual.uv[loaded.faces], uv, rtol=0, atol=1e-8)
    text = path.read_text()
    assert "mtllib" not in text and "\nvt " in text
    assert _hidden_files(tmp_path) == []


def test_obj_without_uvs_keeps_vertices_and_colors(sphere, tmp_path):
    v, f = sphere["vertices"], sphere["faces"]
    path = tmp_path / "plain.obj"
    export_mesh(path, v, f, vertex_colors=sphere["colors"])
    loaded = trimesh.load(path, process=False)
    assert len(loaded.vertices) == len(v)
    np.testing.assert_allclose(loaded.vertices, v, rtol=0, atol=1e-5)
    np.testing.assert_array_equal(loaded.faces, f)
    expected = np.round(sphere["colors"] * 255).astype(np.uint8)
    np.testing.assert_allclose(loaded.visual.vertex_colors[:, :3], expected, atol=1)


def test_obj_with_uvs_and_colors(sphere, tmp_path):
    v, f, uv = sphere["vertices"], sphere["faces"], sphere["face_uvs"]
    path = tmp_path / "both.obj"
    export_mesh(path, v, f, face_uvs=uv, vertex_colors=sphere["colors"])
    loaded = trimesh.load(path, process=False)
    n = len(v)
    np.testing.assert_allclose(loaded.vertices[:n], v, rtol=0, atol=1e-5)
    np.testing.assert_array_equal(merge_duplicates(loaded.vertices, loaded.faces, v), f)
    np.testing.assert_allclose(loaded.visual.uv[loaded.faces], uv, rtol=0, atol=1e-8)
    first_v = next(line for line in path.read_text().splitlines() if line.startswith("v "))
    assert len(first_v.split()) == 7  # v x y z r g b


def test_obj_with_a_textured_material_reloads_with_its_image(sphere, tmp_path):
    """mtllib after the header comment, usemtl before the faces; trimesh finds the material's image."""
    from PIL import Image

    v, f, uv = sphere["vertices"], sphere["faces"], sphere["face_uvs"]
    image = np.random.default_rng(0).integers(0, 256, (16, 32, 3), dtype=np.uint8)
    Image.fromarray(image).save(tmp_path / "texture.png")
    write_mtl(tmp_path / "head.mtl", "skin", "texture.png")
    export_mesh(
        tmp_path / "head.obj", v, f, face_uvs=uv, vertex_colors=sphere["colors"], mtllib="head.mtl", material="skin"
    )
    lines = (tmp_path / "head.obj").read_text().splitlines()
    assert lines[0].startswith("# jnr: millimetres") and lines[1] == "mtllib head.mtl"
    assert lines.index("usemtl skin") == next(i for i, ln in enumerate(lines) if ln.startswith("f ")) - 1
    assert "map_Kd texture.png" in (tmp_path / "head.mtl").read_text().splitlines()

    loaded = trimesh.load(tmp_path / "head.obj", process=False)
    np.testing.assert_allclose(loaded.vertices[: len(v)], v, rtol=0, atol=1e-5)
    np.testing.assert_allclose(loaded.visual.uv[loaded.faces], uv, rtol=0, atol=1e-8)
    np.testing.assert_array_equal(np.asarray(loaded.visual.material.image.convert("RGB")), image)
    # without colours (trimesh's own OBJ text) the material lines are placed the same way
    export_mesh(tmp_path / "plain.obj", v, f, face_uvs=uv, mtllib="head.mtl", material="skin")
    plain = (tmp_path / "plain.obj").read_text().splitlines()
    assert plain[1] == "mtllib head.mtl" and plain.count("usemtl skin") == 1
    assert trimesh.load(tmp_path / "plain.obj", process=False).visual.material.image.size == (32, 16)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"mtllib": "a.mtl"}, "go together"),
        ({"mtllib": "a.mtl", "material": "skin", "file_format": "ply"}, "OBJ files only"),
        ({"mtllib": "a.mtl", "material": "skin", "face_uvs": None}, "needs face_uvs"),
        ({"mtllib": "my head.mtl", "material": "skin"}, "without whitespace"),
    ],
)
def test_bad_materials(sphere, tmp_path, kwargs, match):
    args = {"face_uvs": sphere["face_uvs"], **kwargs}
    with pytest.raises(ValueError, match=match):
        export_mesh(tmp_path / "bad.obj", sphere["vertices"], sphere["faces"], **args)
    with pytest.raises(ValueError, match="without whitespace"):
        write_mtl(tmp_path / "bad.mtl", "skin", "my texture.png")
    with pytest.raises(ValueError, match="diffuse"):
        write_mtl(tmp_path / "bad.mtl", "skin", "texture.png", diffuse=(2.0, 1.0, 1.0))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("uint8", [False, True])
def test_ply_round_trip_with_colors(sphere, tmp_path, uint8):
    v, f = sphere["vertices"], sphere["faces"]
    colors = sphere["colors"]
    expected = np.round(colors * 255).astype(np.uint8)
    path = tmp_path / "head.ply"
    export_mesh(path, v, f, vertex_colors=expected if uint8 else colors)
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian")
    loaded = trimesh.load(path, process=False)
    assert len(loaded.vertices) == len(v)
    np.testing.assert_allclose(loaded.vertices, v, rtol=0, atol=1e-4)  # float32 on disk
    np.testing.assert_array_equal(loaded.faces, f)
    np.testing.assert_array_equal(loaded.visual.vertex_colors[:, :3], expected)


def test_ply_with_uvs(sphere, tmp_path):
    v, f, uv = sphere["vertices"], sphere["faces"], sphere["face_uvs"]
    path = tmp_path / "head.data"
    export_mesh(path, v, f, face_uvs=uv, vertex_colors=sphere["colors"], file_format="ply")
    loaded = trimesh.load(path, file_type="ply", process=False)
    n = len(v)
    np.testing.assert_allclose(loaded.vertices[:n], v, rtol=0, atol=1e-4)
    np.testing.assert_array_equal(merge_duplicates(loaded.vertices, loaded.faces, v), f)
    np.testing.assert_allclose(loaded.visual.uv[loaded.faces], uv, rtol=0, atol=1e-8)


def test_split_uv_seams_keeps_the_input_vertices_first(sphere):
    f, uv = sphere["faces"], sphere["face_uvs"]
    n = len(sphere["vertices"])
    split_faces, uvs, source = split_uv_seams(f, uv, n)
    assert np.array_equal(source[:n], np.arange(n)) and len(source) > n  # the seam was split
    assert np.array_equal(source[split_faces], f)  # every corner still uses its own vertex
    np.testing.assert_array_equal(uvs[split_faces], uv)  # and its own UV
    assert len(np.unique(np.column_stack([source, uvs]), axis=0)) == len(source)  # no needless duplicate


# ----------------------------------------------------------------------------------------------
# errors and atomic writes
# ----------------------------------------------------------------------------------------------


def test_bad_formats(sphere, tmp_path):
    v, f = sphere["vertices"], sphere["faces"]
    with pytest.raises(ValueError, match="unsupported file format 'stl'"):
        export_mesh(tmp_path / "a.stl", v, f)
    with pytest.raises(ValueError, match="unsupported file format"):
        export_mesh(tmp_path / "a.obj", v, f, file_format="fbx")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"vertices": np.zeros((10, 2))}, r"vertices must have shape \(V, 3\).*\(10, 2\)"),
        ({"faces": np.zeros((4, 4), dtype=int)}, r"faces must have shape .*\(4, 4\)"),
        ({"faces": np.full((4, 3), 999)}, r"faces index vertices out of range"),
        ({"face_uvs": np.zeros((5, 3, 2))}, r"face_uvs must have shape .*\(5, 3, 2\)"),
        ({"vertex_colors": np.zeros((3, 3))}, r"vertex_colors must have shape .*\(3, 3\)"),
        ({"vertex_colors": "big"}, r"vertex_colors"),
    ],
)
def test_bad_mesh_shapes(sphere, tmp_path, kwargs, match):
    args = {"vertices": sphere["vertices"], "faces": sphere["faces"]}
    args.update(kwargs)
    if isinstance(kwargs.get("vertex_colors"), str):
        args["vertex_colors"] = sphere["colors"] * 2.0
    path = tmp_path / "bad.obj"
    with pytest.raises(ValueError, match=match):
        export_mesh(path, args.pop("vertices"), args.pop("faces"), **args)
    assert not path.exists()


def test_failed_write_leaves_nothing(sphere, tmp_path, monkeypatch):
    v, f = sphere["vertices"], sphere["faces"]

    def broken_fsync(fd):
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    for name in ("a.obj", "a.ply"):
        with pytest.raises(OSError, match="disk full"):
            export_mesh(tmp_path / name, v, f)
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_existing_file(sphere, tmp_path):
    v, f = sphere["vertices"], sphere["faces"]
    path = tmp_path / "keep.obj"
    path.write_text("old")
    with pytest.raises(ValueError):
        export_mesh(path, v[:, :2], f)
    assert path.read_text() == "old"

    # the destination is a directory: refused, the temporary file is removed
    blocker = tmp_path / "blocked.ply"
    blocker.mkdir()
    with pytest.raises(OSError):
        export_mesh(blocker, v, f)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocked.ply", "keep.obj"]
    assert os.listdir(blocker) == []


def test_units_are_stated_in_the_header(tmp_path, sphere):
    """OBJ and PLY say their units and frame (mm, rig space by default; a caller's line otherwise), and readers
    still load them."""
    from rig.io.mesh import RIG_SPACE_COMMENT

    export_mesh(tmp_path / "a.obj", sphere["vertices"], sphere["faces"])
    export_mesh(tmp_path / "a.ply", sphere["vertices"], sphere["faces"], vertex_colors=sphere["colors"])
    export_mesh(tmp_path / "b.ply", sphere["vertices"], sphere["faces"], comment="metres, camera frame")
    assert (tmp_path / "a.obj").read_text().splitlines()[0] == f"# jnr: {RIG_SPACE_COMMENT}"
    assert "millimetres" in RIG_SPACE_COMMENT and "+Y up" in RIG_SPACE_COMMENT
    header = (tmp_path / "a.ply").read_bytes().split(b"end_header")[0].decode()
    assert f"comment jnr: {RIG_SPACE_COMMENT}" in header.splitlines()
    assert "comment jnr: metres, camera frame" in (tmp_path / "b.ply").read_bytes()[:300].decode("latin-1")
    for name in ("a.obj", "a.ply", "b.ply"):
        loaded = trimesh.load(tmp_path / name, process=False)
        np.testing.assert_allclose(
            np.asarray(loaded.vertices)[: len(sphere["vertices"])], sphere["vertices"], atol=1e-4
        )
    with pytest.raises(ValueError, match="one line"):
        export_mesh(tmp_path / "c.obj", sphere["vertices"], sphere["faces"], comment="two\nlines")
