"""Tests of the reference (path-traced, non-differentiable) renderer, render/reference.py.

Small images (96x96) and few samples per pixel keep the file to a few seconds on 2 CPU cores.
"""

import math

import numpy as np
import pytest
import torch

pytest.importorskip("mitsuba")
pytest.importorskip("kornia")

from kornia.geometry.camera import PinholeCamera

from render.reference import ReferenceLight, ReferenceRender, render_reference

W, H = 96, 96
DISTANCE = 500.0


def _camera(f=150.0, width=W, height=H, distance=DISTANCE):
    """OpenCV camera at world (0, 0, distance) looking at the origin along -Z, principal point at the centre."""
    K = torch.tensor(
        [[f, 0, (width - 1) / 2, 0], [0, f, (height - 1) / 2, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=torch.float64
    )[None]
    E = torch.eye(4, dtype=torch.float64)
    E[:3, :3] = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    E[2, 3] = distance
    return PinholeCamera(
        K,
        E[None],
        torch.tensor([float(height)], dtype=torch.float64),
        torch.tensor([float(width)], dtype=torch.float64),
    )


def _sphere(radius=60.0):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def _quad(half=300.0):
    """A square in the plane z = 0 facing +Z (towards the camera), split into a few triangles."""
    xs = np.linspace(-half, half, 5)
    gx, gy = np.meshgrid(xs, xs)
    v = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    f = []
    for i in range(4):
        for j in range(4):
            a, b, c, d = i * 5 + j, i * 5 + j + 1, (i + 1) * 5 + j, (i + 1) * 5 + j + 1
            f += [[a, b, d], [a, d, c]]
    return v, np.array(f, np.int64)


def _light(position=(0.0, 0.0, 800.0), intensity=1.0e6, environment=0.1):
    return ReferenceLight(position=position, intensity=(intensity,) * 3, environment=(environment,) * 3)


@pytest.fixture(scope="module")
def sphere():
    v, f = _sphere()
    return v, f, np.full(v.shape, 0.5)


# -- smoke and cardinality ----------------------------------------------------------------------------
def test_shapes_and_ranges(sphere):
    v, f, albedo = sphere
    out = render_reference(v, f, albedo, _camera(), _light(), spp=4)
    assert isinstance(out, ReferenceRender)
    assert out.image.shape == (H, W, 3) and out.image.dtype == np.float32
    assert out.mask.shape == (H, W) and out.mask.dtype == np.float32
    assert np.isfinite(out.image).all() and out.image.min() >= 0.0
    assert out.mask.min() >= 0.0 and out.mask.max() <= 1.0
    partial = (out.mask > 0) & (out.mask < 1)
    assert partial.any(), "the outline should have fractional coverage (anti-aliasing)"


def test_torch_inputs_and_non_square_image(sphere):
    v, f, albedo = sphere
    out = render_reference(
        torch.as_tensor(v), torch.as_tensor(f), torch.as_tensor(albedo), _camera(width=80, height=64), _light(), spp=2
    )
    assert out.image.shape == (64, 80, 3) and out.mask.shape == (64, 80)


# -- features --------------------------------------------------------------------------------------------
def test_same_seed_same_image_other_seed_other_noise(sphere):
    v, f, albedo = sphere
    cam = _camera()
    a = render_reference(v, f, albedo, cam, _light(), spp=4, seed=3)
    b = render_reference(v, f, albedo, cam, _light(), spp=4, seed=3)
    c = render_reference(v, f, albedo, cam, _light(), spp=4, seed=4)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.mask, b.mask)
    assert np.abs(a.image - c.image).max() > 0.0


def test_light_in_front_brightens_the_face(sphere):
    v, f, albedo = sphere
    cam = _camera()
    front = render_reference(v, f, albedo, cam, _light((0.0, 0.0, 800.0), environment=0.05), spp=8)
    behind = render_reference(v, f, albedo, cam, _light((0.0, 0.0, -800.0), environment=0.05), spp=8)
    inner = front.mask > 0.99
    assert front.image[inner].mean() > 3.0 * behind.image[inner].mean()
    # behind: only the environment (and interreflection) lights the visible half
    assert behind.image[inner].mean() > 0.0


def test_mask_covers_the_projected_centre_not_the_corner(sphere):
    v, f, albedo = sphere
    out = render_reference(v, f, albedo, _camera(), _light(), spp=4)
    c = (W - 1) / 2.0  # the sphere's centre projects to the principal point: the 2x2 pixels around it
    centre = out.mask[math.floor(c) : math.ceil(c) + 1, math.floor(c) : math.ceil(c) + 1]
    assert (centre == 1.0).all()
    assert out.mask[0, 0] == 0.0 and out.mask[-1, -1] == 0.0
    # projected radius: f r / sqrt(d^2 - r^2) = 150 * 60 / sqrt(500^2 - 60^2) ~ 18.1 px
    radius = 150.0 * 60.0 / math.sqrt(DISTANCE**2 - 60.0**2)
    assert abs(out.mask.sum() - math.pi * radius**2) < 0.03 * math.pi * radius**2


def test_background_is_composited_by_coverage(sphere):
    v, f, albedo = sphere
    cam = _camera()
    bg = np.broadcast_to(np.array([0.2, 0.4, 0.6], np.float32), (H, W, 3)).copy()
    plain = render_reference(v, f, albedo, cam, _light(), spp=4, seed=1)
    over = render_reference(v, f, albedo, cam, _light(), spp=4, seed=1, background=bg)
    np.testing.assert_allclose(over.image, plain.image + (1.0 - plain.mask)[..., None] * bg, atol=1e-6)
    np.testing.assert_allclose(over.image[0, 0], bg[0, 0], atol=1e-7)


def test_point_light_and_environment_levels():
    """Lambert under a point light: a / pi * I / r^2 facing it; under the environment alone: a * L."""
    v, f = _quad()
    albedo = np.full(v.shape, 0.5)
    cam = _camera(f=60.0)
    distance = 1000.0
    key = render_reference(
        v, f, albedo, cam, _light((0.0, 0.0, distance), intensity=math.pi * distance**2, environment=0.0), spp=128
    )
    # Mitsuba picks one of the two emitters per sample (weight 2), so average over pixels; the 8x8 pixels
    # span +-2.7 degrees seen from the light: cos^3 falloff >= 0.997
    centre = key.image[H // 2 - 4 : H // 2 + 4, W // 2 - 4 : W // 2 + 4]
    np.testing.assert_allclose(centre.mean(), 0.5, rtol=0.02)  # E = pi at the centre -> radiance a
    env = render_reference(v, f, albedo, cam, _light(intensity=0.0, environment=0.4), spp=8)
    np.testing.assert_allclose(env.image[H // 4 : 3 * H // 4, W // 4 : 3 * W // 4].mean(), 0.5 * 0.4, rtol=0.03)


def test_seam_split_vertices_shade_like_the_welded_mesh(sphere):
    """Duplicating the vertices of half the faces (a UV seam) changes nothing after welding."""
    v, f, albedo = sphere
    cam = _camera()
    split = f.copy()
    half = np.arange(len(f)) % 2 == 0
    split[half] += len(v)
    v2, a2 = np.concatenate([v, v]), np.concatenate([albedo, albedo])
    a = render_reference(v, f, albedo, cam, _light(), spp=4, seed=2)
    b = render_reference(v2, split, a2, cam, _light(), spp=4, seed=2)
    np.testing.assert_allclose(a.image, b.image, atol=1e-5)


def test_restores_the_previous_variant(sphere):
    import mitsuba as mi

    v, f, albedo = sphere
    mi.set_variant("scalar_rgb")
    render_reference(v, f, albedo, _camera(), _light(), spp=1)
    assert mi.variant() == "scalar_rgb"


# -- exceptions ------------------------------------------------------------------------------------------
def test_bad_shapes_raise(sphere):
    v, f, albedo = sphere
    cam = _camera()
    light = _light()
    with pytest.raises(ValueError, match=r"vertices of shape \(V, 3\)"):
        render_reference(v[:, :2], f, albedo, cam, light, spp=1)
    with pytest.raises(ValueError, match=r"faces of shape \(F, 3\)"):
        render_reference(v, f[:, :2], albedo, cam, light, spp=1)
    with pytest.raises(ValueError, match="face indices"):
        render_reference(v, f + len(v), albedo, cam, light, spp=1)
    with pytest.raises(ValueError, match="integer"):
        render_reference(v, f.astype(float), albedo, cam, light, spp=1)
    with pytest.raises(ValueError, match="albedo"):
        render_reference(v, f, albedo[:-1], cam, light, spp=1)
    with pytest.raises(ValueError, match="background"):
        render_reference(v, f, albedo, cam, light, spp=1, background=np.zeros((H, W + 1, 3)))
    with pytest.raises(ValueError, match="spp"):
        render_reference(v, f, albedo, cam, light, spp=0)
    with pytest.raises(TypeError, match="ReferenceLight"):
        render_reference(v, f, albedo, cam, {"position": (0, 0, 1)}, spp=1)


def test_bad_light_raises():
    with pytest.raises(ValueError, match=r"position of shape \(3,\)"):
        ReferenceLight(position=(0.0, 1.0), intensity=(1.0, 1.0, 1.0), environment=(0.1, 0.1, 0.1))
    with pytest.raises(ValueError, match="intensity must be >= 0"):
        ReferenceLight(position=(0.0, 0.0, 1.0), intensity=(-1.0, 1.0, 1.0), environment=(0.1, 0.1, 0.1))
    with pytest.raises(ValueError, match="finite"):
        ReferenceLight(position=(0.0, np.nan, 1.0), intensity=(1.0, 1.0, 1.0), environment=(0.1, 0.1, 0.1))
    light = ReferenceLight(position=np.array([1.0, 2.0, 3.0]), intensity=torch.ones(3), environment=[0.1, 0.2, 0.3])
    assert light.position == (1.0, 2.0, 3.0) and light.to_dict()["environment"] == [0.1, 0.2, 0.3]
