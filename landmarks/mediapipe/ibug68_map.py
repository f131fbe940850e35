"""The 68 iBUG landmarks from MediaPipe's 468-point face mesh: a fixed table of convex combinations.

Each iBUG-68 landmark (:data:`landmarks.ibug68.names.IBUG68_NAMES` order) is a weighted mean of three mesh
points, ``sum_j w_kj * mesh[i_kj]``, weights ``>= 0`` summing to 1 (:data:`IBUG68_MESH_INDICES`,
:data:`IBUG68_MESH_WEIGHTS`). The table is fitted by ``benchmarks/fit_mediapipe_ibug_map.py`` (it writes
the block below): synthetic photos of the rig's template with their true 68 landmarks (the projections
of the embedding jnr's photo fit uses, the jaw contour as the camera sees it), MediaPipe's mesh on each,
and for each landmark the triple of mesh points near it whose convex combination agrees best with the
true landmark over all the photos (least squares, pixels scaled to an inter-ocular distance of 100).
The jaw contour (0-16) of iBUG follows the face's silhouette as the head turns; a fixed vertex mix
cannot, so those points are the least accurate for turned heads.

The table's error on photos the fit never saw, and against dlib's 68 on a real photo, is measured in
``docs/landmarks.md`` ("MediaPipe's detector and its 68 points").

Example::

    ibug = mesh_to_ibug68(dense[:, :2])        # (468+, 2) pixels -> (68, 2) pixels
"""

from __future__ import annotations

import numpy as np

from rig.errors import InputError

# --- fitted table (benchmarks/fit_mediapipe_ibug_map.py --write replaces this block) ---
# fmt: off
IBUG68_MESH_INDICES = np.array([
    [127, 234, 35], [234, 123, 93], [93, 177, 147], [215, 58, 132], [172, 215, 58], [136, 150, 169],
    [149, 176, 140], [148, 176, 171], [152, 377, 175], [377, 400, 369], [378, 400, 369], [365, 379, 397],
    [397, 435, 416], [435, 288, 361], [366, 361, 323], [447, 323, 366], [356, 447, 368], [71, 225, 63],
    [52, 68, 46], [69, 223, 105], [107, 69, 222], [107, 9, 168], [336, 8, 417], [296, 336, 337],
    [296, 283, 299], [333, 283, 276], [293, 353, 301], [168, 6, 465], [197, 351, 122], [195, 5, 248],
    [4, 275, 274], [98, 75, 60], [97, 141, 99], [164, 2, 462], [326, 305, 393], [327, 460, 392],
    [130, 161, 30], [159, 29, 27], [158, 56, 28], [155, 154, 190], [23, 154, 232], [24, 25, 229],
    [381, 414, 384], [386, 286, 384], [387, 257, 444], [263, 342, 260], [339, 254, 249], [253, 381, 252],
    [43, 96, 78], [73, 40, 88], [37, 72, 12], [11, 302, 0], [302, 267, 269], [270, 303, 304],
    [273, 409, 291], [405, 335, 406], [314, 313, 406], [17, 18, 313], [84, 83, 17], [181, 182, 106],
    [95, 146, 91], [81, 14, 86], [13, 15, 312], [316, 312, 311], [375, 325, 407], [312, 315, 311],
    [13, 16, 312], [14, 81, 85],
], dtype=np.int64)
IBUG68_MESH_WEIGHTS = np.array([
    [0.5688, 0.2654, 0.1658], [0.4777, 0.2902, 0.2321], [0.5529, 0.3539, 0.0932], [0.5413, 0.3594, 0.0993],
    [0.7565, 0.2226, 0.0209], [0.7488, 0.2512, 0.0000], [0.6352, 0.3648, 0.0000], [0.9616, 0.0384, 0.0000],
    [0.9556, 0.0444, 0.0000], [0.7951, 0.2049, 0.0000], [0.8048, 0.1952, 0.0000], [0.9840, 0.0160, 0.0000],
    [0.6967, 0.3033, 0.0000], [0.6446, 0.2085, 0.1469], [0.6470, 0.3475, 0.0055], [0.5140, 0.3015, 0.1845],
    [0.6705, 0.2439, 0.0856], [0.4645, 0.3930, 0.1425], [0.5452, 0.4116, 0.0432], [0.4584, 0.3602, 0.1814],
    [0.5678, 0.2453, 0.1869], [0.6127, 0.2030, 0.1843], [0.6967, 0.2550, 0.0483], [0.5649, 0.4254, 0.0097],
    [0.3896, 0.3524, 0.2580], [0.3985, 0.3334, 0.2681], [0.3971, 0.3512, 0.2517], [0.7477, 0.1678, 0.0845],
    [0.6860, 0.2242, 0.0898], [0.4401, 0.4181, 0.1418], [0.8979, 0.0572, 0.0449], [0.5327, 0.2682, 0.1991],
    [0.9796, 0.0204, 0.0000], [0.5412, 0.3422, 0.1166], [0.7731, 0.1320, 0.0949], [0.4206, 0.3861, 0.1933],
    [0.5903, 0.2163, 0.1934], [0.5139, 0.3867, 0.0994], [0.6202, 0.2534, 0.1264], [0.4656, 0.2779, 0.2565],
    [0.4480, 0.3410, 0.2110], [0.6676, 0.3220, 0.0104], [0.6302, 0.2650, 0.1048], [0.4742, 0.4413, 0.0845],
    [0.5382, 0.4040, 0.0578], [0.6246, 0.3061, 0.0693], [0.4935, 0.3915, 0.1150], [0.3814, 0.3510, 0.2676],
    [0.5948, 0.2442, 0.1610], [0.5703, 0.3114, 0.1183], [0.6021, 0.2000, 0.1979], [0.7809, 0.1137, 0.1054],
    [0.5067, 0.4685, 0.0248], [0.5014, 0.3883, 0.1103], [0.6161, 0.3444, 0.0395], [0.5497, 0.3519, 0.0984],
    [0.7273, 0.2196, 0.0531], [0.7332, 0.1784, 0.0884], [0.6078, 0.2748, 0.1174], [0.5942, 0.2233, 0.1825],
    [0.4332, 0.3376, 0.2292], [0.4111, 0.3776, 0.2113], [0.4205, 0.3899, 0.1896], [0.4304, 0.2889, 0.2807],
    [0.6380, 0.2193, 0.1427], [0.4195, 0.3831, 0.1974], [0.4555, 0.3781, 0.1664], [0.3768, 0.3621, 0.2611],
])
# fmt: on
# --- end of fitted table ---
IBUG68_MESH_INDICES.flags.writeable = False
IBUG68_MESH_WEIGHTS.flags.writeable = False


def mesh_to_ibug68(points: np.ndarray) -> np.ndarray:
    """The 68 iBUG landmarks of a face mesh.

    Args:
        points: ``(N, D)`` the mesh points, ``N >= 468`` (the 478-point layout too), ``D >= 2``; pixels.

    Returns:
        ``(68, D)`` float64, the same units (:data:`IBUG68_MESH_WEIGHTS`-weighted means of
        :data:`IBUG68_MESH_INDICES`).

    Raises:
        ValueError: fewer than 468 points or not 2-D.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[0] < 468:
        raise InputError(f"mesh_to_ibug68: expected points (468+, D), got {points.shape}")
    return np.einsum("kj,kjd->kd", IBUG68_MESH_WEIGHTS, points[IBUG68_MESH_INDICES])


__all__ = ["IBUG68_MESH_INDICES", "IBUG68_MESH_WEIGHTS", "mesh_to_ibug68"]
