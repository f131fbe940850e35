"""The interactive 3D view of a head: a ``plotly`` ``FigureWidget`` with one ``Mesh3d`` (:func:`head_view`),
updated in place (:func:`update_head_view`)."""

from __future__ import annotations

import numpy as np

from pipeline.head.fitted import FittedHead
from pipeline.notebook.extra import require
from rig.errors import InputError, check_shape

SKIN_SRGB = (0.80, 0.67, 0.58)
"""The view's colour when the head has no albedo (sRGB, [0, 1])."""


def head_view(
    head: FittedHead | np.ndarray,
    faces: np.ndarray | None = None,
    *,
    colours=None,
    height: int = 520,
    width: int | None = None,
    title: str | None = None,
):
    """An interactive 3D view of a head: a ``plotly.graph_objects.FigureWidget`` with one ``Mesh3d``.

    Args:
        head: a :class:`FittedHead` (its ``vertices``, ``faces`` and ``colours``), or ``(V, 3)`` vertices
            in rig space, mm.
        faces: ``(F, 3)`` triangles (only with vertices).
        colours: ``(V, 3)`` sRGB in [0, 1] per vertex (default: the head's, else a uniform skin tone).
        height, width: pixels (width default: ``height``, leaving room for
            :func:`~pipeline.notebook.sliders.rig_sliders` beside it).
        title: above the view.

    Rig axes are the plot's (mm): +X the subject's left, +Y up, +Z out of the face; the camera looks at
    the face from the front, a little from the subject's left (+X) and above, with +Y up; the aspect ratio
    is the data's. Drag to orbit, scroll to zoom. The vertex data stays float64 (``view.data[0].x``, ...).
    """
    go = require("plotly.graph_objects")
    if isinstance(head, FittedHead):
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
    mesh = dict(
        x=v[:, 0],
        y=v[:, 1],
        z=v[:, 2],
        i=f[:, 0],
        j=f[:, 1],
        k=f[:, 2],
        flatshading=False,
        hoverinfo="skip",
        name="head",
        lighting=dict(ambient=0.45, diffuse=0.75, specular=0.15, roughness=0.7, fresnel=0.05),
        lightposition=dict(x=400, y=600, z=1500),
    )
    if colours is not None:
        rgb = np.clip(np.round(np.asarray(colours, np.float64) * 255.0), 0, 255).astype(int)
        check_shape(rgb.shape == v.shape, "head_view", "colours", f"({len(v)}, 3)", rgb.shape)
        mesh["vertexcolor"] = [f"rgb({r},{g},{b})" for r, g, b in rgb]
    else:
        mesh["color"] = "rgb({},{},{})".format(*(round(255 * c) for c in SKIN_SRGB))
    hidden = dict(visible=False, showbackground=False)
    layout = dict(
        height=height,
        width=height if width is None else width,
        margin=dict(l=0, r=0, t=30 if title else 0, b=0),
        title=dict(text=title) if title else None,
        scene=dict(
            aspectmode="data",
            xaxis=hidden,
            yaxis=hidden,
            zaxis=hidden,
            camera=dict(up=dict(x=0, y=1, z=0), eye=dict(x=0.75, y=0.2, z=1.45), projection=dict(type="perspective")),
            dragmode="orbit",
        ),
        uirevision="head",
    )  # keep the user's camera when the vertices change
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


__all__ = ["SKIN_SRGB", "head_view", "update_head_view"]
