"""Benchmark: forward + backward of the differentiable renderer on the rig's head (~5k vertices).

Prints the median seconds per iteration (after warm-up), the resolution and spp/integrator settings.
Run: ``.venv/bin/python benchmarks/bench_render.py [--size 256] [--spp 1] [--iters 10]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch


def head_camera(vertices: np.ndarray, size: int, distance: float = 600.0):
    """A kornia camera looking at the head's front (+Z) from ``distance`` mm, face filling the image."""
    from kornia.geometry.camera import PinholeCamera

    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    extent = float((vertices.max(0) - vertices.min(0))[:2].max())
    f = 0.9 * size * distance / extent
    K = torch.tensor(
        [[f, 0, size / 2 - 0.5, 0], [0, f, size / 2 - 0.5, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=torch.float64
    )[None]
    # OpenCV camera on +Z looking at -Z: x right = world +x, y down = world -y, z forward = world -z
    R = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    eye = torch.tensor(centre, dtype=torch.float64) + torch.tensor([0.0, 0.0, distance], dtype=torch.float64)
    E = torch.eye(4, dtype=torch.float64)
    E[:3, :3] = R
    E[:3, 3] = -R @ eye
    hw = torch.tensor([float(size)], dtype=torch.float64)
    return PinholeCamera(K, E[None], hw, hw)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--spp", type=int, default=1)
    parser.add_argument("--spp-primary", type=int, default=None)
    parser.add_argument("--iters", type=int, default=10)
    parser.add_argument("--warmup", type=int, default=3)
    args = parser.parse_args(argv)

    from render.lighting import Lighting
    from render.renderer import DifferentiableRenderer
    from rig.asset import load_asset

    asset = load_asset()
    V = asset.vertices.astype(np.float32)
    albedo = np.broadcast_to(np.array([0.8, 0.58, 0.47], np.float32), V.shape).copy()
    cam = head_camera(asset.vertices, args.size)
    t0 = time.perf_counter()
    renderer = DifferentiableRenderer(
        V, asset.faces, albedo, cam, Lighting.default(), spp=args.spp, spp_primary=args.spp_primary, seed=0
    )
    t_build = time.perf_counter() - t0
    verts = torch.tensor(V, requires_grad=True)
    alb = torch.tensor(albedo, requires_grad=True)
    amb = torch.tensor([0.35, 0.35, 0.35], requires_grad=True)
    irr = torch.tensor([2.0, 2.0, 2.0], requires_grad=True)
    weights = torch.rand(args.size, args.size, 3, generator=torch.Generator().manual_seed(0))
    times = []
    for it in range(args.warmup + args.iters):
        t0 = time.perf_counter()
        light = Lighting(amb, irr, torch.tensor([-0.3, -0.4, -1.0]))
        out = renderer.render(verts, alb, light)
        loss = (out.image * weights).sum()
        loss.backward()
        dt = time.perf_counter() - t0
        if it >= args.warmup:
            times.append(dt)
        verts.grad = alb.grad = amb.grad = irr.grad = None
    sppp = args.spp_primary or args.spp
    print(
        f"bench_render: head {len(V)} vertices / {len(asset.faces)} faces, {args.size}x{args.size}, "
        f"variant {renderer.variant}, integrator direct_projective sppc={args.spp} sppp={sppp} sppi=0, "
        f"box filter, ambient (mesh emission) + directional light"
    )
    print(f"bench_render: scene build {t_build:.2f} s; first iterations (JIT) included in warm-up ({args.warmup})")
    print(
        f"bench_render: forward+backward median {statistics.median(times):.3f} s/iteration "
        f"(min {min(times):.3f}, max {max(times):.3f}, n={len(times)})"
    )


if __name__ == "__main__":
    main()
