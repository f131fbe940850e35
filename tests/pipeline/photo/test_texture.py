"""Tests of pipeline/photo/texture.py: the rasteriser, the z-buffer and the photo unwrapped into UVs."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.photo.texture import (
    rasterize_triangles,
    unwrap_texture,
    uv_raster,
    zbuffer,
)
from rig.errors import InputError, ShapeError
from rig.geometry import head_rotation

SIZE = 256  # texture side of these tests


def coordinate_photo(width: int, height: int) -> np.ndarray:
    """A photo whose red is the pixel's column and green its row (blue 0): a sample decodes to where it was
    taken (bilinear sampling of a linear ramp is exact)."""
    photo = np.zeros((height, width, 3), np.uint8)
    photo[..., 0] = np.arange(width)[None, :]
    photo[..., 1] = np.arange(height)[:, None]
    return photo


def camera(yaw_deg: float = 0.0, distance: float = 600.0, focal: float = 520.0, size: int = 256):
    """``(K (3, 3), extrinsics (4, 4))``: a head at ``distance`` mm turned by ``yaw_deg``, in a ``size``-px photo."""
    k = np.array([[focal, 0.0, (size - 1) / 2], [0.0, focal, (size - 1) / 2], [0.0, 0.0, 1.0]])
    e = np.eye(4)
    e[:3, :3] = np.diag([1.0, -1.0, -1.0]) @ head_rotation(yaw_deg, 0.0, 0.0)
    e[:3, 3] = (0.0, 20.0, distance)  # the face (not the neck) near the centre
    return k, e


def project(points: np.ndarray, k: np.ndarray, e: np.ndarray) -> np.ndarray:
    cam = points @ e[:3, :3].T + e[:3, 3]
    return cam[:, :2] / cam[:, 2:] @ k[:2, :2].T + k[:2, 2]


def texel_points(vertices, faces, face_uvs, rows, cols, size):
    """The 3D point of texel centres, by a brute-force search of the covering UV triangle (the reference)."""
    out = np.full((len(rows), 3), np.nan)
    tri_of = np.full(len(rows), -1)
    a, b, c = face_uvs[:, 0], face_uvs[:, 1], face_uvs[:, 2]
    for i, (r, col) in enumerate(zip(rows, cols)):
        p = np.array([(col + 0.5) / size, 1.0 - (r + 0.5) / size])
        m = np.stack([b - a, c - a], -1)  # (F, 2, 2)
        l12 = np.linalg.solve(m, (p - a)[..., None])[..., 0]
        bary = np.column_stack([1 - l12.sum(1), l12])
        hit = np.flatnonzero((bary >= -1e-9).all(1))
        if len(hit):
            t = hit[0]
            out[i] = bary[t] @ vertices[faces[t]]
            tri_of[i] = t
    return out, tri_of


@pytest.fixture(scope="module")
def asset():
    from rig.asset import load_asset

    return load_asset()


class TestRasterize:
    def test_smoke_counts_the_pixel_centres_inside(self):
        pixel, tri, bary = rasterize_triangles(np.array([[[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]]]), 8, 8)
        xy = np.column_stack([pixel % 8, pixel // 8])
        assert len(pixel) == 15 and (xy.sum(1) <= 4).all() and (tri == 0).all()
        np.testing.assert_allclose(bary.sum(1), 1.0)
        np.testing.assert_allclose(bary @ np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]]), xy, atol=1e-12)

    def test_two_triangles_tile_a_square_without_gaps(self):
        quad = np.array([[[0.2, 0.3], [9.7, 0.3], [9.7, 7.6]], [[0.2, 0.3], [9.7, 7.6], [0.2, 7.6]]])
        pixel, _, _ = rasterize_triangles(quad, 12, 10)
        expected = {y * 12 + x for y in range(1, 8) for x in range(1, 10)}
        assert set(pixel.tolist()) == expected

    def test_pixels_outside_the_image_and_degenerate_triangles_are_left_out(self):
        tris = np.array([[[-5.0, -5.0], [8.0, -5.0], [-5.0, 8.0]], [[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]])
        pixel, tri, _ = rasterize_triangles(tris, 4, 4)
        assert set(tri.tolist()) == {0} and sorted(pixel.tolist()) == [0, 1, 2, 3, 4, 5, 6, 8, 9, 12]

    def test_bad_shape(self):
        with pytest.raises(ShapeError, match=r"rasterize_triangles: points must have shape \(F, 3, 2\)"):
            rasterize_triangles(np.zeros((2, 4, 2)), 4, 4)

    def test_zbuffer_keeps_the_nearest_perspective_correct_depth(self):
        """A slanted triangle in front of a far one: the buffer holds the plane's depth along each pixel ray."""
        k, e = np.array([[50.0, 0, 15.5], [0, 50, 15.5], [0, 0, 1]]), np.eye(4)
        near = np.array([[-20.0, -20, 80], [20, -20, 120], [0, 20, 100]])  # depth changes across the image
        far = np.array([[-40.0, -40, 300], [40, -40, 300], [0, 40, 300]])
        v = np.vstack([near, far])
        depth = zbuffer(project(v, k, e), v[:, 2], np.array([[0, 1, 2], [3, 4, 5]]), 32, 32)
        n = np.cross(near[1] - near[0], near[2] - near[0])
        ys, xs = np.mgrid[0:32, 0:32]
        rays = np.stack([(xs - 15.5) / 50, (ys - 15.5) / 50, np.ones_like(xs, float)], -1)
        plane_z = (n @ near[0]) / (rays @ n)  # z of the ray through each pixel centre on the near plane
        in_near = np.isfinite(depth) & (depth < 250)
        assert in_near.sum() > 100 and (depth[np.isfinite(depth) & ~in_near] == 300).all()
        np.testing.assert_allclose(depth[in_near], plane_z[in_near], rtol=1e-9)

    def test_uv_raster_rows_run_from_v_1_down(self):
        """Texel (row, col) has its centre at u = (col + 0.5) / S, v = 1 - (row + 0.5) / S."""
        top_left = np.array([[[0.0, 1.0], [0.5, 1.0], [0.0, 0.5]]])  # the top-left quarter of the image
        face, bary = uv_raster(top_left, 8)
        assert (face[:4, :4][np.triu(np.ones((4, 4), bool))[:, ::-1]] == 0).all()  # the upper-left triangle
        assert (face[4:] == -1).all() and (face[:, 4:] == -1).all()
        u = bary[face >= 0] @ top_left[0]
        rows, cols = np.nonzero(face >= 0)
        np.testing.assert_allclose(u, np.column_stack([(cols + 0.5) / 8, 1 - (rows + 0.5) / 8]), atol=1e-12)


@pytest.fixture(scope="module")
def turned_head(asset):
    """The template turned by 35 degrees of yaw, unwrapped from a coordinate photo, blue fill."""
    k, e = camera(yaw_deg=35.0)
    fill = np.tile(np.array([0, 0, 255], np.uint8), (len(asset.vertices), 1))
    tex = unwrap_texture(
        coordinate_photo(256, 256),
        asset.vertices,
        asset.faces,
        asset.face_uvs,
        intrinsics=k,
        extrinsics=e,
        fill_colours=fill,
        size=SIZE,
    )
    return tex, k, e


class TestUnwrap:
    def test_cardinality(self, turned_head, asset):
        tex, _, _ = turned_head
        assert tex.image.shape == (SIZE, SIZE, 3) and tex.image.dtype == np.uint8
        assert tex.photo_weight.shape == tex.face.shape == (SIZE, SIZE)
        assert tex.face.max() < len(asset.faces) and 0.15 < (tex.face >= 0).mean() < 0.3  # the atlas: 22 %
        assert tex.fill == "vertex colours" and 0.1 < tex.visible_fraction < 0.6

    def test_seen_texels_decode_to_the_projection_of_their_point(self, turned_head, asset):
        """Fully seen texels hold the photo colour at the projection of their own 3D point (within 1 px)."""
        tex, k, e = turned_head
        rows, cols = np.nonzero(tex.photo_weight == 1.0)
        pick = np.random.default_rng(0).choice(len(rows), 200, replace=False)
        points, tri = texel_points(asset.vertices, asset.faces, asset.face_uvs, rows[pick], cols[pick], SIZE)
        assert (tri >= 0).all()
        expected = project(points, k, e)
        decoded = tex.image[rows[pick], cols[pick], :2].astype(float)
        assert np.abs(decoded - expected).max() <= 1.0
        assert (tex.image[rows[pick], cols[pick], 2] == 0).all()  # no fill mixed in

    def test_texels_facing_away_get_the_fill(self, turned_head, asset):
        tex, _, e = turned_head
        rows, cols = np.nonzero(tex.face >= 0)
        pick = np.random.default_rng(1).choice(len(rows), 250, replace=False)
        points, tri = texel_points(asset.vertices, asset.faces, asset.face_uvs, rows[pick], cols[pick], SIZE)
        v = asset.vertices[asset.faces[tri]]
        normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        centre = -e[:3, :3].T @ e[:3, 3]
        to_camera = centre - points
        cos = (normal * to_camera).sum(1) / np.linalg.norm(normal, axis=1) / np.linalg.norm(to_camera, axis=1)
        away = cos < -0.2
        assert away.sum() > 40
        np.testing.assert_array_equal(tex.image[rows[pick][away], cols[pick][away]], [[0, 0, 255]] * away.sum())
        assert (tex.photo_weight[rows[pick][away], cols[pick][away]] == 0).all()

    def test_the_inside_of_the_closed_mouth_gets_the_fill(self, turned_head, asset):
        """Mouth interior, teeth and tongue texels that face the camera are hidden behind the closed lips."""
        tex, _, e = turned_head
        face, bary = uv_raster(asset.face_uvs, SIZE)
        covered = face >= 0
        corners = asset.vertices[asset.faces[face[covered]]]
        points = np.einsum("tc,tcd->td", bary[covered], corners)
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        to_camera = -e[:3, :3].T @ e[:3, 3] - points
        cos = (normal * to_camera).sum(1) / np.linalg.norm(normal, axis=1) / np.linalg.norm(to_camera, axis=1)
        inside = np.isin(
            asset.regions[asset.faces[face[covered], 0]],
            [asset.region_names.index(r) for r in ("mouth_interior", "teeth", "tongue")],
        )
        facing = inside & (cos > 0.4)
        assert facing.sum() > 100  # measured 363
        assert (tex.photo_weight[covered][facing] == 0).all()
        assert (tex.image[covered][facing] == (0, 0, 255)).all()

    def test_occluded_texels_get_the_fill(self):
        """A small quad in front of a large one: the large one's texels behind it are filled, the rest seen."""
        back = np.array([[-60.0, -60, 0], [60, -60, 0], [60, 60, 0], [-60, 60, 0]])
        front = back * 0.25 + np.array([0, 0, 100.0])
        v = np.vstack([back, front])
        faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
        square = np.array([[0.0, 0.0], [1, 0], [1, 1], [0, 1]])
        left, right = square * [0.5, 1], square * [0.5, 1] + [0.5, 0]  # back in the left half, front in the right
        uvs = np.stack([left[[0, 1, 2]], left[[0, 2, 3]], right[[0, 1, 2]], right[[0, 2, 3]]])
        k = np.array([[200.0, 0, 63.5], [0, 200, 63.5], [0, 0, 1]])
        e = np.diag([1.0, -1, -1, 1])
        e[2, 3] = 400.0
        fill = np.tile([0.0, 0.0, 1.0], (8, 1))
        tex = unwrap_texture(
            coordinate_photo(128, 128), v, faces, uvs, intrinsics=k, extrinsics=e, fill_colours=fill, size=64
        )
        # back quad: texel (row, col) -> x = -60 + 120 (col + 0.5) / 32, y = 60 - 120 (row + 0.5) / 64
        rows, cols = np.mgrid[0:64, 0:32]
        x, y = -60 + 120 * (cols + 0.5) / 32, 60 - 120 * (rows + 0.5) / 64
        xp, yp = x * 200 / 400 + 63.5, -y * 200 / 400 + 63.5
        # the front quad covers |x|, |y| < 15 at depth 300: seen from 400 mm it hides |x|, |y| < 20 at the back
        behind = (np.abs(x) < 19) & (np.abs(y) < 19)
        clear = (np.abs(x) > 21) | (np.abs(y) > 21)
        back_tex = tex.image[:, :32]
        assert (back_tex[behind] == [0, 0, 255]).all()
        assert (back_tex[clear, 2] == 0).all()
        assert np.abs(back_tex[clear, 0] - xp[clear]).max() <= 1.0
        assert np.abs(back_tex[clear, 1] - yp[clear]).max() <= 1.0
        assert (tex.image[:, 32:, 2] == 0).all()  # the front quad is all seen

    def test_points_outside_the_photo_get_the_fill(self):
        quad = np.array([[-60.0, -60, 0], [60, -60, 0], [60, 60, 0], [-60, 60, 0]])
        faces = np.array([[0, 1, 2], [0, 2, 3]])
        uvs = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])
        k = np.array([[200.0, 0, 0.0], [0, 200, 63.5], [0, 0, 1]])  # the quad's centre on the left border
        e = np.diag([1.0, -1, -1, 1])
        e[2, 3] = 400.0
        tex = unwrap_texture(
            coordinate_photo(128, 128),
            quad,
            faces,
            uvs,
            intrinsics=k,
            extrinsics=e,
            fill_colours=np.tile([0.0, 0.0, 1.0], (4, 1)),
            size=32,
        )
        assert (tex.image[:, :15, 2] == 255).all() and (tex.image[:, 17:, 2] == 0).all()

    def test_without_fill_colours_the_median_seen_colour_fills(self, asset):
        k, e = camera(yaw_deg=0.0)
        photo = np.full((256, 256, 3), (180, 120, 90), np.uint8)
        photo[:40] = (20, 20, 20)  # dark hair above the face: not the median skin colour
        skin = np.isin(asset.regions[asset.faces[:, 0]], [asset.region_names.index("cheeks")])
        tex = unwrap_texture(
            photo, asset.vertices, asset.faces, asset.face_uvs, intrinsics=k, extrinsics=e, skin_faces=skin, size=128
        )
        assert tex.fill == "median of visible texels"
        unseen = (tex.face >= 0) & (tex.photo_weight == 0)
        assert unseen.sum() > 100 and (tex.image[unseen] == (180, 120, 90)).all()

    def test_no_holes_outside_the_uv_islands(self, turned_head):
        """Texels outside every UV triangle repeat the nearest covered texel (no black for filtering to bleed in)."""
        tex, _, _ = turned_head
        covered = tex.face >= 0
        rows, cols = np.nonzero(covered)
        colours = {tuple(c) for c in tex.image[covered]}
        outside = tex.image[~covered]
        assert all(tuple(c) in colours for c in outside[:: max(1, len(outside) // 500)])
        # next to an island, a padded texel equals the nearest covered one
        r, c = rows[np.argmin(cols)], cols.min()  # the leftmost covered texel
        if c > 0:
            assert (tex.image[r, c - 1] == tex.image[r, c]).all()

    def test_grazing_texels_blend_towards_the_fill(self, turned_head):
        tex, _, _ = turned_head
        partial = (tex.photo_weight > 0) & (tex.photo_weight < 1)
        assert partial.any()
        assert (tex.image[tex.photo_weight == 1, 2] == 0).all()

    @pytest.mark.parametrize(
        "change, error, match",
        [
            ({"photo": np.zeros((8, 8), np.uint8)}, ShapeError, r"photo must have shape \(H, W, 3\)"),
            ({"photo": np.zeros((8, 8, 3), np.float32)}, InputError, "uint8 sRGB"),
            ({"vertices": np.zeros((4, 2))}, ShapeError, "vertices"),
            ({"faces": np.array([[0, 1, 9]])}, InputError, "faces must index the 4 vertices"),
            ({"face_uvs": np.zeros((2, 3, 2))}, ShapeError, "face_uvs"),
            ({"size": 8}, InputError, "size must be an integer in 16-8192"),
            ({"intrinsics": np.zeros((2, 2))}, ShapeError, "intrinsics"),
            ({"extrinsics": np.full((4, 4), np.nan)}, InputError, "finite"),
            ({"intrinsics": np.array([[1.0, 0.1, 0], [0, 1, 0], [0, 0, 1]])}, InputError, "no skew"),
            ({"intrinsics": np.diag([10.0, 10.0, 10.0])}, InputError, "no skew"),
            ({"fill_colours": np.full((4, 3), 2.0)}, InputError, r"fill_colours must lie in \[0, 1\]"),
            ({"fill_colours": np.zeros((3, 3))}, ShapeError, "fill_colours"),
        ],
    )
    def test_bad_input(self, change, error, match):
        args = {
            "photo": np.zeros((8, 8, 3), np.uint8),
            "vertices": np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]),
            "faces": np.array([[0, 1, 2]]),
            "face_uvs": np.array([[[0.0, 0], [1, 0], [1, 1]]]),
            "intrinsics": np.eye(3),
            "extrinsics": np.eye(4),
            "size": 16,
        }
        args.update(change)
        with pytest.raises(error, match=match):
            unwrap_texture(args.pop("photo"), args.pop("vertices"), args.pop("faces"), args.pop("face_uvs"), **args)

    def test_nothing_seen_without_a_fill_is_an_error(self):
        quad = np.array([[-60.0, -60, 0], [60, -60, 0], [60, 60, 0]])
        e = np.diag([1.0, -1, -1, 1])
        e[2, 3] = -400.0  # the camera behind the triangle's plane, looking away
        with pytest.raises(InputError, match="no texel is seen"):
            unwrap_texture(
                np.zeros((32, 32, 3), np.uint8),
                quad,
                np.array([[0, 1, 2]]),
                np.array([[[0.0, 0], [1, 0], [1, 1]]]),
                intrinsics=np.diag([10.0, 10.0, 1.0]),
                extrinsics=e,
                size=16,
            )
