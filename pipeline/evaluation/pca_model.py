"""A linear PCA shape model: the "3DMM reference" that JNR (Table 1) and ASM (Table 7) compare with.

A :class:`PcaShapeModel` is a mean shape and ``k`` orthonormal principal directions of the training
heads (in mm, vertex order of the template), trained by :func:`train_pca` with one SVD. Fitting a head
with known correspondence (:meth:`PcaShapeModel.fit`) is the closed-form least-squares projection onto
the affine span ``mean + span(components)``; no pose or scale is estimated, so the heads must already
be aligned like the training heads (``jnr eval capacity`` maps every head onto the template by its
least-squares similarity, :func:`pipeline.synthetic.population.similarity_normalised`).

Example:
    >>> import torch
    >>> heads = torch.randn(6, 10, 3, dtype=torch.float64)
    >>> model = train_pca(heads, k=5)
    >>> model.k, model.num_vertices, tuple(model.components.shape)
    (5, 10, (5, 30))
    >>> bool((model.fit(heads) - heads).abs().max() < 1e-9)  # k = N - 1 spans every training head
    True
    >>> model.num_floats()
    {'mean': 30, 'components': 150, 'coefficients': 5}
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from rig.errors import InputError, ShapeError

__all__ = ["PcaShapeModel", "train_pca"]


def _as_heads(vertices, func: str, arg: str, num_vertices: int | None = None) -> torch.Tensor:
    """``(N, V, 3)`` array or tensor -> float64 tensor, or :class:`ShapeError` naming ``func`` and ``arg``."""
    t = vertices if isinstance(vertices, torch.Tensor) else torch.from_numpy(np.array(vertices))  # a copy
    expected = f"(N, {num_vertices if num_vertices is not None else 'V'}, 3)"
    if t.ndim != 3 or t.shape[-1] != 3 or (num_vertices is not None and t.shape[1] != num_vertices):
        raise ShapeError(f"{func}: {arg} must have shape {expected}, got {tuple(t.shape)}")
    if not t.is_floating_point():
        t = t.to(torch.float64)
    if not bool(torch.isfinite(t).all()):
        raise InputError(f"{func}: {arg} must be finite (it holds NaN or inf)")
    return t


@dataclass(frozen=True)
class PcaShapeModel:
    """A linear shape model ``x = mean + components^T a`` (all in mm).

    Attributes:
        mean: ``(V, 3)`` mm, the mean training head.
        components: ``(k, V*3)``, orthonormal rows (unit vectors in R^{3V}, dimensionless), ordered by
            decreasing variance; a row flattens ``(V, 3)`` in C order (x, y, z of vertex 0 first).
        stddev: ``(k,)`` mm, the sample std (ddof=1) of the training heads along each component.
    """

    mean: torch.Tensor
    components: torch.Tensor
    stddev: torch.Tensor

    @property
    def k(self) -> int:
        """Number of components."""
        return int(self.components.shape[0])

    @property
    def num_vertices(self) -> int:
        return int(self.mean.shape[0])

    def num_floats(self) -> dict[str, int]:
        """Model size in floats: the stored ``mean`` (3V) and ``components`` (3Vk), and the
        ``coefficients`` (k) that identify one head. ``stddev`` is left out: a least-squares fit
        (``ridge=0``) does not use it."""
        return {"mean": int(self.mean.numel()), "components": int(self.components.numel()), "coefficients": self.k}

    def truncated(self, k: int) -> PcaShapeModel:
        """The model with only the first ``k`` components (``1 <= k <=`` :attr:`k`): the same as
        :func:`train_pca` with ``k`` on the same heads, without another SVD."""
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= self.k:
            raise InputError(f"PcaShapeModel.truncated: k must be an integer in [1, {self.k}], got {k!r}")
        return PcaShapeModel(mean=self.mean, components=self.components[:k], stddev=self.stddev[:k])

    def coefficients(self, targets, ridge: float = 0.0) -> torch.Tensor:
        """Least-squares coefficients of heads with known correspondence.

        Minimises ``|mean + components^T a - x|^2 + ridge * sum_i (a_i / stddev_i)^2`` per head, in
        closed form: the components are orthonormal, so ``a_i = (c_i . (x - mean)) * s_i^2 / (s_i^2 + ridge)``.

        Args:
            targets: ``(B, V, 3)`` mm, aligned like the training heads.
            ridge: ``>= 0`` mm^2, weight of the Gaussian prior on the coefficients; the default 0 is the
                plain orthogonal projection.

        Returns:
            ``(B, k)`` coefficients (mm), in the model's dtype.
        """
        if not (ridge >= 0.0 and np.isfinite(ridge)):
            raise InputError(f"PcaShapeModel.coefficients: ridge must be a finite number >= 0, got {ridge}")
        x = _as_heads(targets, "PcaShapeModel.fit", "targets", self.num_vertices).to(self.mean)
        a = (x - self.mean).reshape(x.shape[0], -1) @ self.components.T
        if ridge > 0.0:
            var = self.stddev.square()
            a = a * (var / (var + ridge))
        return a

    def reconstruct(self, coefficients: torch.Tensor) -> torch.Tensor:
        """``(B, k)`` coefficients -> ``(B, V, 3)`` mm heads."""
        a = torch.as_tensor(coefficients).to(self.mean)
        if a.ndim != 2 or a.shape[1] != self.k:
            raise ShapeError(
                f"PcaShapeModel.reconstruct: coefficients must have shape (B, {self.k}), got {tuple(a.shape)}"
            )
        return self.mean + (a @ self.components).reshape(a.shape[0], self.num_vertices, 3)

    def fit(self, targets, ridge: float = 0.0) -> torch.Tensor:
        """Fit heads with known correspondence: ``(B, V, 3)`` mm -> ``(B, V, 3)`` mm, the least-squares
        projection onto the model (see :meth:`coefficients` for ``ridge``)."""
        return self.reconstruct(self.coefficients(targets, ridge))


def train_pca(vertices, k: int) -> PcaShapeModel:
    """Train a PCA shape model with ``k`` components on ``N`` aligned heads (one thin SVD, float64).

    Args:
        vertices: ``(N, V, 3)`` mm, the training heads in the template's vertex order, ``N >= 2``.
        k: number of components, ``1 <= k <= N - 1`` (the centred training set has rank at most ``N - 1``).

    Returns:
        :class:`PcaShapeModel` in float64: ``mean`` the training mean, ``components`` the first ``k``
        right singular vectors of the centred ``(N, 3V)`` data (signs arbitrary), ``stddev`` = singular
        value / sqrt(N - 1).

    Raises:
        ShapeError: ``vertices`` is not ``(N, V, 3)``.
        InputError (a ValueError): ``k`` is out of range, or ``vertices`` is not finite.
    """
    x = _as_heads(vertices, "train_pca", "vertices").to(torch.float64)
    n = int(x.shape[0])
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= n - 1:
        raise InputError(
            f"train_pca: k must be an integer in [1, N - 1] = [1, {n - 1}] for N = {n} training heads, got {k!r}"
        )
    mean = x.mean(0)
    centred = (x - mean).reshape(n, -1)
    # the SVD of the tall (3V, N) transpose: the same factors, several times faster than the wide one
    u, s, _ = torch.linalg.svd(centred.T, full_matrices=False)
    return PcaShapeModel(mean=mean, components=u[:, :k].T.contiguous(), stddev=s[:k] / np.sqrt(n - 1))
