"""One error base: every error class jnr raises on purpose derives from rig.errors."""

import pytest

from landmarks.detector import DetectionError
from landmarks.formats import LandmarkFileError
from landmarks.images import ImageError
from landmarks.plausibility import LandmarkPlausibilityError
from landmarks.points3d import LandmarkError
from pipeline.cli import CliError
from pipeline.config import ConfigError
from pipeline.files import OutputError, OutputExistsError
from pipeline.scan.pointcloud.cloud import CloudError
from rig.asset import AssetError
from rig.errors import InputError, JnrError, SetupError, ShapeError
from rig.expressions import ExpressionError
from rig.lbs import ShapeError as LbsShapeError
from rig.parameters import ParameterError


@pytest.mark.parametrize(
    "cls",
    [
        DetectionError,
        ImageError,
        LandmarkFileError,
        LandmarkPlausibilityError,
        LandmarkError,
        ConfigError,
        OutputError,
        OutputExistsError,
        CloudError,
        ExpressionError,
        ParameterError,
        ShapeError,
    ],
)
def test_input_errors_are_value_errors_under_one_base(cls):
    assert issubclass(cls, InputError) and issubclass(cls, JnrError) and issubclass(cls, ValueError)


def test_setup_and_cli_errors():
    assert issubclass(AssetError, SetupError) and issubclass(AssetError, RuntimeError)
    assert issubclass(CliError, JnrError) and not issubclass(CliError, InputError)
    assert LbsShapeError is ShapeError
    assert issubclass(OutputExistsError, FileExistsError)  # callers that catch the OSError still work


def test_the_command_line_maps_errors_by_base_class(monkeypatch, capsys):
    """An InputError from anywhere is exit 2 and a SetupError exit 1, each one line (no list to forget)."""
    from pipeline import cli
    from pipeline.cli import rig as rig_commands

    for error, code in ((DetectionError("a.jpg: no face"), 2), (AssetError("asset missing"), 1)):

        def broken(args, error=error):
            raise error

        monkeypatch.setattr(rig_commands, "cmd_rig_info", broken)
        assert cli.main(["rig", "info"]) == code
        err = capsys.readouterr().err
        assert err == f"jnr: error: {error}\n"


def test_a_defect_inside_a_fit_exits_1_not_2_and_says_where(monkeypatch, capsys, photo_dir, tmp_path):
    """A ValueError that nobody raised on purpose (here numpy's, inside the fit) is a defect in jnr: exit 1
    with one line naming where it was raised, not exit 2 blaming the user's photo; nothing is written."""
    import numpy as np

    from pipeline import cli
    from pipeline.photo import photo_file
    from tests.pipeline.conftest import fast_fit_args

    def broken_fit(*args, **kwargs):
        return np.zeros(3).reshape(2, 2)  # numpy's own ValueError: cannot reshape

    monkeypatch.setattr(photo_file, "fit_photo", broken_fit)
    out = tmp_path / "out"
    photo = photo_dir / "face0.png"
    code = cli.main(
        ["fit", str(photo), "--landmarks", str(photo_dir / "face0.pts"), "--out", str(out), *fast_fit_args()]
    )
    err = capsys.readouterr().err
    assert code == 1, err
    assert err.startswith("jnr: internal error: ValueError: cannot reshape") and err.count("\n") == 1, err
    assert "test_errors.py" in err and "broken_fit" in err  # the frame that raised
    assert "Traceback" not in err and not out.exists()


def test_bad_input_found_inside_a_fit_stays_exit_2(monkeypatch, capsys, photo_dir, tmp_path):
    """The library's own checks raise InputError (a ValueError), which stays the user's input: exit 2, the
    photo named."""
    from pipeline import cli
    from pipeline.photo import photo_file
    from rig.errors import InputError
    from tests.pipeline.conftest import fast_fit_args

    def refusing_fit(*args, **kwargs):
        raise InputError("landmarks: 12 points lie outside the image")

    monkeypatch.setattr(photo_file, "fit_photo", refusing_fit)
    out = tmp_path / "out"
    code = cli.main(
        ["fit", str(photo_dir / "face0.png"), "--landmarks", str(photo_dir / "face0.pts"), "--out", str(out)]
        + fast_fit_args()
    )
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("jnr: error:") and "face0.png" in err and "outside the image" in err, err
    assert "internal" not in err and not out.exists()


def test_the_packages_raise_no_bare_value_error():
    """Errors raised on purpose use rig.errors' classes (render: its RenderArgumentError), so the command line
    tells the user's input from a defect (issue 39: at most 20 bare ValueError raises; today none)."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    bare = []
    for pkg in ("rig", "pipeline", "landmarks", "render"):
        for path in (root / pkg).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Raise) and node.exc is not None:
                    exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
                    if isinstance(exc, ast.Name) and exc.id == "ValueError":
                        bare.append(f"{path.relative_to(root)}:{node.lineno}")
    assert not bare, bare
