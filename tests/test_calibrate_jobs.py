"""Issue 14.6: `imucal calibrate *.h5 --jobs N`: many sessions in one process pool, one summary
table, each calibration what a single `calibrate` gives, non-zero exit if any failed."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.calibrate.batch import calibrate_many
from imucal_cli.formats.config import Config
from tests.cli_helpers import assert_one_line_error, run

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def sessions(tmp_path):
    paths = []
    for k, name in enumerate(["qureshi18-seed1.h5", "random30-seed2.h5", "qureshi18-seed1-si.h5"]):
        p = tmp_path / f"s{k}.h5"
        shutil.copy(ROOT / "sessions" / name, p)
        paths.append(p)
    return paths


def test_jobs_match_single_runs_and_one_table(tmp_path, sessions):
    bad = tmp_path / "bad.h5"
    bad.write_text("not a session")
    proc = run("calibrate", *sessions, bad, "--jobs", "2", "--no-store")
    assert proc.returncode == 2, proc.stderr  # the worst status: bad input
    assert proc.stdout.count("saved") >= 3 and "failed (2)" in proc.stdout
    assert "bad.h5: not an HDF5 file" in proc.stdout
    assert "sessions per CPU second" in proc.stdout
    single = tmp_path / "single.json"
    ok = run("calibrate", sessions[1], "-o", single, "--no-store")
    assert ok.returncode == 0, ok.stderr
    many = json.loads(sessions[1].with_suffix(".cal.json").read_text())
    one = json.loads(single.read_text())
    np.testing.assert_array_equal(many["accel"]["matrix"], one["accel"]["matrix"])
    np.testing.assert_array_equal(many["accel"]["bias"], one["accel"]["bias"])
    for p in sessions:
        assert p.with_suffix(".cal.json").exists()


def test_in_process_results_in_order(sessions):
    seen = []
    results = calibrate_many(sessions, Config(), jobs=1, store=False, progress=seen.append)
    assert [r.session for r in results] == [str(p) for p in sessions]
    assert len(seen) == 3 and all(r.exit_code == 0 for r in results)
    assert all(r.figures.accel_rms_after < 0.01 for r in results)


def test_refusals(tmp_path, sessions):
    assert_one_line_error(run("calibrate", *sessions, "-o", tmp_path / "x.json"), "--output")
    assert_one_line_error(run("calibrate", *sessions, "--jobs", "-1"), "--jobs")


def test_a_session_named_twice_is_refused(tmp_path, sessions):
    """Audit: ``calibrate A A ./A`` calibrated A three times, wrote A.cal.json three times and
    stored three calibrations in A; ``--with A`` of A itself (or a copy) counted its still
    periods and turns twice (every std too small by sqrt(2)), exit 0."""
    a = sessions[0]
    before = a.read_bytes()
    assert_one_line_error(run("calibrate", a, a, tmp_path / "." / a.name), "given twice")
    assert a.read_bytes() == before and not a.with_suffix(".cal.json").exists()
    copy = Path(shutil.copy(a, tmp_path / "copy.h5"))
    out = tmp_path / "o.json"
    assert_one_line_error(run("calibrate", a, "--with", a, "-o", out), "given twice")
    assert_one_line_error(run("calibrate", a, "--with", copy, "-o", out), "the same recording")
    assert not out.exists()


def test_with_a_session_of_another_unit_warns(tmp_path, sessions):
    """Sessions naming different units joined by --with: said (they were joined silently)."""
    proc = run("calibrate", sessions[0], "--with", sessions[1], "-o", tmp_path / "o.json",
               "--no-store")  # fmt: skip
    assert "imucal: warning:" in proc.stderr and "joins sessions of one unit" in proc.stderr
    assert "'sim-16bit seed 2'" in proc.stderr and "'sim-16bit seed 1'" in proc.stderr
