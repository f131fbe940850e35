"""The point-cloud fit's data term: closest-point correspondences both ways, point-to-plane residuals
under a Geman-McClure loss, rebuilt as the fit goes (:class:`ScanObjective`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from pipeline.fitting.engine import Loss, Stage
from pipeline.fitting.state import ScanState
from pipeline.fitting.terms import Inputs, Term, Value, term_values
from pipeline.scan.fit_config import FitScanConfig
from pipeline.scan.pointcloud.cloud import CloudError
from pipeline.scan.registration import (
    closest_on_one_ring,
    incident_faces,
)
from rig.geometry import vertex_normals


@dataclass(frozen=True)
class Pairs:
    """Correspondences of one rebuild: cloud -> model pairs (cloud point ``c_i``, triangle ``c_tri (M, 3)``,
    barycentric ``c_bary (M, 3)``, fixed normal ``c_n (M, 3)``), model -> cloud pairs (vertex ``m_j``,
    cloud point ``m_k``, cloud normal ``m_n``) and the Geman-McClure scale ``sigma`` (mm)."""

    c_i: torch.Tensor
    c_tri: torch.Tensor
    c_bary: torch.Tensor
    c_n: torch.Tensor
    m_j: torch.Tensor
    m_k: torch.Tensor
    m_n: torch.Tensor
    sigma: float


def plane_residual(d: torch.Tensor, n: torch.Tensor, tangential: float) -> torch.Tensor:
    """Squared point-to-plane distance plus a weighted tangential part: ``d, n (M, 3) -> (M,)`` mm^2."""
    normal = (d * n).sum(-1)
    tangent = d - normal[:, None] * n
    return normal**2 + tangential * (tangent**2).sum(-1)


def geman_mcclure(e: torch.Tensor, sigma: float) -> torch.Tensor:
    """Geman-McClure of squared residuals ``e`` (mm^2) at scale ``sigma`` (mm): ``s^2 e / (s^2 + e)``."""
    s2 = sigma * sigma
    return s2 * e / (s2 + e)


class ScanObjective:
    """The non-rigid ICP loss of one cloud: correspondences rebuilt every ``correspondences.every`` steps
    (:meth:`rebuild`, the engine's ``before_step``), the robust data term, the head model's priors
    (:meth:`~pipeline.fitting.state.FitState.prior_terms`) with L_m diminishing as the correspondences settle,
    and the optional 3D landmark term, as :class:`~pipeline.fitting.terms.Term` s (the data and landmark terms
    are given by their values: Adam only).

    Args:
        state: the fit state (:class:`~pipeline.fitting.state.ScanState`).
        points, normals: ``(N, 3)`` the cloud and its unit normals, mm. border: ``(N,)`` bool scan border.
        view_dir: ``(3,)`` unit viewing direction of a single-view scan, or None.
        config: the fit's settings. rng: subsampling generator.
        landmarks: ``(vertex ids (L,), positions (L, 3) mm)`` or None.
    """

    def __init__(
        self,
        state: ScanState,
        points: np.ndarray,
        normals: np.ndarray,
        border: np.ndarray,
        view_dir: np.ndarray | None,
        config: FitScanConfig,
        rng: np.random.Generator,
        landmarks: tuple[np.ndarray, np.ndarray] | None,
    ) -> None:
        c = config.correspondences
        dtype = state.dtype
        self.state, self.config, self.c = state, config, c
        self.points, self.normals, self.border, self.view_dir = points, normals, border, view_dir
        sub = (
            np.sort(rng.choice(len(points), size=c.max_cloud_points, replace=False))
            if len(points) > c.max_cloud_points
            else np.arange(len(points))
        )
        self.p_sub, self.n_sub = points[sub], normals[sub]
        self.cloud_tree = cKDTree(points)
        self.P_sub = torch.as_tensor(self.p_sub, dtype=dtype)
        self.P_all = torch.as_tensor(points, dtype=dtype)
        self.cos_max = math.cos(math.radians(c.normal_angle_deg))
        self.landmarks = (
            None if landmarks is None else (torch.as_tensor(landmarks[0]), torch.as_tensor(landmarks[1], dtype=dtype))
        )
        faces = state.asset.faces
        self.incident = incident_faces(faces, len(state.asset.vertices))
        self.max_d, self.lambda_m, self.previous = c.max_distance_mm, config.prior.lambda_m, None
        self.pairs: Pairs | None = None

    def before_step(self, stage: Stage, iteration: int) -> None:
        """Rebuild the correspondences at the stage's first step and every ``correspondences.every``."""
        if iteration % self.c.every == 0:
            with torch.no_grad():
                v = self.state.to_cloud(self.state.rig_vertices()).numpy().astype(np.float64)
            self.pairs = self.rebuild(v)

    def _candidates(self, v_cloud: np.ndarray):
        """Both pair directions, found and rejected (module docstring), with their residuals (mm^2)."""
        c, faces = self.c, self.state.asset.faces
        vn = vertex_normals(v_cloud, faces)
        _, j1 = cKDTree(v_cloud).query(self.p_sub)
        # cloud -> model: the closest point on the model's surface (around the nearest vertex).
        f1, b1, q1 = closest_on_one_ring(self.p_sub, v_cloud, faces, self.incident, j1)
        n1 = (b1[:, :, None] * vn[faces[f1]]).sum(1)
        n1 /= np.linalg.norm(n1, axis=1, keepdims=True).clip(1e-12)
        d1 = np.linalg.norm(self.p_sub - q1, axis=1)
        ok1 = (d1 <= self.max_d) & ((self.n_sub * n1).sum(1) >= self.cos_max)
        d2, k2 = self.cloud_tree.query(v_cloud)
        ok2 = (d2 <= self.max_d) & ~self.border[k2] & ((vn * self.normals[k2]).sum(1) >= self.cos_max)
        if self.view_dir is not None:
            ok2 &= vn @ self.view_dir > c.min_facing
        e1 = plane_residual(
            torch.from_numpy(self.p_sub[ok1] - q1[ok1]), torch.from_numpy(n1[ok1]), c.tangential_weight
        ).numpy()
        e2 = plane_residual(
            torch.from_numpy(v_cloud[ok2] - self.points[k2[ok2]]), torch.from_numpy(self.normals[k2[ok2]]), 0.0
        ).numpy()
        return (f1, b1, n1, ok1), (k2, ok2), np.sqrt(np.concatenate([e1, e2]))

    def rebuild(self, v_cloud: np.ndarray) -> Pairs:
        """New pairs for the model at ``v_cloud (V, 3)`` (float64, mm); adapts the rejection distance and
        lowers L_m's weight by how far the model moved since the last rebuild."""
        c, p, faces, dtype = self.c, self.config.prior, self.state.asset.faces, self.state.dtype
        (f1, b1, n1, ok1), (k2, ok2), r = self._candidates(v_cloud)
        if r.size == 0:
            raise CloudError(
                "no point of the cloud lies near the head model any more (no correspondences); "
                "check the cloud's units (--units) and frame (--frame)"
            )
        sigma = max(c.robust_sigma_min_mm, float(np.quantile(r, c.robust_sigma_quantile)))
        inlier_rms = float(np.sqrt(np.mean(np.minimum(r, sigma * 3) ** 2)))
        self.max_d = float(np.clip(3.0 * max(inlier_rms, sigma), c.min_distance_mm, c.max_distance_mm))
        if self.previous is not None:
            motion = float(np.median(np.linalg.norm(v_cloud - self.previous, axis=1)))
            target = p.lambda_m_end + (p.lambda_m - p.lambda_m_end) * min(1.0, motion / p.settle_mm)
            self.lambda_m = min(self.lambda_m, target)
        self.previous = v_cloud.copy()
        return Pairs(
            c_i=torch.as_tensor(np.flatnonzero(ok1), dtype=torch.long),
            c_tri=torch.as_tensor(faces[f1[ok1]], dtype=torch.long),
            c_bary=torch.as_tensor(torch.as_tensor(b1[ok1], dtype=dtype)),
            c_n=torch.as_tensor(torch.as_tensor(n1[ok1], dtype=dtype)),
            m_j=torch.as_tensor(np.flatnonzero(ok2), dtype=torch.long),
            m_k=torch.as_tensor(k2[ok2], dtype=torch.long),
            m_n=torch.as_tensor(torch.as_tensor(self.normals[k2[ok2]], dtype=dtype)),
            sigma=float(sigma),
        )

    def __call__(self, free: tuple[str, ...]) -> Loss:
        """One step's loss: ``sqrt(mean robust residual)``, the head model's priors, the landmark RMSE."""
        pairs, c = self.pairs, self.c
        v_rig = self.state.rig_vertices(free)
        v_cloud = self.state.to_cloud(v_rig)
        on_surface = (pairs.c_bary[:, :, None] * v_cloud[pairs.c_tri]).sum(1)
        e1 = plane_residual(self.P_sub[pairs.c_i] - on_surface, pairs.c_n, c.tangential_weight)
        e2 = plane_residual(v_cloud[pairs.m_j] - self.P_all[pairs.m_k], pairs.m_n, 0.0)
        inputs = self.state.term_inputs().add({"rig_vertices": v_rig[None], "cloud_vertices": v_cloud[None]})
        terms = (
            self.data_term(e1, e2, pairs.sigma),
            *self.state.prior_terms(self.config.prior, lambda_m=self.lambda_m),
            *(() if self.landmarks is None else (self.landmark_term(),)),
        )
        data_rms = e1.detach().clamp_max((3 * pairs.sigma) ** 2).mean().sqrt()
        return Loss(
            term_values(terms, inputs),
            {
                "data_rms_mm": data_rms,
                "lambda_m": self.lambda_m,
                "pairs_cloud_to_model": len(pairs.c_i),
                "pairs_model_to_cloud": len(pairs.m_j),
            },
        )

    def data_term(self, e1: torch.Tensor, e2: torch.Tensor, sigma: float) -> Term:
        """``data``: ``sqrt(mean robust residual)`` of the squared residuals ``e1 (M,)`` (cloud -> model) and
        ``e2 (K,)`` (model -> cloud, weighted ``model_to_cloud_weight``), Geman-McClure at scale ``sigma``."""
        w2 = self.c.model_to_cloud_weight

        def root_mean_robust(p: Inputs) -> torch.Tensor:
            robust = (geman_mcclure(e1, sigma).sum() + w2 * geman_mcclure(e2, sigma).sum()) / (len(e1) + w2 * len(e2))
            return (robust + 1e-12).sqrt()[None, None]

        return Term(
            "data",
            1.0,
            root_mean_robust,
            Value(),
            lm="none",
            note="the root of a mean robust residual is not a sum of squares",
        )

    def landmark_term(self) -> Term:
        """``landmarks``: ``lambda_landmarks`` times the RMSE of the 3D landmarks (mm, cloud frame; the input
        ``cloud_vertices (B, V, 3)``)."""
        ids, positions = self.landmarks
        return Term(
            "landmarks",
            self.config.lambda_landmarks,
            lambda p: ((p["cloud_vertices"][:, ids] - positions) ** 2).sum(-1).mean(-1).sqrt()[:, None],
            Value(),
            lm="none",
            note="an RMSE (the root of a mean) is not a sum of squares",
        )
