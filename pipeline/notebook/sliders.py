"""``ipywidgets`` sliders that re-pose a fitted head by joint channel and ARKit shape and update its view
(:func:`rig_sliders`, :class:`RigSliders`)."""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch

from pipeline.head.fitted import FittedHead
from pipeline.notebook.extra import require
from pipeline.notebook.view import update_head_view
from rig.errors import InputError
from rig.expressions import EXPRESSION_NAMES, expression_limits
from rig.joints import JOINTS
from rig.parameters import CHANNEL_INDEX, CHANNELS


def _expression_family(name: str) -> str:
    return re.match(r"[a-z]+", name).group(0)


class RigSliders:
    """Sliders for a :class:`FittedHead` (made by :func:`rig_sliders`).

    Attributes:
        head: the head. view: the ``FigureWidget`` updated on every change (or None).
        joint_sliders: channel name (``nose_tip.translate_z``) -> ``FloatSlider`` in the channel's unit
            (deg, mm, scale factor with 1 = rest), limited to its range.
        expression_sliders: ARKit name -> ``FloatSlider`` in [low, high] of the shape.
        widget: the ``ipywidgets`` box to display (a reset button, then tabs ``joints`` and
            ``expressions``, each an accordion by joint or ARKit family).
        vertices: ``(V, 3)`` the head at the sliders' values, mm (updated with the view).

    A slider change calls :meth:`apply`, which re-poses the head (:meth:`FittedHead.pose`) and updates
    the view; :meth:`set_values` and :meth:`reset` change many sliders and re-pose once.
    """

    def __init__(
        self,
        head: FittedHead,
        view=None,
        *,
        channels: Iterable[str] | None = None,
        expressions: bool = True,
        continuous_update: bool = False,
    ) -> None:
        widgets = require("ipywidgets")
        self.head, self.view = head, view
        names = [c.name for c in CHANNELS] if channels is None else list(channels)
        unknown = [n for n in names if n not in CHANNEL_INDEX]
        if unknown:
            raise InputError(
                f"rig_sliders: unknown joint channel(s) {unknown}; names are '<joint>.<channel>' "
                "of rig.parameters.CHANNELS"
            )
        self._holding = False
        joint_style, expression_style = {"description_width": "9.5em"}, {"description_width": "11em"}
        self.joint_sliders: dict[str, Any] = {}
        for name in names:
            c = CHANNELS[CHANNEL_INDEX[name]]
            span = c.high - c.low
            self.joint_sliders[name] = widgets.FloatSlider(
                value=c.from_theta(float(head.theta[CHANNEL_INDEX[name]])),
                min=c.low,
                max=c.high,
                step=_nice_step(span),
                description=f"{c.kind} ({c.unit})",
                style=joint_style,
                continuous_update=continuous_update,
                readout_format=".3f" if c.is_scale else ".2f",
                layout=widgets.Layout(width="400px"),
            )
        low, high = (x.numpy() for x in expression_limits(torch.float64))
        self.expression_sliders: dict[str, Any] = {}
        if expressions:
            for e, name in enumerate(EXPRESSION_NAMES):
                self.expression_sliders[name] = widgets.FloatSlider(
                    value=float(head.expressions[e]),
                    min=float(low[e]),
                    max=float(high[e]),
                    step=_nice_step(float(high[e] - low[e])),
                    description=name,
                    style=expression_style,
                    continuous_update=continuous_update,
                    readout_format=".2f",
                    layout=widgets.Layout(width="400px"),
                )
        for slider in (*self.joint_sliders.values(), *self.expression_sliders.values()):
            slider.observe(self._changed, names="value")
        self.vertices = head.vertices
        self.widget = self._layout(widgets)

    def _layout(self, widgets):
        by_joint: dict[str, list] = {}
        for name, slider in self.joint_sliders.items():
            by_joint.setdefault(JOINTS[CHANNELS[CHANNEL_INDEX[name]].joint].name, []).append(slider)
        by_family: dict[str, list] = {}
        for name, slider in self.expression_sliders.items():
            by_family.setdefault(_expression_family(name), []).append(slider)
        tabs, titles = [], []
        height = f"{int(self.view.layout.height) - 90}px" if self.view is not None and self.view.layout.height else None
        for label, groups in (("joints", by_joint), ("expressions", by_family)):
            if groups:
                # a long list: scrolled beside the view rather than below it
                tabs.append(
                    widgets.Accordion(
                        children=[widgets.VBox(s) for s in groups.values()],
                        titles=tuple(groups),
                        layout=widgets.Layout(max_height=height, overflow="auto"),
                    )
                )
                titles.append(label)
        reset = widgets.Button(description="reset to the fit", icon="undo")
        reset.on_click(lambda _: self.reset())
        return widgets.VBox(
            [reset, widgets.Tab(children=tabs, titles=tuple(titles))],
            layout=widgets.Layout(width="470px", flex="0 0 470px"),
        )

    def _repr_mimebundle_(self, **kwargs):
        return self.widget._repr_mimebundle_(**kwargs)

    # -- values ---------------------------------------------------------------------------------------
    def theta(self) -> np.ndarray:
        """``(P,)`` joint channels at the sliders (deg, mm, ``scale - 1``); channels without a slider keep
        the fit's value."""
        theta = np.array(self.head.theta, np.float64)
        for name, slider in self.joint_sliders.items():
            i = CHANNEL_INDEX[name]
            theta[i] = CHANNELS[i].to_theta(float(slider.value))
        return theta

    def expressions(self) -> np.ndarray:
        """``(E,)`` ARKit coefficients at the sliders (the fit's where there is no slider)."""
        c = np.array(self.head.expressions, np.float64)
        for e, name in enumerate(EXPRESSION_NAMES):
            if name in self.expression_sliders:
                c[e] = float(self.expression_sliders[name].value)
        return c

    def apply(self) -> np.ndarray:
        """Re-pose the head at the sliders' values and update the view; returns ``(V, 3)`` mm."""
        self.vertices = self.head.pose(self.theta(), self.expressions())
        if self.view is not None:
            update_head_view(self.view, self.vertices)
        return self.vertices

    def _changed(self, change) -> None:
        if not self._holding:
            self.apply()

    @contextmanager
    def hold(self):
        """Change several sliders, then re-pose once on leaving (the sliders' own callbacks wait)."""
        self._holding = True
        try:
            yield self
        finally:
            self._holding = False
        self.apply()

    def set_values(self, values: Mapping[str, float]) -> np.ndarray:
        """Set sliders by name (joint channels in their unit, scales as factors; ARKit names) and re-pose
        once. Raises InputError for a name without a slider or a value outside its range."""
        for name, value in values.items():
            slider = self.joint_sliders.get(name) or self.expression_sliders.get(name)
            if slider is None:
                raise InputError(f"RigSliders.set_values: no slider named {name!r}")
            if not slider.min <= float(value) <= slider.max:
                raise InputError(f"RigSliders.set_values: {name} = {value} is outside [{slider.min}, {slider.max}]")
        with self.hold():
            for name, value in values.items():
                (self.joint_sliders.get(name) or self.expression_sliders[name]).value = float(value)
        return self.vertices

    def reset(self) -> np.ndarray:
        """Every slider back to the fitted value; re-poses once."""
        with self.hold():
            for name, slider in self.joint_sliders.items():
                i = CHANNEL_INDEX[name]
                slider.value = CHANNELS[i].from_theta(float(self.head.theta[i]))
            for e, name in enumerate(EXPRESSION_NAMES):
                if name in self.expression_sliders:
                    self.expression_sliders[name].value = float(self.head.expressions[e])
        return self.vertices


def _nice_step(span: float) -> float:
    """A round slider step of about ``span / 400``."""
    raw = span / 400.0
    exponent = np.floor(np.log10(raw))
    for m in (1.0, 2.0, 5.0):
        if m * 10.0**exponent >= raw:
            return float(m * 10.0**exponent)
    return float(10.0 ** (exponent + 1))


def rig_sliders(
    head: FittedHead,
    view=None,
    *,
    channels: Iterable[str] | None = None,
    expressions: bool = True,
    continuous_update: bool = False,
) -> RigSliders:
    """``ipywidgets`` sliders that re-pose a fitted head and update its 3D view in place.

    Args:
        head: the :class:`FittedHead` (:func:`~pipeline.notebook.head.posable_head`).
        view: the :func:`~pipeline.notebook.view.head_view` to update (None: only :attr:`RigSliders.vertices` changes).
        channels: joint channels to offer by name (default all 107 of :data:`rig.parameters.CHANNELS`),
            grouped by joint; each slider is in the channel's unit (deg, mm, scale factor) within its limits.
        expressions: also a slider per ARKit shape (grouped by family: brow, eye, jaw, mouth, ...).
        continuous_update: re-pose while a slider is dragged (default: on release).

    Returns:
        :class:`RigSliders`; display it (or its ``widget``), e.g. ``ipywidgets.HBox([view, s.widget])``.

    Raises:
        InputError: an unknown channel name.
    """
    return RigSliders(head, view, channels=channels, expressions=expressions, continuous_update=continuous_update)


__all__ = ["RigSliders", "rig_sliders"]
