"""The data of a ``viewer.html`` page (:mod:`pipeline.viewer` writes it): :func:`viewer_payload` gathers the
fitted head into one JSON-ready dict, a section at a time (the mesh and its UVs, the skinning, the joints and
channels, the expressions, the photos and cameras, the "Save pose" file), with the arrays base64-encoded
(:func:`encode_array`) and the images as JPEG ``data:`` URLs."""

from __future__ import annotations

import base64
import io
from dataclasses import dataclass

import numpy as np

from rig.expressions import EXPRESSION_NAMES, EXPRESSIONS, JAW_ANGLE_DEG, JAW_INDEX, ExpressionModel, jaw_pivot
from rig.io.params import PARAMS_UNITS
from rig.joints import CHANNEL_KINDS
from rig.parameters import CHANNELS, NUM_PARAMETERS

SAVE_FILE = "params_edited.json"
"""The name the page's "Save pose" button downloads its parameter file as."""
VIEWER_FORMAT = "jnr-viewer/1"
PHOTO_MAX_SIDE = 1280
"""Photos are embedded reduced to this longer side (pixels); the camera does not change with it."""
TEXTURE_MAX_SIDE = 1024
JPEG_QUALITY = 88
SAMPLE_VERTICES = 24
"""How many vertices the page reports in its ``#jnr-state`` check (all of them with ``#state=all``)."""
_DTYPES = {"float32": np.float32, "uint8": np.uint8, "uint16": np.uint16, "uint32": np.uint32}


class ViewerError(ValueError):
    """Bad arguments to :func:`pipeline.viewer.write_viewer` (a programming error, not a user's input)."""


@dataclass(frozen=True)
class ViewerView:
    """One photo of a fit and its camera.

    Attributes:
        name: shown in the page's view menu (e.g. the photo's file name).
        camera: ``params.json``'s ``camera`` entry: ``width``, ``height`` (pixels), ``focal_px``,
            ``principal_point_px`` ``[cx, cy]`` (OpenCV, 0-based), ``extrinsics_rig_to_camera`` ``(4, 4)``
            (``x_cam = E @ [x_rig, 1]``, OpenCV axes: x right, y down, z forward).
        photo: ``(H, W, 3)`` uint8 sRGB, the photo as the camera sees it (any size with the camera's aspect:
            a photo fitted reduced is shown with the camera of the full-size file), or None.
        expressions: ``(E,)`` this view's ARKit coefficients (multi-view fits), None: the head's.
    """

    name: str
    camera: dict
    photo: np.ndarray | None = None
    expressions: np.ndarray | None = None


def encode_array(array: np.ndarray, dtype: str) -> dict:
    """``{"dtype", "shape", "b64"}``: ``array`` as little-endian ``dtype`` bytes in base64 (the page decodes
    it into a typed array)."""
    a = np.ascontiguousarray(np.asarray(array).astype(np.dtype(_DTYPES[dtype]).newbyteorder("<")))
    return {"dtype": dtype, "shape": list(a.shape), "b64": base64.b64encode(a.tobytes()).decode("ascii")}


def decode_array(entry: dict | None) -> np.ndarray | None:
    """The inverse of :func:`encode_array` (None stays None)."""
    if entry is None:
        return None
    dtype = np.dtype(_DTYPES[entry["dtype"]]).newbyteorder("<")
    return np.frombuffer(base64.b64decode(entry["b64"]), dtype=dtype).reshape(entry["shape"])


def _jpeg_data_url(image: np.ndarray, max_side: int) -> str:
    from PIL import Image

    im = Image.fromarray(np.ascontiguousarray(np.asarray(image, np.uint8)[..., :3]))
    if max(im.size) > max_side:
        scale = max_side / max(im.size)
        im = im.resize((max(1, round(im.width * scale)), max(1, round(im.height * scale))), Image.LANCZOS)
    buffer = io.BytesIO()
    im.save(buffer, format="JPEG", quality=JPEG_QUALITY)
    return "data:image/jpeg;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _top4(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(joints (V, 4) int, weights (V, 4), largest dropped weight)``: each vertex's 4 largest weights,
    renormalised to sum 1 when any was dropped."""
    w = np.asarray(weights, np.float64)
    order = np.argsort(-w, axis=1, kind="stable")[:, :4]
    top = np.take_along_axis(w, order, 1)
    dropped = float(np.sort(w, axis=1)[:, :-4].max()) if w.shape[1] > 4 else 0.0
    if dropped > 0:
        top = top / top.sum(1, keepdims=True)
    top[top <= 0] = 0.0
    return order, top, dropped


def _render_vertices(asset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices split where the UVs are (seams): ``(render_vertex (R,), faces (F, 3) into them, uv (R, 2))``."""
    corners_v = np.asarray(asset.faces, np.int64).reshape(-1)
    corners_uv = np.asarray(asset.face_uvs, np.float64).reshape(-1, 2)
    keys = np.column_stack([corners_v.astype(np.float64), corners_uv])
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    return unique[:, 0].astype(np.int64), inverse.reshape(-1, 3), unique[:, 1:]


def _checked_head(asset, theta, expressions, weights, latent_z) -> tuple[np.ndarray, ...]:
    """``(theta, coefficients, weights, latent_z)`` as float64 arrays (theta and coefficients zeros when
    None, the asset's weights when None), checked against the asset."""
    from rig.skinning.neural import LATENT

    n_vertices, n_joints = len(asset.vertices), len(asset.joint_names)
    parents = np.asarray(asset.parents, np.int64)
    if any(p >= k for k, p in enumerate(parents)):
        raise ViewerError("viewer_payload: the joints must be ordered parents first")
    theta = np.zeros(NUM_PARAMETERS) if theta is None else np.asarray(theta, np.float64).reshape(-1)
    coefficients = np.zeros(len(EXPRESSION_NAMES)) if expressions is None else np.asarray(expressions, np.float64)
    if theta.shape != (NUM_PARAMETERS,):
        raise ViewerError(f"viewer_payload: theta must have shape ({NUM_PARAMETERS},), got {theta.shape}")
    if coefficients.shape != (len(EXPRESSION_NAMES),):
        raise ViewerError(
            f"viewer_payload: expressions must have shape ({len(EXPRESSION_NAMES)},), got {coefficients.shape}"
        )
    weights = asset.weights if weights is None else np.asarray(weights, np.float64)
    if weights.shape != (n_vertices, n_joints):
        raise ViewerError(f"viewer_payload: weights must have shape ({n_vertices}, {n_joints}), got {weights.shape}")
    if latent_z is not None:
        latent_z = np.asarray(latent_z, np.float64).reshape(-1)
        if latent_z.shape != (LATENT,) or not np.isfinite(latent_z).all():
            raise ViewerError(f"viewer_payload: latent_z must be ({LATENT},) finite values, got {latent_z.shape}")
    if n_joints > 255 or n_vertices >= 2**16:
        raise ViewerError(f"viewer_payload: at most 255 joints and 65535 vertices, got {n_joints} and {n_vertices}")
    return theta, coefficients, weights, latent_z


def _checked_mesh(n_vertices: int, static_vertices, vertex_colors) -> np.ndarray | None:
    """``static_vertices`` as float64 (or None), both arrays checked to have one row per vertex."""
    if static_vertices is not None:
        static_vertices = np.asarray(static_vertices, np.float64)
        if static_vertices.shape != (n_vertices, 3):
            raise ViewerError(
                f"viewer_payload: static_vertices must have shape ({n_vertices}, 3), got {static_vertices.shape}"
            )
    if vertex_colors is not None and np.shape(vertex_colors) != (n_vertices, 3):
        raise ViewerError(
            f"viewer_payload: vertex_colors must have shape ({n_vertices}, 3), got {np.shape(vertex_colors)}"
        )
    return static_vertices


def _expression_entries(asset, coefficients: np.ndarray) -> dict:
    """``expressions`` (names, limits, values), ``morph`` (the 52 shapes' non-zero rows: vertex, offset)
    and ``jaw`` (the ``jawOpen`` hinge) of :class:`rig.expressions.ExpressionModel`."""
    import torch

    model = ExpressionModel(asset, dtype=torch.float64)
    basis = model.basis.numpy()  # (E, V, 3); jawOpen: its corrective
    rows = [np.flatnonzero(np.any(basis[e] != 0, axis=1)) for e in range(len(basis))]
    jaw_weight = model.jaw_weight.numpy()
    jaw_rows = np.flatnonzero(jaw_weight != 0)
    return {
        "expressions": {
            "names": list(EXPRESSION_NAMES),
            "low": [float(s.low) for s in EXPRESSIONS],
            "high": [float(s.high) for s in EXPRESSIONS],
            "values": [float(x) for x in coefficients],
        },
        "morph": {
            "counts": [len(r) for r in rows],
            "index": encode_array(np.concatenate(rows), "uint16"),
            "offsets": encode_array(np.concatenate([basis[e, r] for e, r in enumerate(rows)]), "float32"),
        },
        "jaw": {
            "expression": int(JAW_INDEX),
            "angle_deg": float(JAW_ANGLE_DEG),
            "pivot": [float(x) for x in jaw_pivot(asset)],
            "index": encode_array(jaw_rows, "uint16"),
            "weight": encode_array(jaw_weight[jaw_rows], "float32"),
        },
    }


def _seam_entries(asset) -> dict:
    """The triangles over the vertices split at UV seams (:func:`_render_vertices`), and their UVs."""
    render_vertex, render_faces, uv = _render_vertices(asset)
    return {
        "render_vertex": encode_array(render_vertex, "uint16"),
        "faces": encode_array(render_faces, "uint16" if len(render_vertex) < 2**16 else "uint32"),
        "uv": encode_array(uv, "float32"),
    }


def _channel_entries(theta: np.ndarray) -> list[dict]:
    """The 107 channels: joint, kind, limits, unit and fitted value (:mod:`rig.parameters`)."""
    return [
        {
            "name": c.name,
            "joint": int(c.joint),
            "kind": CHANNEL_KINDS.index(c.kind),
            "low": float(c.low),
            "high": float(c.high),
            "unit": c.unit,
            "value": float(c.from_theta(t)),
        }
        for c, t in zip(CHANNELS, theta)
    ]


def _view_entries(views, texture: np.ndarray | None) -> tuple[dict, list[dict]]:
    """``(images, views)``: the ``<img>`` id -> ``data:`` URL of each photo and of the texture
    (:func:`pipeline.viewer.render_html` writes them as elements of the page), and each view's entry."""
    images = {}
    view_entries = []
    for k, view in enumerate(views):
        cam = view.camera
        if view.photo is not None:
            images[f"jnr-photo-{k}"] = _jpeg_data_url(view.photo, PHOTO_MAX_SIDE)
        entry = {
            "name": view.name,
            "photo": None if view.photo is None else f"jnr-photo-{k}",
            "camera": {
                "width": float(cam["width"]),
                "height": float(cam["height"]),
                "focal_px": float(cam["focal_px"]),
                "principal_point_px": [float(x) for x in cam["principal_point_px"]],
                "extrinsics_rig_to_camera": np.asarray(cam["extrinsics_rig_to_camera"], float).tolist(),
            },
            "expressions": None if view.expressions is None else [float(x) for x in view.expressions],
        }
        view_entries.append(entry)
    if texture is not None:
        images["jnr-texture"] = _jpeg_data_url(texture, TEXTURE_MAX_SIDE)
    return images, view_entries


def viewer_payload(
    asset,
    *,
    theta: np.ndarray | None = None,
    expressions: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    latent_z: np.ndarray | None = None,
    views: tuple[ViewerView, ...] | list = (),
    texture: np.ndarray | None = None,
    vertex_colors: np.ndarray | None = None,
    static_vertices: np.ndarray | None = None,
    title: str = "jnr fit",
    subtitle: str = "",
) -> tuple[dict, float]:
    """The data of a page (:mod:`pipeline.viewer`'s docstring) and the largest skinning weight left out.

    Args:
        asset: the fit's :class:`rig.asset.RigAsset` (template, faces, UVs, joints).
        theta: ``(P,)`` fitted channels (deg, mm, ``scale - 1``; :mod:`rig.parameters`); None: rest.
        expressions: ``(E,)`` fitted ARKit coefficients; None: zeros.
        weights: ``(V, K)`` the fit's skinning weights (its latent Z's); None: the asset's.
        latent_z: ``(50,)`` the fit's latent Z (the one ``weights`` were decoded from), or None. With it the
            page's "Save pose" writes a whole head (joints, latent Z, expressions: what a fit's ``params.json``
            holds for ``jnr rig edit``); without it the joint channels only.
        views: the photos and cameras (none: an orbit view only).
        texture: ``(T, T, 3)`` uint8 sRGB texture in the asset's UVs, or None.
        vertex_colors: ``(V, 3)`` uint8 sRGB, used when there is no texture, or None.
        static_vertices: ``(V, 3)`` mm: show this mesh (an ASM fit's, with ``expressions`` applied) instead
            of posing the rig; the page then has expression sliders only.
        title, subtitle: shown in the page.

    Raises:
        ViewerError: arrays of the wrong shape.
    """
    theta, coefficients, weights, latent_z = _checked_head(asset, theta, expressions, weights, latent_z)
    skin_joints, skin_weights, dropped = _top4(weights)
    expression_entries = _expression_entries(asset, coefficients)
    seam_entries = _seam_entries(asset)
    channels = _channel_entries(theta)
    n_vertices = len(asset.vertices)
    static_vertices = _checked_mesh(n_vertices, static_vertices, vertex_colors)
    static = static_vertices is not None
    images, view_entries = _view_entries(views, texture)
    head = static_vertices if static else np.asarray(asset.vertices, np.float64)
    data = {
        "format": VIEWER_FORMAT,
        "title": title,
        "subtitle": subtitle,
        "mode": "static" if static else "rig",
        "vertex_count": n_vertices,
        "template": encode_array(asset.vertices, "float32"),
        "base": encode_array(static_vertices, "float32") if static else None,
        "base_expressions": [float(x) for x in coefficients] if static else None,
        **seam_entries,
        "skin_joints": encode_array(skin_joints, "uint8"),
        "skin_weights": encode_array(skin_weights, "float32"),
        "joints": {
            "names": list(asset.joint_names),
            "parents": np.asarray(asset.parents, np.int64).tolist(),
            "bind": np.asarray(asset.joint_positions, np.float64).tolist(),
        },
        "channels": [] if static else channels,
        **expression_entries,
        "colors": None if vertex_colors is None or texture is not None else encode_array(vertex_colors, "uint8"),
        "texture": None if texture is None else "jnr-texture",
        "images": images,
        "views": view_entries,
        "head_centre": [float(x) for x in (head.min(0) + head.max(0)) / 2],
        "sample_vertices": np.linspace(0, n_vertices - 1, SAMPLE_VERTICES).round().astype(int).tolist(),
        # the Save button's parameter file: its name, units, model and the head's latent Z
        "save": {
            "file": SAVE_FILE,
            "units": dict(PARAMS_UNITS),
            "model": "jnr",
            "latent_z": None if static or latent_z is None else [float(x) for x in latent_z],
        },
    }
    return data, dropped
