"""What each jnr output folder holds: one description per folder, from which the writers' checks, the
resume check of a folder run, the printed file lists and ``--help`` all derive.

Adding an output file is: the writer writes it, and one :class:`OutputFile` entry here. This module
imports nothing heavy (``jnr fit --help`` reads it).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class OutputFile:
    """One file of an output folder.

    Attributes:
        name: the file name (``<k>`` stands for a number: one file per view).
        description: what it holds, one sentence (the ``--help`` text and the docs use it).
        optional: written only by some runs (e.g. only when a detector's points exist): a folder without it
            is still complete.
    """

    name: str
    description: str
    optional: bool = False

    @property
    def per_item(self) -> bool:
        """Whether the name is a pattern with one file per item (``overlay_<k>.png``)."""
        return "<k>" in self.name


@dataclass(frozen=True)
class OutputFolder:
    """The files of one kind of output folder, in the order they are listed."""

    command: str
    files: tuple[OutputFile, ...]

    @property
    def names(self) -> tuple[str, ...]:
        """Every file name (patterns included)."""
        return tuple(f.name for f in self.files)

    @property
    def required(self) -> tuple[str, ...]:
        """The names every run writes (patterns included; :attr:`OutputFile.optional` files left out)."""
        return tuple(f.name for f in self.files if not f.optional)

    def listing(self, folder: str | Path | None = None) -> str:
        """The names as printed after a run: ``mesh.obj, mesh.mtl, ...``; with ``folder``, only those it holds
        (a pattern when one of its files is there), so that a summary never lists a file that was not written
        (``preview.mp4`` of ``--no-preview``)."""
        if folder is None:
            return ", ".join(self.names)
        folder = Path(folder)

        def there(f: OutputFile) -> bool:
            if f.per_item:
                return any(folder.glob(f.name.replace("<k>", "*")))
            return (folder / f.name).exists()

        return ", ".join(f.name for f in self.files if there(f))

    def help_text(self) -> str:
        """The files with their descriptions, as ``--help`` prints them."""
        return "; ".join(f"{f.name}: {f.description}" for f in self.files)

    def missing(self, folder: str | Path, names: tuple[str, ...] | None = None) -> tuple[str, ...]:
        """The fixed-name files ``folder`` lacks (patterns are not checked), of ``names`` (default: all)."""
        folder = Path(folder)
        return tuple(
            f.name
            for f in self.files
            if not f.per_item
            and not f.optional
            and (names is None or f.name in names)
            and not (folder / f.name).is_file()
        )

    def is_complete(self, folder: str | Path, names: tuple[str, ...] | None = None) -> bool:
        """Whether ``folder`` holds every fixed-name file (of ``names``; what a resumed folder run calls
        complete)."""
        return not self.missing(folder, names)


_MESH = (
    OutputFile("mesh.obj", "the fitted head, rig space, mm, +Y up, +Z out of the face, UVs, material of mesh.mtl"),
    OutputFile("mesh.mtl", "the material: map_Kd texture.png"),
    OutputFile("texture.png", "the face unwrapped from the photo into the template's UVs"),
    OutputFile("mesh.ply", "the same head, binary PLY with vertex colours"),
    OutputFile(
        "mesh.glb",
        "skinned glTF 2.0 in metres: the fitted head as its bind mesh (what every reader loads), 52 joints, the 52 "
        "ARKit shapes as morph targets, textured",
    ),
)
_PARAMS = OutputFile(
    "params.json",
    "the head model's parameters by name, the camera, head pose and light (format jnr-params/2); "
    "its joints key is a jnr rig edit parameter file",
)
_REPORT = OutputFile("report.json", "errors, every loss term per stage, timings, inputs, the configuration")
_CONFIG = OutputFile("config.yaml", "the configuration used, every field resolved (--config repeats the fit)")
_VIEWER = OutputFile(
    "viewer.html",
    "a page that works offline: the head over the photo, sliders for the joints and ARKit shapes, Save pose "
    "(in a folder run it loads the run's one three.jnr.js)",
)

PHOTO_FOLDER = OutputFolder(
    "jnr fit PHOTO",
    (
        *_MESH,
        OutputFile(
            "mesh_keys.glb",
            "the same head for animation tools (Blender, Unity, three.js): the expression on the 52 shape keys at "
            "params.json's values, the mesh without it (mesh.glb bakes it in, its keys at 0)",
        ),
        _PARAMS,
        OutputFile("overlay.png", "the photo with the fitted face over it, input landmarks green, fitted red"),
        OutputFile("render.png", "the fitted head, albedo and light, alone at the photo's size"),
        OutputFile("landmarks.pts", "the input landmarks, iBUG .pts, 1-based pixels"),
        OutputFile("landmarks_fitted.pts", "the fitted head's landmarks projected, iBUG .pts"),
        OutputFile("landmarks3d.json", "the fitted landmarks in 3D, camera frame (OpenCV), mm"),
        OutputFile("landmarks3d_mesh.json", "the same landmarks in mesh.obj's frame (rig space), mm: on mesh.obj"),
        OutputFile("landmarks3d.pp", "the same, as MeshLab picked points of mesh.obj (Edit > PickPoints > Load)"),
        OutputFile(
            "landmarks_now.txt",
            "the NoW benchmark's 7 points of mesh.obj (eye corners, nose bottom, mouth corners), one x y z a line",
        ),
        OutputFile(
            "landmarks3d_mediapipe.json",
            "MediaPipe's 478 fitted points in mesh.obj's frame (only when MediaPipe found the face)",
            optional=True,
        ),
        OutputFile("expressions.csv", "the 52 ARKit coefficients under their ARKit names"),
        OutputFile(
            "expressions_livelink.csv", "the same in Live Link Face's CSV (Timecode, BlendShapeCount, head angles)"
        ),
        _REPORT,
        _CONFIG,
        _VIEWER,
    ),
)
"""``jnr fit PHOTO --out DIR`` (one face; ``--face all`` writes one such folder per face)."""

PHOTO_OUTPUT_SETS: dict[str, tuple[str, ...]] = {
    "all": PHOTO_FOLDER.names,
    "mesh": (
        "mesh.obj",
        "mesh.mtl",
        "texture.png",
        "mesh.ply",
        "mesh.glb",
        "mesh_keys.glb",
        "params.json",
        "report.json",
        "config.yaml",
    ),
    "minimal": ("params.json", "report.json", "config.yaml"),
}
"""The files of each ``jnr fit --outputs`` set (``outputs.files``), in :data:`PHOTO_FOLDER`'s order."""

VIEWS_FOLDER = OutputFolder(
    "jnr fit --views",
    (
        *_MESH,
        OutputFile(
            "params.json",
            "the shared identity's parameters and, per view, the photo, camera, head pose and ARKit "
            "expressions (format jnr-params/2)",
        ),
        OutputFile("overlay.png", "the per-view overlays side by side"),
        OutputFile("overlay_<k>.png", "view k (input order, from 0): the photo with the fitted head over the face"),
        _REPORT,
        _CONFIG,
        _VIEWER,
    ),
)
"""``jnr fit A.jpg B.jpg ... --views --out DIR``."""

SCAN_FOLDER = OutputFolder(
    "jnr fit-scan",
    (
        OutputFile("mesh.ply", "the fitted head in the input cloud's frame and units (it overlays the cloud)"),
        OutputFile("mesh.obj", "the same, OBJ"),
        OutputFile(
            "params.json",
            "the head model's parameters by name, the pose (rig space -> cloud), the input's units and frame "
            "(format jnr-params/2)",
        ),
        OutputFile("cloud_error.ply", "the input cloud coloured by its distance to the fitted mesh (error_mm)"),
        OutputFile("report.json", "scan-to-mesh distance, pre-alignment, every loss term per stage, timings"),
        _CONFIG,
        OutputFile("viewer.html", "a self-contained page: the fitted head to orbit, sliders for joints and shapes"),
    ),
)
"""``jnr fit-scan CLOUD --out DIR``."""

ACCESSORY_FOLDER = OutputFolder(
    "jnr accessory",
    (
        OutputFile("accessory.obj", "the accessory posed on the fitted head, mm"),
        OutputFile("head_with_accessory.glb", "the head and the accessory on one skin, ARKit morph targets on both"),
        OutputFile("accessory_weights.npz", "the accessory's skinning weights and expression offsets"),
        OutputFile("preview.png", "front and side views"),
        OutputFile("report.json", "the transfer's settings and figures"),
    ),
)
"""``jnr accessory FIT_DIR ACCESSORY --out DIR``."""

RETARGET_FOLDER = OutputFolder(
    "jnr retarget",
    (
        OutputFile("mesh.obj", "the target's identity with the source's expression, rig space, mm"),
        OutputFile("mesh.ply", "the same head, PLY"),
        OutputFile("mesh.glb", "the same head, skinned glTF with the ARKit morph targets"),
        OutputFile("params.json", "the target's parameters with the source's 52 ARKit coefficients"),
        OutputFile("expressions.csv", "the 52 ARKit coefficients under their ARKit names"),
        OutputFile("preview.png", "source, target and result, grey, three-quarter view"),
        OutputFile("report.json", "the inputs, the coefficients and the largest vertex change"),
    ),
)
"""``jnr retarget SOURCE_FIT TARGET_FIT --out DIR``."""

TRACK_FOLDER = OutputFolder(
    "jnr track",
    (
        OutputFile(
            "livelink.csv",
            "the ARKit curves in Live Link Face's CSV (Timecode at the clip's rate, BlendShapeCount, head angles)",
        ),
        OutputFile("curves.csv", "the same curves, plain: time in seconds, the 52 ARKit names, head angles in degrees"),
        OutputFile("track.glb", "the fitted head, skinned, animated by the curves (morph weights, head rotation)"),
        OutputFile("params.json", "the clip's identity as a fit's parameters (jnr animate / rig edit read the folder)"),
        OutputFile("params.npz", "every frame's head pose, ARKit coefficients, landmarks and landmark error"),
        OutputFile("preview.mp4", "the clip with the fitted head over it, beside the grey head (not --no-preview)"),
        OutputFile("report.json", "frames, lost (bridged) frames, keyframes, errors, seconds and frames/s per phase"),
        OutputFile("config.yaml", "the settings used, every field resolved (--config repeats the run)"),
    ),
)
"""``jnr track VIDEO --out DIR``."""
