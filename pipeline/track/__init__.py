"""``jnr track``: a face followed through a video, fitted frame by frame on one identity, written as ARKit
curves (Live Link Face and plain CSV), an animated glTF, every frame's parameters and a preview.

- :mod:`pipeline.track.video`: the frames of a video file or a folder of numbered images;
- :mod:`pipeline.track.follow`: MediaPipe's dense points frame by frame (each frame's crop from the last);
- :mod:`pipeline.track.tracker`: the identity from keyframes, then pose, expressions per frame with a
  temporal prior;
- :mod:`pipeline.track.outputs`: the output folder.
"""
