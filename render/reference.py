"""Reference renderer for synthetic test photos: Mitsuba 3 path tracing, not differentiable.

Fitting a model to images rendered by the very renderer used for the fit (same light model, same
integrator, same noise) is an *inverse crime*: it hides the model's mismatch with real photos. This
renderer deliberately differs from :class:`render.renderer.DifferentiableRenderer` (ambient rendered as
emission + one directional light, ``direct_projective``, no occlusion of the ambient term):

- the light is a **point light** (irradiance falling off with the square of the distance, direction
  varying over the face) plus a **constant environment** (sky dome) that is occluded by the head itself
  (soft shadows in the eye sockets, under the nose and chin);
- the ``path`` integrator with ``max_depth = 3`` adds one bounce of interreflection;
- the environment is hidden from the camera, so the head is composited over a background image, with
  anti-aliased edges (coverage fraction from the film's alpha channel).

Frames and units: the mesh is in the world frame of the kornia ``PinholeCamera`` (OpenCV convention,
mm; :func:`render.camera.sensor_from_pinhole` converts it exactly), the light's position too.
Colours are linear RGB.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from render.backend import resolve_variant, use_variant
from render.camera import sensor_from_pinhole
from render.errors import RenderArgumentError
from render.renderer import weld_vertices

__all__ = ["ReferenceLight", "ReferenceRender", "render_reference"]


def _vector3(value, name: str, *, non_negative: bool) -> tuple[float, float, float]:
    arr = np.asarray(value.detach().cpu().numpy() if hasattr(value, "detach") else value, dtype=np.float64)
    if arr.shape != (3,):
        raise RenderArgumentError(f"ReferenceLight: expected {name} of shape (3,), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise RenderArgumentError(f"ReferenceLight: {name} must be finite, got {arr.tolist()}")
    if non_negative and (arr < 0).any():
        raise RenderArgumentError(f"ReferenceLight: {name} must be >= 0, got {arr.tolist()}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


@dataclass(frozen=True)
class ReferenceLight:
    """A point light plus a constant environment (Mitsuba ``point`` + ``constant`` emitters).

    A Lambertian point of albedo ``a`` (linear RGB), unit normal ``n``, at distance ``r`` from the light
    and direction ``l`` towards it, receives the direct radiance ``a / pi * intensity / r^2 *
    max(0, n . l) * visible`` plus, from the environment, ``a * environment * (unoccluded fraction of the
    cosine-weighted hemisphere)`` (and one bounce of interreflection).

    Attributes:
        position: ``(3,)`` the point light's position, world frame of the camera (mm).
        intensity: ``(3,)`` linear RGB radiant intensity (W/sr, with mm as the length unit): the
            irradiance ``intensity / r^2`` on a surface facing the light from ``r`` mm is comparable with
            :class:`render.lighting.Lighting`'s ``irradiance`` (e.g. ``2.0 * 800.0 ** 2`` at 800 mm).
        environment: ``(3,)`` linear RGB radiance of the constant environment (a surface of albedo ``a``
            open to the whole sky reflects ``a * environment``).

    Fields are stored as tuples of floats (any ``(3,)`` array-like is accepted); negative intensities
    or radiances and non-finite values raise ``ValueError``.

    Example:
        >>> light = ReferenceLight(position=(300.0, 400.0, 900.0), intensity=(2.0e6,) * 3,
        ...                        environment=(0.3, 0.3, 0.3))
        >>> light.environment
        (0.3, 0.3, 0.3)
    """

    position: tuple[float, float, float]
    intensity: tuple[float, float, float]
    environment: tuple[float, float, float]

    def __post_init__(self):
        object.__setattr__(self, "position", _vector3(self.position, "position", non_negative=False))
        object.__setattr__(self, "intensity", _vector3(self.intensity, "intensity", non_negative=True))
        object.__setattr__(self, "environment", _vector3(self.environment, "environment", non_negative=True))

    def to_dict(self) -> dict[str, list[float]]:
        """JSON-ready ``{"position": [x, y, z], "intensity": [r, g, b], "environment": [r, g, b]}``."""
        return {
            "position": list(self.position),
            "intensity": list(self.intensity),
            "environment": list(self.environment),
        }


@dataclass(frozen=True)
class ReferenceRender:
    """What :func:`render_reference` returns (``H``, ``W``: the camera's image size in pixels).

    Attributes:
        image: ``(H, W, 3)`` float32 linear RGB, the head composited over the background
            (``head + (1 - mask) * background``); may exceed 1 in highlights.
        mask: ``(H, W)`` float32 coverage: the fraction of the pixel's samples that hit the mesh, in
            [0, 1] (1 inside the head, fractional along its outline, 0 on the background).
    """

    image: np.ndarray
    mask: np.ndarray


def _as_array(x, dtype) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=dtype)


def _check_inputs(
    vertices, faces, albedo, background, spp: int, max_depth: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    func = "render_reference"
    v = _as_array(vertices, np.float64)
    f = _as_array(faces, None)
    if not np.issubdtype(f.dtype, np.integer):
        raise RenderArgumentError(f"{func}: expected faces an integer array (F, 3), got dtype {f.dtype}")
    f = f.astype(np.int64)
    a = _as_array(albedo, np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise RenderArgumentError(f"{func}: expected vertices of shape (V, 3), got {v.shape}")
    if not np.isfinite(v).all():
        raise RenderArgumentError(f"{func}: vertices must be finite")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise RenderArgumentError(f"{func}: expected faces of shape (F, 3), got {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        raise RenderArgumentError(f"{func}: face indices must lie in [0, {len(v)}), got [{f.min()}, {f.max()}]")
    if a.shape != v.shape:
        raise RenderArgumentError(
            f"{func}: expected albedo of shape {v.shape} (one linear RGB per vertex), got {a.shape}"
        )
    if not np.isfinite(a).all():
        raise RenderArgumentError(f"{func}: albedo must be finite")
    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
        raise RenderArgumentError(f"{func}: expected spp an integer >= 1, got {spp!r}")
    if isinstance(max_depth, bool) or not isinstance(max_depth, (int, np.integer)) or max_depth < 2:
        raise RenderArgumentError(
            f"{func}: expected max_depth an integer >= 2 (2: direct light only), got {max_depth!r}"
        )
    bg = None if background is None else _as_array(background, np.float64)
    return v, f, a, bg


def render_reference(
    vertices,
    faces,
    albedo,
    camera,
    light: ReferenceLight,
    *,
    spp: int = 64,
    seed: int = 0,
    background=None,
    max_depth: int = 3,
    device: str = "cpu",
) -> ReferenceRender:
    """Path-trace a vertex-coloured Lambertian mesh under a point light and a constant environment.

    Coincident vertices are welded first (mean albedo), so meshes split along UV seams shade without
    seams; vertex normals are recomputed from the (welded) mesh. The Mitsuba variant current before the
    call (if any) is current again afterwards.

    Args:
        vertices: ``(V, 3)`` mm, world frame of ``camera`` (numpy or torch; gradients are not tracked).
        faces: ``(F, 3)`` integer vertex indices, counter-clockwise seen from outside (the diffuse
            material is one-sided: back faces are black).
        albedo: ``(V, 3)`` linear RGB reflectance per vertex, normally in [0, 1].
        camera: ``kornia.geometry.camera.PinholeCamera``, batch 1, OpenCV convention (world -> camera
            extrinsics in mm, intrinsics in pixels, square pixels, no skew); the image is
            ``camera.height x camera.width`` pixels.
        light: :class:`ReferenceLight` (position in the same world frame, mm).
        spp: samples per pixel (Monte Carlo noise falls as ``1 / sqrt(spp)``).
        seed: sampler seed; the same inputs and seed give the same image.
        background: ``(H, W, 3)`` linear RGB image behind the head, or None (black).
        max_depth: longest light path (Mitsuba convention: 2 = direct light only, 3 = one bounce).
        device: ``"cpu"`` (``llvm_ad_rgb``) or ``"cuda"`` (``cuda_ad_rgb``); see
            :func:`render.backend.resolve_variant`.

    Returns:
        :class:`ReferenceRender` with ``image`` ``(H, W, 3)`` and ``mask`` ``(H, W)``, float32.

    Raises:
        ValueError: bad shapes (received shape named), indices out of range, non-finite values,
            ``spp < 1``, a background whose size is not the camera's, or a camera
            :func:`render.camera.sensor_from_pinhole` refuses. TypeError: ``light`` is not a
            :class:`ReferenceLight`. render.backend.LLVMError: unusable libLLVM.

    Example:
        >>> import numpy as np, torch, trimesh
        >>> from pipeline.camera import make_camera
        >>> sphere = trimesh.creation.icosphere(subdivisions=2, radius=80.0)
        >>> cam = make_camera(64, 48, 90.0, translation=np.array([0.0, 0.0, 500.0]))
        >>> light = ReferenceLight((0.0, 300.0, 800.0), (1.5e6,) * 3, (0.2,) * 3)
        >>> out = render_reference(sphere.vertices, sphere.faces, np.full((len(sphere.vertices), 3), 0.5),
        ...                        cam, light, spp=4)
        >>> out.image.shape, out.mask.shape
        ((48, 64, 3), (48, 64))
    """
    if not isinstance(light, ReferenceLight):
        raise TypeError(f"render_reference: expected light a ReferenceLight, got {type(light).__name__}")
    v, f, a, bg = _check_inputs(vertices, faces, albedo, background, spp, max_depth)
    sensor = sensor_from_pinhole(camera, spp=int(spp), seed=int(seed))
    width, height = sensor["film"]["width"], sensor["film"]["height"]
    if bg is not None and bg.shape != (height, width, 3):
        raise RenderArgumentError(
            f"render_reference: expected background of shape ({height}, {width}, 3) (the camera's "
            f"image size), got {bg.shape}"
        )
    if bg is not None and not np.isfinite(bg).all():
        raise RenderArgumentError("render_reference: background must be finite")

    variant = resolve_variant(device)
    previous = _current_variant()
    try:
        rgba = _render_rgba(use_variant(variant), v, f, a, sensor, light, int(spp), int(seed), int(max_depth))
    finally:
        if previous is not None and previous != variant:
            use_variant(previous)

    mask = np.clip(rgba[..., 3], 0.0, 1.0)
    # The environment is hidden from camera rays, so the film's RGB is the head's radiance averaged over
    # the pixel's samples, zero for samples that miss it: compositing is "head + (1 - coverage) * bg".
    image = rgba[..., :3]
    if bg is not None:
        image = image + (1.0 - mask)[..., None] * bg
    return ReferenceRender(
        image=np.ascontiguousarray(image, dtype=np.float32), mask=np.ascontiguousarray(mask, dtype=np.float32)
    )


def _current_variant() -> str | None:
    import mitsuba as mi

    return mi.variant()


def _render_rgba(
    mi,
    vertices: np.ndarray,
    faces: np.ndarray,
    albedo: np.ndarray,
    sensor: dict,
    light: ReferenceLight,
    spp: int,
    seed: int,
    max_depth: int,
) -> np.ndarray:
    """``(H, W, 4)`` float32: RGB radiance and alpha (coverage) of the head alone."""
    weld_index, welded_faces, n_welded = weld_vertices(vertices, faces)
    counts = np.bincount(weld_index, minlength=n_welded).astype(np.float64)[:, None]
    welded_v = np.zeros((n_welded, 3))
    np.add.at(welded_v, weld_index, vertices)
    welded_a = np.zeros((n_welded, 3))
    np.add.at(welded_a, weld_index, albedo)
    welded_v /= counts
    welded_a /= counts

    sensor = dict(sensor)
    sensor["film"] = {**sensor["film"], "pixel_format": "rgba"}
    sensor["to_world"] = mi.ScalarTransform4f(np.asarray(sensor["to_world"], float))

    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}})
    mesh = mi.Mesh(
        "head",
        vertex_count=n_welded,
        face_count=len(welded_faces),
        props=props,
        has_vertex_normals=True,
        has_vertex_texcoords=False,
    )
    mesh.add_attribute("vertex_color", 3, welded_a.astype(np.float32).ravel().tolist())
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(welded_v.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(welded_faces.astype(np.uint32).ravel())
    params.update()
    mesh.recompute_vertex_normals()

    scene = mi.load_dict(
        {
            "type": "scene",
            # hide_emitters: camera rays that miss the head return 0 (not the environment), so the
            # background can be composited with the alpha channel
            "integrator": {"type": "path", "max_depth": max_depth, "hide_emitters": True},
            "sensor": sensor,
            "key": {
                "type": "point",
                "position": list(light.position),
                "intensity": {"type": "rgb", "value": list(light.intensity)},
            },
            "environment": {"type": "constant", "radiance": {"type": "rgb", "value": list(light.environment)}},
            "head": mesh,
        }
    )
    rgba = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float32)
    if rgba.shape[-1] != 4 or not math.isfinite(float(rgba.sum())):
        raise RuntimeError(f"render_reference: Mitsuba returned an unusable image of shape {rgba.shape}")
    return rgba
