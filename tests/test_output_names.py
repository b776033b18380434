"""What an output's name promises is what is written there.

Audit: ``imucal import FILE -o x.csv`` (and ``simulate -o x.csv``, ``capture -o x.csv``) wrote
an HDF5 session under a .csv name, exit 0: a user expecting a CSV got a binary file that CSV
readers choke on.  Those commands write HDF5 sessions only: a name that does not end in .h5 or
.hdf5 is refused in one line, before anything is read or written.  ``apply`` writes CSV or
HDF5 by the suffix (kept), and refuses a ``--format`` that contradicts it (``-f h5 -o x.csv``
wrote HDF5 under the .csv name).
"""

from __future__ import annotations

import h5py
import pytest

from imucal_cli.formats.output import SESSION_SUFFIXES, check_session_output
from imucal_cli.simulate.triad import simulate

from .cli_helpers import assert_one_line_error, run
from .test_import import write_csv


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A simulated recording as CSV, its session and the session's truth."""
    folder = tmp_path_factory.mktemp("names")
    session, _ = simulate(plan="six", seed=3, created="2026-01-01T00:00:00Z")
    csv = write_csv(folder / "run.csv", session, header="t,ax,ay,az,gx,gy,gz")
    h5 = folder / "run.h5"
    assert run("simulate", "--plan", "six", "--seed", "3", "-o", h5).returncode == 0
    return csv, h5, folder / "run.truth.json"


@pytest.mark.parametrize("name", ["x.csv", "x.txt", "x", "x.json", "x.h5.csv"])
def test_import_refuses_a_name_that_is_not_hdf5(recorded, tmp_path, name):
    csv = recorded[0]
    out = tmp_path / name
    proc = run("import", csv, "--accel-units", "counts", "--gyro-units", "counts", "-o", out)
    assert_one_line_error(proc, name, "HDF5 session", ".h5 or .hdf5")
    assert not out.exists()


@pytest.mark.parametrize("name", ["x.h5", "x.hdf5", "X.H5"])
def test_import_writes_hdf5_names(recorded, tmp_path, name):
    out = tmp_path / name
    proc = run("import", recorded[0], "--accel-units", "counts", "--gyro-units", "counts",
               "-o", out)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert h5py.is_hdf5(out)


def test_simulate_refuses_a_csv_name(tmp_path):
    out = tmp_path / "sim.csv"
    assert_one_line_error(run("simulate", "--plan", "six", "-o", out), "sim.csv", "HDF5 session")
    assert not out.exists() and not (tmp_path / "sim.truth.json").exists()


def test_capture_refuses_a_csv_name_before_opening_the_port(tmp_path):
    out = tmp_path / "cap.csv"
    proc = run("capture", "--port", "/dev/null/x", "--no-prompt", "--duration", "1", "-o", out)
    assert_one_line_error(proc, "cap.csv", "HDF5 session")  # not the port's error
    assert not out.exists()


def test_apply_keeps_its_suffixes_and_refuses_a_contradicting_format(recorded, tmp_path):
    _, h5, truth = recorded
    as_csv = tmp_path / "cal.csv"
    assert run("apply", truth, h5, "-o", as_csv).returncode == 0
    assert as_csv.read_text().startswith("t,ax,ay,az,gx,gy,gz")
    as_h5 = tmp_path / "cal.h5"
    assert run("apply", truth, h5, "-o", as_h5).returncode == 0 and h5py.is_hdf5(as_h5)
    other = tmp_path / "cal.dat"  # a suffix that names no format: --format decides
    assert run("apply", truth, h5, "-o", other, "-f", "csv").returncode == 0
    for fmt, name in (("h5", "wrong.csv"), ("csv", "wrong.h5"), ("h5", "wrong.txt")):
        out = tmp_path / name
        assert_one_line_error(run("apply", truth, h5, "-o", out, "-f", fmt), name, fmt)
        assert not out.exists()


def test_the_session_suffixes():
    assert SESSION_SUFFIXES == (".h5", ".hdf5")
    for ok in ("a.h5", "dir.csv/a.hdf5", "A.HDF5"):
        check_session_output(ok, "imucal import")


def test_a_session_given_for_the_calibration_is_named_so(recorded, tmp_path):
    """``apply SESSION CAL.json`` (the arguments swapped) said 'not a text (UTF-8) file'."""
    _, h5, truth = recorded
    out = tmp_path / "x.csv"
    assert_one_line_error(run("apply", h5, truth, "-o", out), "an HDF5 file",
                          "not a calibration file")  # fmt: skip
    assert_one_line_error(run("export", h5, "-f", "c-header"), "an HDF5 file")
    assert not out.exists()


def test_plots_and_certificates_are_named_as_written(recorded, tmp_path):
    """``report --plot r.csv`` and ``noise --plot y.txt`` wrote a PNG, ``certificate -o c.txt``
    HTML, under those names, exit 0."""
    _, h5, truth = recorded
    cal = tmp_path / "cal.json"
    assert run("calibrate", h5, "--no-store", "-o", cal).returncode == 0
    for name in ("r.csv", "r", "r.jpg"):
        out = tmp_path / name
        assert_one_line_error(run("report", cal, "--plot", out), name, "PNG", ".png")
        assert_one_line_error(run("noise", h5, "--plot", out), name, "PNG", ".png")
        assert_one_line_error(run("registry", "lot", "L", "--registry", tmp_path / "r.db",
                                  "--plot", out), name, ".png")  # fmt: skip
        assert not out.exists()
    cert = tmp_path / "c.txt"
    assert_one_line_error(run("certificate", truth, "-o", cert), "c.txt", ".html or .pdf")
    assert not cert.exists()
    ok = tmp_path / "c.HTML"
    assert run("certificate", truth, "-o", ok).returncode == 0
    assert ok.read_text().lstrip().lower().startswith("<!doctype html")
