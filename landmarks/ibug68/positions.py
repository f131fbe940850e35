"""Landmark positions on a posed mesh: one gather and one einsum (:func:`landmark_positions`)."""

from __future__ import annotations

import numpy as np
import torch

from landmarks.ibug68.embedding import LandmarkEmbedding
from rig.lbs import ShapeError


def landmark_positions(vertices, embedding: LandmarkEmbedding, faces):
    """Landmark positions on a posed mesh.

    Args:
        vertices: ``(B, V, 3)`` or ``(V, 3)`` mm, torch tensor or numpy array.
        embedding: :class:`LandmarkEmbedding` (``L`` landmarks).
        faces: ``(F, 3)`` template faces (torch or numpy).

    Returns:
        ``(B, L, 3)`` mm, the same kind (torch/numpy) and dtype as ``vertices`` (a batch of one for
        ``(V, 3)`` input); differentiable w.r.t. ``vertices`` in torch.

    Example:
        >>> a = load_asset(); emb = ibug68_embedding(a)
        >>> landmark_positions(torch.as_tensor(a.vertices), emb, a.faces).shape
        torch.Size([1, 68, 3])
    """
    if vertices.ndim not in (2, 3) or vertices.shape[-1] != 3:
        raise ShapeError(
            f"landmark_positions: vertices must have shape (B, V, 3) or (V, 3), got {tuple(vertices.shape)}"
        )
    tri = np.asarray(faces.cpu() if isinstance(faces, torch.Tensor) else faces)[embedding.faces]  # (L, 3)
    if isinstance(vertices, torch.Tensor):
        verts = vertices if vertices.ndim == 3 else vertices.unsqueeze(0)
        idx = torch.as_tensor(tri, dtype=torch.long, device=verts.device)
        bary = torch.as_tensor(embedding.barycentric, dtype=verts.dtype, device=verts.device)
        return torch.einsum("blkc,lk->blc", verts[:, idx], bary)
    verts = np.asarray(vertices)
    verts = verts if verts.ndim == 3 else verts[None]
    return np.einsum("blkc,lk->blc", verts[:, tri], embedding.barycentric.astype(verts.dtype))


__all__ = ["landmark_positions"]
