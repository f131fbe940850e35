"""viewer.html (pipeline.viewer): the data it holds, and the page in a real browser (headless Chromium).

The browser tests skip when Chromium is not installed, except with ``JNR_REQUIRE_BROWSER=1`` (CI), where
they fail. Ground truth: the rig posed in Python (rig.model.JointRig, rig.expressions.ExpressionModel) and
the head's silhouette projected with the camera in numpy.
"""

import html
import json
import re
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

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
    return {
        "theta": theta.numpy(),
        "c": c.numpy(),
        "z": z.numpy(),
        "weights": weights,
        "camera": camera,
        "photo": photo,
    }


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
        latent_z=head["z"],
        views=[ViewerView("known head", head["camera"], head["photo"])],
        title="known head",
    )
    assert info.bytes == path.stat().st_size and info.dropped_weight == 0.0
    return path


@pytest.fixture(scope="module")
def shared_page(head, asset, three, tmp_path_factory):
    """The known head's page in shared mode as a folder run lays it out: ``run/three.jnr.js`` and
    ``run/known head/viewer.html`` (a space in the folder's name, as photos' names have)."""
    run = tmp_path_factory.mktemp("run")
    (run / "known head").mkdir()
    path = run / "known head" / "viewer.html"
    viewer.write_shared_three(run)
    src = viewer.shared_three_src(path.parent, run)
    assert src == "../three.jnr.js"
    write_viewer(
        path,
        asset,
        three_src=src,
        theta=head["theta"],
        expressions=head["c"],
        weights=head["weights"],
        latent_z=head["z"],
        views=[ViewerView("known head", head["camera"], head["photo"])],
        title="known head",
    )
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
    state = page_state(chromium, page, "state=all&jawOpen=0.5&mouthSmileRight=0&params=1")
    assert state["camera"] == "orbit" and state["joints"] == {} and state["params"] is None  # nothing to save
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


# ------------------------------------------------------------------------------------------ shared three.js


def _module_exports() -> list[str]:
    """The names ``three.module.min.js`` exports, read from its final ``export{a as B,...}`` here."""
    code = viewer.three_js_path().read_text(encoding="utf-8")
    items = code[code.rindex("export{") + len("export{") : code.rindex("}")].split(",")
    return [re.split(r"\s+as\s+", item.strip())[-1] for item in items]


@needs_three
def test_shared_three_script_keeps_the_licence_and_exports_every_name(three):
    script = viewer.shared_three_script()
    module = viewer.three_js_path().read_text(encoding="utf-8")
    header = module[: module.index("*/") + 2]
    assert "@license" in header and script.startswith(header + "\n")
    exports = _module_exports()
    assert len(exports) > 400 and {"WebGLRenderer", "REVISION", "BufferGeometry"} <= set(exports)
    final = script[script.rindex("globalThis.JNR_THREE=Object.freeze({") :]
    assert final.endswith("});\n})();\n")
    frozen = final[len("globalThis.JNR_THREE=Object.freeze({") : -len("});\n})();\n")]
    assert [item.split(":")[0] for item in frozen.split(",")] == exports
    assert "export{" not in script and '(function () {\n"use strict";\n' in script
    assert abs(len(script) - len(module)) < 2000  # the module's code itself, unchanged


@needs_three
def test_shared_three_refuses_a_three_js_of_another_shape(tmp_path, monkeypatch):
    header = "/**\n * @license\n * Copyright 2010-2024 Three.js Authors\n * SPDX-License-Identifier: MIT\n */\n"
    cases = {
        "imports other modules": header + 'import{a as b}from"./three.core.js";const c=1;export{c as C};\n',
        "does not end with one export": header + "const c=1;export{c as C};c.x=2;\n",
        "more than the final export": header + "export const d=2;const c=1;export{c as C};\n",
        "@license": "const c=1;export{c as C};\n",
    }
    for k, (why, code) in enumerate(cases.items()):
        folder = tmp_path / f"assets{k}"
        folder.mkdir()
        (folder / viewer.THREE_FILE).write_text(code)
        monkeypatch.setattr(viewer, "ASSETS_DIR", folder)
        with pytest.raises(viewer.ThreeModuleError, match=why):
            viewer.write_shared_three(tmp_path)
    assert not (tmp_path / viewer.SHARED_THREE_FILE).exists()
    (folder / viewer.THREE_FILE).write_text(header + 'const t="170";export{t as REVISION,t as Same};\n')
    assert viewer.shared_three_script().endswith(
        '"use strict";\nconst t="170";\nglobalThis.JNR_THREE=Object.freeze({REVISION:t,Same:t});\n})();\n'
    )


@needs_three
def test_write_shared_three_is_atomic_and_idempotent(tmp_path):
    path = viewer.write_shared_three(tmp_path)
    assert path == tmp_path / viewer.SHARED_THREE_FILE and path.read_text() == viewer.shared_three_script()
    before = path.stat()
    assert viewer.write_shared_three(tmp_path) == path
    after = path.stat()
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)  # left as it was
    path.write_text("stale")
    viewer.write_shared_three(tmp_path)
    assert path.read_text() == viewer.shared_three_script()
    assert [p.name for p in tmp_path.iterdir()] == [viewer.SHARED_THREE_FILE]  # no temporary left
    with pytest.raises(FileNotFoundError):
        viewer.write_shared_three(tmp_path / "missing")


@needs_three
def test_shared_page_is_smaller_and_escapes_its_url(page, shared_page, asset, tmp_path):
    inline, shared = page.stat().st_size, shared_page.stat().st_size
    # measured: 2,310,209 bytes inline, 1,389,054 shared: three.js's 921,155 bytes of base64 left out
    assert inline - shared > 0.9e6 and shared < 0.62 * inline
    text = shared_page.read_text()
    assert "data:text/javascript" not in text and 'type="importmap"' not in text
    assert '<script id="jnr-three" src="../three.jnr.js"></script>' in text
    assert read_viewer_data(shared_page)["channels"] == read_viewer_data(page)["channels"]
    odd = tmp_path / "odd.html"
    write_viewer(odd, asset, three_src='../a "b"&<c>.js')
    assert '<script id="jnr-three" src="../a &quot;b&quot;&amp;&lt;c&gt;.js"></script>' in odd.read_text()
    assert viewer.shared_three_src(tmp_path / "a b" / "c#d", tmp_path) == "../../three.jnr.js"
    assert viewer.shared_three_src(tmp_path, tmp_path / "x y") == "x%20y/three.jnr.js"
    for bad in ("", "  ", "../a\nb.js"):
        with pytest.raises(viewer.ViewerError, match="three_src"):
            write_viewer(tmp_path / "bad.html", asset, three_src=bad)


@needs_browser
def test_browser_shared_three_defines_every_export_as_one_global(chromium, tmp_path):
    viewer.write_shared_three(tmp_path)
    probe = tmp_path / "probe.html"
    probe.write_text(
        "<!doctype html><html><body><pre id=out></pre>\n"
        "<script>const before = new Set(Object.getOwnPropertyNames(globalThis));</script>\n"
        f'<script src="{viewer.SHARED_THREE_FILE}"></script>\n'
        "<script>const T = globalThis.JNR_THREE; document.getElementById('out').textContent = JSON.stringify({"
        "names: Object.keys(T), frozen: Object.isFrozen(T), revision: T.REVISION, renderer: typeof T.WebGLRenderer,"
        "added: Object.getOwnPropertyNames(globalThis).filter((n) => !before.has(n)).sort()});</script>"
        "</body></html>"
    )
    dom = _browse(chromium, probe, "", "--dump-dom").stdout.decode("utf-8")
    out = json.loads(html.unescape(re.search(r"<pre id=\"out\">(.*?)</pre>", dom, re.S).group(1)))
    assert out["names"] == _module_exports() and out["frozen"] and out["renderer"] == "function"
    assert out["revision"] == "170" and out["added"] == ["JNR_THREE", "__THREE__"]  # three's own marker


@needs_browser
def test_browser_shared_page_renders_as_the_inline_page(chromium, page, shared_page, grey_shot, tmp_path):
    hash_ = "state=all&jawOpen=0.7&nose_tip.translate_z=5&skull_root.rotate_x=20"
    state, inline = page_state(chromium, shared_page, hash_), page_state(chromium, page, hash_)
    assert state["ready"] and state["three_revision"] == "170"
    assert state["vertices"] == inline["vertices"] and state["joints"] == inline["joints"]
    shot = screenshot(chromium, shared_page, "opacity=1&mode=grey", tmp_path).astype(int)
    assert np.abs(shot - grey_shot).max() == 0  # the same three.js code on the same data


@needs_browser
def test_browser_shared_page_without_its_file_says_which_file(chromium, shared_page, tmp_path):
    alone = tmp_path / "copied" / "viewer.html"  # the page's folder copied without ../three.jnr.js
    alone.parent.mkdir()
    shutil.copy(shared_page, alone)
    dom = _browse(chromium, alone, "", "--dump-dom").stdout.decode("utf-8")
    message = html.unescape(re.search(r'<div id="jnr-error"[^>]*>(.*?)</div>', dom, re.S).group(1))
    assert "could not load three.js from the file three.jnr.js" in message
    assert "../three.jnr.js" in message and (tmp_path / "three.jnr.js").as_uri() in message
    with pytest.raises(ValueError, match="no #jnr-state"):
        read_viewer_state(dom)


# ------------------------------------------------------------------------------------------ saving a pose

SAVE_PROBE = """<script>
window.addEventListener("load", () => setTimeout(async () => {
  let blob = null, name = null;
  URL.createObjectURL = (b) => { blob = b; return "blob:jnr-test"; };
  HTMLAnchorElement.prototype.click = function () { name = this.download; };
  document.getElementById("save").click();
  const out = Object.assign(document.createElement("pre"), { id: "jnr-saved", hidden: true });
  out.textContent = JSON.stringify({ name, type: blob.type, text: await blob.text() });
  document.body.appendChild(out);
}, 0));
</script>
"""
"""Test-only: clicks the page's Save button after the page's own start, keeping the Blob it downloads."""


@needs_browser
def test_browser_saved_pose_is_the_fit_params_jnr_rig_edit_reads(chromium, page, head, rig64, tmp_path, capsys):
    """The "Save pose" file of a page with the fit's latent Z: a whole head (joints, latent Z, expressions) that
    ``jnr rig edit`` reads as a fit's params.json, posing exactly what the page shows."""
    import trimesh

    from pipeline.cli import main
    from pipeline.edit import load_edit_params

    # the page, with a script that clicks "Save pose" once it is drawn and keeps what it downloads
    probe = tmp_path / "probe.html"
    probe.write_text(page.read_text().replace("</body>", SAVE_PROBE + "</body>"))
    hash_ = "state=all&params=1&jawOpen=0.7&mouthSmileLeft=1&nose_tip.translate_z=5&crown.translate_y=1000"
    dom = _browse(chromium, probe, hash_, "--dump-dom").stdout.decode("utf-8")
    state = read_viewer_state(dom)
    download = json.loads(html.unescape(re.search(r'<pre id="jnr-saved"[^>]*>(.*?)</pre>', dom, re.S).group(1)))
    assert download["name"] == "params_edited.json" and download["type"] == "application/json"
    saved = json.loads(download["text"])
    assert saved == state["params"] and list(saved) == ["model", "units", "joints", "latent_z", "expressions"]
    assert saved["joints"] == state["joints"] and saved["expressions"] == state["expressions"]
    assert saved["joints"]["crown.translate_y"] == CHANNELS[CHANNEL_INDEX["crown.translate_y"]].high  # at a limit
    path = tmp_path / download["name"]
    path.write_text(download["text"])
    theta, fit = load_edit_params(path)
    assert theta is None and fit is not None
    assert np.array_equal(fit.theta, params_to_theta(state["joints"], dtype=torch.float64).numpy())
    assert np.array_equal(fit.expressions, [state["expressions"][n] for n in EXPRESSION_NAMES])
    assert np.array_equal(fit.params["latent"], head["z"])
    assert np.abs(fit.vertices - np.asarray(state["vertices"])).max() < 1e-3  # mm: what the page drew
    out = tmp_path / "edited.ply"
    assert main(["rig", "edit", str(path), "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    assert np.abs(trimesh.load(out, process=False).vertices - fit.vertices).max() < 1e-3


@needs_browser
def test_browser_saved_pose_without_latent_z_is_a_joint_file_inside_the_limits(chromium, asset, tmp_path):
    """Without the fit's latent Z the page saves its joint channels (``{"units", "joints"}``); a fitted
    value a little outside its limits (a soft penalty allows it) is saved at the limit."""
    from pipeline.edit import load_edit_params

    theta = np.zeros(len(CHANNELS))
    over = CHANNELS[CHANNEL_INDEX["jaw_front.rotate_z"]]
    theta[CHANNEL_INDEX["jaw_front.rotate_z"]] = over.to_theta(over.high + 0.01 * (over.high - over.low))
    page = tmp_path / "viewer.html"
    write_viewer(page, asset, theta=theta)
    state = page_state(chromium, page, "params=1&neck.rotate_x=-12.345678901234&left_cheek.scale=1.2")
    saved = state["params"]
    assert list(saved) == ["units", "joints"] and saved["units"] == {
        "rotate": "deg",
        "translate": "mm",
        "scale": "factor",
    }
    assert list(saved["joints"]) == [c.name for c in CHANNELS]
    assert saved["joints"]["jaw_front.rotate_z"] == over.high and state["joints"]["jaw_front.rotate_z"] > over.high
    path = tmp_path / viewer.SAVE_FILE
    path.write_text(json.dumps(saved))
    loaded, fit = load_edit_params(path)
    assert fit is None
    expected = params_to_theta(saved["joints"], dtype=torch.float32).double()  # how the rig reads joint files
    assert torch.equal(loaded, expected) and loaded[CHANNEL_INDEX["neck.rotate_x"]] == pytest.approx(-12.345678901234)


def test_the_committed_three_js_is_the_version_package_json_pins():
    """three.js ships in the package (issue 38: a pip installation wrote no viewer.html); ``make three``
    refreshes it, and a pin changed without that is caught here."""
    root = Path(__file__).resolve().parents[2]
    pinned = json.loads((root / "package.json").read_text())["dependencies"]["three"]
    shipped = json.loads((root / "pipeline" / "viewer_assets" / "three-package.json").read_text())
    assert shipped["name"] == "three" and shipped["version"] == pinned
    assert viewer.viewer_available() and (root / "pipeline" / "viewer_assets" / "three-LICENSE").is_file()
