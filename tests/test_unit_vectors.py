"""An up or axis direction of any finite size is the direction it points to.

Audit: ``imucal label SESSION --segment 0000 --up 1e300,0,1`` printed numpy's overflow warning
and stored an up of 0,0,0 (its norm overflowed to inf), exit 0; a session whose segment held
``up = [1e300, 0, 1]`` was read as 0,0,0, and a plan's ``up = [1e-200, 1e-200, 0]`` (its norm
underflowed to 0) as NaN. The direction is scaled before its norm is taken.
"""

from __future__ import annotations

import warnings

import h5py
import numpy as np
import pytest

from imucal_cli.formats.session import read_session
from imucal_cli.model.session import as_unit_vector
from imucal_cli.plans import load_plan

from .cli_helpers import run


@pytest.mark.parametrize(
    ("value", "direction"),
    [([1e300, 0, 1], [1, 0, 0]), ([1e-200, 1e-200, 0], [0.5**0.5, 0.5**0.5, 0]),
     ([-1e308, -1e308, 0], [-(0.5**0.5), -(0.5**0.5), 0]), ([0, 0, 2], [0, 0, 1])],
)  # fmt: skip
def test_as_unit_vector_of_any_size(value, direction):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's overflow warning fails the test
        np.testing.assert_allclose(as_unit_vector(value), direction, atol=1e-15)


def test_label_stores_the_direction_of_a_huge_up(tmp_path):
    h5 = tmp_path / "s.h5"
    assert run("simulate", "--plan", "six", "-o", h5).returncode == 0
    proc = run("label", h5, "--segment", "0000", "--up", "1e300,0,1")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    up = read_session(h5).segments[0].up
    np.testing.assert_allclose(up, [1, 0, 0], atol=1e-15)


def test_a_session_and_a_plan_read_the_direction(tmp_path):
    h5 = tmp_path / "s.h5"
    assert run("simulate", "--plan", "six", "-o", h5).returncode == 0
    with h5py.File(h5, "r+") as f:
        f["segments/0000"].attrs["up"] = [1e300, 0.0, 1.0]
    np.testing.assert_allclose(read_session(h5).segments[0].up, [1, 0, 0], atol=1e-15)
    plan = tmp_path / "p.toml"
    plan.write_text('[[step]]\nkind = "static"\nlabel = "tilted"\nup = [1e-200, 1e-200, 0]\n')
    (step,) = load_plan(str(plan)).steps
    np.testing.assert_allclose(step.up, [0.5**0.5, 0.5**0.5, 0], atol=1e-15)
