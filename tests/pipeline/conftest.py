import pytest


@pytest.fixture(scope="session")
def photo_dir(tmp_path_factory):
    """Two small synthetic photos with their landmarks beside them (face.png + face.pts)."""
    import shutil

    from pipeline.synthetic.photos import (
        PhotoSettings,
        synthetic_photo,
        write_synthetic_photo,
    )

    root = tmp_path_factory.mktemp("photos")
    settings = PhotoSettings(width=128, height=128, spp=4, offset_px=4)
    for i in (0, 1):
        src = write_synthetic_photo(synthetic_photo(i, seed=5, settings=settings), root / f"src{i}")
        shutil.copy(src / "photo.png", root / f"face{i}.png")
        shutil.copy(src / "landmarks.pts", root / f"face{i}.pts")
        shutil.rmtree(src)
    return root


def fast_fit_args(*extra):
    """``jnr fit`` settings that keep a CLI fit to a few seconds."""
    return ["--landmarks-only", "--set", "landmarks.stages=[{name: a, free: [pose, joints], iterations: 5}]",
            "--quiet", *extra]


@pytest.fixture(scope="session")
def two_faces_photo(tmp_path_factory):
    """scikit-image's astronaut twice, side by side, at 256 and 192 px (faces about 44 and 36 px wide, so
    that dlib's HOG detector is quick): ``two_faces.png`` (448 x 256)."""
    import numpy as np
    from PIL import Image
    from skimage import data

    portrait = Image.fromarray(data.astronaut())
    canvas = np.full((256, 448, 3), 128, np.uint8)
    canvas[:, :256] = np.asarray(portrait.resize((256, 256), Image.BILINEAR))
    canvas[:192, 256:] = np.asarray(portrait.resize((192, 192), Image.BILINEAR))
    path = tmp_path_factory.mktemp("two_faces") / "two_faces.png"
    Image.fromarray(canvas).save(path)
    return path
