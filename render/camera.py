"""kornia ``PinholeCamera`` (OpenCV convention) -> Mitsuba 3 ``perspective`` sensor, exactly.

OpenCV/kornia camera frame: +X right, +Y down, +Z forward; pixel ``(u, v)`` with ``u`` to the right, ``v``
down, pixel centres at integer + 0.5 in Mitsuba's film (the projection ``u = fx X/Z + cx`` is compared with
the continuous film coordinate minus 0.5). Mitsuba's camera frame: +X left, +Y up, +Z forward. So
``to_world = inverse(extrinsics) @ diag(-1, -1, 1, 1)``; the horizontal field of view is
``2 atan(W / (2 fx))``; the principal point goes to ``principal_point_offset_x/y`` as a fraction of the
film size.
"""

from __future__ import annotations

import math

import numpy as np

from render.errors import RenderArgumentError

_FLIP = np.diag([-1.0, -1.0, 1.0, 1.0])


def _single(camera, name: str) -> np.ndarray:
    value = getattr(camera, name)
    arr = value.detach().cpu().double().numpy() if hasattr(value, "detach") else np.asarray(value, float)
    if arr.ndim == 3:
        if arr.shape[0] != 1:
            raise RenderArgumentError(
                f"sensor_from_pinhole: expected a single camera (batch 1), got {name} of shape {arr.shape}"
            )
        arr = arr[0]
    if arr.shape != (4, 4):
        raise RenderArgumentError(f"sensor_from_pinhole: expected {name} (1, 4, 4), got {arr.shape}")
    return arr


def sensor_from_pinhole(
    camera, *, spp: int = 4, seed: int = 0, near_clip: float = 1.0, far_clip: float = 1.0e5, sample_border: bool = True
) -> dict:
    """Mitsuba ``perspective`` sensor dict (with ``hdrfilm`` and box filter) from a kornia camera.

    Args:
        camera: ``kornia.geometry.camera.PinholeCamera`` with batch size 1: ``intrinsics`` ``(1, 4, 4)``
            (pixels; square pixels ``fx == fy`` and zero skew required), ``extrinsics`` ``(1, 4, 4)``
            world -> camera (OpenCV axes, mm), ``height``/``width`` ``(1,)`` pixels. Any image size,
            principal point anywhere.
        spp: samples per pixel of the sensor's sampler; ``seed``: its seed.
        near_clip, far_clip: clip distances, mm.
        sample_border: Mitsuba film option; on (default) so shapes entering or leaving the image get correct gradients.

    Returns:
        A dict for ``mi.load_dict`` (the ``to_world`` is a plain ``(4, 4)`` nested list; see
        :func:`to_world_matrix`). Needs no Mitsuba variant.

    Raises:
        ValueError: batch size other than 1, non-square pixels, skew, or a non-rigid extrinsic.
    """
    K = _single(camera, "intrinsics")
    E = _single(camera, "extrinsics")
    width = int(
        round(
            float(
                np.asarray(camera.width.detach().cpu() if hasattr(camera.width, "detach") else camera.width).reshape(
                    -1
                )[0]
            )
        )
    )
    height = int(
        round(
            float(
                np.asarray(camera.height.detach().cpu() if hasattr(camera.height, "detach") else camera.height).reshape(
                    -1
                )[0]
            )
        )
    )
    fx, fy, cx, cy, skew = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    if width <= 0 or height <= 0:
        raise RenderArgumentError(f"sensor_from_pinhole: expected a positive image size, got {width}x{height}")
    if fx <= 0 or abs(fx - fy) > 1e-6 * abs(fx):
        raise RenderArgumentError(
            f"sensor_from_pinhole: Mitsuba's perspective sensor needs square pixels fx == fy > 0, got fx={fx}, fy={fy}"
        )
    if abs(skew) > 1e-9 * abs(fx):
        raise RenderArgumentError(f"sensor_from_pinhole: expected zero skew, got {skew}")
    return {
        "type": "perspective",
        "fov_axis": "x",
        "fov": math.degrees(2.0 * math.atan(width / (2.0 * fx))),
        # OpenCV puts pixel centres at integers, Mitsuba's film at integer + 0.5; Mitsuba's offset is
        # positive towards the left/top of the image (measured), hence the minus signs
        "principal_point_offset_x": float(-(cx + 0.5 - width / 2.0) / width),
        "principal_point_offset_y": float(-(cy + 0.5 - height / 2.0) / height),
        "near_clip": float(near_clip),
        "far_clip": float(far_clip),
        "to_world": to_world_matrix(E).tolist(),
        "film": {
            "type": "hdrfilm",
            "width": width,
            "height": height,
            "pixel_format": "rgb",
            "rfilter": {"type": "box"},
            "sample_border": bool(sample_border),
        },
        "sampler": {"type": "independent", "sample_count": int(spp), "seed": int(seed)},
    }


def to_world_matrix(extrinsics: np.ndarray) -> np.ndarray:
    """Mitsuba camera-to-world ``(4, 4)`` from an OpenCV world-to-camera ``(4, 4)`` (rigid, mm).

    Raises:
        ValueError: the rotation part is not a rotation (scale or reflection).
    """
    E = np.asarray(extrinsics, float)
    R = E[:3, :3]
    if E.shape != (4, 4) or not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
        raise RenderArgumentError(
            f"to_world_matrix: expected a rigid (4, 4) world-to-camera transform, got {E.tolist()}"
        )
    return np.linalg.inv(E) @ _FLIP
