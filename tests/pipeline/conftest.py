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
