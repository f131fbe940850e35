"""viewer.html (pipeline.viewer): the data it holds, and the page in a real browser (headless Chromium).

The browser tests skip when Chromium is not installed, except with ``JNR_REQUIRE_BROWSER=1`` (CI), where
they fail. Ground truth: the rig posed in Python (rig.model.JointRig, rig.expressions.ExpressionModel) and
the head's silhouette projected with the camera in numpy.
"""

import json
import shutil
import subprocess
import tempfile
import warnings

import numpy as np
import pytest
import torch

import pipeline.viewer as viewer
from pipeline.viewer import (
    ViewerUnavailableError,
    ViewerView,
    read_viewer_data,
    read_viewer_state,
    viewer_payload,
    write_fit_viewer,
    write_viewer,
)
from rig.expressions import EXPRESSION_NAMES, ExpressionModel, coefficients_from_dict
from rig.parameters import CHANNEL_INDEX, CHANNELS, params_to_theta, random_theta, theta_to_params
from rig.skinning.neural import load_neural
from tests.conftest import needs_tool
from tests.pipeline.conftest import fast_fit_args

WIDTH, HEIGHT = 400, 360
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--virtual-time-budget=15000",
]


THREE_MISSING = "three.js is not vendored (make venv)"
CHROMIUM_MISSING = "chromium is not installed (make browser)"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_three = needs_tool(viewer.viewer_available(), THREE_MISSING)
needs_browser = needs_tool(viewer.viewer_available() and CHROMIUM is not None, f"{THREE_MISSING} or {CHROMIUM_MISSING}")


@pytest.fixture(scope="module")
def three():
    assert viewer.viewer_available(), THREE_MISSING


@pytest.fixture(scope="module")
def chromium(three):
    assert CHROMIUM is not None, CHROMIUM_MISSING
    return CHROMIUM


def _browse(exe: str, page, hash_: str, *args: str) -> subprocess.CompletedProcess:
    with tempfile.TemporaryDirectory(prefix="jnr-chromium-") as profile:
        return subprocess.run(
            [exe, *FLAGS, f"--user-data-dir={profile}", *args, page.as_uri() + "#" + hash_],
            capture_output=True,
            timeout=120,
            check=True,
        )


def screenshot(exe: str, page, hash_: str, tmp_path) -> np.ndarray:
    """``(HEIGHT, WIDTH, 3)`` uint8: the page without its panel (``ui=0``) in a WIDTH x HEIGHT window."""
    from PIL import Image

    out = tmp_path / f"shot_{abs(hash(hash_))}.png"
    _browse(exe, page, "ui=0&" + hash_, f"--window-size={WIDTH},{HEIGHT}", f"--screenshot={out}")
    return np.asarray(Image.open(out).convert("RGB"))


def page_state(exe: str, page, hash_: str) -> dict:
    return read_viewer_state(_browse(exe, page, hash_, "--dump-dom").stdout.decode("utf-8"))


# ------------------------------------------------------------------------------------------ a known head


@pytest.fixture(scope="module")
def head(rig64):
    """Known parameters (random, inside the limits; no jawOpen), weights of a random latent Z, a camera
    with an off-centre principal point and a turned head, and a saturated photo (so grey differs)."""
    from scipy.spatial.transform import Rotation

    from pipeline.camera import camera_from_head_pose

    g = torch.Generator().manual_seed(7)
    theta = random_theta(g, spread=0.3, dtype=torch.float64)[0]
    c = torch.rand(len(EXPRESSION_NAMES), generator=g, dtype=torch.float64) * 0.15
    c[EXPRESSION_NAMES.index("jawOpen")] = 0.0
    z = torch.randn(50, generator=g, dtype=torch.float64) * 0.5
    with torch.no_grad():
        weights = load_neural(rig64)[0](z[None])[0].numpy()
    rotation = Rotation.from_euler("YX", [18, -6], degrees=True).as_matrix()
    camera = {
        "width": WIDTH,
        "height": HEIGHT,
        "focal_px": 1.4 * WIDTH,
        "principal_point_px": [190.0, 187.5],
        "extrinsics_rig_to_camera": camera_from_head_pose(rotation, np.array([8.0, 14.0, 640.0])).tolist(),
    }
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    photo = np.stack([200 + 55 * xx / WIDTH, 40 + 80 * yy / HEIGHT, 30 + 0 * xx], -1).astype(np.uint8)
    return {"theta": theta.numpy(), "c": c.numpy(), "weights": weights, "camera": camera, "photo": photo}


def posed(rig64, weights, joints: dict, expressions: dict) -> np.ndarray:
    """``(V, 3)`` mm: the rig posed in Python (the ground truth of the page's JavaScript)."""
    theta = params_to_theta(joints, dtype=torch.float64)
    c = coefficients_from_dict(expressions, dtype=torch.float64)
    with torch.no_grad():
        rest = ExpressionModel(rig64.asset, dtype=torch.float64).vertices(c[None])
        return rig64(theta[None], weights=torch.as_tensor(weights), vertices=rest).vertices[0].numpy()


def silhouette(vertices: np.ndarray, faces: np.ndarray, camera: dict) -> np.ndarray:
    """``(H, W)`` bool: the pixels whose centre a projected triangle covers (OpenCV pinhole, numpy)."""
    import cv2

    e = np.asarray(camera["extrinsics_rig_to_camera"])
    x = vertices @ e[:3, :3].T + e[:3, 3]
    cx, cy = camera["principal_point_px"]
    uv = np.stack([camera["focal_px"] * x[:, 0] / x[:, 2] + cx, camera["focal_px"] * x[:, 1] / x[:, 2] + cy], 1)
    mask = np.zeros((HEIGHT, WIDTH), np.uint8)
    for tri in np.round(uv[faces] * 16).astype(np.int32):
        cv2.fillConvexPoly(mask, tri, 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


@pytest.fixture(scope="module")
def page(head, asset, three, tmp_path_factory):
    path = tmp_path_factory.mktemp("viewer") / "viewer.html"
    info = write_viewer(
        path,
        asset,
        theta=head["theta"],
        expressions=head["c"],
        weights=head["weights"],
        views=[ViewerView("known head", head["camera"], head["photo"])],
        title="known head",
    )
    assert info.bytes == path.stat().st_size and info.dropped_weight == 0.0
    return path


@pytest.fixture(scope="module")
def grey_shot(chromium, page, tmp_path_factory):
    """The known head's page, grey and opaque, at the photo's size."""
    return screenshot(chromium, page, "opacity=1&mode=grey", tmp_path_factory.mktemp("shots")).astype(int)


# ------------------------------------------------------------------------------------------ Python side


@needs_three
def test_page_holds_the_head_and_decodes_back_to_the_arrays(page, head, asset):
    data = read_viewer_data(page)
    assert data["format"] == "jnr-viewer/1" and data["mode"] == "rig" and page.stat().st_size < 8e6
    assert np.abs(data["template"] - asset.vertices).max() < 1e-4  # float32 mm
    # triangles over UV-split vertices: the same triangles and per-corner UVs as the asset
    assert np.array_equal(data["render_vertex"][data["faces"]], asset.faces)
    assert np.abs(data["uv"][data["faces"]] - asset.face_uvs).max() < 1e-6
    dense = np.zeros_like(head["weights"])
    np.add.at(dense, (np.arange(len(dense))[:, None], data["skin_joints"].astype(int)), data["skin_weights"])
    assert np.abs(dense - head["weights"]).max() < 1e-6
    basis = ExpressionModel(asset, dtype=torch.float64).basis.numpy()
    sparse = np.zeros_like(basis)
    start = np.concatenate([[0], np.cumsum(data["morph"]["counts"])])
    for e in range(len(basis)):
        rows = slice(start[e], start[e + 1])
        sparse[e, data["morph"]["index"][rows]] = data["morph"]["offsets"][rows]
    assert np.abs(sparse - basis).max() < 1e-5 and len(data["morph"]["index"]) < basis.shape[0] * basis.shape[1] / 4
    assert [c["value"] for c in data["channels"]] == pytest.approx(
        list(theta_to_params(torch.as_tensor(head["theta"])).values()), abs=1e-12
    )
    assert [c["name"] for c in data["channels"]] == [c.name for c in CHANNELS]
    assert data["expressions"]["values"] == pytest.approx(head["c"].tolist(), abs=1e-12)
    view = data["views"][0]
    assert np.allclose(
        view["camera"]["extrinsics_rig_to_camera"], head["camera"]["extrinsics_rig_to_camera"], atol=1e-12
    )
    from base64 import b64decode
    from io import BytesIO

    from PIL import Image

    jpeg = b64decode(data["images"][view["photo"]].split(",", 1)[1])
    photo = np.asarray(Image.open(BytesIO(jpeg)).convert("RGB"), float)
    assert photo.shape == head["photo"].shape and np.abs(photo - head["photo"]).mean() < 2.0  # JPEG


def test_top4_keeps_the_largest_weights_and_renormalises():
    rng = np.random.default_rng(3)
    w = rng.random((50, 7)) * (rng.random((50, 7)) < 0.8)
    w[:, 0] += 0.01
    joints, top, dropped = viewer._top4(w)
    for v in range(len(w)):  # the naive loop
        order = sorted(range(7), key=lambda k: -w[v, k])[:4]
        assert sorted(joints[v]) == sorted(order)
        assert top[v] == pytest.approx(w[v, joints[v]] / w[v, joints[v]].sum())
    assert dropped == pytest.approx(max(sorted(row)[-5] for row in w))


def test_without_three_js_a_fit_skips_the_page_with_one_warning(tmp_path, monkeypatch, asset):
    monkeypatch.setattr(viewer, "ASSETS_DIR", tmp_path / "missing")
    monkeypatch.setattr(viewer, "_warned_missing", False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert write_fit_viewer(tmp_path / "a.html", asset) is None
        assert write_fit_viewer(tmp_path / "b.html", asset) is None
    messages = [str(w.message) for w in caught]
    assert len(messages) == 1 and "make venv" in messages[0]
    assert not list(tmp_path.glob("*.html"))
    with pytest.raises(ViewerUnavailableError, match="make venv"):
        write_viewer(tmp_path / "c.html", asset)


def test_payload_rejects_wrong_shapes(asset):
    with pytest.raises(ValueError, match="theta must have shape"):
        viewer_payload(asset, theta=np.zeros(3))
    with pytest.raises(ValueError, match="weights must have shape"):
        viewer_payload(asset, weights=np.ones((4, 52)))


# ------------------------------------------------------------------------------------------ the browser


@needs_browser
def test_browser_draws_the_head_where_the_camera_projects_it(grey_shot, head, rig64, asset):
    import cv2

    shot = grey_shot
    assert shot.shape == (HEIGHT, WIDTH, 3)
    fitted = {c.name: v for c, v in zip(CHANNELS, theta_to_params(torch.as_tensor(head["theta"])).values())}
    vertices = posed(rig64, head["weights"], fitted, dict(zip(EXPRESSION_NAMES, head["c"])))
    mask = silhouette(vertices, asset.faces, head["camera"])
    differs = np.abs(shot - head["photo"].astype(int)).max(-1) > 40
    kernel = np.ones((5, 5), np.uint8)
    inside = cv2.erode(mask.astype(np.uint8), kernel).astype(bool)
    outside = ~cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)
    assert mask.sum() > 0.1 * mask.size and outside.sum() > 0.2 * mask.size
    assert differs[inside].mean() > 0.98  # the grey head covers its silhouette
    assert differs[outside].mean() < 0.002  # and nothing else: the photo is drawn unchanged
    iou = (differs & mask).sum() / (differs | mask).sum()
    assert iou > 0.95


@needs_browser
def test_browser_slider_from_the_hash_changes_the_mouth_only(chromium, page, grey_shot, head, rig64, asset, tmp_path):
    base = grey_shot
    jaw = screenshot(chromium, page, "opacity=1&jawOpen=1", tmp_path).astype(int)
    changed = np.abs(jaw - base).max(-1) > 30
    # where the camera sees the lips and chin before or after opening the jaw
    fitted = dict(zip([c.name for c in CHANNELS], theta_to_params(torch.as_tensor(head["theta"])).values()))
    expressions = dict(zip(EXPRESSION_NAMES, head["c"]))
    moved_vertices = []
    for jaw_open in (0.0, 1.0):
        v = posed(rig64, head["weights"], fitted, {**expressions, "jawOpen": jaw_open})
        moved_vertices.append(v)
    moving = np.linalg.norm(moved_vertices[1] - moved_vertices[0], axis=1) > 1.0
    faces = asset.faces[moving[asset.faces].any(1)]
    mouth = silhouette(moved_vertices[0], faces, head["camera"]) | silhouette(moved_vertices[1], faces, head["camera"])
    assert changed.sum() > 300
    assert changed[mouth].sum() / changed.sum() > 0.97
    # the forehead and the photo around the head did not change
    still = ~silhouette(moved_vertices[1], faces, head["camera"]) & ~silhouette(
        moved_vertices[0], faces, head["camera"]
    )
    assert changed[still].mean() < 0.001


@needs_browser
def test_browser_deformation_matches_the_python_rig(chromium, page, head, rig64):
    hash_ = (
        "state=all&jawOpen=0.7&mouthSmileLeft=0.6&nose_tip.translate_z=5&left_cheek.scale=1.2"
        "&skull_root.rotate_x=20&neck.rotate_z=-12&crown.translate_y=1000&notAName=1"
    )
    state = page_state(chromium, page, hash_)
    assert state["ready"] and state["three_revision"] == "170" and state["camera"] == "photo"
    assert state["hash_unknown"] == ["notAName"] and state["hash_clamped"] == ["crown.translate_y"]
    crown = CHANNELS[CHANNEL_INDEX["crown.translate_y"]]
    assert state["joints"]["crown.translate_y"] == crown.high
    fitted = dict(zip([c.name for c in CHANNELS], theta_to_params(torch.as_tensor(head["theta"])).values()))
    joints = {
        **fitted,
        "nose_tip.translate_z": 5.0,
        "left_cheek.scale": 1.2,
        "skull_root.rotate_x": 20.0,
        "neck.rotate_z": -12.0,
        "crown.translate_y": crown.high,
    }
    expressions = {**dict(zip(EXPRESSION_NAMES, head["c"])), "jawOpen": 0.7, "mouthSmileLeft": 0.6}
    assert state["joints"] == pytest.approx(joints, abs=1e-12)
    assert state["expressions"] == pytest.approx(expressions, abs=1e-12)
    truth = posed(rig64, head["weights"], joints, expressions)
    js = np.asarray(state["vertices"])
    assert state["vertex_ids"] == list(range(len(truth)))
    assert np.abs(js - truth).max() < 1e-3  # mm
    assert np.abs(truth - posed(rig64, head["weights"], fitted, dict(zip(EXPRESSION_NAMES, head["c"])))).max() > 5


@needs_browser
def test_browser_orbit_view_and_static_mesh_without_a_photo(chromium, asset, rig64, tmp_path):
    """A scan fit's page (no photo: orbit view) of an ASM-like fit (a static mesh): the head is drawn in the
    middle of the window, and the expression sliders move it by the expression offsets."""
    g = np.random.default_rng(5)
    mesh = asset.vertices + g.normal(0, 0.5, asset.vertices.shape)
    base_c = np.zeros(len(EXPRESSION_NAMES))
    base_c[EXPRESSION_NAMES.index("mouthSmileRight")] = 0.5
    page = tmp_path / "scan_viewer.html"
    write_viewer(page, asset, expressions=base_c, static_vertices=mesh, title="static")
    state = page_state(chromium, page, "state=all&jawOpen=0.5&mouthSmileRight=0")
    assert state["camera"] == "orbit" and state["joints"] == {}
    model = ExpressionModel(asset, dtype=torch.float64)
    c = base_c.copy()
    c[EXPRESSION_NAMES.index("jawOpen")], c[EXPRESSION_NAMES.index("mouthSmileRight")] = 0.5, 0.0
    with torch.no_grad():
        truth = mesh + model(torch.as_tensor(c)[None])[0].numpy() - model(torch.as_tensor(base_c)[None])[0].numpy()
    assert np.abs(np.asarray(state["vertices"]) - truth).max() < 1e-3
    shot = screenshot(chromium, page, "", tmp_path).astype(int)
    background = shot[2, 2]
    drawn = np.abs(shot - background).max(-1) > 20
    assert drawn[HEIGHT // 2 - 20 : HEIGHT // 2 + 20, WIDTH // 2 - 20 : WIDTH // 2 + 20].all()
    assert 0.05 < drawn.mean() < 0.6 and not drawn[:, :20].any()


@needs_browser
def test_jnr_fit_writes_a_viewer_that_poses_the_fitted_head(chromium, head, rig64, asset, tmp_path, capsys):
    """A real ``jnr fit`` (of the known head's photo, landmarks projected from it): its viewer.html holds
    params.json's camera and draws the head params.json makes."""
    from PIL import Image

    from landmarks.formats import write_landmarks
    from landmarks.ibug68.embedding import ibug68_embedding
    from landmarks.ibug68.positions import landmark_positions
    from pipeline.cli import main
    from pipeline.photo.outputs import mesh_from_photo_params

    fitted = dict(zip([c.name for c in CHANNELS], theta_to_params(torch.as_tensor(head["theta"])).values()))
    truth = posed(rig64, head["weights"], fitted, dict(zip(EXPRESSION_NAMES, head["c"])))
    points = landmark_positions(truth, ibug68_embedding(asset), asset.faces)[0]
    e, cam = np.asarray(head["camera"]["extrinsics_rig_to_camera"]), head["camera"]
    x = points @ e[:3, :3].T + e[:3, 3]
    px = cam["focal_px"] * x[:, :2] / x[:, 2:] + np.asarray(cam["principal_point_px"])
    Image.fromarray(head["photo"]).save(tmp_path / "photo.png")
    write_landmarks(tmp_path / "photo.pts", px)
    out = tmp_path / "fit"
    short = (
        "landmarks.lm_stages=[{name: pose, free: [pose], iterations: 2}, "
        "{name: all, free: [pose, joints, expressions], iterations: 2}]"
    )
    code = main(
        [
            "fit",
            str(tmp_path / "photo.png"),
            "--landmarks",
            str(tmp_path / "photo.pts"),
            "--out",
            str(out),
            *fast_fit_args("--set", short),
        ]
    )
    assert code == 0, capsys.readouterr().err
    params = json.loads((out / "params.json").read_text())
    data = read_viewer_data(out / "viewer.html")
    camera = data["views"][0]["camera"]
    assert np.allclose(camera["extrinsics_rig_to_camera"], params["camera"]["extrinsics_rig_to_camera"], atol=1e-12)
    assert [camera[k] for k in ("width", "height", "focal_px")] == pytest.approx(
        [params["camera"][k] for k in ("width", "height", "focal_px")]
    )
    state = page_state(chromium, out / "viewer.html", "")
    rebuilt = mesh_from_photo_params(params)
    assert np.abs(np.asarray(state["vertices"]) - rebuilt[state["vertex_ids"]]).max() < 1e-3
