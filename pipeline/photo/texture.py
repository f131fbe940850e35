"""The face unwrapped from a photo into the template's UVs: ``texture.png`` of ``jnr fit``.

For every texel of a square texture the triangle that covers its centre in UV space gives, by its
barycentric coordinates, a point on the fitted head (rig space, mm); the point is projected with the
fit's pinhole camera and the photo is sampled there (bilinear, ``cv2.remap``). A texel takes the
photo's colour where its point is seen: facing the camera (the cosine between the smooth surface
normal and the direction to the camera at least :data:`VISIBLE_COS`) and not hidden by another part
of the head (a depth test against a z-buffer of the whole mesh rasterised at the photo's size). Every
other texel takes the fill colour: the fitted per-vertex albedo (sRGB-encoded), or, for a fit without
one (the default landmark fit), the median photo colour of the visible skin texels. Between
:data:`VISIBLE_COS` and :data:`FULL_WEIGHT_COS` the photo fades into the fill, since grazing texels
stretch a few pixels over many texels. Texels outside every UV triangle take the colour of the
nearest covered texel, so the texture has no holes for a viewer's filtering to bleed in.

Conventions:

- **Texture** ``(S, S, 3)`` uint8 sRGB, rows from the top: texel ``(row, col)`` has its centre at
  ``u = (col + 0.5) / S``, ``v = 1 - (row + 0.5) / S`` in OBJ / OpenGL UVs (``v`` up, the template's
  ``face_uvs``); glTF's ``TEXCOORD_0`` is ``(u, 1 - v)`` for the same image.
- **Camera**: ``x_cam = extrinsics @ [x_rig, 1]`` (OpenCV axes, mm), pixel ``= K @ x_cam / z`` (no skew), pixel
  centres at integer coordinates (:func:`pipeline.camera.camera_points_to_pixels`).

Seams need nothing special: the UVs are per face corner, so each triangle is rasterised with its own
corners' UVs and a vertex on a seam is sampled from both sides.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from pipeline.camera import camera_points_to_pixels
from pipeline.colour import linear_to_srgb
from rig.errors import InputError, shape_error
from rig.geometry import vertex_normals

__all__ = [
    "FULL_WEIGHT_COS",
    "TEXTURE_SIZE",
    "UVTexture",
    "VISIBLE_COS",
    "rasterize_triangles",
    "texture_from_fit",
    "unwrap_texture",
    "uv_raster",
    "vertex_colours_from_texture",
    "zbuffer",
]

TEXTURE_SIZE = 1024
"""Side of ``texture.png`` in texels (the template's UV islands cover 22 % of the square, the face
regions about 4 %: some 200 x 200 texels for the face)."""

VISIBLE_COS = 0.1
"""A texel is seen if the cosine between its normal and the direction to the camera exceeds this
(about 84 degrees from the line of sight) and no other part of the head is in front of it."""

FULL_WEIGHT_COS = 0.35
"""From this cosine on (about 70 degrees) a seen texel is the photo's colour alone; below it the photo
fades linearly into the fill colour down to :data:`VISIBLE_COS`."""

_MAX_CANDIDATES = 2_000_000  # (pixel, triangle) pairs tested per chunk: bounds the memory of the rasteriser


@dataclass(frozen=True)
class UVTexture:
    """What :func:`unwrap_texture` returns (``S``: the texture's side in texels).

    Attributes:
        image: ``(S, S, 3)`` uint8 sRGB, rows from the top (``v = 1`` first, module docstring).
        photo_weight: ``(S, S)`` float32 in [0, 1]: the photo's share of each texel (0: the fill only).
        face: ``(S, S)`` int64 the triangle whose UV triangle covers the texel centre, -1 for none.
        fill: how the fill colour was chosen: ``"vertex colours"`` or ``"median of visible texels"``.
        seconds: wall time of the unwrap.
    """

    image: np.ndarray
    photo_weight: np.ndarray
    face: np.ndarray
    fill: str
    seconds: float

    @property
    def visible_fraction(self) -> float:
        """Share of the covered texels that see the photo (weight > 0)."""
        covered = self.face >= 0
        return float((self.photo_weight[covered] > 0).mean()) if covered.any() else 0.0


def rasterize_triangles(points: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every (pixel, triangle) pair whose pixel centre lies in the triangle, by bounding boxes.

    Args:
        points: ``(F, 3, 2)`` the triangles' corners in pixels (x right, y down), pixel centres at integer
            coordinates. Degenerate triangles (zero area) cover nothing.
        width, height: the image; pixels outside it are left out.

    Returns:
        ``(pixel, triangle, bary)``: ``(N,)`` int64 flat pixel index ``y * width + x``, ``(N,)`` int64
        triangle, ``(N, 3)`` float64 barycentric coordinates of the pixel centre (sum 1, each >= 0 up to
        rounding). A pixel on an edge shared by two triangles is listed for both.

    Example:
        >>> pix, tri, bary = rasterize_triangles(np.array([[[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]]]), 8, 8)
        >>> len(pix)  # the 15 pixel centres with x, y >= 0 and x + y <= 4
        15
    """
    p = np.asarray(points, np.float64)
    if p.ndim != 3 or p.shape[1:] != (3, 2):
        raise shape_error("rasterize_triangles", "points", "(F, 3, 2)", p.shape)
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    e1, e2 = b - a, c - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    with np.errstate(invalid="ignore"):
        x0 = np.maximum(np.ceil(p[..., 0].min(1)), 0)
        x1 = np.minimum(np.floor(p[..., 0].max(1)), width - 1)
        y0 = np.maximum(np.ceil(p[..., 1].min(1)), 0)
        y1 = np.minimum(np.floor(p[..., 1].max(1)), height - 1)
    ok = np.isfinite(p).all((1, 2)) & (np.abs(det) > 1e-12)
    nx = np.where(ok, np.maximum(x1 - x0 + 1, 0), 0).astype(np.int64)
    ny = np.where(ok, np.maximum(y1 - y0 + 1, 0), 0).astype(np.int64)
    counts = nx * ny
    out_pixel, out_tri, out_bary = [], [], []
    ends = np.cumsum(counts)
    start_face = 0
    while start_face < len(counts):  # chunks of faces with at most _MAX_CANDIDATES pixels (one face may exceed it)
        base = ends[start_face - 1] if start_face else 0
        stop = max(int(np.searchsorted(ends, base + _MAX_CANDIDATES, side="right")), start_face + 1)
        tri_ids = np.arange(start_face, stop)
        n = counts[tri_ids]
        start_face = stop
        if n.sum() == 0:
            continue
        tri = np.repeat(tri_ids, n)
        local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        px = x0[tri] + local % nx[tri]
        py = y0[tri] + local // nx[tri]
        dx, dy = px - a[tri, 0], py - a[tri, 1]
        d = det[tri]
        l1 = (dx * e2[tri, 1] - dy * e2[tri, 0]) / d
        l2 = (e1[tri, 0] * dy - e1[tri, 1] * dx) / d
        l0 = 1.0 - l1 - l2
        eps = -1e-9
        inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
        out_pixel.append((py[inside] * width + px[inside]).astype(np.int64))
        out_tri.append(tri[inside])
        out_bary.append(np.stack([l0[inside], l1[inside], l2[inside]], 1))
    if not out_pixel:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    return np.concatenate(out_pixel), np.concatenate(out_tri), np.concatenate(out_bary)


def uv_raster(face_uvs: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The triangle covering each texel centre of a ``size x size`` texture, and its barycentrics.

    Args:
        face_uvs: ``(F, 3, 2)`` UVs per face corner (OBJ convention, ``v`` up; module docstring).
        size: the texture's side in texels.

    Returns:
        ``(face (S, S) int64, -1 where no triangle covers the texel centre; bary (S, S, 3) float64)``. Where
        UV triangles overlap, one of them is kept.
    """
    uv = np.asarray(face_uvs, np.float64)
    if uv.ndim != 3 or uv.shape[1:] != (3, 2):
        raise shape_error("uv_raster", "face_uvs", "(F, 3, 2)", uv.shape)
    pts = np.stack([uv[..., 0] * size - 0.5, (1.0 - uv[..., 1]) * size - 0.5], -1)
    pixel, tri, bary = rasterize_triangles(pts, size, size)
    face = np.full(size * size, -1, np.int64)
    bary_img = np.zeros((size * size, 3))
    face[pixel] = tri
    bary_img[pixel] = bary
    return face.reshape(size, size), bary_img.reshape(size, size, 3)


def zbuffer(points_px: np.ndarray, depth: np.ndarray, faces: np.ndarray, width: int, height: int) -> np.ndarray:
    """``(H, W)`` float64 the nearest depth of a triangle mesh at each pixel centre (inf where none).

    Args:
        points_px: ``(V, 2)`` vertices projected to pixels (centres at integer coordinates).
        depth: ``(V,)`` their camera depth (> 0 in front of the camera); triangles with a corner at or
            behind 1e-6 are left out. Depth is interpolated perspective-correctly (``1 / z`` linear in
            the image).
        faces: ``(F, 3)`` vertex indices.
    """
    faces = np.asarray(faces, np.int64)
    z = np.asarray(depth, np.float64)
    front = (z[faces] > 1e-6).all(1)
    f = faces[front]
    pixel, tri, bary = rasterize_triangles(np.asarray(points_px, np.float64)[f], width, height)
    inv_z = (bary * (1.0 / z[f[tri]])).sum(1)
    buffer = np.full(width * height, np.inf)
    np.minimum.at(buffer, pixel, 1.0 / inv_z)
    return buffer.reshape(height, width)


def _check_camera(intrinsics, extrinsics) -> tuple[np.ndarray, np.ndarray]:
    k = np.asarray(intrinsics, np.float64)
    e = np.asarray(extrinsics, np.float64)
    if k.shape[-2:] == (4, 4):
        k = k[..., :3, :3]
    if k.shape != (3, 3):
        raise shape_error("unwrap_texture", "intrinsics", "(3, 3) or (4, 4)", np.asarray(intrinsics).shape)
    if e.shape == (3, 4):
        e = np.vstack([e, [0.0, 0.0, 0.0, 1.0]])
    if e.shape != (4, 4):
        raise shape_error("unwrap_texture", "extrinsics", "(4, 4) or (3, 4)", np.asarray(extrinsics).shape)
    if not (np.isfinite(k).all() and np.isfinite(e).all() and k[0, 0] > 0 and k[1, 1] > 0):
        raise InputError("unwrap_texture: the camera must be finite with a positive focal length")
    if k[0, 1] != 0.0 or k[1, 0] != 0.0 or not np.allclose(k[2], [0.0, 0.0, 1.0]):
        raise InputError("unwrap_texture: the intrinsics must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
    return k, e


def _check_mesh_inputs(photo, vertices, faces, face_uvs, size) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The photo ``(H, W, 3)`` uint8, vertices ``(V, 3)`` mm, faces ``(F, 3)`` int64 and UVs ``(F, 3, 2)``, checked."""
    func = "unwrap_texture"
    img = np.asarray(photo)
    if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 1:
        raise shape_error(func, "photo", "(H, W, 3)", img.shape)
    if img.dtype != np.uint8:
        raise InputError(f"{func}: photo must be uint8 sRGB, got dtype {img.dtype}")
    v = np.asarray(vertices, np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise shape_error(func, "vertices", "(V, 3) finite", v.shape)
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise shape_error(func, "faces", "(F, 3) integer", f.shape)
    f = f.astype(np.int64)
    if len(f) == 0 or f.min() < 0 or f.max() >= len(v):
        raise InputError(
            f"{func}: faces must index the {len(v)} vertices, got range [{f.min(initial=0)}, "
            f"{f.max(initial=0)}] over {len(f)} faces"
        )
    uv = np.asarray(face_uvs, np.float64)
    if uv.shape != (len(f), 3, 2) or not np.isfinite(uv).all():
        raise shape_error(func, "face_uvs", f"({len(f)}, 3, 2) finite", uv.shape)
    if not (isinstance(size, (int, np.integer)) and 16 <= size <= 8192):
        raise InputError(f"{func}: size must be an integer in 16-8192 texels, got {size!r}")
    return img, v, f, uv


def _check_fill_inputs(fill_colours, skin_faces, n_vertices: int, n_faces: int) -> tuple[np.ndarray | None, np.ndarray]:
    """The fill ``(V, 3)`` as float sRGB in [0, 1] (or None) and the ``(F,)`` bool skin faces, checked."""
    func = "unwrap_texture"
    fill = None
    if fill_colours is not None:
        fill = np.asarray(fill_colours)
        if fill.shape != (n_vertices, 3):
            raise shape_error(func, "fill_colours", f"({n_vertices}, 3)", fill.shape)
        fill = fill.astype(np.float64) / 255.0 if fill.dtype == np.uint8 else fill.astype(np.float64)
        if not (np.isfinite(fill).all() and fill.min() >= 0.0 and fill.max() <= 1.0):
            raise InputError(f"{func}: float fill_colours must lie in [0, 1]")
    skin = np.ones(n_faces, bool) if skin_faces is None else np.asarray(skin_faces, bool)
    if skin.shape != (n_faces,):
        raise shape_error(func, "skin_faces", f"({n_faces},)", skin.shape)
    return fill, skin


def _texel_weights(
    points: np.ndarray,
    normals: np.ndarray,
    v: np.ndarray,
    f: np.ndarray,
    k: np.ndarray,
    e: np.ndarray,
    width: int,
    height: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Photo pixel ``(T, 2)`` of each texel point ``(T, 3)`` mm and the photo's weight there: 0 where unseen."""
    rot, trans = e[:3, :3], e[:3, 3]
    to_camera = -rot.T @ trans - points
    distance = np.linalg.norm(to_camera, axis=1).clip(1e-12)
    cos = (normals * to_camera).sum(1) / distance
    cam = _transform(rot, points) + trans
    z = cam[:, 2]
    in_front = z > 1e-6
    zs = np.where(in_front, z, 1.0)
    focal, centre = np.diag(k)[:2], k[:2, 2]
    xy = camera_points_to_pixels(cam, focal, centre)
    inside = in_front & (xy[:, 0] > -0.5) & (xy[:, 0] < width - 0.5) & (xy[:, 1] > -0.5) & (xy[:, 1] < height - 0.5)

    v_cam = _transform(rot, v) + trans
    vz = v_cam[:, 2]
    v_px = camera_points_to_pixels(v_cam, focal, centre)
    depth = zbuffer(v_px, vz, f, width, height)
    # the nearest surface around the point: the farthest of the 4 pixel centres around it (a point on the
    # visible surface has it within the tolerance, a hidden one has all 4 on the surface in front of it);
    # tolerance: the surface's depth change over a pixel (steeper towards grazing angles, capped at 3:1)
    # plus 0.5 mm
    c0 = np.clip(np.floor(xy[:, 0]), 0, width - 1).astype(np.int64)
    r0 = np.clip(np.floor(xy[:, 1]), 0, height - 1).astype(np.int64)
    c1, r1 = np.minimum(c0 + 1, width - 1), np.minimum(r0 + 1, height - 1)
    nearest = np.maximum(np.maximum(depth[r0, c0], depth[r0, c1]), np.maximum(depth[r1, c0], depth[r1, c1]))
    pixel_mm = zs / k[0, 0]
    slope = np.sqrt(np.clip(1.0 - cos**2, 0.0, 1.0)) / np.clip(cos, 1e-3, None)
    tolerance = 0.5 + pixel_mm * np.minimum(slope, 3.0)
    unoccluded = z <= nearest + tolerance
    seen = inside & unoccluded & (cos > VISIBLE_COS)
    weight = np.where(seen, np.clip((cos - VISIBLE_COS) / (FULL_WEIGHT_COS - VISIBLE_COS), 0.0, 1.0), 0.0)
    return xy, weight


def unwrap_texture(
    photo: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    face_uvs: np.ndarray,
    *,
    intrinsics: np.ndarray,
    extrinsics: np.ndarray,
    fill_colours: np.ndarray | None = None,
    skin_faces: np.ndarray | None = None,
    size: int = TEXTURE_SIZE,
) -> UVTexture:
    """Unwrap a photo into a mesh's UVs (module docstring).

    Args:
        photo: ``(H, W, 3)`` uint8 sRGB.
        vertices: ``(V, 3)`` the head as the photo shows it, in the camera's world frame (rig space), mm.
        faces: ``(F, 3)`` vertex indices, counter-clockwise seen from outside.
        face_uvs: ``(F, 3, 2)`` UVs per face corner (``v`` up).
        intrinsics: ``(3, 3)`` (or ``(4, 4)``) pinhole matrix, pixels (centres at integer coordinates).
        extrinsics: ``(4, 4)`` (or ``(3, 4)``) world -> camera (OpenCV axes), mm.
        fill_colours: ``(V, 3)`` sRGB fill per vertex (uint8, or float in [0, 1]); None: the median of the
            seen texels (of ``skin_faces``' texels where any of them is seen).
        skin_faces: ``(F,)`` bool, the faces whose texels give the median fill (default: all).
        size: the texture's side in texels (16-8192).

    Returns:
        :class:`UVTexture`.

    Raises:
        rig.errors.InputError: bad shapes, dtypes or values (ShapeError for shapes), or, without
            ``fill_colours``, no texel is seen.

    Example:
        >>> import numpy as np
        >>> quad = np.array([[-50.0, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]])
        >>> faces = np.array([[0, 1, 2], [0, 2, 3]])
        >>> uvs = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])
        >>> photo = np.full((64, 64, 3), 200, np.uint8)
        >>> k = np.array([[100.0, 0, 31.5], [0, 100, 31.5], [0, 0, 1]])
        >>> e = np.diag([1.0, -1, -1, 1]); e[2, 3] = 300  # a camera 300 mm in front of the quad
        >>> tex = unwrap_texture(photo, quad, faces, uvs, intrinsics=k, extrinsics=e, size=32)
        >>> tex.image.shape, int(tex.image[16, 16, 0]), tex.visible_fraction
        ((32, 32, 3), 200, 1.0)
    """
    import cv2

    t0 = time.perf_counter()
    func = "unwrap_texture"
    img, v, f, uv = _check_mesh_inputs(photo, vertices, faces, face_uvs, size)
    k, e = _check_camera(intrinsics, extrinsics)
    fill, skin = _check_fill_inputs(fill_colours, skin_faces, len(v), len(f))
    height, width = img.shape[:2]

    # the covered texels and their points on the head
    face_img, bary_img = uv_raster(uv, int(size))
    covered = face_img >= 0
    tri = face_img[covered]
    bary = bary_img[covered]
    corners = f[tri]  # (T, 3)
    points = np.einsum("tc,tcd->td", bary, v[corners])
    normals = np.einsum("tc,tcd->td", bary, vertex_normals(v, f)[corners])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True).clip(1e-12)

    # where they land in the photo, and whether they are seen there
    xy, weight = _texel_weights(points, normals, v, f, k, e, width, height)

    map_x = np.full((size, size), -1.0, np.float32)
    map_y = np.full((size, size), -1.0, np.float32)
    map_x[covered], map_y[covered] = xy[:, 0], xy[:, 1]
    sampled = cv2.remap(img, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    photo_rgb = sampled[covered].astype(np.float64) / 255.0

    if fill is not None:
        fill_rgb = np.einsum("tc,tcd->td", bary, fill[corners])
        how = "vertex colours"
    else:
        pick = (weight > 0.5) & skin[tri]
        if not pick.any():
            pick = weight > 0
        if not pick.any():
            raise InputError(
                f"{func}: no texel is seen by the camera, so there is no colour to fill with (give fill_colours)"
            )
        fill_rgb = np.broadcast_to(np.median(photo_rgb[pick], axis=0), photo_rgb.shape)
        how = "median of visible texels"
    rgb = weight[:, None] * photo_rgb + (1.0 - weight[:, None]) * fill_rgb

    image = np.zeros((size, size, 3), np.uint8)
    image[covered] = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
    weight_img = np.zeros((size, size), np.float32)
    weight_img[covered] = weight
    image = _pad_islands(image, covered)
    return UVTexture(image=image, photo_weight=weight_img, face=face_img, fill=how, seconds=time.perf_counter() - t0)


def _transform(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(N, d)`` ``matrix @ p`` of every row ``p`` of ``points`` (einsum: BLAS costs ~10x more at this size)."""
    return np.einsum("ed,nd->ne", matrix, points)


def _pad_islands(image: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """Every uncovered texel takes the colour of the nearest covered one (no holes for filtering to bleed in)."""
    import cv2

    if covered.all() or not covered.any():
        return image
    source = np.where(covered, 0, 255).astype(np.uint8)  # distances to the zero (covered) texels
    _, labels = cv2.distanceTransformWithLabels(source, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    covered_index = np.flatnonzero(covered.ravel())
    lookup = np.zeros(int(labels.max()) + 1, np.int64)
    lookup[labels.ravel()[covered_index]] = covered_index
    flat = image.reshape(-1, 3)
    return flat[lookup[labels.ravel()]].reshape(image.shape)


def texture_from_fit(
    photo: np.ndarray,
    fit,
    faces: np.ndarray,
    face_uvs: np.ndarray,
    *,
    regions: np.ndarray | None = None,
    skin_region_ids=None,
    size: int = TEXTURE_SIZE,
) -> UVTexture:
    """:func:`unwrap_texture` of a photo fit: its head (``fit.rig_vertices``), its camera, and its fitted
    albedo as the fill (sRGB-encoded) when the photometric stages ran; otherwise (the default landmark fit,
    whose albedo is a placeholder) the median colour of the seen skin texels.

    Args:
        photo: ``(H, W, 3)`` uint8 sRGB, the photo as fitted (at the fit's size).
        fit: a :class:`pipeline.photo.fit.PhotoFit`.
        faces, face_uvs: the rig asset's ``(F, 3)`` faces and ``(F, 3, 2)`` UVs.
        regions: ``(V,)`` region of every vertex; with ``skin_region_ids`` (region indices), the faces whose
            first vertex is in one of them give the median fill.
        size: the texture's side in texels.
    """
    img = np.asarray(photo)
    if img.shape[:2] != (fit.height, fit.width):
        raise InputError(
            f"texture_from_fit: the photo is {img.shape[1]} x {img.shape[0]} px, the fit's camera "
            f"{fit.width} x {fit.height}"
        )
    intrinsics = fit.camera.intrinsics[0].detach().double().numpy()
    extrinsics = fit.camera.extrinsics[0].detach().double().numpy()
    fill = linear_to_srgb(np.asarray(fit.appearance.albedo, np.float64)) if len(fit.stages) else None
    skin = None
    if regions is not None and skin_region_ids is not None:
        skin = np.isin(np.asarray(regions)[np.asarray(faces)[:, 0]], list(skin_region_ids))
    return unwrap_texture(
        img,
        fit.rig_vertices,
        faces,
        face_uvs,
        intrinsics=intrinsics,
        extrinsics=extrinsics,
        fill_colours=fill,
        skin_faces=skin,
        size=size,
    )


def vertex_colours_from_texture(
    image: np.ndarray, faces: np.ndarray, face_uvs: np.ndarray, n_vertices: int
) -> np.ndarray:
    """Per-vertex colours sampled from a texture: each face corner's UV sampled bilinearly (texel centres at
    ``((i + 0.5) / S, 1 - (j + 0.5) / S)``, rows from the top as :class:`UVTexture`), a vertex the mean of
    its corners (a vertex on a UV seam has corners on both sides: their samples are averaged).

    Args:
        image: ``(S, S, 3)`` uint8 sRGB texture. faces: ``(F, 3)`` int. face_uvs: ``(F, 3, 2)`` UVs, v up.
        n_vertices: ``V``.

    Returns:
        ``(V, 3)`` uint8 sRGB; a vertex in no face gets the texture's mean colour.
    """
    from scipy.ndimage import map_coordinates

    image = np.asarray(image)
    size_y, size_x = image.shape[:2]
    uv = np.asarray(face_uvs, np.float64).reshape(-1, 2)
    cols, rows = uv[:, 0] * size_x - 0.5, (1.0 - uv[:, 1]) * size_y - 0.5
    samples = np.stack(
        [map_coordinates(image[..., c].astype(np.float64), [rows, cols], order=1, mode="nearest") for c in range(3)],
        axis=1,
    )
    corner_vertex = np.asarray(faces, np.int64).reshape(-1)
    total = np.zeros((n_vertices, 3))
    count = np.zeros(n_vertices)
    np.add.at(total, corner_vertex, samples)
    np.add.at(count, corner_vertex, 1.0)
    mean = image.reshape(-1, 3).mean(0)
    colours = np.where(count[:, None] > 0, total / np.maximum(count, 1.0)[:, None], mean)
    return np.clip(np.round(colours), 0, 255).astype(np.uint8)
