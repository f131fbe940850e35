"""Synthetic portrait photos of held-out synthetic heads, with known ground truth.

Validates the photo fit on images whose answer is known: a held-out head (never seen in training) gets
a random skin/hair/eye albedo, a random pose and camera, a random point light + environment and a
random background, and is path-traced by :func:`render.reference.render_reference` -- a renderer and a
light model that differ from the fitting renderer's, so a fit is not rewarded for sharing its
approximations (no inverse crime). The 68 iBUG landmarks are projected from the true mesh (jaw contour:
the silhouette seen from the camera, :func:`landmarks.ibug68.contour.contour_landmarks`) and jittered like a
landmark detector's output.

Frames (as :mod:`pipeline.camera`):

- **rig space**: mm, right-handed, +X the subject's left, +Y up, +Z out of the face. The true mesh
  ``gt_vertices`` is unposed, in rig space.
- **head pose** ``(rotation, translation)``: ``x_cam = RIG_TO_OPENCV @ rotation @ x_rig + translation``,
  with ``x_cam`` in OpenCV camera coordinates (x right, y down, z forward, mm);
  ``rotation = R_z(roll) R_x(pitch) R_y(yaw)`` (:func:`rig.geometry.head_rotation`): a positive yaw turns the face
  towards the subject's left, i.e. towards the image's right.
- **pixels**: OpenCV / kornia, 0-based, pixel centres at integer coordinates, principal point at the
  image centre ``((W - 1) / 2, (H - 1) / 2)`` (:func:`pipeline.camera.make_camera`).

Colours: ``*_linear`` arrays and albedos are linear RGB; ``image`` is 8-bit sRGB.
Everything is deterministic given the random generator (or ``(seed, index, expressive)``).

Modules: :mod:`~pipeline.synthetic.photos.simulate` (photographing a head:
:func:`~pipeline.synthetic.photos.simulate.simulate_photo`,
:func:`~pipeline.synthetic.photos.simulate.synthetic_photo`), :mod:`~pipeline.synthetic.photos.settings`
(:class:`~pipeline.synthetic.photos.settings.PhotoSettings`,
:class:`~pipeline.synthetic.photos.settings.SyntheticPhoto`), :mod:`~pipeline.synthetic.photos.albedo`
(the random skin, hair and eyes), :mod:`~pipeline.synthetic.photos.background` and
:mod:`~pipeline.synthetic.photos.write` (a photo and its truth as files).
"""
