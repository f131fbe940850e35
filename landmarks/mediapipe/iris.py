"""MediaPipe's iris model on both eyes of a face mesh: the 478-point layout (468 mesh + 2 x 5 iris points).

The steps of MediaPipe's ``IrisLandmarkLeftAndRightCpu`` graph:

1. :func:`eye_rect`: for each eye, the box of its two mesh corners, grown to a square of 2.3 times its
   longer side around its centre, turned so that the corner-to-corner line is horizontal
   (``IrisLandmarkLandmarksToRoi``). The corners are listed image-left first (:data:`EYE_CORNERS`).
2. The crop at 64 x 64, edge pixels replicated, values in ``[0, 1]``. The model knows one eye only, the
   one on the image's left of a face towards the camera (the subject's right eye, MediaPipe's "left
   eye"); the other eye's crop (the subject's left eye) is mirrored left-right before the model and its
   points mirrored back (``IS_RIGHT_EYE``).
3. The model: 71 eye-contour and brow points and 5 iris points (centre, then four on the iris's edge),
   ``(x, y, z)`` in crop pixels.
4. Back to image pixels. The 5 iris points are appended to the mesh in MediaPipe's 478-point order
   (:data:`IRIS_INDICES`): 468-472 the subject's **right** iris (image left; the eye of mesh points 33
   and 133), 473-477 the subject's **left** iris (the eye of 362 and 263). Their ``z`` is the mean ``z``
   of the mesh's 16 eyelid points of that eye (MediaPipe's ``assign_average`` refinement).
   With ``refine_eyes`` the contour points of the eyelids and the rings around them also replace the
   ``(x, y)`` of the mesh points they refine (:data:`EYE_CONTOUR_MESH_INDICES`,
   :data:`REFINED_CONTOUR_POINTS`; ``z`` kept), as MediaPipe's iris graph does for all 71.

Example::

    dense = add_irises(image, mesh.points)     # (478, 3) pixels
    dense[468], dense[473]                     # the centres of the subject's right and left irises
"""

from __future__ import annotations

import numpy as np

from landmarks.mediapipe.crop import RotatedRect, crop_to_image, square_rect, warp_crop
from landmarks.mediapipe.mesh import NUM_MESH_POINTS, eye_line_angle
from landmarks.mediapipe.models import model

NUM_DENSE_POINTS = 478
IRIS_INPUT_SIZE = 64
"""The iris model's input side, pixels."""
EYE_RECT_SCALE = 2.3
"""The eye crop's side over the longer side of the box of the eye's two corners."""
EYE_CORNERS = {"right": (33, 133), "left": (362, 263)}
"""The mesh points of each eye's corners, image-left first (outer then inner corner of the subject's
right eye; inner then outer corner of the left eye)."""
IRIS_INDICES = {"right": range(468, 473), "left": range(473, 478)}
"""Where each eye's 5 iris points go in the 478-point layout: centre, then four points on the iris's edge."""
_EYE_CONTOUR_RIGHT = (
    # eyelids: lower contour (outer to inner corner), then upper contour without the corners
    (33, 7, 163, 144, 145, 153, 154, 155, 133, 246, 161, 160, 159, 158, 157, 173)
    # rings around the eye, each lower then upper, growing outwards; the last is the brow's lower edge
    + (130, 25, 110, 24, 23, 22, 26, 112, 243, 247, 30, 29, 27, 28, 56, 190)
    + (226, 31, 228, 229, 230, 231, 232, 233, 244, 113, 225, 224, 223, 222, 221, 189)
    + (35, 124, 46, 53, 52, 65)
    + (143, 111, 117, 118, 119, 120, 121, 128, 245, 156, 70, 63, 105, 66, 107, 55, 193)
)
_EYE_CONTOUR_LEFT = (
    (263, 249, 390, 373, 374, 380, 381, 382, 362, 466, 388, 387, 386, 385, 384, 398)
    + (359, 255, 339, 254, 253, 252, 256, 341, 463, 467, 260, 259, 257, 258, 286, 414)
    + (446, 261, 448, 449, 450, 451, 452, 453, 464, 342, 445, 444, 443, 442, 441, 413)
    + (265, 353, 276, 283, 282, 295)
    + (372, 340, 346, 347, 348, 349, 350, 357, 465, 383, 300, 293, 334, 296, 336, 285, 417)
)
EYE_CONTOUR_MESH_INDICES = {"right": _EYE_CONTOUR_RIGHT, "left": _EYE_CONTOUR_LEFT}
"""The mesh point each of the iris model's 71 eye-contour points refines, per eye (MediaPipe's order; the
left eye's are the mirror images of the right eye's)."""
EYELID_POINTS = 16
"""The first 16 of each eye's contour are its eyelids (their mean ``z`` is the iris's ``z``)."""
REFINED_CONTOUR_POINTS = 48
"""With ``refine_eyes``, the first 48 of each eye's contour points (the eyelids and the two rings around them)
replace the mesh's; MediaPipe replaces all 71, but the outer rings run along the brow at the edge of the
eye crop, where the mesh, which sees the whole brow, is better: on the synthetic views of
``benchmarks/fit_mediapipe_ibug_map.py`` replacing 48 rather than 71 lowered the mapped brows' error from 4.3
to 3.8 px (at an inter-ocular distance of 100 px) and left the eyes' at 2.2 (2.9 without refinement)."""


def eye_rect(points: np.ndarray, eye: str) -> RotatedRect:
    """The iris model's crop of one eye.

    Args:
        points: ``(468, 2+)`` mesh points, pixels. eye: ``"right"`` or ``"left"`` (the subject's).

    Returns:
        The square :class:`~landmarks.mediapipe.crop.RotatedRect` of side 2.3 x the longer side of the box
        of the eye's corners (:data:`EYE_CORNERS`), around the box centre, turned by the corner-to-corner line.
    """
    first, second = (np.asarray(points[i, :2], dtype=np.float64) for i in EYE_CORNERS[eye])
    low, high = np.minimum(first, second), np.maximum(first, second)
    width, height = high - low
    return square_rect((low + high) / 2.0, width, height, eye_line_angle(first, second), EYE_RECT_SCALE)


def eye_landmarks(
    image: np.ndarray, rect: RotatedRect, mirrored: bool, num_threads: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Run the iris model on one eye's crop.

    Args:
        image: ``(H, W, 3)`` uint8 RGB. rect: the eye's crop (:func:`eye_rect`). mirrored: mirror the crop
            left-right for the model and its points back (the subject's left eye). num_threads: LiteRT's.

    Returns:
        ``(71, 3)`` eye-contour and ``(5, 3)`` iris points, float64: ``(x, y)`` 0-based OpenCV pixels, ``z``
        in the same pixel scale (relative to the eye crop's own depth origin).

    Raises:
        DetectionError: the runtime or the model file is missing.
    """
    crop = warp_crop(image, rect, IRIS_INPUT_SIZE)
    if mirrored:
        crop = crop[:, ::-1]
    net = model("iris_landmark", num_threads)
    outputs = {o.size: o for o in net.run((crop.astype(np.float32) / np.float32(255.0))[None])}
    result = []
    for count in (71, 5):
        raw = outputs[count * 3].reshape(count, 3).astype(np.float64) / IRIS_INPUT_SIZE
        if mirrored:
            raw[:, 0] = 1.0 - raw[:, 0]
        result.append(crop_to_image(raw, rect))
    return result[0], result[1]


def add_irises(
    image: np.ndarray, mesh: np.ndarray, refine_eyes: bool = True, num_threads: int = 1
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The 478-point layout of a face: its mesh and both irises.

    Args:
        image: ``(H, W, 3)`` uint8 RGB. mesh: ``(468, 3)`` the face's mesh points (pixels,
            :func:`~landmarks.mediapipe.mesh.face_mesh`). refine_eyes: replace the ``(x, y)`` of the mesh's
            eye points with the iris model's contour (:data:`REFINED_CONTOUR_POINTS` of
            :data:`EYE_CONTOUR_MESH_INDICES`).
            num_threads: LiteRT's.

    Returns:
        ``(478, 3)`` float64 (0-based OpenCV pixels; ``z`` in the same scale), and each eye's ``(71, 3)``
        contour points by ``"right"`` / ``"left"`` (the subject's).

    Raises:
        DetectionError: the runtime or the model file is missing.
    """
    mesh = np.asarray(mesh, dtype=np.float64)
    dense = np.empty((NUM_DENSE_POINTS, 3))
    dense[:NUM_MESH_POINTS] = mesh
    contours = {}
    for eye in ("right", "left"):
        contour, iris = eye_landmarks(image, eye_rect(mesh, eye), mirrored=eye == "left", num_threads=num_threads)
        lids = list(EYE_CONTOUR_MESH_INDICES[eye][:EYELID_POINTS])
        iris[:, 2] = mesh[lids, 2].mean()
        dense[list(IRIS_INDICES[eye])] = iris
        if refine_eyes:
            refined = list(EYE_CONTOUR_MESH_INDICES[eye][:REFINED_CONTOUR_POINTS])
            dense[refined, :2] = contour[:REFINED_CONTOUR_POINTS, :2]
        contours[eye] = contour
    return dense, contours


__all__ = [
    "EYELID_POINTS",
    "REFINED_CONTOUR_POINTS",
    "EYE_CONTOUR_MESH_INDICES",
    "EYE_CORNERS",
    "EYE_RECT_SCALE",
    "IRIS_INDICES",
    "IRIS_INPUT_SIZE",
    "NUM_DENSE_POINTS",
    "add_irises",
    "eye_landmarks",
    "eye_rect",
]
