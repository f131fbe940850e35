"""2D facial landmarks: detection, file formats, their embedding on the mesh, the reprojection loss.

May use :mod:`rig`; nothing here yet (see the project issues).
"""
