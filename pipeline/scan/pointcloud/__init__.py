"""Point clouds for ``jnr fit-scan CLOUD``: read, validate, estimate normals, find the scan border, write.

Every cloud that leaves this package is in rig space: millimetres, right-handed, +Y up, +Z out of the face
(``N`` points, shapes ``(N, 3)``). Files may be in millimetres, centimetres or metres (detected from the
cloud's size, or given with ``units``) and in the rig frame (``frame="y-up"``) or in OpenCV camera
coordinates (``frame="opencv"``: x right, y down, z forward, as depth cameras write them).

Supported files (extension, case-insensitive): ``.ply`` (ASCII or binary, point cloud or mesh),
``.obj``, ``.xyz`` / ``.txt`` / ``.csv`` (3 or 6 columns) and ``.npy`` (``(N, 3)`` or ``(N, 6)``).

Large clouds are reduced as soon as they are checked:
:func:`~pipeline.scan.pointcloud.validate.validate_points` (so also
:func:`~pipeline.scan.pointcloud.read.read_point_cloud`) keeps a cloud of at most
:data:`~pipeline.scan.pointcloud.validate.LARGE_CLOUD_POINTS` (200 000) points exactly as given, and
replaces a larger one by a seeded uniform random subsample of
:data:`~pipeline.scan.pointcloud.validate.SUBSAMPLE_POINTS` (50 000) of its points, in file order (its
units are still detected on all points). The fit draws its 8 000 points
(``FitScanConfig.correspondences.max_cloud_points``) uniformly at random anyway, so the reduced cloud has
the statistics the fit would have seen (the pre-alignment's inlier fraction, which decides "not a head",
the share of outliers), while everything after reading (normals, the scan border, the error map,
``cloud_error.ply``, the report) costs what a 50k-point scan costs.
:class:`~pipeline.scan.pointcloud.cloud.PointCloud` records the input's point count. (Merging on a voxel
grid was measured and not used: it weights every occupied cube alike, so isolated outliers in a dense
scan count far more and push a head towards the not-a-head threshold; the figures are in
``docs/fit_scan.md``, "Large clouds".)

Modules: :mod:`~pipeline.scan.pointcloud.cloud` (:class:`~pipeline.scan.pointcloud.cloud.PointCloud`,
:class:`~pipeline.scan.pointcloud.cloud.CloudError`), :mod:`~pipeline.scan.pointcloud.read` (the file
formats), :mod:`~pipeline.scan.pointcloud.validate` (checks and the subsample of a large cloud),
:mod:`~pipeline.scan.pointcloud.units` (units and frames), :mod:`~pipeline.scan.pointcloud.normals`
(normals and the scan border), :mod:`~pipeline.scan.pointcloud.write` (PLY) and
:mod:`~pipeline.scan.pointcloud.error_colors`, :mod:`~pipeline.scan.pointcloud.landmarks3d` (named 3D
landmarks of a scan).
"""
