"""Read photos for detection and fitting: upright ``(H, W, 3)`` uint8 RGB arrays, large ones reduced.

:func:`load_working_image` reads a photo as the fit uses it (reduced by a power of two when it is large,
:class:`LoadedImage` maps pixels back to the file's); :func:`load_image` reads it at full size. Pixel
coordinates are 0-based OpenCV ones (origin at the centre of the top-left pixel, x right, y down).
Pillow is imported when a file is read.

Example::

    photo = load_working_image("big.jpg")      # LoadedImage
    photo.image.shape, photo.factor            # ((1250, 1250, 3), 8) for a 10000 x 10000 photo
"""

from __future__ import annotations

import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from landmarks.detector import DetectionError
from rig.errors import InputError
from rig.io.inputs import regular_file

MAX_IMAGE_FILE_BYTES = 4 << 30
"""The largest image file read (4 GiB; a 120-megapixel 16-bit PNG is under 1 GiB)."""
MAX_IMAGE_PIXELS = 120_000_000
"""Larger images (width x height) are refused with one line before they are decoded (a 10000 x 12000
photo is accepted). Pillow's own guard would raise a multi-line ``DecompressionBombError``."""
WORKING_MAX_SIDE = 2048
"""Photos whose longer side exceeds this are fitted at a reduced size: decoded shrunk by a power of two
``k`` (JPEG: by the decoder itself, ``Image.draft``, so a 10000 x 10000 JPEG never exists in memory at
full size), so that the longer side is at most this (and at least half of it). dlib's detector and
68-point model work on faces from about 80 px across; at 1024-2048 px a face that fills a fifth of
the frame is still 200-400 px wide, so nothing the fit uses is lost."""


class ImageError(InputError):
    """A file that is not a readable image, or one too large to read."""


@dataclass(frozen=True)
class LoadedImage:
    """A photo as the fit sees it: possibly reduced by an integer factor ``k`` from the file.

    Working pixel ``(x, y)`` (0-based, OpenCV) covers the file's ``k x k`` block whose centre is
    ``(k x + (k - 1) / 2, k y + (k - 1) / 2)`` in the file's 0-based pixels (:meth:`to_original`)."""

    image: np.ndarray
    """``(h, w, 3)`` uint8 RGB, upright (EXIF orientation applied)."""
    factor: int
    """``k``: 1 when the photo is used at its own size."""
    original_size: tuple[int, int]
    """``(W, H)`` of the upright photo in the file, pixels."""

    def to_original(self, points: np.ndarray) -> np.ndarray:
        """``(*, 2)`` working pixels -> the file's pixels (0-based OpenCV)."""
        return np.asarray(points, float) * self.factor + (self.factor - 1) / 2.0

    def to_working(self, points: np.ndarray) -> np.ndarray:
        """``(*, 2)`` the file's pixels -> working pixels (0-based OpenCV)."""
        return (np.asarray(points, float) - (self.factor - 1) / 2.0) / self.factor


def _reason(exc: Exception) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text.replace("cannot identify image file", "not an image file or a corrupt one")


@contextmanager
def _open_unguarded(path: Path):
    """``Image.open`` without Pillow's decompression-bomb guard (:data:`MAX_IMAGE_PIXELS` is checked
    instead, in one line); the guard is restored at once, only the lazy header read runs without it."""
    from PIL import Image

    saved, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(path)
    finally:
        Image.MAX_IMAGE_PIXELS = saved
    with img:
        yield img


WIDE_MODES = ("I;16", "I;16B", "I;16L", "I;16N", "I", "F")
"""Pillow's single-channel modes wider than 8 bits: 16-bit and 32-bit integers, 32-bit floats."""


def _to_8bit(img):
    """A 16/32-bit integer or float greyscale image as 8-bit greyscale, by what its values mean: integers up to
    65535 are 16-bit (divided by 257), larger ones 32-bit; floats within [0, 1] are fractions of white,
    larger ones read as 8-bit or 16-bit levels. (Pillow's own conversion clips them at 255: a 16-bit photo
    came out almost white, a float one black.)"""
    from PIL import Image

    values = np.asarray(img, dtype=np.float64)
    finite = values[np.isfinite(values)]
    top = float(finite.max()) if finite.size else 0.0
    if img.mode == "F" and top <= 1.0:
        scale = 255.0
    elif img.mode.startswith("I;16") or 255.0 < top <= 65535.0:
        scale = 255.0 / 65535.0
    elif top > 65535.0:
        scale = 255.0 / 4294967295.0
    else:
        scale = 1.0
    grey = np.clip(np.round(np.nan_to_num(values) * scale), 0, 255).astype(np.uint8)
    return Image.fromarray(grey, "L")


def load_working_image(
    path: str | Path, max_side: int = WORKING_MAX_SIDE, max_pixels: int = MAX_IMAGE_PIXELS
) -> LoadedImage:
    """Read a photo for fitting: upright RGB, reduced by a power of two when its longer side exceeds
    ``max_side`` (see :data:`WORKING_MAX_SIDE`), refused above ``max_pixels``.

    Grayscale, palette, CMYK, 16-bit and RGBA images are converted to RGB (alpha dropped); an animated
    image gives its first frame.

    Returns:
        :class:`LoadedImage`.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ImageError: not a readable image, or more than ``max_pixels`` pixels (one line).

    Example:
        >>> photo = load_working_image("big.jpg")  # doctest: +SKIP
        >>> photo.image.shape, photo.factor, photo.original_size  # doctest: +SKIP
        ((1250, 1250, 3), 8, (10000, 10000))
    """
    from PIL import ImageOps, UnidentifiedImageError

    path = regular_file(path, "image file", MAX_IMAGE_FILE_BYTES)  # a FIFO or a device is not "not found"
    try:
        with _open_unguarded(path) as img:
            width, height = img.size
            if width * height > max_pixels:
                raise ImageError(
                    f"image {path} is {width} x {height} = {width * height / 1e6:.0f} megapixels; jnr reads photos "
                    f"up to {max_pixels / 1e6:.0f} megapixels: downscale it first"
                )
            k = 1
            while max(width, height) > max_side * k:
                k *= 2
            if k > 1 and img.format == "JPEG":
                img.draft("RGB", (-(-width // k), -(-height // k)))  # decoder-side 1/2, 1/4, 1/8 scaling
            done = max(1, round(width / img.size[0]))  # what the decoder already reduced
            img = _to_8bit(img) if img.mode in WIDE_MODES else img
            img = img.convert("RGB") if img.mode != "RGB" else img
            img.load()
            rotated = img.getexif().get(0x0112, 1) in (5, 6, 7, 8)  # after load: PNG keeps EXIF after IDAT
            if k > done:
                img = img.reduce(k // done)
            img = ImageOps.exif_transpose(img)
            rgb = np.asarray(img, dtype=np.uint8)
    except ImageError:
        raise
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, EOFError) as exc:
        raise ImageError(f"cannot read image {path}: {_reason(exc)}") from None
    except MemoryError:
        raise ImageError(f"image {path} is too large to decode in the available memory") from None
    original = (height, width) if rotated else (width, height)
    if rgb.ndim != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise ImageError(f"cannot read image {path}: it has no pixels")
    return LoadedImage(image=np.ascontiguousarray(rgb), factor=k, original_size=original)


def load_image(path: str | Path) -> np.ndarray:
    """Read an image file at its full size as an ``(H, W, 3)`` uint8 RGB array.

    The EXIF orientation is applied (``ImageOps.exif_transpose``), so the array is upright as a viewer
    shows it; grayscale, palette, CMYK and RGBA images are converted to RGB (alpha is dropped). For
    fitting, :func:`load_working_image` reads large photos at a reduced size.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ImageError: the file cannot be decoded as an image, or has more than :data:`MAX_IMAGE_PIXELS` pixels.
    """
    return load_working_image(path, max_side=1 << 30).image


__all__ = [
    "MAX_IMAGE_FILE_BYTES",
    "MAX_IMAGE_PIXELS",
    "WORKING_MAX_SIDE",
    "ImageError",
    "LoadedImage",
    "check_image",
    "load_image",
    "load_working_image",
]


def check_image(image: np.ndarray, function: str) -> np.ndarray:
    """``image`` as a C-contiguous ``(H, W, 3)`` uint8 array.

    Raises:
        DetectionError: another shape or dtype, or no pixels (the message names ``function``).
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise DetectionError(
            f"{function}: image must be an (H, W, 3) uint8 RGB array; got shape {image.shape}, dtype {image.dtype}"
        )
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise DetectionError(f"{function}: image is empty; got shape {image.shape}")
    return np.ascontiguousarray(image)
