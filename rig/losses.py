"""The fitting losses of JNR section 3.1 (eqs. 3-7), as pure functions.

Eq. 3 and eq. 6 as printed put ``1/N`` outside the square root, which is not the RMSE the text names
and would shrink with the vertex count; we implement the RMSE, ``sqrt(mean_n |v_p - v_g|^2)`` (mm).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch

from rig.geometry import mesh_edges
from rig.lbs import ShapeError

LAMBDA_M = 0.03
LAMBDA_X = 0.3
LAMBDA_P = 0.3


def vertex_rmse(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """L_v (eq. 3): RMSE of vertex positions, ``(B, V, 3)`` x2 -> ``(B,)`` mm."""
    if pred.shape != target.shape or pred.shape[-1] != 3:
        raise ShapeError(
            f"vertex_rmse: pred and target must both be (B, V, 3), got {tuple(pred.shape)} and {tuple(target.shape)}"
        )
    return ((pred - target) ** 2).sum(-1).mean(-1).clamp_min(1e-20).sqrt()


def regularizer(theta: torch.Tensor, num_joints: int = 52) -> torch.Tensor:
    """L_m (eq. 4): ``(1/K) sum_k (|R_k| + |T_k| + |S_k - 1|)`` over the flat parameters.

    Args:
        theta: ``(B, P)`` (deg, mm, ``scale - 1``): ``|theta|`` is exactly ``|R|``, ``|T|`` and ``|S - 1|``.

    Returns:
        ``(B,)``.
    """
    return theta.abs().sum(-1) / num_joints


def limit_loss(theta: torch.Tensor, low: torch.Tensor, high: torch.Tensor, num_joints: int = 52) -> torch.Tensor:
    """L_x (eq. 5), summed over rotation, translation and scale channels: ``(B, P) -> (B,)``.

    ``low``/``high`` are ``(P,)`` limits in the units of ``theta`` (see :func:`rig.parameters.theta_limits`).
    """
    over = (theta - high).clamp_min(0.0)
    under = (low - theta).clamp_min(0.0)
    return (over + under).sum(-1) / num_joints


def uniform_laplacian(faces: np.ndarray, num_vertices: int) -> torch.Tensor:
    """Sparse ``(V, V)`` graph Laplacian ``L = I - D^-1 A`` of the mesh (float64 COO tensor)."""
    e = mesh_edges(faces)
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_vertices, num_vertices))
    a = (a + a.T).tocsr()
    deg = np.asarray(a.sum(axis=1)).ravel()
    lap = (sp.identity(num_vertices) - sp.diags(1.0 / deg) @ a).tocoo()
    idx = torch.tensor(np.stack([lap.row, lap.col]), dtype=torch.long)
    return torch.sparse_coo_tensor(
        idx, torch.tensor(lap.data), (num_vertices, num_vertices), check_invariants=True
    ).coalesce()


def laplacian_loss(pred: torch.Tensor, target: torch.Tensor, laplacian: torch.Tensor) -> torch.Tensor:
    """L_p (eq. 6): RMSE between the Laplacian coordinates of ``pred`` and ``target``, ``(B, V, 3)`` -> ``(B,)``."""
    lap = laplacian.to(pred.dtype)
    diff = pred - target
    B, V, _ = diff.shape
    lap_diff = torch.sparse.mm(lap, diff.permute(1, 0, 2).reshape(V, B * 3)).reshape(V, B, 3).permute(1, 0, 2)
    return (lap_diff**2).sum(-1).mean(-1).clamp_min(1e-20).sqrt()


def rig_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    theta: torch.Tensor,
    low: torch.Tensor,
    high: torch.Tensor,
    laplacian: torch.Tensor,
    lambda_m: float = LAMBDA_M,
    lambda_x: float = LAMBDA_X,
    lambda_p: float = LAMBDA_P,
) -> dict[str, torch.Tensor]:
    """Eq. 7: ``L_v + lambda_m L_m + lambda_x L_x + lambda_p L_p``; each term ``(B,)``, returned by name."""
    terms = {
        "vertex": vertex_rmse(pred, target),
        "regularizer": regularizer(theta),
        "limits": limit_loss(theta, low, high),
        "laplacian": laplacian_loss(pred, target, laplacian),
    }
    terms["total"] = (
        terms["vertex"] + lambda_m * terms["regularizer"] + lambda_x * terms["limits"] + lambda_p * terms["laplacian"]
    )
    return terms
