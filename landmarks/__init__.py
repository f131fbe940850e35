"""Facial landmarks: detection, file formats, their embedding on the template, the reprojection loss.

* :mod:`landmarks.detector`: the :class:`~landmarks.detector.FaceDetector` protocol and the registry of
  detectors (``--detector NAME``); :mod:`landmarks.detect` runs one by name and sorts the faces.
* :mod:`landmarks.dlib_detector`: dlib's ``hog``, ``cnn`` and ``dlib`` detectors (68 iBUG points).
* :mod:`landmarks.mediapipe`: MediaPipe's detector, 478-point mesh and irises (``mediapipe``; ``auto``, the
  default, is it with dlib's detectors behind it), their embedding on the template and their layout.
* :mod:`landmarks.ibug68`: the 68 iBUG landmarks embedded on the template and posed with the mesh.
* :mod:`landmarks.layout`: :class:`~landmarks.layout.LandmarkLayout`, a point scheme as the photo fit uses it.
* :mod:`landmarks.formats` (``.pts``, ``.json``, ``.csv`` files), :mod:`landmarks.images` (reading photos),
  :mod:`landmarks.plausibility` (is a set of 68 points a face), :mod:`landmarks.loss` (the reprojection
  loss), :mod:`landmarks.points3d` (named 3D landmarks on the template, for point clouds).

May use :mod:`rig`, nothing else of jnr (the layers in ``pyproject.toml``); the detectors' libraries are
imported only when a detector is made.
"""
