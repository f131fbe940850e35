import numpy as np
import pytest
import torch

from rig.expressions import EXPRESSION_NAMES
from rig.head_model import HeadParams, HeadPose, ParameterGroup


@pytest.fixture(scope="session")
def photo_dir(tmp_path_factory):
    """Two small synthetic photos with their landmarks beside them (face.png + face.pts)."""
    import shutil

    from pipeline.synthetic.photos.settings import PhotoSettings
    from pipeline.synthetic.photos.simulate import synthetic_photo
    from pipeline.synthetic.photos.write import write_synthetic_photo

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
    return [
        "--landmarks-only",
        "--set",
        "landmarks.stages=[{name: a, free: [pose, joints], iterations: 5}]",
        "--quiet",
        *extra,
    ]


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


def rig_head_vertices(params: dict, rig=None):
    """``(V, 3)`` float64 mm: a JNR fit's ``params.json`` entries (``joints``, ``latent_z``, ``expressions`` by
    name) posed straight by the rig's own pieces (the learned skinning of Z, the ARKit shapes, the joint
    hierarchy), without pipeline.head: the tests' independent oracle for every reader of a fit's head."""
    import numpy as np
    import torch

    from rig.expressions import ExpressionModel, coefficients_from_dict
    from rig.model import JointRig
    from rig.parameters import params_to_theta
    from rig.skinning.neural import load_neural

    rig = rig if rig is not None and rig.template.dtype == torch.float64 else JointRig(dtype=torch.float64)
    theta = params_to_theta(params["joints"], dtype=torch.float64)
    c = coefficients_from_dict(params["expressions"], dtype=torch.float64)
    z = torch.as_tensor(np.asarray(params["latent_z"], np.float64))
    with torch.no_grad():
        rest = ExpressionModel(rig.asset, dtype=torch.float64).vertices(c[None])[0]
        weights = load_neural(rig)[0](z[None])[0]
        return rig(theta[None], weights=weights, vertices=rest).vertices[0].numpy()


class StretchedHead:
    """A throwaway head model: the template stretched vertically about its centre by ``1 + grow`` (one float, in a
    group named ``joints`` so the fit's joint stages free it), not posable, no expressions."""

    kind = "test_stretched"
    posable = False

    def __init__(self, asset=None) -> None:
        from rig.asset import load_asset

        self.asset = asset or load_asset()
        self.template = torch.as_tensor(self.asset.vertices, dtype=torch.float64)
        self.centre = self.template.mean(0)

    def groups(self):
        return (ParameterGroup("joints", ("grow",), np.array([-0.3]), np.array([0.3]), "fraction"),)

    def initial(self):
        return HeadParams("test_stretched", {"joints": np.zeros(1)})

    def vertices(self, values, vertex_ids=None):
        grow = values["joints"][:, 0].to(torch.float64)
        v = self.template if vertex_ids is None else self.template[vertex_ids]
        stretch = torch.stack([torch.ones_like(grow), 1.0 + grow, torch.ones_like(grow)], -1)[:, None]
        return self.centre + stretch * (v - self.centre)

    def forward(self, params):
        v = self.vertices({"joints": torch.as_tensor(np.asarray(params["joints"], np.float64))[None]})[0].numpy()
        return HeadPose(v, v, None, None, np.zeros(len(EXPRESSION_NAMES)))

    def to_dict(self, params):
        return {"model": "test_stretched", "grow": float(params["joints"][0])}

    def from_dict(self, data):
        return HeadParams("test_stretched", {"joints": np.array([float(data["grow"])])})

    @staticmethod
    def options_from_dict(data):
        return {}


@pytest.fixture
def stretched_model():
    """:class:`StretchedHead` registered as head model ``test_stretched`` for the test (a fit of it must need no
    other code: issue 39), its instance on the committed asset."""
    from rig.head_model import create, register_head_model, unregister_head_model

    register_head_model("test_stretched", StretchedHead)
    try:
        yield create("test_stretched")
    finally:
        unregister_head_model("test_stretched")
