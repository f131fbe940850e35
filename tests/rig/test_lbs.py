import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from rig.lbs import (
    ShapeError,
    euler_to_matrix,
    joint_world_transforms,
    local_transforms,
    skin_vertices,
    skin_vertices_shared_weights,
)
from rig.parameters import NUM_PARAMETERS, random_theta


def test_euler_matches_scipy(rng):
    angles = rng.uniform(-np.pi, np.pi, size=(50, 3))
    ours = euler_to_matrix(torch.tensor(angles)).numpy()
    # R = Rz Ry Rx on column vectors = extrinsic rotations about x, then y, then z.
    ref = Rotation.from_euler("xyz", angles).as_matrix()
    assert np.abs(ours - ref).max() < 1e-12


def test_euler_shape_error():
    with pytest.raises(ShapeError, match=r"\(\*, 3\)"):
        euler_to_matrix(torch.zeros(4, 2))


def test_zero_parameters_reproduce_template(rig64, rig32, asset):
    out = rig64(torch.zeros(2, NUM_PARAMETERS, dtype=torch.float64)).vertices
    assert torch.abs(out - torch.as_tensor(asset.vertices)).max() < 1e-10
    out32 = rig32(torch.zeros(1, NUM_PARAMETERS)).vertices
    assert torch.abs(out32.double() - torch.as_tensor(asset.vertices)).max() < 1e-4


def _naive_world(tau, positions, parents):
    """Recursive composition, one joint at a time: G_k = G_parent T(p_k - p_parent) tau_k."""
    K = len(parents)
    world = [None] * K
    for k in range(K):
        offset = np.eye(4)
        p_parent = positions[parents[k]] if parents[k] >= 0 else np.zeros(3)
        offset[:3, 3] = positions[k] - p_parent
        local = offset @ tau[k]
        world[k] = local if parents[k] < 0 else world[parents[k]] @ local
    return np.stack(world)


def test_world_transforms_match_naive_chain(rig64, asset):
    theta = random_theta(torch.Generator().manual_seed(3), 1, spread=0.8, dtype=torch.float64)
    world, skinning = rig64.joint_transforms(theta)
    from rig.lbs import channels_to_trs

    r, t, s = channels_to_trs(theta, rig64.channel_joint, rig64.channel_kind, 52)
    tau = local_transforms(r, t, s)[0].numpy()
    ref = _naive_world(tau, asset.joint_positions, asset.parents)
    assert np.abs(world[0].numpy() - ref).max() < 1e-9
    inv_bind = np.tile(np.eye(4), (52, 1, 1))
    inv_bind[:, :3, 3] = -asset.joint_positions
    assert np.abs(skinning[0].numpy() - ref @ inv_bind).max() < 1e-9


def test_lbs_equals_naive_per_vertex_loop(rig64, asset):
    theta = random_theta(torch.Generator().manual_seed(5), 2, spread=0.5, dtype=torch.float64)
    out = rig64(theta)
    A = out.skinning.numpy()
    W = asset.weights
    V = asset.vertices
    for b in range(2):
        expected = np.empty_like(V)
        for i in range(len(V)):
            acc = np.zeros(3)
            for k in np.flatnonzero(W[i]):
                acc += W[i, k] * (A[b, k, :3, :3] @ V[i] + A[b, k, :3, 3])
            expected[i] = acc
        assert np.abs(out.vertices[b].numpy() - expected).max() < 1e-9


def test_shared_weights_skinning_equals_naive_loop(rig64, asset):
    """The blended-transform path (one weight set, many poses, per-row rest vertices) against a per-vertex loop."""
    gen = torch.Generator().manual_seed(9)
    theta = random_theta(gen, 5, spread=0.5, dtype=torch.float64)
    A = rig64.joint_transforms(theta)[1]
    ids = np.arange(0, len(asset.vertices), 37)
    rest = torch.as_tensor(asset.vertices[ids])[None] + torch.randn(5, len(ids), 3, generator=gen, dtype=torch.float64)
    W = torch.as_tensor(asset.weights[ids])
    out = skin_vertices_shared_weights(rest, W, A).numpy()
    An, Wn, Rn = A.numpy(), W.numpy(), rest.numpy()
    for b in range(5):
        for i in range(len(ids)):
            expected = sum(Wn[i, k] * (An[b, k, :3, :3] @ Rn[b, i] + An[b, k, :3, 3]) for k in np.flatnonzero(Wn[i]))
            assert np.abs(out[b, i] - expected).max() < 1e-9
    # one rest shape for the whole batch, and the same result as skin_vertices
    np.testing.assert_allclose(
        skin_vertices_shared_weights(rest[0], W, A).numpy(), skin_vertices(rest[0], W, A).numpy(), atol=1e-9
    )
    with pytest.raises(ShapeError, match="weights"):
        skin_vertices_shared_weights(rest[0], W[:, :5], A)


def test_skin_vertices_shapes_and_errors():
    v = torch.randn(10, 3)
    w = torch.softmax(torch.randn(10, 4), -1)
    A = torch.eye(4).expand(2, 4, 4, 4).clone()
    assert skin_vertices(v, w, A).shape == (2, 10, 3)
    assert skin_vertices(v.expand(2, 10, 3), w.expand(2, 10, 4), A).shape == (2, 10, 3)
    with pytest.raises(ShapeError, match="weights"):
        skin_vertices(v, torch.rand(10, 5), A)
    with pytest.raises(ShapeError, match="tau"):
        joint_world_transforms(torch.eye(4).expand(1, 3, 4, 4), torch.zeros(4, 3), torch.tensor([-1, 0, 1, 2]))


def test_gradcheck_through_the_chain(rig64):
    subset = torch.tensor([100, 1500, 2600, 3300, 4100])

    def f(theta, free):
        return rig64(theta, weights=rig64.dense_weights(free)).vertices[:, subset]

    theta = random_theta(torch.Generator().manual_seed(9), 1, spread=0.3, dtype=torch.float64).requires_grad_()
    free = rig64.weights_free.clone().requires_grad_()
    # Gradients w.r.t. all 107 parameters and all skinning floats, float64.
    assert torch.autograd.gradcheck(lambda t: f(t, free.detach()), (theta,), eps=1e-6, atol=1e-6)
    # 7k skinning floats: random-projection (fast mode) gradcheck.
    assert torch.autograd.gradcheck(lambda w: f(theta.detach(), w), (free,), eps=1e-6, atol=1e-6, fast_mode=True)


def test_sparse_default_path_equals_dense_path(rig64, asset):
    theta = random_theta(torch.Generator().manual_seed(2), 4, spread=0.5, dtype=torch.float64)
    sparse = rig64(theta).vertices
    dense = rig64(theta, weights=torch.as_tensor(asset.weights)).vertices
    assert torch.abs(sparse - dense).max() < 1e-10
    # gradients w.r.t. theta agree too
    t1 = theta.clone().requires_grad_()
    rig64(t1).vertices.square().sum().backward()
    t2 = theta.clone().requires_grad_()
    rig64(t2, weights=torch.as_tensor(asset.weights)).vertices.square().sum().backward()
    assert torch.allclose(t1.grad, t2.grad, rtol=1e-9, atol=1e-6)


def test_batched_weights_and_vertices(rig64, asset):
    theta = random_theta(torch.Generator().manual_seed(4), 2, spread=0.5, dtype=torch.float64)
    w = torch.as_tensor(asset.weights).expand(2, -1, -1)
    v = torch.as_tensor(asset.vertices).expand(2, -1, -1)
    assert torch.abs(rig64(theta, weights=w, vertices=v).vertices - rig64(theta).vertices).max() < 1e-10


def test_blended_skinning_equals_basis_skinning_and_batched_bind_positions_equal_shared():
    from rig.lbs import skin_vertices, skin_vertices_blended

    g = torch.Generator().manual_seed(11)
    B, V, K = 3, 40, 5
    verts = torch.randn(B, V, 3, generator=g, dtype=torch.float64)
    w = torch.rand(B, V, K, generator=g, dtype=torch.float64)
    w = w / w.sum(-1, keepdim=True)
    A = torch.randn(B, K, 4, 4, generator=g, dtype=torch.float64)
    A[:, :, 3] = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
    assert torch.allclose(skin_vertices_blended(verts, w, A), skin_vertices(verts, w, A), atol=1e-12)
    # per-head bind positions: each head equals the shared call with its own positions
    parents = torch.tensor([-1, 0, 0, 1, 3])
    tau = torch.eye(4, dtype=torch.float64).repeat(B, K, 1, 1)
    tau[..., :3, 3] = torch.randn(B, K, 3, generator=g, dtype=torch.float64)
    bind = torch.randn(B, K, 3, generator=g, dtype=torch.float64)
    world, skin = joint_world_transforms(tau, bind, parents)
    for b in range(B):
        w1, s1 = joint_world_transforms(tau[b : b + 1], bind[b], parents)
        assert torch.allclose(world[b], w1[0]) and torch.allclose(skin[b], s1[0])
