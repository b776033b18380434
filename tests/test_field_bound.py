"""The local geomagnetic field is a field a magnetometer can be in: at most 10000 uT.

Audit: ``imucal import ... --field-uT 1e300`` stored 1e300 uT in the session, exit 0;
``calibrate`` of a session holding it printed numpy's overflow warnings (several lines on
stderr). ``capture`` refused it without saying the bound. One bound for the three: the reader,
import and capture.
"""

from __future__ import annotations

import h5py
import pytest

from imucal_cli.model.session import MAX_FIELD_UT

from .cli_helpers import assert_one_line_error, run
from .test_import import write_csv


def test_the_bound():
    assert MAX_FIELD_UT == 1e4  # the Earth's 25-65 uT, coils and magnets in a lab far below


@pytest.mark.parametrize("field", ["1e300", "20000", "nan", "0"])
def test_import_and_capture_refuse_the_field(tmp_path, field):
    from imucal_cli.simulate.triad import simulate

    session, _ = simulate(plan="six", seed=1, created="2026-01-01T00:00:00Z")
    csv = write_csv(tmp_path / "r.csv", session, header="t,ax,ay,az,gx,gy,gz")
    out = tmp_path / "r.h5"
    assert_one_line_error(run("import", csv, "--field-uT", field, "-o", out),
                          "--field-uT", "10000 uT")  # fmt: skip
    assert not out.exists()
    assert_one_line_error(run("capture", "--port", tmp_path / "nope", "--field-uT", field,
                              "-o", out), "--field-uT", "10000 uT")  # fmt: skip


def test_a_session_holding_a_huge_field_is_refused_in_one_line(tmp_path):
    h5 = tmp_path / "m.h5"
    assert run("simulate", "--plan", "six", "--mag", "-o", h5).returncode == 0
    with h5py.File(h5, "r+") as f:
        f.attrs["magnetic_field_uT"] = 1e300
    assert_one_line_error(run("calibrate", h5, "--no-store", "-o", tmp_path / "c.json"),
                          "magnetic_field_uT", "10000 uT")  # fmt: skip
