"""The free parameters of a rig fit and their differentiable map to rig-space vertices.

Shared by the point-cloud fit (:mod:`pipeline.scan.fit`) and the photo fit (:mod:`pipeline.photo.landmark_fit`),
which add their own pose on top. Joint channels are optimised as ``theta / span`` (each channel's range),
so degrees, millimetres and scale factors take comparable steps.
"""

from __future__ import annotations

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from scipy.spatial.transform import Rotation

from rig.expressions import EXPRESSION_NAMES, ExpressionModel, expression_limits
from rig.lbs import skin_vertices, skin_with_basis, skinning_basis
from rig.model import JointRig
from rig.parameters import NUM_PARAMETERS, theta_limits
from rig.skinning.neural import LATENT, NeuralSkinning

FREE_GROUPS = ("pose", "joints", "latent", "expressions")


class RigState:
    """Joints ``theta (P,)``, latent ``z (50,)``, expressions ``c (E,)`` (leaf tensors) and a head rotation.

    Args:
        rig, neural, expressions: the models (``neural=None``: the rig's own weights, no latent).
        rotation: initial ``(3, 3)`` head rotation (kept as a rotation vector ``rotvec``).
    """

    def __init__(self, rig: JointRig, neural: NeuralSkinning | None, expressions: ExpressionModel,
                 rotation: np.ndarray) -> None:
        self.rig, self.neural, self.expr = rig, neural, expressions
        dtype = rig.template.dtype
        self.low, self.high = theta_limits(dtype)
        self.span = (self.high - self.low).clamp_min(1e-3)
        self.c_low, self.c_high = expression_limits(dtype)
        self.rotvec = torch.tensor(Rotation.from_matrix(rotation).as_rotvec(), dtype=dtype, requires_grad=True)
        self.theta_n = torch.zeros(NUM_PARAMETERS, dtype=dtype, requires_grad=True)
        self.z = torch.zeros(LATENT, dtype=dtype, requires_grad=True)
        self.c = torch.zeros(len(EXPRESSION_NAMES), dtype=dtype, requires_grad=True)
        self._basis: tuple[tuple[int, int], torch.Tensor] | None = None

    @property
    def theta(self) -> torch.Tensor:
        """``(P,)`` joint channels (deg, mm, ``scale - 1``)."""
        return self.theta_n * self.span

    def weights(self) -> torch.Tensor:
        """``(V, K)`` skinning weights: neural of ``z``, or the rig's own."""
        return self.rig.dense_weights() if self.neural is None else self.neural(self.z[None])[0]

    def rotation(self) -> torch.Tensor:
        """``(3, 3)`` head rotation from ``rotvec``."""
        return axis_angle_to_rotation_matrix(self.rotvec[None])[0]

    def rig_vertices(self, free: tuple[str, ...] = ()) -> torch.Tensor:
        """``(V, 3)`` rig-space vertices, mm; only the groups in ``free`` carry gradients."""
        theta = self.theta if "joints" in free else self.theta.detach()
        c = self.c if "expressions" in free else self.c.detach()
        _, skinning = self.rig.joint_transforms(theta[None])
        if "latent" not in free and "expressions" not in free:
            # Rest shape and weights are fixed: reuse their skinning basis (one GEMM per step).
            key = (self.z._version, self.c._version)
            if self._basis is None or self._basis[0] != key:
                with torch.no_grad():
                    rest = self.expr.template + self.expr(self.c[None])[0]
                    self._basis = (key, skinning_basis(rest, self.weights()))
            return skin_with_basis(self._basis[1], skinning)[0]
        with torch.set_grad_enabled("latent" in free):
            w = self.weights()
        rest = self.expr.template + self.expr(c[None])[0]
        return skin_vertices(rest, w if "latent" in free else w.detach(), skinning)[0]

    def clamp_joints(self) -> None:
        """Project the joint channels back into their limits (in place), so every fit is a valid rig pose."""
        with torch.no_grad():
            self.theta_n.copy_(torch.maximum(torch.minimum(self.theta_n, self.high / self.span), self.low / self.span))

    def clamp_expressions(self) -> None:
        """Project the expression coefficients back into their limits (in place)."""
        with torch.no_grad():
            self.c.copy_(torch.maximum(torch.minimum(self.c, self.c_high), self.c_low))


def head_vertices(rig: JointRig, neural: NeuralSkinning | None, theta, z, expressions) -> np.ndarray:
    """``(V, 3)`` float64 rig-space head (mm) of fitted parameters: joint channels ``theta (P,)``, latent
    ``z (50,)`` (ignored without ``neural``: the rig's own weights) and expression coefficients ``(E,)``."""
    dtype = rig.template.dtype
    with torch.no_grad():
        c = torch.as_tensor(np.asarray(expressions, np.float64), dtype=dtype)[None]
        rest = ExpressionModel(rig.asset, dtype=dtype).vertices(c)[0]
        weights = rig.dense_weights() if neural is None else neural(
            torch.as_tensor(np.asarray(z, np.float64), dtype=dtype)[None])[0]
        theta = torch.as_tensor(np.asarray(theta, np.float64), dtype=dtype)[None]
        return rig(theta, weights=weights, vertices=rest).vertices[0].double().numpy()
