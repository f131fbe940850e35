"""Still pictures of a mesh (docs, demo, previews) with Mitsuba 3; not differentiable.

The camera looks at the head from a named view; the mesh comes in as arrays (mm, rig space), the
picture goes out as an ``(H, W, 3)`` uint8 array. Uses Mitsuba's ``scalar_rgb`` variant, which needs no
libLLVM, so previews work on any machine where the ``mitsuba`` wheel installs.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from render.errors import RenderArgumentError

VIEWS = {
    # name: (yaw degrees, pitch degrees); yaw 0 looks at the face, +90 at the subject's left side.
    "front": (0.0, 0.0),
    "three_quarter": (40.0, 5.0),
    "side": (90.0, 0.0),
    "back": (180.0, 0.0),
}


def _mitsuba():
    import mitsuba as mi  # imported here: render/ is the only package that touches Mitsuba

    # Always scalar_rgb (needs no libLLVM), even where the differentiable renderer has made llvm_ad_rgb
    # current; render_preview restores the caller's variant afterwards.
    if mi.variant() != "scalar_rgb":
        mi.set_variant("scalar_rgb")
    return mi


def _current_variant():
    import mitsuba as mi

    return mi.variant()


def render_preview(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    colors: np.ndarray | None = None,
    view: str = "front",
    yaw: float | None = None,
    pitch: float | None = None,
    size: tuple[int, int] = (512, 640),
    spp: int = 16,
    distance: float = 900.0,
    fov: float = 22.0,
    target: tuple[float, float, float] = (0.0, -30.0, 0.0),
    markers: np.ndarray | None = None,
    marker_radius: float = 2.5,
    marker_color: tuple[float, float, float] = (0.9, 0.1, 0.1),
) -> np.ndarray:
    """Render a shaded picture of a mesh.

    Args:
        vertices: ``(V, 3)`` mm, rig space (+Y up, +Z out of the face).
        faces: ``(F, 3)`` vertex indices.
        colors: optional ``(V, 3)`` linear RGB in [0, 1] per vertex; a skin tone when omitted.
        view: one of :data:`VIEWS` (ignored where ``yaw``/``pitch`` are given).
        size: ``(width, height)`` in pixels.
        spp: samples per pixel.
        distance: camera distance from ``target`` in mm; ``fov``: horizontal field of view in degrees.
        markers: optional ``(N, 3)`` points (mm) drawn as small spheres (e.g. joints), seen through the
            mesh, which is then drawn half-transparent.

    Returns:
        ``(H, W, 3)`` uint8 sRGB image.
    """
    previous = _current_variant()
    try:
        return _render_preview(
            vertices,
            faces,
            colors=colors,
            view=view,
            yaw=yaw,
            pitch=pitch,
            size=size,
            spp=spp,
            distance=distance,
            fov=fov,
            target=target,
            markers=markers,
            marker_radius=marker_radius,
            marker_color=marker_color,
        )
    finally:
        if previous is not None and previous != "scalar_rgb":
            import mitsuba as mi

            mi.set_variant(previous)


def _render_preview(
    vertices, faces, *, colors, view, yaw, pitch, size, spp, distance, fov, target, markers, marker_radius, marker_color
) -> np.ndarray:
    mi = _mitsuba()
    vertices = np.asarray(vertices, np.float32)
    faces = np.asarray(faces, np.uint32)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise RenderArgumentError(
            f"render_preview: expected vertices (V, 3) and faces (F, 3), got {vertices.shape}, {faces.shape}"
        )
    base_yaw, base_pitch = VIEWS[view]
    yaw = base_yaw if yaw is None else yaw
    pitch = base_pitch if pitch is None else pitch

    if colors is None:
        colors = np.broadcast_to(np.array([0.80, 0.58, 0.47], np.float32), vertices.shape)
    used = np.unique(faces)  # only the drawn vertices (unreferenced ones would get invalid normals)
    if len(used) < len(vertices):
        remap = np.zeros(len(vertices), np.uint32)
        remap[used] = np.arange(len(used), dtype=np.uint32)
        vertices, colors, faces = vertices[used], np.asarray(colors)[used], remap[faces]
    props = mi.Properties()
    skin = {"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}}
    if markers is not None:  # see the joints inside the head
        skin = {"type": "blendbsdf", "weight": 0.55, "bsdf_0": skin, "bsdf_1": {"type": "null"}}
    props["bsdf"] = mi.load_dict(skin)
    mesh = mi.Mesh(
        "head",
        vertex_count=len(vertices),
        face_count=len(faces),
        props=props,
        has_vertex_normals=True,
        has_vertex_texcoords=False,
    )
    mesh.add_attribute("vertex_color", 3, np.asarray(colors, np.float32).ravel().tolist())
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.ascontiguousarray(vertices.ravel()).tolist()
    params["faces"] = np.ascontiguousarray(faces.ravel()).tolist()
    params.update()
    mesh.recompute_vertex_normals()

    ty, tp = math.radians(yaw), math.radians(pitch)
    direction = np.array([math.sin(ty) * math.cos(tp), math.sin(tp), math.cos(ty) * math.cos(tp)])
    target_arr = np.asarray(target, float)
    origin = target_arr + distance * direction
    key_dir = -np.array([0.55, 0.65, 0.5]) if yaw < 90 else -np.array([-0.3, 0.6, 0.75])
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 8} if markers is not None else {"type": "direct"},
            "sensor": {
                "type": "perspective",
                "fov": fov,
                "fov_axis": "x",
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=origin.tolist(), target=target_arr.tolist(), up=[0, 1, 0]
                ),
                "film": {"type": "hdrfilm", "width": int(size[0]), "height": int(size[1]), "pixel_format": "rgb"},
                "sampler": {"type": "independent", "sample_count": int(spp)},
            },
            "key": {"type": "directional", "direction": key_dir.tolist(), "irradiance": {"type": "rgb", "value": 2.4}},
            "fill": {"type": "constant", "radiance": {"type": "rgb", "value": [0.30, 0.32, 0.36]}},
            "head": mesh,
            **_marker_shapes(mi, markers, marker_radius, marker_color),
        }
    )
    image = np.asarray(mi.render(scene, spp=int(spp)))
    srgb = np.where(image <= 0.0031308, 12.92 * image, 1.055 * np.power(np.clip(image, 0, None), 1 / 2.4) - 0.055)
    return (np.clip(srgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _marker_shapes(mi, markers, radius, color) -> dict:
    if markers is None:
        return {}
    bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(color)}}
    return {
        f"marker_{i}": {"type": "sphere", "center": [float(c) for c in p], "radius": float(radius), "bsdf": bsdf}
        for i, p in enumerate(np.asarray(markers, float))
    }


def save_png(image: np.ndarray, path: str | Path) -> None:
    """Write an ``(H, W, 3)`` uint8 image as PNG."""
    from PIL import Image

    Image.fromarray(np.asarray(image, np.uint8)).save(str(path))
