"""rig.geometry: Similarity against known transforms and a naive per-point loop; normals and closest points
against naive loops (tests/support/geometry.py)."""

import numpy as np
import pytest
import torch

from rig.errors import InputError, ShapeError
from rig.geometry import (
    Similarity,
    closest_points_on_triangles,
    closest_surface_points,
    face_normals,
    head_rotation,
    surface_values,
    vertex_normals,
)
from tests.support.geometry import brute_force_distance, closest_points_on_each_triangle, loop_vertex_normals


def _known(rng):
    return Similarity(head_rotation(*rng.uniform(-60, 60, 3)), rng.normal(0, 50, 3), 1.17)


def test_apply_matches_a_loop_and_the_matrix():
    rng = np.random.default_rng(0)
    s, pts = _known(rng), rng.normal(0, 80, (20, 3))
    loop = np.array([s.scale * s.rotation @ p + s.translation for p in pts])
    np.testing.assert_allclose(s.apply(pts), loop, atol=1e-9)
    np.testing.assert_allclose((s.matrix() @ np.c_[pts, np.ones(20)].T).T[:, :3], loop, atol=1e-9)
    np.testing.assert_allclose(s.apply_inverse(s.apply(pts)), pts, atol=1e-9)
    np.testing.assert_allclose(s.inverse().apply(s.apply(pts)), pts, atol=1e-9)
    other = _known(rng)
    np.testing.assert_allclose(s.then(other).apply(pts), other.apply(s.apply(pts)), atol=1e-9)


def test_fit_recovers_a_known_similarity_even_with_noise_and_weights():
    rng = np.random.default_rng(1)
    truth, src = _known(rng), rng.normal(0, 60, (40, 3))
    fit = Similarity.fit(src, truth.apply(src), with_scale=True)
    np.testing.assert_allclose(fit.rotation, truth.rotation, atol=1e-9)
    assert fit.scale == pytest.approx(truth.scale) and np.linalg.det(fit.rotation) == pytest.approx(1.0)
    dst = truth.apply(src)
    dst[:5] += 500.0  # outliers given zero weight do not move it
    w = np.ones(40)
    w[:5] = 0
    np.testing.assert_allclose(Similarity.fit(src, dst, w, with_scale=True).translation, truth.translation, atol=1e-6)
    assert Similarity.fit(src, truth.apply(src)).scale == 1.0  # without scale: rotation only


def test_bad_input():
    with pytest.raises(ValueError, match="Similarity.fit"):
        Similarity.fit(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="scale"):
        Similarity(np.eye(3), np.zeros(3), -1.0)
    with pytest.raises(ValueError, match="rotation"):
        Similarity(np.eye(2), np.zeros(3))


# --- normals -----------------------------------------------------------------------------------------------


def test_vertex_normals_match_a_loop_over_faces(asset, rng):
    v = asset.vertices + rng.normal(0, 0.5, asset.vertices.shape)
    np.testing.assert_allclose(vertex_normals(v, asset.faces), loop_vertex_normals(v, asset.faces), atol=1e-12)
    # a vertex in no face gets (0, 0, 0)
    lonely = np.vstack([v, [[0.0, 0.0, 500.0]]])
    assert not vertex_normals(lonely, asset.faces)[-1].any()


def test_vertex_normals_point_out_of_the_template(asset):
    n = vertex_normals(asset.vertices, asset.faces)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    nose = asset.region_mask("nose")
    assert (n[nose, 2] > 0).mean() > 0.8  # the nose faces +Z
    top = asset.vertices[:, 1] > asset.vertices[:, 1].max() - 5
    assert (n[top, 1] > 0.8).all()  # the crown faces up


def test_torch_normals_match_numpy_and_have_gradients(asset):
    v = torch.as_tensor(asset.vertices, dtype=torch.float64).requires_grad_(True)
    n = vertex_normals(v, torch.as_tensor(np.asarray(asset.faces, np.int64)))
    assert isinstance(n, torch.Tensor) and n.dtype == torch.float64
    np.testing.assert_allclose(n.detach().numpy(), vertex_normals(asset.vertices, asset.faces), atol=1e-10)
    (n[:, 2].sum()).backward()
    assert torch.isfinite(v.grad).all() and v.grad.abs().sum() > 0
    # numpy faces are accepted with tensor vertices
    torch.testing.assert_close(vertex_normals(v.detach(), asset.faces), n.detach())


def test_torch_normals_gradcheck_in_float64():
    v = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.1, 0.2, 1]], dtype=torch.float64, requires_grad=True)
    f = torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    assert torch.autograd.gradcheck(lambda x: vertex_normals(x, f), (v,))


def test_face_normals_are_twice_the_area_and_batch(asset, rng):
    heads = asset.vertices[None] + rng.normal(0, 0.5, (3,) + asset.vertices.shape)
    n = face_normals(heads, asset.faces)
    assert n.shape == (3, len(asset.faces), 3)
    for b in range(3):
        np.testing.assert_array_equal(n[b], face_normals(heads[b], asset.faces))
    a, b_, c = (heads[1][asset.faces[7, i]] for i in range(3))
    assert np.linalg.norm(n[1, 7]) == pytest.approx(2.0 * 0.5 * np.linalg.norm(np.cross(b_ - a, c - a)))
    torch.testing.assert_close(face_normals(torch.as_tensor(heads), torch.as_tensor(asset.faces)), torch.as_tensor(n))


# --- closest points --------------------------------------------------------------------------------------


def test_closest_points_on_triangles_match_the_naive_projection(rng):
    """Random triangles (some nearly degenerate) and points in every Voronoi region: interior, edges, corners."""
    tri = rng.normal(0, 10, (400, 3, 3))
    tri[:40, 2] = tri[:40, 0] + 1e-3 * rng.normal(size=(40, 3))  # slivers
    p = tri.mean(1) + rng.normal(0, 15, (400, 3))
    q = closest_points_on_triangles(p, tri[:, 0], tri[:, 1], tri[:, 2])
    for i in range(len(p)):
        naive = closest_points_on_each_triangle(p[i], tri[i : i + 1, 0], tri[i : i + 1, 1], tri[i : i + 1, 2])[0]
        assert np.linalg.norm(q[i] - p[i]) == pytest.approx(np.linalg.norm(naive - p[i]), abs=1e-9)
        np.testing.assert_allclose(q[i], naive, atol=1e-6)


def test_closest_surface_points_equal_brute_force(asset, rng):
    v, f = asset.vertices, asset.faces
    near = v[rng.choice(len(v), 300)] + rng.normal(0, 3, (300, 3))
    far = v[rng.choice(len(v), 40)] + rng.normal(0, 40, (40, 3))
    pts = np.vstack([near, far])
    found = closest_surface_points(pts, v, f)
    np.testing.assert_allclose(found.distance, brute_force_distance(pts, v, f), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(found.closest - pts, axis=1), found.distance, atol=1e-9)
    # the closest point lies on the reported triangle, at its barycentric coordinates
    corners = v[f[found.face]]
    np.testing.assert_allclose(np.einsum("nc,ncd->nd", found.barycentric, corners), found.closest, atol=1e-8)
    assert found.barycentric.min() >= 0 and np.allclose(found.barycentric.sum(1), 1.0)
    np.testing.assert_allclose(surface_values(v, f, found), found.closest, atol=1e-8)
    # points on the surface are at distance 0
    w = rng.dirichlet([1, 1, 1], 50)
    on = np.einsum("nc,ncd->nd", w, v[f[rng.choice(len(f), 50)]])
    assert closest_surface_points(on, v, f).distance.max() < 1e-9
    # k = 1 (most points need the widening passes) finds the same distances
    np.testing.assert_allclose(closest_surface_points(pts, v, f, k=1).distance, found.distance, atol=1e-12)


def test_closest_surface_points_break_ties_by_the_lowest_face(asset):
    """A vertex is on each of its faces: it is returned on the first of them, exactly, whatever the search."""
    v, f = asset.vertices, asset.faces
    ids = np.arange(0, len(v), 97)
    first_face = np.array([np.flatnonzero((f == i).any(1)).min() for i in ids])
    for k in (1, 8, 64):
        found = closest_surface_points(v[ids], v, f, k=k)
        np.testing.assert_array_equal(found.distance, 0.0)
        np.testing.assert_array_equal(found.closest, v[ids])
        np.testing.assert_array_equal(found.face, first_face)


def test_closest_surface_points_bad_input(asset):
    v, f = asset.vertices, asset.faces
    assert closest_surface_points(np.zeros((0, 3)), v, f).distance.shape == (0,)
    with pytest.raises(ShapeError, match="closest_surface_points: points"):
        closest_surface_points(np.zeros((4, 2)), v, f)
    with pytest.raises(InputError, match="non-finite"):
        closest_surface_points(np.array([[0.0, np.nan, 0.0]]), v, f)
    with pytest.raises(ShapeError, match="faces"):
        closest_surface_points(np.zeros((1, 3)), v, f[:0])
    with pytest.raises(InputError, match="faces index outside"):
        closest_surface_points(np.zeros((1, 3)), v, f + len(v))


def _bumpy_sphere(seed=0):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=3, radius=50.0)
    v = np.asarray(s.vertices, float)
    v = v * (1.0 + 0.05 * np.sin(3 * v[:, :1] / 50.0))
    rng = np.random.default_rng(seed)
    shapes = v[None] + rng.normal(0.0, 1.0, (3, 1, 3)) * np.exp(-(((v - v[0]) / 30.0) ** 2).sum(1))[None, :, None]
    return v, np.asarray(s.faces), shapes


def test_deformation_transfer_on_the_source_returns_its_offsets():
    from rig.geometry import deformation_transfer

    v, f, shapes = _bumpy_sphere()
    np.testing.assert_allclose(deformation_transfer(v, shapes, v, f), shapes - v, atol=1e-6)


def test_deformation_transfer_onto_a_scaled_moved_copy_scales_the_offsets():
    """A target that is ``s source + t``: every triangle deforms as on the source, so the transferred offsets
    are ``s offsets`` up to one translation, which the anchor sets to the raw offsets' mean: ``s o + (1 - s)
    mean(o)`` (a known deformation to recover); the raw offsets are not."""
    from rig.geometry import deformation_transfer

    v, f, shapes = _bumpy_sphere(1)
    target = 1.3 * v + np.array([5.0, -7.0, 2.0])
    # the anchor pulls towards the raw offsets, which differ here: a small anchor for the exact answer
    out = deformation_transfer(v, shapes, target, f, anchor=1e-6)
    o = shapes - v
    np.testing.assert_allclose(out, 1.3 * o - 0.3 * o.mean(1, keepdims=True), atol=1e-4)
    assert np.abs(out - o).max() > 0.1


def test_deformation_transfer_checks_shapes():
    from rig.geometry import deformation_transfer

    v, f, shapes = _bumpy_sphere()
    with pytest.raises(ShapeError, match="target"):
        deformation_transfer(v, shapes, v[:-1], f)
