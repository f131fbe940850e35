"""Tests of pipeline/photo/outputs.py: the texture in mesh.obj / mesh.mtl / mesh.glb, the face-only overlay.

A hand-made fit (the template, a known head pose and camera) over a photo whose colour encodes the pixel
(red = column, green = row) keeps these tests to seconds and the expected values exact.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from rig.geometry import head_rotation
from rig.template import FACE_REGIONS

WIDTH = HEIGHT = 192
FOCAL = 400.0
TEXTURE = 256


def _ibug_names(indices) -> list[str]:
    from landmarks.ibug68.names import IBUG68_NAMES

    return [IBUG68_NAMES[i] for i in indices]


def coordinate_photo() -> np.ndarray:
    photo = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    photo[..., 0] = np.arange(WIDTH)[None, :]
    photo[..., 1] = np.arange(HEIGHT)[:, None]
    photo[..., 2] = 60
    return photo


@pytest.fixture(scope="module")
def asset():
    from rig.asset import load_asset

    return load_asset()


@pytest.fixture(scope="module")
def hand_fit(asset):
    """A PhotoFit of the template turned 20 degrees (yaw), 600 mm away, without photometric stages.

    The rig's origin is on the optical axis: the face is well inside the 192 px photo and so is the front of
    the neck below the chin (row ~181), the top of the scalp and the bottom of the neck are cut off.
    """
    from landmarks.ibug68.embedding import ibug68_embedding
    from landmarks.ibug68.positions import landmark_positions
    from pipeline.camera import make_camera
    from pipeline.photo.fit import PhotoAppearance, PhotoFit, PhotoLandmarks
    from pipeline.photo.landmark_fit import LandmarkFit
    from rig.expressions import EXPRESSION_NAMES
    from rig.head_model import HeadParams
    from rig.parameters import NUM_PARAMETERS

    rotation, translation = head_rotation(20.0, 0.0, 0.0), np.array([0.0, 0.0, 600.0])
    camera = make_camera(WIDTH, HEIGHT, FOCAL, rotation=rotation, translation=translation)
    v = np.asarray(asset.vertices, np.float64)
    points = landmark_positions(v, ibug68_embedding(asset), asset.faces)[0]
    points = np.asarray(points, np.float64)
    cam = points @ (np.diag([1.0, -1, -1]) @ rotation).T + translation
    px = cam[:, :2] / cam[:, 2:] * FOCAL + (WIDTH - 1) / 2
    theta, z, expressions = np.zeros(NUM_PARAMETERS), np.zeros(50), np.zeros(len(EXPRESSION_NAMES))
    lfit = LandmarkFit(
        theta=theta,
        z=z,
        expressions=expressions,
        rotation=rotation,
        translation=translation,
        camera=camera,
        landmarks_px=px,
        error_px=np.zeros(68),
        nme=0.0,
        landmarks3d=points,
        losses={},
        stages=(),
        seconds=0.0,
    )
    head = HeadParams("jnr", {"joints": theta, "latent": z, "expressions": expressions})
    return PhotoFit(
        head=head,
        rotation=rotation,
        translation=translation,
        focal=FOCAL,
        width=WIDTH,
        height=HEIGHT,
        camera=camera,
        rig_vertices=v,
        appearance=PhotoAppearance(
            albedo=np.full((len(v), 3), 0.5),
            ambient=np.full(3, 0.6),
            irradiance=np.zeros(3),
            light_camera=np.array([0.0, 0.0, 1.0]),
            light_rig=np.array([0.0, 0.0, -1.0]),
        ),
        landmarks=PhotoLandmarks(px, px, np.zeros(68), 0.0, cam),
        landmark_fit=lfit,
        stages=(),
        crop=None,
        timings={},
    )


@pytest.fixture(scope="module")
def out_dir(hand_fit, tmp_path_factory):
    from pipeline.photo.outputs import write_photo_outputs

    return write_photo_outputs(
        tmp_path_factory.mktemp("fit") / "out", coordinate_photo(), hand_fit, spp=1, texture_size=TEXTURE
    )


@pytest.fixture(scope="module")
def face_render(hand_fit, asset):
    """``(image, face mask, coverage)`` of the hand-made fit."""
    from pipeline.photo.outputs import render_fit

    image, face = render_fit(hand_fit, spp=1, asset=asset, mask_regions=FACE_REGIONS)
    _, coverage = render_fit(hand_fit, spp=1, asset=asset)
    return image, face, coverage


def _project(fit, points):
    cam = points @ (np.diag([1.0, -1, -1]) @ fit.rotation).T + fit.translation
    return cam[:, :2] / cam[:, 2:] * fit.focal + (WIDTH - 1) / 2


class TestTextureFiles:
    def test_texture_png_reloads_at_its_size_and_is_the_unwrap(self, out_dir, hand_fit, asset):
        from PIL import Image

        from pipeline.head.folders import PHOTO_FOLDER
        from pipeline.photo.texture import texture_from_fit

        assert {"texture.png", "mesh.mtl"} <= set(PHOTO_FOLDER.required) <= {p.name for p in out_dir.iterdir()}
        image = np.asarray(Image.open(out_dir / "texture.png"))
        assert image.shape == (TEXTURE, TEXTURE, 3) and image.dtype == np.uint8
        skin = [asset.region_names.index(r) for r in FACE_REGIONS]  # the median fill's texels
        again = texture_from_fit(
            coordinate_photo(),
            hand_fit,
            asset.faces,
            asset.face_uvs,
            regions=asset.regions,
            skin_region_ids=skin,
            size=TEXTURE,
        )
        np.testing.assert_array_equal(image, again.image)
        # without photometric stages the fill is the median seen colour, recorded in the report
        report = json.loads((out_dir / "report.json").read_text())["texture"]
        assert report["size_px"] == TEXTURE and report["fill"] == "median of visible texels"
        assert 0.1 < report["seen_fraction"] < 0.6

    def test_obj_reloads_with_uvs_and_the_texture(self, out_dir, asset):
        import trimesh
        from PIL import Image

        assert "map_Kd texture.png" in (out_dir / "mesh.mtl").read_text().splitlines()
        lines = (out_dir / "mesh.obj").read_text().splitlines()
        assert lines[0].startswith("# jnr: millimetres") and lines[1] == "mtllib mesh.mtl" and "usemtl skin" in lines
        obj = trimesh.load(out_dir / "mesh.obj", process=False)
        assert isinstance(obj.visual, trimesh.visual.TextureVisuals)
        np.testing.assert_allclose(obj.visual.uv[obj.faces], asset.face_uvs, atol=1e-8)
        np.testing.assert_array_equal(
            np.asarray(obj.visual.material.image.convert("RGB")), np.asarray(Image.open(out_dir / "texture.png"))
        )

    def test_glb_carries_the_same_texture_and_flipped_uvs(self, out_dir, asset):
        import pygltflib
        import trimesh

        from tests.support.gltf_reader import read_skinned_gltf

        glb = read_skinned_gltf(out_dir / "mesh.glb")
        assert glb["base_color_texture"] == (out_dir / "texture.png").read_bytes()
        assert glb["colors"] is None  # no COLOR_0 to multiply the texture with
        np.testing.assert_allclose(glb["texcoords"][glb["gltf_faces"]], asset.face_uvs, atol=1e-6)
        gltf = pygltflib.GLTF2.load(str(out_dir / "mesh.glb"))
        accessor = gltf.accessors[gltf.meshes[0].primitives[0].attributes.TEXCOORD_0]
        view = gltf.bufferViews[accessor.bufferView]
        raw = np.frombuffer(gltf.binary_blob(), "<f4", accessor.count * 2, view.byteOffset).reshape(-1, 2)
        np.testing.assert_allclose(raw[:, 1], 1.0 - glb["texcoords"][:, 1], atol=1e-6)  # glTF's v points down

        # a viewer reads the same colour for every vertex from both files
        obj = trimesh.load(out_dir / "mesh.obj", process=False)
        mesh = next(iter(trimesh.load(out_dir / "mesh.glb", process=False).geometry.values()))
        n = len(asset.vertices)
        from_obj = obj.visual.to_color().vertex_colors[:n, :3]
        from_glb = mesh.visual.to_color().vertex_colors[:n, :3]
        np.testing.assert_array_equal(from_obj, from_glb)

    def test_obj_and_ply_vertex_colours_are_the_texture_at_their_uvs(self, out_dir, asset):
        """MeshLab, CloudCompare and Open3D show the vertex colours: they are texture.png at each vertex's UV
        (a naive bilinear loop, for the vertices off the UV seams), not one grey."""
        import trimesh
        from PIL import Image

        texture = np.asarray(Image.open(out_dir / "texture.png").convert("RGB"))
        n = len(asset.vertices)
        ply = trimesh.load(out_dir / "mesh.ply", process=False)
        colours = np.asarray(ply.visual.vertex_colors)[:n, :3].astype(int)
        assert len(np.unique(colours, axis=0)) > 100  # they vary
        obj_colours = trimesh.load(out_dir / "mesh.obj", process=False).visual.to_color().vertex_colors[:n, :3]
        # (the OBJ's vertex colours are written beside its UVs; trimesh's loader keeps the texture visuals)
        corners: dict[int, list] = {}
        for f, uvs in zip(asset.faces, asset.face_uvs):
            for vertex, uv in zip(f, uvs):
                corners.setdefault(int(vertex), []).append(tuple(np.round(uv, 6)))
        size = texture.shape[0]
        checked = 0
        for vertex, uvs in corners.items():
            if len(set(uvs)) != 1:
                continue  # on a seam: its corners are averaged
            u, v = uvs[0]
            x, y = u * size - 0.5, (1.0 - v) * size - 0.5  # texel centres at (i + 0.5) / size, rows from the top
            x0, y0 = int(np.floor(x)), int(np.floor(y))
            fx, fy = x - x0, y - y0
            value = np.zeros(3)
            for dy, wy in ((0, 1.0 - fy), (1, fy)):
                for dx, wx in ((0, 1.0 - fx), (1, fx)):
                    row, col = min(max(y0 + dy, 0), size - 1), min(max(x0 + dx, 0), size - 1)
                    value += wy * wx * texture[row, col]
            assert np.abs(colours[vertex] - value).max() <= 1.0, (vertex, colours[vertex], value)
            checked += 1
        assert checked > 0.8 * n
        assert obj_colours.shape == (n, 3)

    def test_landmarks_in_the_mesh_frame_lie_on_mesh_obj_and_load_in_meshlab(self, out_dir, hand_fit, asset):
        """landmarks3d_mesh.json and landmarks3d.pp: the camera-frame landmarks taken back to mesh.obj's frame
        lie on its surface (<= 0.01 mm); the .pp is MeshLab's picked-points XML with the 68 names."""
        import json
        import xml.etree.ElementTree as ET

        import trimesh

        data = json.loads((out_dir / "landmarks3d_mesh.json").read_text())
        points = np.asarray(data["points"])
        assert data["units"] == "mm" and data["frame"].startswith("mesh") and points.shape == (68, 3)
        mesh = trimesh.load(out_dir / "mesh.obj", process=False)
        triangles = np.asarray(mesh.triangles)  # every landmark against every triangle (no spatial index)
        pairs = trimesh.triangles.closest_point(
            np.tile(triangles, (len(points), 1, 1)), np.repeat(points, len(triangles), axis=0)
        )
        distance = np.linalg.norm(pairs - np.repeat(points, len(triangles), axis=0), axis=1)
        assert distance.reshape(len(points), -1).min(1).max() <= 0.01
        np.testing.assert_allclose(points, hand_fit.landmark_fit.landmarks3d, atol=1e-6)
        root = ET.parse(out_dir / "landmarks3d.pp").getroot()
        assert root.tag == "PickedPoints"
        assert root.find("DocumentData/DataFileName").get("name") == "mesh.obj"
        picked = root.findall("point")
        assert [p.get("name") for p in picked] == data["names"]
        xyz = np.array([[float(p.get(k)) for k in "xyz"] for p in picked])
        np.testing.assert_allclose(xyz, points, atol=1e-5)

    def test_now_landmarks_are_the_seven_ibug_points_in_nows_order(self, out_dir):
        """landmarks_now.txt: 7 lines ``x y z`` (single spaces, as the NoW evaluation splits them) =
        landmarks3d_mesh.json's right eye outer/inner, left eye inner/outer corners, nose bottom, right/left
        mouth corners; the subject's right eye and mouth corner on -X (rig space: +X is their left)."""
        data = json.loads((out_dir / "landmarks3d_mesh.json").read_text())
        lines = (out_dir / "landmarks_now.txt").read_text().splitlines()
        assert len(lines) == 7 and all(len(line.split(" ")) == 3 for line in lines)
        now = np.array([[float(c) for c in line.split(" ")] for line in lines])
        by_name = dict(zip(data["names"], np.asarray(data["points"]), strict=True))
        expected = [by_name[n] for n in _ibug_names((36, 39, 42, 45, 33, 48, 54))]
        np.testing.assert_allclose(now, expected, atol=1e-6)
        assert now[0, 0] < now[1, 0] < 0 < now[2, 0] < now[3, 0]  # right outer, right inner, left inner, outer
        assert now[5, 0] < 0 < now[6, 0] and now[4, 1] > now[5:, 1].max() and now[4, 1] < now[:4, 1].min()

    def test_live_link_file_holds_the_fits_coefficients_and_head_angles(self, out_dir, hand_fit):
        """expressions_livelink.csv: Live Link Face's layout, read back by jnr animate's reader to the fit's
        coefficients and its head pose's yaw (20 degrees here)."""
        from pipeline.head.curves import read_curves
        from rig.geometry import head_angles

        text = (out_dir / "expressions_livelink.csv").read_text().splitlines()
        assert text[0].startswith("Timecode,BlendShapeCount,EyeBlinkLeft,") and len(text) == 2
        back = read_curves(out_dir / "expressions_livelink.csv")
        assert back.layout == "live-link-face"
        np.testing.assert_allclose(back.coefficients[0], hand_fit.expressions, atol=1e-6)
        np.testing.assert_allclose(back.head_rotation[0], head_angles(hand_fit.rotation), atol=1e-4)
        assert back.head_rotation[0][0] == pytest.approx(20.0, abs=1e-4)

    def test_trimesh_loads_the_fitted_head_from_the_glb(self, out_dir, hand_fit, asset):
        """Readers that do not skin (trimesh, Open3D, MeshLab) load the fitted head from mesh.glb, as from
        mesh.obj: the glTF's bind mesh is the fit (issue 27), not the template."""
        import trimesh
        from scipy.spatial import cKDTree

        obj = np.asarray(trimesh.load(out_dir / "mesh.obj", process=False).vertices)
        glb = trimesh.load(out_dir / "mesh.glb", process=False)
        glb = glb.to_geometry() if isinstance(glb, trimesh.Scene) else glb
        loaded = np.asarray(glb.vertices) * 1000.0  # glTF metres -> mm
        assert cKDTree(obj).query(loaded)[0].max() < 0.1  # seam duplicates included
        assert cKDTree(loaded).query(obj)[0].max() < 0.1
        assert np.abs(obj[: len(asset.vertices)] - hand_fit.rig_vertices).max() < 1e-3

    def test_seen_faces_show_the_photo_where_they_project(self, out_dir, hand_fit, asset):
        """Through the OBJ's texture as a viewer reads it (trimesh: the nearest texel, ~2.4 photo px here), the
        centres of the forehead and cheek triangles that face the camera show the photo where they project."""
        import trimesh
        from trimesh.visual.color import uv_to_color

        obj = trimesh.load(out_dir / "mesh.obj", process=False)
        corners = obj.vertices[obj.faces]
        centres, centre_uvs = corners.mean(1), obj.visual.uv[obj.faces].mean(1)
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        to_camera = -hand_fit.rotation.T @ np.diag([1.0, -1, -1]) @ hand_fit.translation - centres
        cos = (normals * to_camera).sum(1) / np.linalg.norm(normals, axis=1) / np.linalg.norm(to_camera, axis=1)
        ids = [asset.region_names.index(r) for r in ("forehead", "cheeks")]
        pick = np.isin(asset.regions[asset.faces[:, 0]], ids) & (cos > 0.5)
        assert pick.sum() > 300  # measured 765
        colours = uv_to_color(centre_uvs[pick], obj.visual.material.image)[:, :3].astype(float)
        error = np.linalg.norm(colours[:, :2] - _project(hand_fit, centres[pick]), axis=1)
        assert np.median(error) < 2.0 and np.percentile(error, 95) < 3.5, np.percentile(error, [50, 95])  # 1.4, 2.7


def test_a_photometric_fit_fills_with_its_albedo(hand_fit, asset):
    """With photometric stages the unseen texels take the fitted albedo, sRGB-encoded."""
    from dataclasses import replace

    from pipeline.colour import linear_to_srgb
    from pipeline.photo.texture import texture_from_fit

    albedo = np.tile([0.2, 0.1, 0.05], (len(asset.vertices), 1))
    fit = replace(hand_fit, stages=("a stage",), appearance=replace(hand_fit.appearance, albedo=albedo))
    tex = texture_from_fit(coordinate_photo(), fit, asset.faces, asset.face_uvs, size=128)
    unseen = (tex.face >= 0) & (tex.photo_weight == 0)
    assert tex.fill == "vertex colours" and unseen.sum() > 1000
    expected = np.round(linear_to_srgb(np.array([0.2, 0.1, 0.05])) * 255)
    np.testing.assert_array_equal(np.unique(tex.image[unseen], axis=0), [expected])
    with pytest.raises(ValueError, match="the fit's camera"):
        texture_from_fit(coordinate_photo()[:100], fit, asset.faces, asset.face_uvs, size=128)


class TestOverlay:
    def test_the_face_mask_is_the_face_regions_of_the_coverage(self, face_render, hand_fit, asset):
        _, face, coverage = face_render
        assert face.shape == coverage.shape == (HEIGHT, WIDTH)
        assert (face <= coverage).all() and 0.2 * coverage.sum() < face.sum() < 0.8 * coverage.sum()
        nose_tip = _project(hand_fit, asset.vertices[[np.argmax(asset.vertices[:, 2])]])[0]
        neck = asset.vertices[asset.regions == asset.region_names.index("neck")]
        chin = asset.vertices[asset.regions == asset.region_names.index("chin")]
        # The front of the neck below the chin: its top, tucked under the chin, is hidden by the chin.
        neck = neck[neck[:, 1] < chin[:, 1].min() - 5.0]
        front_neck = _project(hand_fit, neck[[np.argmax(neck[:, 2])]])[0]
        assert face[round(nose_tip[1]), round(nose_tip[0])] == 1
        assert coverage[round(front_neck[1]), round(front_neck[0])] == 1
        assert face[round(front_neck[1]), round(front_neck[0])] == 0

    def test_overlay_leaves_the_photo_outside_the_face(self, face_render):
        from pipeline.photo.outputs import overlay_image

        image, face, _ = face_render
        photo = coordinate_photo()
        none = np.zeros((0, 2))
        out = overlay_image(photo, image, face, none, none)
        np.testing.assert_array_equal(out[face == 0], photo[face == 0])
        assert (out[face == 1] != photo[face == 1]).any(axis=1).mean() > 0.9

    def test_overlay_png_is_the_photo_outside_the_face_and_the_markers(self, out_dir, face_render, hand_fit):
        from PIL import Image

        _, face, _ = face_render
        overlay = np.asarray(Image.open(out_dir / "overlay.png"))
        ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH]
        near_marker = np.zeros((HEIGHT, WIDTH), bool)
        for x, y in hand_fit.landmarks.fitted:
            near_marker |= (xs - x) ** 2 + (ys - y) ** 2 < 6.0**2
        keep = (face == 0) & ~near_marker
        np.testing.assert_array_equal(overlay[keep], coordinate_photo()[keep])
        assert (overlay[(face == 1) & ~near_marker] != coordinate_photo()[(face == 1) & ~near_marker]).any()

    def test_unknown_region_is_an_error(self, hand_fit, asset):
        from pipeline.photo.outputs import render_fit

        with pytest.raises(ValueError, match="unknown mask_regions"):
            render_fit(hand_fit, spp=1, asset=asset, mask_regions=("face",))


def test_a_textured_head_takes_no_vertex_colours(asset, tmp_path):
    from pipeline.head.skinned import write_skinned_head

    with pytest.raises(ValueError, match="no vertex colours"):
        write_skinned_head(
            tmp_path / "a.glb",
            asset,
            asset.weights,
            torch.eye(4).repeat(52, 1, 1).numpy(),
            vertex_colors=np.zeros((len(asset.vertices), 3)),
            base_color_texture=b"\x89PNG",
        )
    assert list(tmp_path.iterdir()) == []


def test_ply_up_z_turns_only_the_ply_into_blenders_axes(tmp_path, asset):
    """``outputs.ply_up: z``: mesh.ply's vertices are the Y-up ones turned +90 degrees about x (the top of the
    head along +Z, the nose towards -Y, the subject's left still +X); mesh.obj does not change."""
    import trimesh

    from pipeline.photo.outputs import write_textured_meshes

    v = np.asarray(asset.vertices, np.float64)
    colours = np.full((len(v), 3), 128, np.uint8)
    for up in ("y", "z"):
        (tmp_path / up).mkdir()
        write_textured_meshes(tmp_path / up, v, asset, colours, b"", files=("mesh.obj", "mesh.ply"), ply_up=up)
    y = np.asarray(trimesh.load(tmp_path / "y" / "mesh.ply", process=False).vertices)
    z = np.asarray(trimesh.load(tmp_path / "z" / "mesh.ply", process=False).vertices)
    np.testing.assert_allclose(y, v, atol=1e-6)
    np.testing.assert_allclose(z, np.c_[v[:, 0], -v[:, 2], v[:, 1]], atol=1e-6)
    assert z[:, 2].argmax() == v[:, 1].argmax() and z[:, 1].argmin() == v[:, 2].argmax()
    assert (tmp_path / "y" / "mesh.obj").read_bytes() == (tmp_path / "z" / "mesh.obj").read_bytes()
    assert "+Z up" in (tmp_path / "z" / "mesh.ply").read_bytes()[:400].decode("ascii", "replace")
