"""Interactive pieces for the notebooks: a 3D view of a fitted head, sliders that re-pose it by name, and
the loss curves of a fit, one panel per stage.

* :class:`PosableHead` (:func:`posable_head`): what a fitted head is made of (its skinning weights from
  the latent Z, joint channels, expression coefficients), so that :meth:`PosableHead.pose` rebuilds it
  for any joint values and ARKit coefficients exactly as the rig's forward pass does
  (:class:`rig.model.JointRig`, float64).
* :func:`head_view`: the head as a ``plotly`` ``FigureWidget`` (a ``Mesh3d`` in rig space, mm, +Y up,
  seen from the front, a little from the subject's left and above); :func:`update_head_view` replaces its
  vertices in place.
* :func:`rig_sliders`: ``ipywidgets`` sliders for the joint channels (by name, within their limits) and
  the 52 ARKit shapes; moving one re-poses the head and updates the view (:class:`RigSliders`).
* :func:`stage_curves` / :func:`loss_curves`: every loss term per iteration of every stage of a fit
  (``matplotlib``, log y).

``plotly``, ``ipywidgets`` and ``matplotlib`` are imported only by the functions that draw (the
``notebook`` extra: ``pip install -e ".[notebook]"``); importing this module needs none of them, and no
Jupyter: the callbacks are plain methods that tests drive by setting slider values.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Iterable, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from rig.errors import InputError, SetupError, check_shape
from rig.expressions import EXPRESSION_NAMES, ExpressionModel, expression_limits
from rig.joints import JOINTS
from rig.model import JointRig
from rig.parameters import CHANNEL_INDEX, CHANNELS, NUM_PARAMETERS, theta_to_params

NOTEBOOK_EXTRA = 'pip install -e ".[notebook]"'

SKIN_SRGB = (0.80, 0.67, 0.58)
"""The view's colour when the head has no albedo (sRGB, [0, 1])."""


def _require(module: str):
    """Import one of the drawing libraries, or raise :class:`rig.errors.SetupError` naming the install."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise SetupError(f"pipeline.notebook needs {module.split('.')[0]} ({NOTEBOOK_EXTRA}): {exc}") from None


# ----------------------------------------------------------------------------------------------------
# The head
# ----------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class PosableHead:
    """A fitted head ready to be re-posed.

    Attributes:
        theta: ``(P,)`` the fitted joint channels (deg, mm, ``scale - 1``; :data:`rig.parameters.CHANNELS`).
        expressions: ``(E,)`` the fitted ARKit coefficients (:data:`rig.expressions.EXPRESSION_NAMES`).
        weights: ``(V, K)`` float64 skinning weights of the fit's latent Z.
        vertices: ``(V, 3)`` float64 the fitted head in rig space, mm (``pose(theta, expressions)``).
        faces: ``(F, 3)`` int triangles.
        colours: ``(V, 3)`` sRGB in [0, 1] per vertex (a photo fit's albedo), or None.
        rig: the float64 rig that poses it; expression_model: its float64 expression shapes.
    """

    theta: np.ndarray
    expressions: np.ndarray
    weights: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    colours: np.ndarray | None
    rig: JointRig = field(repr=False)
    expression_model: ExpressionModel = field(repr=False)

    def rest(self, expressions) -> np.ndarray:
        """``(V, 3)`` float64 rest mesh with the ARKit coefficients ``expressions (E,)`` applied, mm."""
        c = _vector(expressions, len(EXPRESSION_NAMES), "PosableHead.rest", "expressions", "(E,)")
        with torch.no_grad():
            return self.expression_model.vertices(torch.as_tensor(c)[None])[0].numpy()

    def pose(self, theta, expressions) -> np.ndarray:
        """The head for joint channels ``theta (P,)`` (deg, mm, ``scale - 1``) and ARKit coefficients
        ``expressions (E,)``: ``(V, 3)`` float64, rig space, mm. The rest mesh with the expressions applied,
        skinned with the fit's weights (:meth:`rig.model.JointRig.forward`)."""
        t = _vector(theta, NUM_PARAMETERS, "PosableHead.pose", "theta", "(P,)")
        rest = torch.as_tensor(self.rest(expressions))
        with torch.no_grad():
            out = self.rig(torch.as_tensor(t)[None], weights=torch.as_tensor(self.weights), vertices=rest)
        return out.vertices[0].numpy()


def _vector(values, size: int, function: str, name: str, shape: str) -> np.ndarray:
    v = np.asarray(values.detach().cpu() if isinstance(values, torch.Tensor) else values, np.float64)
    check_shape(v.shape == (size,), function, name, shape, v.shape)
    return v


def posable_head(fit_or_params, *, rig: JointRig | None = None) -> PosableHead:
    """The :class:`PosableHead` of a fit.

    Args:
        fit_or_params: a fit result with ``theta``, ``z`` and ``expressions`` (``fit_photo``, ``fit_scan``,
            ``fit_landmarks``; a photo fit's ``albedo`` becomes the colours), or the content of a fit's
            ``params.json`` (``joints``, ``expressions`` by name, ``latent_z``).
        rig: a float64 :class:`rig.model.JointRig` to reuse (default: a new one).

    The arrays are :func:`pipeline.scan.outputs.head_arrays_from_params`'s (float64), so the head is the
    one ``jnr rig export --params`` writes; a float32 fit's own ``rig_vertices`` agree to ~1e-4 mm.

    Raises:
        InputError: an ASM fit (its head has no joint channels), or parameters that
            :func:`pipeline.scan.outputs.head_arrays_from_params` refuses.
    """
    from pipeline.scan.outputs import head_arrays_from_params
    from rig.parameters import params_to_theta

    if isinstance(fit_or_params, Mapping):
        params = dict(fit_or_params)
        colours = None
    else:
        if getattr(fit_or_params, "asm", None):
            raise InputError("posable_head: an ASM fit has no joint channels to pose (fit with skinning: jnr)")
        missing = [k for k in ("theta", "z", "expressions") if not hasattr(fit_or_params, k)]
        if missing:
            raise InputError(f"posable_head: expected a fit result or a params.json dict, got "
                             f"{type(fit_or_params).__name__} without {missing}")
        params = {"joints": theta_to_params(torch.as_tensor(np.asarray(fit_or_params.theta, np.float64)),
                                            include_rest=True),
                  "expressions": dict(zip(EXPRESSION_NAMES, map(float, fit_or_params.expressions))),
                  "latent_z": [float(x) for x in fit_or_params.z]}
        albedo = getattr(fit_or_params, "albedo", None)
        colours = None
        if albedo is not None:
            from pipeline.photo.colour import linear_to_srgb

            colours = np.asarray(linear_to_srgb(np.clip(np.asarray(albedo, np.float64), 0.0, 1.0)))
    if params.get("skinning") == "asm":
        raise InputError("posable_head: an ASM fit has no joint channels to pose (fit with skinning: jnr)")
    rig = rig if rig is not None and rig.template.dtype == torch.float64 else JointRig(dtype=torch.float64)
    try:
        posed, _, weights, _, c = head_arrays_from_params(params, rig=rig)
        theta = params_to_theta(params["joints"], dtype=torch.float64).numpy()
    except KeyError as exc:
        raise InputError(f"posable_head: the parameters lack {exc}") from None
    return PosableHead(theta=theta, expressions=np.asarray(c, np.float64), weights=weights, vertices=posed,
                       faces=np.asarray(rig.asset.faces), colours=colours, rig=rig,
                       expression_model=ExpressionModel(rig.asset, dtype=torch.float64))


# ----------------------------------------------------------------------------------------------------
# The 3D view
# ----------------------------------------------------------------------------------------------------

def head_view(head: PosableHead | np.ndarray, faces: np.ndarray | None = None, *, colours=None,
              height: int = 520, width: int | None = None, title: str | None = None):
    """An interactive 3D view of a head: a ``plotly.graph_objects.FigureWidget`` with one ``Mesh3d``.

    Args:
        head: a :class:`PosableHead` (its ``vertices``, ``faces`` and ``colours``), or ``(V, 3)`` vertices
            in rig space, mm.
        faces: ``(F, 3)`` triangles (only with vertices).
        colours: ``(V, 3)`` sRGB in [0, 1] per vertex (default: the head's, else a uniform skin tone).
        height, width: pixels (width default: ``height``, leaving room for :func:`rig_sliders` beside it).
        title: above the view.

    Rig axes are the plot's (mm): +X the subject's left, +Y up, +Z out of the face; the camera looks at
    the face from the front, a little from the subject's left (+X) and above, with +Y up; the aspect ratio
    is the data's. Drag to orbit, scroll to zoom. The vertex data stays float64 (``view.data[0].x``, ...).
    """
    go = _require("plotly.graph_objects")
    if isinstance(head, PosableHead):
        vertices, faces = head.vertices, head.faces
        colours = head.colours if colours is None else colours
    else:
        vertices = head
        if faces is None:
            raise InputError("head_view: faces are needed with bare vertices")
    v = np.asarray(vertices, np.float64)
    check_shape(v.ndim == 2 and v.shape[1] == 3, "head_view", "vertices", "(V, 3)", v.shape)
    f = np.asarray(faces)
    check_shape(f.ndim == 2 and f.shape[1] == 3, "head_view", "faces", "(F, 3)", f.shape)
    mesh = dict(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2], flatshading=False,
                hoverinfo="skip", name="head",
                lighting=dict(ambient=0.45, diffuse=0.75, specular=0.15, roughness=0.7, fresnel=0.05),
                lightposition=dict(x=400, y=600, z=1500))
    if colours is not None:
        rgb = np.clip(np.round(np.asarray(colours, np.float64) * 255.0), 0, 255).astype(int)
        check_shape(rgb.shape == v.shape, "head_view", "colours", f"({len(v)}, 3)", rgb.shape)
        mesh["vertexcolor"] = [f"rgb({r},{g},{b})" for r, g, b in rgb]
    else:
        mesh["color"] = "rgb({},{},{})".format(*(round(255 * c) for c in SKIN_SRGB))
    hidden = dict(visible=False, showbackground=False)
    layout = dict(height=height, width=height if width is None else width, margin=dict(l=0, r=0, t=30 if title else 0, b=0),
                  title=dict(text=title) if title else None,
                  scene=dict(aspectmode="data", xaxis=hidden, yaxis=hidden, zaxis=hidden,
                             camera=dict(up=dict(x=0, y=1, z=0), eye=dict(x=0.75, y=0.2, z=1.45),
                                         projection=dict(type="perspective")),
                             dragmode="orbit"),
                  uirevision="head")  # keep the user's camera when the vertices change
    return go.FigureWidget(data=[go.Mesh3d(**mesh)], layout=layout)


def update_head_view(view, vertices) -> None:
    """Replace the vertices of :func:`head_view`'s mesh in place (one message to the browser).

    Args:
        view: the ``FigureWidget``. vertices: ``(V, 3)`` rig space, mm, the view's vertex count.
    """
    v = np.asarray(vertices, np.float64)
    mesh = view.data[0]
    check_shape(v.shape == (len(mesh.x), 3), "update_head_view", "vertices", f"({len(mesh.x)}, 3)", v.shape)
    with view.batch_update():
        mesh.x, mesh.y, mesh.z = v[:, 0], v[:, 1], v[:, 2]


# ----------------------------------------------------------------------------------------------------
# The sliders
# ----------------------------------------------------------------------------------------------------

def _expression_family(name: str) -> str:
    return re.match(r"[a-z]+", name).group(0)


class RigSliders:
    """Sliders for a :class:`PosableHead` (made by :func:`rig_sliders`).

    Attributes:
        head: the head. view: the ``FigureWidget`` updated on every change (or None).
        joint_sliders: channel name (``nose_tip.translate_z``) -> ``FloatSlider`` in the channel's unit
            (deg, mm, scale factor with 1 = rest), limited to its range.
        expression_sliders: ARKit name -> ``FloatSlider`` in [low, high] of the shape.
        widget: the ``ipywidgets`` box to display (a reset button, then tabs ``joints`` and
            ``expressions``, each an accordion by joint or ARKit family).
        vertices: ``(V, 3)`` the head at the sliders' values, mm (updated with the view).

    A slider change calls :meth:`apply`, which re-poses the head (:meth:`PosableHead.pose`) and updates
    the view; :meth:`set_values` and :meth:`reset` change many sliders and re-pose once.
    """

    def __init__(self, head: PosableHead, view=None, *, channels: Iterable[str] | None = None,
                 expressions: bool = True, continuous_update: bool = False) -> None:
        widgets = _require("ipywidgets")
        self.head, self.view = head, view
        names = [c.name for c in CHANNELS] if channels is None else list(channels)
        unknown = [n for n in names if n not in CHANNEL_INDEX]
        if unknown:
            raise InputError(f"rig_sliders: unknown joint channel(s) {unknown}; names are '<joint>.<channel>' "
                             "of rig.parameters.CHANNELS")
        self._holding = False
        joint_style, expression_style = {"description_width": "9.5em"}, {"description_width": "11em"}
        self.joint_sliders: dict[str, Any] = {}
        for name in names:
            c = CHANNELS[CHANNEL_INDEX[name]]
            span = c.high - c.low
            self.joint_sliders[name] = widgets.FloatSlider(
                value=c.from_theta(float(head.theta[CHANNEL_INDEX[name]])), min=c.low, max=c.high,
                step=_nice_step(span), description=f"{c.kind} ({c.unit})", style=joint_style,
                continuous_update=continuous_update, readout_format=".3f" if c.is_scale else ".2f",
                layout=widgets.Layout(width="400px"))
        low, high = (x.numpy() for x in expression_limits(torch.float64))
        self.expression_sliders: dict[str, Any] = {}
        if expressions:
            for e, name in enumerate(EXPRESSION_NAMES):
                self.expression_sliders[name] = widgets.FloatSlider(
                    value=float(head.expressions[e]), min=float(low[e]), max=float(high[e]),
                    step=_nice_step(float(high[e] - low[e])), description=name, style=expression_style,
                    continuous_update=continuous_update, readout_format=".2f",
                    layout=widgets.Layout(width="400px"))
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
                tabs.append(widgets.Accordion(children=[widgets.VBox(s) for s in groups.values()],
                                              titles=tuple(groups),
                                              layout=widgets.Layout(max_height=height, overflow="auto")))
                titles.append(label)
        reset = widgets.Button(description="reset to the fit", icon="undo")
        reset.on_click(lambda _: self.reset())
        return widgets.VBox([reset, widgets.Tab(children=tabs, titles=tuple(titles))],
                            layout=widgets.Layout(width="470px", flex="0 0 470px"))

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
        if m * 10.0 ** exponent >= raw:
            return float(m * 10.0 ** exponent)
    return float(10.0 ** (exponent + 1))


def rig_sliders(head: PosableHead, view=None, *, channels: Iterable[str] | None = None,
                expressions: bool = True, continuous_update: bool = False) -> RigSliders:
    """``ipywidgets`` sliders that re-pose a fitted head and update its 3D view in place.

    Args:
        head: the :class:`PosableHead` (:func:`posable_head`).
        view: the :func:`head_view` to update (None: only :attr:`RigSliders.vertices` changes).
        channels: joint channels to offer by name (default all 105 of :data:`rig.parameters.CHANNELS`),
            grouped by joint; each slider is in the channel's unit (deg, mm, scale factor) within its limits.
        expressions: also a slider per ARKit shape (grouped by family: brow, eye, jaw, mouth, ...).
        continuous_update: re-pose while a slider is dragged (default: on release).

    Returns:
        :class:`RigSliders`; display it (or its ``widget``), e.g. ``ipywidgets.HBox([view, s.widget])``.

    Raises:
        InputError: an unknown channel name.
    """
    return RigSliders(head, view, channels=channels, expressions=expressions,
                      continuous_update=continuous_update)


# ----------------------------------------------------------------------------------------------------
# Loss curves
# ----------------------------------------------------------------------------------------------------

LM_COST = "LM cost ½|r|²"
"""The curve of a Levenberg-Marquardt stage (the landmark fit's default solver), which records its cost
after every accepted step (``metrics["lm_costs"]``) rather than each term per step."""


@dataclass(frozen=True)
class StageCurves:
    """The per-iteration record of one stage.

    Attributes:
        name: the stage's name. solver: ``adam`` (the engine: every weighted term per step) or ``lm``
            (Levenberg-Marquardt: its cost after each accepted step, one curve named :data:`LM_COST`).
        terms: curve name -> ``(N,)`` values in step order.
    """

    name: str
    solver: str
    terms: dict[str, np.ndarray]


def _stage_logs(fit) -> tuple:
    if isinstance(fit, Sequence):
        return tuple(fit)
    landmark = getattr(getattr(fit, "landmark_fit", None), "stages", ())
    stages = getattr(fit, "stages", None)
    if stages is None:
        raise InputError(f"loss_curves: expected a fit result with stages or a sequence of StageLog, "
                         f"got {type(fit).__name__}")
    return tuple(landmark) + tuple(stages)


def stage_curves(fit) -> list[StageCurves]:
    """Every recorded loss curve of a fit, stage by stage in the order they ran.

    Args:
        fit: a fit result (``fit_photo``'s: its landmark stages, then the photometric ones; ``fit_scan``,
            ``fit_landmarks``, a multi-view fit) or a sequence of
            :class:`pipeline.fitting.engine.StageLog`.

    Stages that kept no per-iteration record (0 steps, or a log made outside the engine without LM
    costs) are left out.
    """
    out = []
    for log in _stage_logs(fit):
        history = getattr(log, "history", None) or {}
        if history:
            out.append(StageCurves(log.name, "adam", {k: np.asarray(v, np.float64) for k, v in history.items()}))
        elif log.metrics.get("lm_costs"):
            out.append(StageCurves(log.name, "lm", {LM_COST: np.asarray(log.metrics["lm_costs"], np.float64)}))
    return out


def loss_curves(fit, *, columns: int = 3, title: str | None = None):
    """A ``matplotlib`` figure of every loss term per iteration, one panel per stage (log y).

    Args:
        fit: as :func:`stage_curves`.
        columns: panels per row. title: the figure's title.

    Returns:
        ``matplotlib.figure.Figure`` (made without pyplot): one axes per stage, titled with the stage's
        name and solver, one line per term labelled with the term's name (x: step, y: the weighted term as
        the objective minimised it at that step). A term has one colour in every panel; one legend below
        the panels names them, marking terms that are 0 throughout (a log axis cannot draw 0).

    Raises:
        InputError: nothing to draw (no stage kept a per-iteration record).
    """
    figure_module = _require("matplotlib.figure")
    ticker = _require("matplotlib.ticker")
    curves = stage_curves(fit)
    if not curves:
        raise InputError("loss_curves: no stage of this fit recorded its losses per iteration")
    names = list(dict.fromkeys(name for stage in curves for name in stage.terms))
    zero = {name for name in names
            if all(not np.any(stage.terms[name]) for stage in curves if name in stage.terms)}
    palette = [f"C{i}" for i in (0, 1, 2, 3, 4, 5, 6, 8, 9)] + ["black", "#1b4965", "#9d0208", "#386641", "#6a4c93"]
    drawn = [name for name in names if name not in zero]
    colour = {name: palette[i % len(palette)] for i, name in enumerate(drawn)} | dict.fromkeys(zero, "0.6")
    cols = max(1, min(columns, len(curves)))
    rows = -(-len(curves) // cols)
    legend_rows = -(-len(names) // 6)
    fig = figure_module.Figure(figsize=(4.4 * cols, 3.0 * rows + 0.3 * legend_rows + (0.4 if title else 0.0)),
                               layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    handles = {}
    plain = ticker.FormatStrFormatter("%g")
    for ax, stage in zip(axes.flat, curves):
        for name, values in stage.terms.items():
            line, = ax.plot(np.arange(len(values)), values, label=name, color=colour[name],
                            marker="o" if len(values) < 12 else None, markersize=3, linewidth=1.4)
            handles.setdefault(name, line)
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(plain)
        low, high = ax.get_ylim()
        # within one decade the major ticks are too few to read: label the minor ones too
        ax.yaxis.set_minor_formatter(plain if 0 < low and high < 10 * low else ticker.NullFormatter())
        ax.xaxis.set_major_locator(ticker.MaxNLocator(integer=True))
        solver = "Adam" if stage.solver == "adam" else "Levenberg-Marquardt"
        ax.set_title(f"{stage.name} ({solver})", fontsize=10)
        ax.set_xlabel("accepted step" if stage.solver == "lm" else "step", fontsize=9)
        ax.tick_params(labelsize=8, which="both")
        ax.grid(True, which="major", alpha=0.3)
    for ax in list(axes.flat)[len(curves):]:
        ax.set_visible(False)
    fig.legend([handles[n] for n in names], [f"{n} (0 throughout)" if n in zero else n for n in names],
               loc="outside lower center", ncols=min(6, len(names)), fontsize=8, frameon=False)
    if title:
        fig.suptitle(title)
    return fig
