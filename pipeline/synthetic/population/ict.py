"""Synthetic identity heads from real-scan statistics: the ICT Face Model's identity space on the template's
topology (issue 25).

A head is ``template + sum_i c_i mode_i`` (mm), where the template is the ICT mean on MakeHuman's topology
(:func:`rig.ict.mean.ict_template`) and ``mode_i`` is ICT's identity mode ``i`` transferred onto the
template's vertices (:func:`rig.ict.modes.identity_modes`), then translated so that its eyeball centres
sit where the template's do (the rule of the MakeHuman population; the modes also move the eyes by a few
mm in ICT's frame, which is head placement, not identity).

Distributions (:data:`MODE_SD`):

- ``train`` (85, as JNR), ``val`` (2), ``test`` (7): ``c ~ N(0, I)`` over the 100 modes, the model's own
  sampler.
- ``heldout`` (100), *shifted*: a wider spread and the fine modes emphasised: ``c_i ~ N(0, 1.25^2)`` for
  modes 1-30 and ``N(0, 1.5^2)`` for modes 31-100 (the modes that hold the last 3 % of ICT's variance
  carry 2.25x as much here: detail the training heads rarely show). A spread of 2 on modes 31-100 folds
  ICT's own surface (lids, lips, ears) on most heads.

Folds. A draw whose visible skin (no vertex in :data:`rig.template.HIDDEN_REGIONS`) has a triangle turned by
90 degrees or more from the template's is redrawn from the same stream (as the MakeHuman population does):
measured with seed 0, 2 of the 85 training heads' first draws fold (one lip triangle) and 29 of the 100
held-out heads' (lids, lips, scalp and ears at the wider spread).

Each split draws from its own stream and each head from its own integer seed
(:func:`pipeline.synthetic.population.splits.split_seeds`): ``ict_coefficients(seed, shifted)`` reproduces
a head. The MakeHuman population stays as the out-of-distribution split ``makehuman``.
"""

from __future__ import annotations

import numpy as np

from rig.asset import RigAsset, load_asset
from rig.errors import InputError
from rig.ict.data import NUM_IDENTITY_MODES

__all__ = ["MAX_DRAWS", "MODE_NAMES", "MODE_SD", "SHIFTED_MODE_SD", "ict_coefficients", "ict_heads"]

MODE_NAMES: tuple[str, ...] = tuple(f"ict_identity_{i:03d}" for i in range(NUM_IDENTITY_MODES))
MODE_SD = np.ones(NUM_IDENTITY_MODES)
"""Standard deviation of each mode's coefficient in ``train``, ``val`` and ``test``."""
SHIFTED_MODE_SD = np.where(np.arange(NUM_IDENTITY_MODES) < 30, 1.25, 1.5)
"""... and in the shifted ``heldout`` split."""


MAX_DRAWS = 100


def ict_coefficients(
    seed: int, shifted: bool = False, asset: RigAsset | None = None, spread: float = 1.0
) -> np.ndarray:
    """``(100,)`` coefficients of the head of ``seed``: with ``rng = default_rng(seed)``,
    ``rng.standard_normal(100)`` times :data:`MODE_SD` (or :data:`SHIFTED_MODE_SD`) times ``spread``, drawn
    again from the same ``rng`` while the head folds its visible skin (module docstring). ``spread`` widens
    the distribution for other uses than the splits (the identity regressor's wide training heads)."""
    from pipeline.synthetic.population.heads import flipped_against

    asset = load_asset() if asset is None else asset
    rng = np.random.default_rng(int(seed))
    if not (np.isfinite(spread) and spread > 0):
        raise InputError(f"ict_coefficients: spread must be a positive number, got {spread}")
    sd = (SHIFTED_MODE_SD if shifted else MODE_SD) * float(spread)
    for _ in range(MAX_DRAWS):
        c = rng.standard_normal(NUM_IDENTITY_MODES) * sd
        if flipped_against(ict_heads(c, asset), asset.vertices, asset) == 0:
            return c
    raise RuntimeError(f"ict_coefficients: {MAX_DRAWS} draws of seed {seed} all fold the skin")


def ict_heads(coefficients: np.ndarray, asset: RigAsset | None = None) -> np.ndarray:
    """Heads ``(n, V, 3)`` mm (``(V, 3)`` for ``(k,)`` coefficients) for coefficients ``(n, k)``, k <= 100 (the
    first k modes): template + modes, eyeball centres kept in place."""
    from rig.ict.modes import identity_modes

    asset = load_asset() if asset is None else asset
    c = np.asarray(coefficients, float)
    one = c.ndim == 1
    c = np.atleast_2d(c)
    if c.ndim != 2 or c.shape[1] > NUM_IDENTITY_MODES or not np.isfinite(c).all():
        raise InputError(f"coefficients must be finite, (n, k <= {NUM_IDENTITY_MODES}); got {np.shape(coefficients)}")
    modes = identity_modes(asset)[: c.shape[1]]
    d = np.tensordot(c, modes, axes=([1], [0]))  # (n, V, 3)
    eyes = asset.region_mask("eyeballs")
    d -= d[:, eyes].mean(1, keepdims=True)
    heads = asset.vertices + d
    return heads[0] if one else heads
