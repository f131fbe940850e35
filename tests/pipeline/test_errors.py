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
