"""`imucal import`: CSV and imu_tk files to a segmented session, every error, real recordings."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.errors import InputError
from imucal_cli.formats.config import Config
from imucal_cli.formats.importers import import_files, infer_columns, parse_columns
from imucal_cli.formats.session import read_session
from imucal_cli.simulate.triad import simulate
from tests.cli_helpers import IMUCAL, assert_one_line_error, run  # noqa: F401

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture(scope="module")
def sim():
    return simulate(seed=7, created="2026-01-01T00:00:00Z")


def write_csv(
    path: Path,
    session,
    order=("t", "ax", "ay", "az", "gx", "gy", "gz"),
    sep=",",
    header: str | None = None,
    extra: list[str] = (),
) -> Path:
    cols = {"t": session.time, "_": np.arange(len(session.time)) * 7.0}
    for i, a in enumerate("xyz"):
        cols["a" + a] = session.accel[:, i]
        cols["g" + a] = session.gyro[:, i]
    data = np.column_stack([cols[c] for c in order])
    lines = [] if header is None else [header]
    lines += [sep.join(f"{v:.10g}" for v in row) for row in data]
    lines[5:5] = list(extra)
    path.write_text("\n".join(lines) + "\n")
    return path


def assert_segments_match(imported, truth_session, rate_hz: float) -> None:
    window = int(round(0.5 * rate_hz))
    found = imported.static_segments()
    true = truth_session.static_segments()
    assert len(found) == len(true)
    for f, t in zip(found[1:], true[1:], strict=True):  # the first also holds the lead-in
        assert abs(f.start - t.start) <= window and abs(f.stop - t.stop) <= window
    assert len(imported.rotation_segments()) == len(true) - 1


# ------------------------------------------------------------------ round trip and calibration


def test_csv_round_trip_segments_and_calibrates_to_truth(tmp_path, sim):
    session, truth = sim
    path = write_csv(tmp_path / "run.csv", session)
    out = tmp_path / "run.h5"
    proc = run(
        "import",
        path,
        "--columns",
        "t,ax,ay,az,gx,gy,gz",
        "--accel-units",
        "counts",
        "--gyro-units",
        "counts",
        "-o",
        out,
    )
    assert proc.returncode == 0, proc.stderr
    assert "18 static segments" in proc.stdout
    imported = read_session(out)
    np.testing.assert_array_equal(imported.accel, session.accel)
    np.testing.assert_allclose(imported.time, session.time, rtol=1e-9, atol=1e-12)
    assert imported.source == "import:run.csv"
    assert (imported.accel_units, imported.gyro_units) == ("counts", "counts")
    assert_segments_match(imported, session, 100.0)
    cal = calibrate_session(imported, Config())
    ref = calibrate_session(session, Config())
    # same poses (slightly shorter holds): same calibration within its own uncertainty
    std = np.array([p.std for p in cal.accel.parameters])
    np.testing.assert_allclose(cal.accel.bias, ref.accel.bias, atol=4 * std[:3].max())
    np.testing.assert_allclose(cal.accel.bias, truth.accel.bias, atol=5 * std[:3].max() + 2)
    assert cal.accel.rms_after < 0.01


def test_reordered_and_skipped_columns(tmp_path, sim):
    session, _ = sim
    path = write_csv(tmp_path / "r.csv", session, order=("_", "gx", "gy", "gz", "ax", "ay", "az"))
    imported = import_files([path], "csv", "_,gx,gy,gz,ax,ay,az", rate_hz=100.0)
    np.testing.assert_array_equal(imported.accel, session.accel)
    np.testing.assert_array_equal(imported.gyro, session.gyro)
    np.testing.assert_allclose(imported.time, np.arange(len(session.time)) / 100.0)
    assert_segments_match(imported, session, 100.0)


def test_time_units(tmp_path, sim):
    session, _ = sim
    s = type(session)(**{**session.__dict__, "time": session.time * 1000.0})
    path = write_csv(tmp_path / "ms.csv", s)
    imported = import_files([path], "csv", "t,ax,ay,az,gx,gy,gz", time_unit="ms")
    np.testing.assert_allclose(imported.time, session.time, atol=1e-9)
    assert imported.sample_rate_hz == pytest.approx(100.0)


@pytest.mark.parametrize("sep", [",", " ", "\t", "  "])
def test_delimiters_and_header_inference(tmp_path, sim, sep):
    session, _ = sim
    header = sep.join(["timestamp", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"])
    path = write_csv(tmp_path / "h.txt", session, sep=sep, header=header)
    imported = import_files([path], "csv")
    np.testing.assert_array_equal(imported.gyro, session.gyro)
    assert imported.import_stats.header == 1
    assert_segments_match(imported, session, 100.0)


def test_header_aliases():
    assert infer_columns(["n_samples", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z"]) == [
        None, "gx", "gy", "gz", "ax", "ay", "az"]  # fmt: skip
    assert infer_columns(["Time", "Accel X [m/s^2]", "accel_y", "AZ"]) == ["t", "ax", "ay", "az"]
    assert infer_columns(["a", "b", "c"]) is None
    assert infer_columns(["ax", "ay", "q"]) is None  # an incomplete triad is no sensor


def test_parse_columns():
    assert parse_columns("_,ax,ay,az,gx,gy,gz") == [None, "ax", "ay", "az", "gx", "gy", "gz"]
    assert parse_columns(" T , AX,ay,az,temp,_,_") == ["t", "ax", "ay", "az", "temp", None, None]
    for bad, word in [("ax,ay", "all three"), ("t,ax,ay,az,ax", "twice"), ("t,,ax", "empty"),
                      ("t,bx,ay,az", "unknown"), ("t,temp", "no accelerometer")]:  # fmt: skip
        with pytest.raises(InputError, match=word):
            parse_columns(bad)


def test_comments_and_malformed_rows_are_counted(tmp_path, sim):
    session, _ = sim
    extra = ["# a comment", "1,2,3", "x,y,z,1,2,3,4", "", "1,2,3,4,5,6,nan"]
    path = write_csv(tmp_path / "m.csv", session, header="# recorded by hand", extra=extra)
    proc = run("import", path, "--columns", "t,ax,ay,az,gx,gy,gz", "-o", tmp_path / "m.h5")
    assert proc.returncode == 0, proc.stderr
    assert "2 comment" in proc.stdout and "3 malformed (first at m.csv:7)" in proc.stdout
    imported = read_session(tmp_path / "m.h5")
    assert len(imported.time) == len(session.time)


def test_imu_tk_pair(tmp_path, sim):
    session, _ = sim
    acc, gyr = tmp_path / "acc.txt", tmp_path / "gyro.txt"
    t = session.time + 0.02984
    lines = [
        f"{ti:15.7e} {a[0]:15.7e} {a[1]:15.7e} {a[2]:15.7e}"
        for ti, a in zip(t, session.accel, strict=True)
    ]
    acc.write_text("\n".join(lines) + "\n")
    lines = [
        f"{ti:15.7e} {g[0]:15.7e} {g[1]:15.7e} {g[2]:15.7e}"
        for ti, g in zip(t, session.gyro, strict=True)
    ]
    gyr.write_text("\n".join(lines[3:]) + "\n")  # the gyro file misses the first 3 samples
    imported = import_files([acc, gyr], "imu_tk", accel_units="counts", gyro_units="counts")
    np.testing.assert_array_equal(imported.accel, session.accel[3:])
    np.testing.assert_array_equal(imported.gyro, session.gyro[3:])
    assert imported.import_stats.unmatched == 3
    assert len(imported.static_segments()) == 18
    with pytest.raises(InputError, match="--format imu_tk"):  # the pair, the format not given
        import_files([acc, gyr], None, accel_units="counts", gyro_units="counts")
    # the accelerometer file given twice became the gyroscope's data too, exit 0 (audit)
    with pytest.raises(InputError, match="the same numbers twice"):
        import_files([acc, acc], "imu_tk", accel_units="counts", gyro_units="counts")


# ------------------------------------------------------------------ errors


def run_in_process(capsys, monkeypatch, *args) -> subprocess.CompletedProcess:
    """``imucal ARGS`` through :func:`imucal_cli.cli.main`, in this process (fast)."""
    from imucal_cli.cli import main

    monkeypatch.setattr(sys, "argv", ["imucal", *map(str, args)])
    capsys.readouterr()
    code = 0
    try:
        main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, out, err)


def test_errors_one_line_exit_2(tmp_path, sim, capsys, monkeypatch):
    session, _ = sim
    good = write_csv(tmp_path / "good.csv", session)
    empty = tmp_path / "empty.csv"
    empty.write_text("\n\n")
    text = tmp_path / "text.csv"
    text.write_text("hello,world\nfoo,bar\n")
    back = tmp_path / "back.csv"
    back.write_text("0,0,0,1\n0.01,0,0,1\n0.005,0,0,1\n")
    short = tmp_path / "short.csv"
    short.write_text("0,0,0,1\n0.01,0,0,1\n0.02,0,0,1\n")
    moving = tmp_path / "moving.csv"
    tt = np.arange(3000) / 100.0
    rows = np.column_stack([tt, np.sin(tt), np.cos(tt), np.sin(2.1 * tt)])
    moving.write_text("\n".join(",".join(f"{v:.6f}" for v in r) for r in rows))
    huge = tmp_path / "huge.csv"  # a reading no sensor gives: numpy's warnings, then a wrong
    huge.write_text("\n".join(",".join(f"{v:.6g}" for v in (r[0], *r[1:] * 1e303))
                               for r in rows))  # reason (no still period), before the audit
    out = tmp_path / "o.h5"
    cases = [
        ((tmp_path / "nope.csv", "--rate", 100), ["nope.csv", "no such file"]),
        ((tmp_path / "nope.bag",), ["nope.bag", "no such file"]),  # not a reader's wording
        ((tmp_path / "nope.ulg",), ["nope.ulg", "no such file"]),
        ((empty, "--rate", 100), ["empty file"]),
        ((text, "--rate", 100), ["no numeric rows"]),
        ((good, "--columns", "t,ax,ay,az"), ["4 fields", "--columns"]),
        ((good, "--columns", "_,ax,ay,az,gx,gy,gz"), ["no time column", "--rate"]),
        ((back, "--columns", "t,ax,ay,az"), ["does not increase at line 3"]),
        ((short, "--columns", "t,ax,ay,az"), ["too few samples"]),
        ((moving, "--columns", "t,ax,ay,az"), ["no still period", "held still"]),
        ((huge, "--columns", "t,ax,ay,az"), ["accel reads", "beyond any sensor"]),
        ((good, "--columns", "t,ax,ay,az,gx,gy,gz", "--accel-units", "furlongs"), ["counts"]),
        ((good, "--format", "imu_tk"), ["two files"]),
        ((good, "--format", "xml"), ["unknown format"]),
        ((good,), ["--columns"]),  # no header: cannot tell the columns
    ]
    # one through the installed console script, the rest through main() in this process
    assert_one_line_error(run("import", *cases[0][0], "-o", out), *cases[0][1])
    for args, words in cases:
        proc = run_in_process(capsys, monkeypatch, "import", *args, "-o", out)
        assert_one_line_error(proc, *words)
    assert not out.exists()
    ok = run("import", good, "--columns", "t,ax,ay,az,gx,gy,gz", "-o", out)
    assert ok.returncode == 0, ok.stderr
    assert_one_line_error(run("import", good, "--columns", "t,ax,ay,az,gx,gy,gz", "-o", out),
                          "exists")  # fmt: skip
    again = run("import", good, "--columns", "t,ax,ay,az,gx,gy,gz", "-o", out, "--force")
    assert again.returncode == 0, again.stderr


# ------------------------------------------------------------------ real recordings


REAL = [
    ("xsens", ["imu_tk_xsens/xsens_acc.mat", "imu_tk_xsens/xsens_gyro.mat"],
     ["--format", "imu_tk", "--accel-units", "counts", "--gyro-units", "counts"], 38),
    ("mikoff0", ["mikoff_mpu9150/imu0.log"],
     ["--rate", 100, "--columns", "ax,ay,az,gx,gy,gz", "--accel-units", "m/s^2",
      "--gyro-units", "rad/s"], 22),
    ("tomi", ["tomisuarez2_mpu6050/example_data_calibration.csv"],
     ["--rate", 100, "--accel-units", "counts", "--gyro-units", "counts"], 10),
]  # fmt: skip


@pytest.mark.skipif(not DATA.is_dir(), reason="shared/data recordings not present")
@pytest.mark.parametrize("name,files,args,n_static", REAL, ids=[r[0] for r in REAL])
def test_real_recordings_import_and_calibrate(tmp_path, name, files, args, n_static):
    out = tmp_path / f"{name}.h5"
    proc = run("import", *[DATA / f for f in files], *args, "-o", out)
    assert proc.returncode == 0, proc.stderr
    session = read_session(out)
    assert len(session.static_segments()) == n_static
    cal = calibrate_session(session, Config())
    x = cal.accel
    if n_static > 10:
        assert x.warnings == []
    else:  # 10 poses for 9 parameters: said out loud (issue 10.3), not refused
        assert any("1 spare equations" in w for w in x.warnings), x.warnings
        assert any(w.startswith("held-out error") for w in x.warnings), x.warnings
        assert x.blocking == []
    assert x.outliers == []
    assert x.rms_after < 0.1 * x.rms_before
    assert x.rms_loo < 0.01  # m/s^2, about 1 mg held out


@pytest.mark.skipif(not DATA.is_dir(), reason="shared/data recordings not present")
def test_xsens_matches_the_datasheet(tmp_path):
    session = import_files(
        [DATA / "imu_tk_xsens/xsens_acc.mat", DATA / "imu_tk_xsens/xsens_gyro.mat"], "imu_tk",
        accel_units="counts",
    )  # fmt: skip
    assert session.static_segments()[0].n_samples > 50 * 100  # the 51 s initial rest
    cal = calibrate_session(session, Config())
    np.testing.assert_allclose(cal.accel.sensitivity, [415, 413, 415], rtol=0.005)


@pytest.mark.skipif(not DATA.is_dir(), reason="shared/data recordings not present")
def test_ferraris_six_faces_refused_with_the_reason(tmp_path):
    out = tmp_path / "fer.h5"
    path = DATA / "imucal_ferraris/example_ferraris_session.csv"
    proc = run("import", path, "--rate", 102.4, "--accel-units", "m/s^2", "--gyro-units",
               "deg/s", "-o", out)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    session = read_session(out)
    assert session.gyro_units == "deg/s"
    assert len(session.static_segments()) >= 6
    # issue 27.3: six unlabelled faces measure each axis's bias and gain; the angles
    # between the axes (edges would measure them) are held at the nominal prior
    proc = run("calibrate", out, "--json", "--no-store")
    assert proc.returncode == 0, proc.stderr
    acc = json.loads(proc.stdout)["calibration"]["accel"]
    assert acc["solver"] == "partial"
    assert {"b_x", "b_y", "b_z", "s_x", "s_y", "s_z"} <= set(acc["partial"]["measured"])
    assert "only 6 distinct gravity directions" in " ".join(acc["notes"])


def test_skipped_columns_may_hold_text(tmp_path):
    from imucal_cli.formats.importers import read_recording

    path = tmp_path / "tagged.csv"
    rows = [f"imu{i % 2},{i / 100:.2f},0,0,9.8,0,0,0" for i in range(300)]
    path.write_text("tag,t,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n")
    rec = read_recording([path], "csv", "_,t,ax,ay,az,gx,gy,gz")
    assert rec.accel.shape == (300, 3) and rec.stats.malformed == 0


def test_import_warns_when_the_units_are_not_stated(tmp_path, sim):
    """Issue 10.4: without --accel-units the import says so (and how to state them later)."""
    session, _ = sim
    path = write_csv(tmp_path / "nounits.csv", session)
    cols = ("--columns", "t,ax,ay,az,gx,gy,gz")
    proc = run("import", path, *cols, "-o", tmp_path / "a.h5")
    assert proc.returncode == 0, proc.stderr
    assert "warning: accelerometer units not stated" in proc.stdout
    assert "--accel-units" in proc.stdout
    proc = run("import", path, *cols, "--accel-units", "counts", "-o", tmp_path / "b.h5")
    assert "units not stated" not in proc.stdout
