"""A fit's head, ready to be re-posed by the notebook's sliders (:func:`posable_head`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from pipeline.colour import linear_to_srgb
from pipeline.head.fitted import FittedHead, fitted_head, fitted_head_from_arrays
from rig.errors import InputError
from rig.head_model import HeadParams, JnrHead, is_posable
from rig.model import JointRig

NOTEBOOK_TASK = "the notebook's sliders"


def posable_head(fit_or_params, *, rig: JointRig | None = None) -> FittedHead:
    """The :class:`~pipeline.head.fitted.FittedHead` of a fit, ready to be re-posed
    (:meth:`~pipeline.head.fitted.FittedHead.pose`).

    Args:
        fit_or_params: a fit result with ``theta``, ``z`` and ``expressions`` (``fit_photo``, ``fit_scan``,
            ``fit_landmarks``; a photo fit's ``albedo`` becomes the colours), or the content of a fit's
            ``params.json`` (``joints``, ``expressions`` by name, ``latent_z``).
        rig: a float64 :class:`rig.model.JointRig` to reuse (default: a new one).

    The head is the float64 forward pass of :class:`rig.head_model.JnrHead`, the one ``jnr rig export
    --params`` writes; a float32 fit's own ``rig_vertices`` agree to ~1e-4 mm.

    Raises:
        InputError: an ASM fit (its head has no joint channels), or parameters that the head model refuses.
    """
    model = JnrHead(rig=rig)
    if isinstance(fit_or_params, Mapping):
        return fitted_head(dict(fit_or_params), model=model, posable_for=NOTEBOOK_TASK)
    head = getattr(fit_or_params, "head", None)
    if isinstance(head, HeadParams) and not is_posable(head.kind):
        raise InputError(f"posable_head: a fit of the {head.kind!r} head model has no joint channels to pose")
    missing = [k for k in ("theta", "z", "expressions") if not hasattr(fit_or_params, k)]
    if missing:
        raise InputError(
            f"posable_head: expected a fit result or a params.json dict, got "
            f"{type(fit_or_params).__name__} without {missing}"
        )
    albedo = getattr(fit_or_params, "albedo", None)
    colours = None if albedo is None else linear_to_srgb(np.asarray(albedo, np.float64))  # clipped to [0, 1]
    return fitted_head_from_arrays(
        fit_or_params.theta, fit_or_params.z, fit_or_params.expressions, model=model, colours=colours
    )


__all__ = ["NOTEBOOK_TASK", "posable_head"]
