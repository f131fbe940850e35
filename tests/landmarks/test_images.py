"""Reading photos (:mod:`landmarks.images`): modes, EXIF orientation, missing and corrupt files."""

import numpy as np
import pytest

skimage_data = pytest.importorskip("skimage.data")

from PIL import Image

from landmarks.images import ImageError, load_image, load_working_image
from rig.errors import InputError


@pytest.fixture(scope="module")
def astronaut() -> np.ndarray:
    return np.ascontiguousarray(skimage_data.astronaut())  # (512, 512, 3) uint8 RGB


class TestLoadImage:
    @pytest.mark.parametrize("mode", ["L", "RGBA", "RGB", "P"])
    def test_modes_load_as_rgb(self, tmp_path, astronaut, mode):
        path = tmp_path / f"img_{mode}.png"
        Image.fromarray(astronaut[:40, :60]).convert(mode).save(path)
        image = load_image(path)
        assert image.shape == (40, 60, 3) and image.dtype == np.uint8
        if mode == "RGB":
            np.testing.assert_array_equal(image, astronaut[:40, :60])

    def test_exif_orientation_applied(self, tmp_path, astronaut):
        path = tmp_path / "rotated.jpg"
        exif = Image.Exif()
        exif[0x0112] = 6  # stored sideways: the viewer rotates 90 degrees clockwise
        Image.fromarray(astronaut[:40, :60]).save(path, exif=exif)
        assert load_image(path).shape == (60, 40, 3)

    def test_small_photo_is_its_own_working_image(self, tmp_path, astronaut):
        path = tmp_path / "astronaut.png"
        Image.fromarray(astronaut).save(path)
        photo = load_working_image(path)
        assert photo.factor == 1 and photo.original_size == (512, 512)
        np.testing.assert_array_equal(photo.image, astronaut)
        np.testing.assert_array_equal(photo.to_original(np.array([3.0, 7.0])), [3.0, 7.0])


class TestExceptions:
    def test_missing_file(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="nope.png"):
            load_image(tmp_path / "nope.png")

    def test_corrupt_file(self, tmp_path):
        path = tmp_path / "corrupt.png"
        path.write_bytes(np.random.default_rng(0).integers(0, 256, 1000, dtype=np.uint8).tobytes())
        with pytest.raises(ImageError, match="corrupt.png"):
            load_image(path)
        assert issubclass(ImageError, InputError)

    def test_too_many_pixels(self, tmp_path):
        path = tmp_path / "wide.png"
        Image.new("RGB", (300, 200)).save(path)
        with pytest.raises(ImageError, match=r"wide.png is 300 x 200 .* downscale it first"):
            load_working_image(path, max_pixels=50_000)
