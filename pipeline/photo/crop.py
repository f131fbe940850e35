"""The face crop the photometric stages render and compare at."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch
from kornia.geometry.camera import PinholeCamera

from pipeline.camera import make_camera


@dataclass(frozen=True)
class Crop:
    """The square part of the photo the photometric loss sees: photo pixels ``[x0, x0 + side)`` x
    ``[y0, y0 + side)`` (may extend past the photo; those pixels are masked), resampled to ``size``."""

    x0: int
    y0: int
    side: int
    size: int

    @property
    def scale(self) -> float:
        """Crop pixels per photo pixel."""
        return self.size / self.side

    def camera(self, focal: float, width: int, height: int, dtype=torch.float32) -> PinholeCamera:
        """The crop's pinhole (identity extrinsics: points are given in the photo camera's frame)."""
        s = self.scale
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        # pixel centres at integers: continuous coordinate u + 0.5 scales about the crop's corner
        principal = ((cx + 0.5 - self.x0) * s - 0.5, (cy + 0.5 - self.y0) * s - 0.5)
        return make_camera(self.size, self.size, focal * s, principal=principal, dtype=dtype, pose=False)

    def cut(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(H, W, C)`` photo -> ``(size, size, C)`` float32 crop (area-averaged) and its ``(size, size)``
        float32 in-photo mask."""
        h, w = image.shape[:2]
        pad = np.zeros((self.side, self.side, image.shape[2]), np.float32)
        inside = np.zeros((self.side, self.side), np.float32)
        xa, ya = max(self.x0, 0), max(self.y0, 0)
        xb, yb = min(self.x0 + self.side, w), min(self.y0 + self.side, h)
        if xb > xa and yb > ya:
            pad[ya - self.y0 : yb - self.y0, xa - self.x0 : xb - self.x0] = image[ya:yb, xa:xb]
            inside[ya - self.y0 : yb - self.y0, xa - self.x0 : xb - self.x0] = 1.0
        interp = cv2.INTER_AREA if self.size < self.side else cv2.INTER_LINEAR
        out = cv2.resize(pad, (self.size, self.size), interpolation=interp)
        mask = cv2.resize(inside, (self.size, self.size), interpolation=interp)
        return out.reshape(self.size, self.size, -1), (mask > 0.999).astype(np.float32)


def face_crop(landmarks2d: np.ndarray, size: int, margin: float) -> Crop:
    """Square crop around the 68 landmarks: their box grown by ``margin`` (twice at the top), squared."""
    lo, hi = landmarks2d.min(0), landmarks2d.max(0)
    extent = hi - lo
    x0, x1 = lo[0] - margin * extent[0], hi[0] + margin * extent[0]
    y0, y1 = lo[1] - 2.0 * margin * extent[1], hi[1] + margin * extent[1]
    side = math.ceil(max(x1 - x0, y1 - y0, 8.0))
    cx, cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    return Crop(math.floor(cx - side / 2.0), math.floor(cy - side / 2.0), side, int(size))
