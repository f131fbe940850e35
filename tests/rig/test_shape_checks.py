"""One error base and one shape-check vocabulary."""

import pytest
import torch

from rig.errors import InputError, JnrError, ShapeError, check_shape, shape_error
from rig.io.mesh import export_mesh
from rig.lbs import euler_to_matrix


def test_shape_errors_are_input_errors_with_one_message():
    err = shape_error("f", "x", "(N, 3)", (2, 2))
    assert isinstance(err, ShapeError) and isinstance(err, InputError) and isinstance(err, ValueError)
    assert isinstance(err, JnrError) and str(err) == "f: x must have shape (N, 3), got (2, 2)"
    check_shape(True, "f", "x", "(N, 3)", (2, 3))
    with pytest.raises(ShapeError, match=r"^f: x must have shape \(N, 3\), got \(2, 2\)$"):
        check_shape(False, "f", "x", "(N, 3)", (2, 2))


def test_the_rig_and_its_writers_use_it(tmp_path):
    with pytest.raises(ShapeError, match="euler_to_matrix: angles must have shape"):
        euler_to_matrix(torch.zeros(4, 2))
    with pytest.raises(ShapeError, match="must have shape"):
        export_mesh(tmp_path / "m.obj", torch.zeros(5, 2).numpy(), [[0, 1, 2]])
