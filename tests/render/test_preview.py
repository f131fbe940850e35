import math

import numpy as np
import pytest

from render.preview import render_preview, save_png


def _project(points, yaw, distance, fov, target, size):
    """Pinhole projection of the preview camera (look-at from yaw, +Y up), pixels."""
    w, h = size
    ty = math.radians(yaw)
    forward = -np.array([math.sin(ty), 0.0, math.cos(ty)])
    origin = np.asarray(target) - distance * forward
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel = points - origin
    x, y, z = rel @ right, rel @ up, rel @ forward
    f = (w / 2) / math.tan(math.radians(fov) / 2)
    return np.stack([w / 2 + f * x / z, h / 2 - f * y / z], -1)


@pytest.mark.parametrize("yaw", [0.0, 90.0])
def test_silhouette_lands_where_the_camera_projects_the_mesh(asset, yaw, tmp_path):
    size, distance, fov, target = (160, 200), 900.0, 22.0, (0.0, -30.0, 0.0)
    image = render_preview(
        asset.vertices, asset.faces, yaw=yaw, pitch=0.0, size=size, spp=4, distance=distance, fov=fov, target=target
    )
    assert image.shape == (200, 160, 3) and image.dtype == np.uint8
    background = image[0, 0].astype(int)
    mask = np.abs(image.astype(int) - background).sum(-1) > 12
    rows, cols = np.nonzero(mask)
    uv = _project(asset.vertices, yaw, distance, fov, target, size)
    assert abs(cols.min() - uv[:, 0].min()) <= 2 and abs(cols.max() + 1 - uv[:, 0].max()) <= 2
    assert abs(rows.min() - uv[:, 1].min()) <= 2
    save_png(image, tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 0


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="expected vertices"):
        render_preview(np.zeros((4, 2)), np.zeros((1, 3), int))
