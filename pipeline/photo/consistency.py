"""Photometric consistency between the views of the multi-view fit (ASM eqs. 21-22; ``--photometric``).

Each view's photo (luminance of linear RGB) is sampled at the projected vertices of the face regions and their
1-ring neighbours; a patch (a vertex's 1-ring) counts in a pair of views when its vertex is visible in both.
The stage (:class:`PhotoConsistency`, an Adam stage of :func:`pipeline.fitting.engine.run_schedule` on the
identity and the poses) minimises the joint landmark refinement's least-squares cost (its terms at their last
IRLS weights) plus ``lambda_pc * (1 - mean over view pairs of LNCC)``.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch

from pipeline.colour import srgb_to_linear
from pipeline.fitting.engine import Loss, Stage
from pipeline.fitting.terms import LeastSquaresTerms
from pipeline.photo.multiview_config import PhotoConsistencyConfig
from pipeline.photo.multiview_problem import MultiViewProblem
from pipeline.photo.texture import zbuffer
from rig.geometry import mesh_edges, vertex_normals
from rig.lbs import ShapeError

# ----------------------------------------------------------------------------------------------------
# LNCC, sampling, visibility: pure functions
# ----------------------------------------------------------------------------------------------------


def ncc(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor | None = None, eps: float = 1e-6) -> torch.Tensor:
    """Normalised cross-correlation of patches along the last axis.

    Args:
        a, b: ``(*, P)`` intensities of corresponding patches (any units; NCC is invariant to ``a -> g a + o``
            with ``g > 0`` per patch).
        mask: ``(*, P)`` 0/1 (or weights) of the entries that count (default: all).
        eps: added to the product of the variances (a flat patch gives ~0, not NaN).

    Returns:
        ``(*)`` NCC in [-1, 1]: ``sum m a' b' / sqrt(sum m a'^2 sum m b'^2 + eps)``, ``a' = a - mean_m(a)``.

    Example:
        >>> a = torch.tensor([[0.1, 0.5, 0.2]])
        >>> round(float(ncc(a, 3.0 * a + 1.0)[0]), 4)
        1.0
    """
    if a.shape != b.shape:
        raise ShapeError(f"ncc: a and b must have the same shape, got {tuple(a.shape)} and {tuple(b.shape)}")
    m = torch.ones_like(a) if mask is None else mask.to(a.dtype).expand_as(a)
    count = m.sum(-1, keepdim=True).clamp_min(1e-12)
    da = (a - (m * a).sum(-1, keepdim=True) / count) * m
    db = (b - (m * b).sum(-1, keepdim=True) / count) * m
    return (da * db).sum(-1) / ((da * da).sum(-1) * (db * db).sum(-1) + eps).sqrt()


def lncc(
    a: torch.Tensor,
    b: torch.Tensor,
    patches: torch.Tensor,
    patch_mask: torch.Tensor,
    visible_a: torch.Tensor,
    visible_b: torch.Tensor,
    eps: float = 1e-6,
) -> torch.Tensor:
    """Local NCC of two views' per-vertex intensities (ASM eq. 21, with mesh patches).

    Args:
        a, b: ``(S,)`` intensity sampled at each of ``S`` vertices in view i and view j.
        patches: ``(X, P)`` int64, the patch of each of the ``X`` scored vertices (indices into ``S``; entry 0 the
            vertex itself, then its 1-ring; padded).
        patch_mask: ``(X, P)`` bool, the real (not padded) entries.
        visible_a, visible_b: ``(S,)`` bool or 0/1 visibility of each vertex in view i / j (z-buffer + facing).
        eps: as :func:`ncc`.

    Returns:
        Scalar: the mean of ``NCC(patch_i(x), patch_j(x))`` over the scored vertices ``x`` visible in both
        views (ASM's ``V(S_x^i) V(S_x^j)``); inside a patch only entries visible in both views count. 0 when
        no vertex is visible in both.
    """
    if a.shape != b.shape or a.dim() != 1:
        raise ShapeError(f"lncc: a and b must be (S,), got {tuple(a.shape)} and {tuple(b.shape)}")
    if patches.shape != patch_mask.shape or patches.dim() != 2:
        raise ShapeError(
            f"lncc: patches and patch_mask must be (X, P), got {tuple(patches.shape)} and {tuple(patch_mask.shape)}"
        )
    both = visible_a.to(a.dtype) * visible_b.to(a.dtype)  # (S,)
    m = patch_mask.to(a.dtype) * both[patches]  # (X, P)
    centre = both[patches[:, 0]] * (m.sum(-1) >= 3).to(a.dtype)  # the vertex itself seen, and >= 3 entries
    scores = ncc(a[patches], b[patches], m, eps)
    n = centre.sum()
    if float(n) == 0:
        return a.new_zeros(())
    return (scores * centre).sum() / n


def one_ring_patches(faces: np.ndarray, vertex_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 1-ring patch of each vertex of ``vertex_ids``.

    Returns:
        ``(sampled (S,) int64 vertex ids: vertex_ids and their neighbours, patches (X, P) int64 indices into
        sampled (column 0: the vertex itself), mask (X, P) bool)``, ``P = 1 + max degree``.
    """
    edges = mesh_edges(np.asarray(faces))
    ids = np.asarray(vertex_ids, np.int64)
    chosen = np.zeros(int(edges.max()) + 1, bool)
    chosen[ids] = True
    keep = chosen[edges[:, 0]] | chosen[edges[:, 1]]
    e = edges[keep]
    both = np.concatenate([e, e[:, ::-1]])
    neighbours: dict[int, list[int]] = {int(i): [] for i in ids}
    for u, w in both:
        if int(u) in neighbours:
            neighbours[int(u)].append(int(w))
    sampled = np.unique(np.concatenate([ids, e.ravel()]))
    where = {int(v): k for k, v in enumerate(sampled)}
    width = 1 + max(len(n) for n in neighbours.values())
    patches = np.zeros((len(ids), width), np.int64)
    mask = np.zeros((len(ids), width), bool)
    for row, i in enumerate(ids):
        entries = [int(i)] + neighbours[int(i)]
        patches[row, : len(entries)] = [where[v] for v in entries]
        mask[row, : len(entries)] = True
    return sampled, patches, mask


def sample_image(image: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of an image at pixel positions (differentiable in ``pixels``).

    Args:
        image: ``(C, H, W)``.
        pixels: ``(N, 2)`` x right, y down, pixel centres at integer coordinates (OpenCV).

    Returns:
        ``(N, C)``; positions outside the image take the border value.
    """
    c, h, w = image.shape
    grid = torch.stack([2.0 * pixels[:, 0] / max(w - 1, 1) - 1.0, 2.0 * pixels[:, 1] / max(h - 1, 1) - 1.0], -1)
    out = torch.nn.functional.grid_sample(
        image[None].to(pixels.dtype), grid[None, None], mode="bilinear", padding_mode="border", align_corners=True
    )
    return out[0, :, 0].T


# ----------------------------------------------------------------------------------------------------
# Photometric consistency
# ----------------------------------------------------------------------------------------------------


def luminance(image: np.ndarray) -> np.ndarray:
    """``(H, W)`` float64 luminance (Rec. 709) of a uint8 sRGB photo, in linear RGB."""
    lin = srgb_to_linear(np.asarray(image, np.float32) / 255.0).astype(np.float64)
    return lin @ np.array([0.2126, 0.7152, 0.0722])


def vertex_visibility(
    camera_vertices: np.ndarray,
    faces: np.ndarray,
    width: int,
    height: int,
    pixels: np.ndarray,
    ids: np.ndarray,
    visible_cos: float,
    tolerance_mm: float,
) -> np.ndarray:
    """``(U,)`` bool: vertices ``ids`` of a head (``camera_vertices (V, 3)``, OpenCV camera frame, mm; their
    ``pixels (V, 2)``) seen by the camera: inside the image, facing it (``cos >= visible_cos``) and not behind
    another part of the head (:func:`pipeline.photo.texture.zbuffer` within ``tolerance_mm``)."""
    depth = camera_vertices[:, 2]
    buffer = zbuffer(pixels, depth, faces, width, height)
    p = pixels[ids]
    col = np.clip(np.round(p[:, 0]).astype(np.int64), 0, width - 1)
    row = np.clip(np.round(p[:, 1]).astype(np.int64), 0, height - 1)
    inside = (p[:, 0] >= 0) & (p[:, 0] <= width - 1) & (p[:, 1] >= 0) & (p[:, 1] <= height - 1)
    unoccluded = depth[ids] <= buffer[row, col] + tolerance_mm
    normals = vertex_normals(camera_vertices, faces)[ids]
    to_camera = -camera_vertices[ids]
    cos = (normals * to_camera).sum(1) / np.linalg.norm(to_camera, axis=1).clip(1e-12)
    return inside & unoccluded & (cos >= visible_cos)


class PhotoConsistency:
    """The photometric consistency stage's objective and its ``before_step`` hook (module docstring).

    Args:
        problem: the multi-view problem (its state is what the stage moves).
        rows: the refinement's terms as least-squares rows (:class:`~pipeline.fitting.terms.LeastSquaresTerms`):
            their cost is the landmark part of the loss, re-weighted with the visibility.
        images: ``N`` ``(H, W, 3)`` uint8 sRGB photos. settings: :class:`PhotoConsistencyConfig`.
    """

    def __init__(
        self, problem: MultiViewProblem, rows: LeastSquaresTerms, images, settings: PhotoConsistencyConfig
    ) -> None:
        self.problem, self.rows, self.settings = problem, rows, settings
        asset = problem.state.rig.asset
        self.faces = np.asarray(asset.faces, np.int64)
        self.scored = np.flatnonzero(asset.region_mask(*settings.regions))
        self.sampled, patches, mask = one_ring_patches(self.faces, self.scored)
        self.patches, self.patch_mask = torch.as_tensor(patches), torch.as_tensor(mask)
        self.ids = torch.as_tensor(self.sampled)
        self.everything = torch.arange(len(asset.vertices))
        self.grey = [torch.as_tensor(luminance(img))[None] for img in images]
        self.pairs = list(itertools.combinations(range(len(images)), 2))
        self.visible: list[torch.Tensor] = []

    def before_step(self, stage: Stage, iteration: int) -> None:
        """Every ``visibility_every`` steps: the jaw contours, the IRLS weights and each view's visible
        vertices at the current estimate."""
        if iteration % self.settings.visibility_every:
            return
        problem, settings = self.problem, self.settings
        with torch.no_grad():
            problem.repick()
            self.rows.reweight(problem.state_inputs())
            self.visible = []
            for k, grey in enumerate(self.grey):
                cam, px = problem.camera_vertices(k, self.everything)
                h, w = grey.shape[1:]
                seen = vertex_visibility(
                    cam.numpy(),
                    self.faces,
                    w,
                    h,
                    px.numpy(),
                    self.sampled,
                    settings.visible_cos,
                    settings.depth_tolerance_mm,
                )
                self.visible.append(torch.as_tensor(seen))

    def __call__(self, free: tuple[str, ...]) -> Loss:
        """The landmark cost of every view, the intensities at the projected vertices, LNCC per pair."""
        problem = self.problem
        landmarks = self.rows.cost(problem.state_inputs())[0]
        samples = [
            sample_image(grey, problem.camera_vertices(k, self.ids)[1])[:, 0] for k, grey in enumerate(self.grey)
        ]
        scores = [
            lncc(samples[i], samples[j], self.patches, self.patch_mask, self.visible[i], self.visible[j])
            for i, j in self.pairs
        ]
        pc = 1.0 - torch.stack(scores).mean()
        return Loss(
            {"landmarks": landmarks, "photo_consistency": self.settings.lambda_pc * pc},
            {"one_minus_lncc": pc, "pairs": len(self.pairs), "scored_vertices": int(len(self.scored))},
        )
