"""The test mesh of the rig.io tests: an icosphere with a UV seam, colours and a 3-joint chain."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

RADIUS_MM = 100.0
JOINT_NAMES = ["neck", "head", "crown"]
PARENTS = np.array([-1, 0, 1])
JOINT_POSITIONS = np.array([[0.0, -90.0, -10.0], [0.0, 0.0, 5.0], [0.0, 60.0, 0.0]])


@pytest.fixture(scope="module")
def sphere():
    """Icosphere (162 vertices) of radius 100 mm with a UV seam, colours and 3-joint weights."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * RADIUS_MM
    faces = np.asarray(mesh.faces, dtype=np.int64)

    # spherical UVs per face corner; faces straddling u = 0 / 1 get u + 1 on their low corners,
    # so the vertices on the seam carry two different UVs
    unit = vertices / RADIUS_MM
    u = np.arctan2(unit[:, 0], unit[:, 2]) / (2.0 * np.pi) + 0.5
    v = 0.5 + np.arcsin(np.clip(unit[:, 1], -1.0, 1.0)) / np.pi
    face_uvs = np.stack([u[faces], v[faces]], axis=-1)
    wraps = np.ptp(face_uvs[:, :, 0], axis=1) > 0.5
    low = wraps[:, None] & (face_uvs[:, :, 0] < 0.5)
    face_uvs[:, :, 0] = np.where(low, face_uvs[:, :, 0] + 1.0, face_uvs[:, :, 0])
    assert wraps.any()

    # smooth weights along the chain (Gaussian in y around each joint)
    dist = np.abs(vertices[:, 1:2] - JOINT_POSITIONS[None, :, 1])
    weights = np.exp(-((dist / 45.0) ** 2))
    weights /= weights.sum(axis=1, keepdims=True)

    rng = np.random.default_rng(0)
    colors = rng.uniform(0.0, 1.0, size=(len(vertices), 3))
    return {"vertices": vertices, "faces": faces, "face_uvs": face_uvs, "weights": weights, "colors": colors}


def merge_duplicates(loaded_vertices, faces, vertices):
    """Map every vertex index >= V of a loaded mesh to the input vertex at the same position."""
    n = len(vertices)
    source = np.arange(len(loaded_vertices))
    for i in range(n, len(loaded_vertices)):
        d = np.linalg.norm(vertices - loaded_vertices[i], axis=1)
        source[i] = int(np.argmin(d))
        assert d[source[i]] < 1e-4
    return source[faces]
