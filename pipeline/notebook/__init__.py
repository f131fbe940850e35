"""Interactive pieces for the notebooks: a 3D view of a fitted head, sliders that re-pose it by name, and
the loss curves of a fit, one panel per stage.

* :func:`~pipeline.notebook.head.posable_head`: a fit's :class:`pipeline.head.fitted.FittedHead` (its
  skinning weights from the latent Z, joint channels, expression coefficients), so that
  :meth:`FittedHead.pose <pipeline.head.fitted.FittedHead.pose>` rebuilds it for any joint values and ARKit
  coefficients exactly as the rig's forward pass does (:class:`rig.model.JointRig`, float64).
* :func:`~pipeline.notebook.view.head_view`: the head as a ``plotly`` ``FigureWidget`` (a ``Mesh3d`` in rig
  space, mm, +Y up, seen from the front, a little from the subject's left and above);
  :func:`~pipeline.notebook.view.update_head_view` replaces its vertices in place.
* :func:`~pipeline.notebook.sliders.rig_sliders`: ``ipywidgets`` sliders for the joint channels (by name,
  within their limits) and the 52 ARKit shapes; moving one re-poses the head and updates the view
  (:class:`~pipeline.notebook.sliders.RigSliders`).
* :func:`~pipeline.notebook.curves.stage_curves` / :func:`~pipeline.notebook.curves.loss_curves`: every
  loss term per iteration of every stage of a fit (``matplotlib``, log y).
* :func:`~pipeline.notebook.embed.picture` / :func:`~pipeline.notebook.embed.viewer_frame`: what a saved
  notebook keeps: one JPEG or PNG per picture (a PIL image displayed as such is stored twice), and a fit's
  ``viewer.html`` (three.js and the head in one file, :mod:`pipeline.viewer`) in an ``<iframe>`` whose
  address is relative to the notebook, so that the saved 3D view is one line, works offline and needs no
  widget state (``IPython`` and ``PIL``, which a kernel has).

``plotly``, ``ipywidgets`` and ``matplotlib`` are imported only by the functions that draw (the
``notebook`` extra: ``pip install -e ".[notebook]"``, :mod:`pipeline.notebook.extra`); importing this
package needs none of them, and no Jupyter: the callbacks are plain methods that tests drive by setting
slider values.
"""
