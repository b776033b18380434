"""`imucal apply`: exact agreement with SensorCalibration.apply, CSV in and out, chunk
boundaries, every refusal as one line, and constant memory on a long session."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import h5py
import numpy as np
import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import write_calibration
from imucal_cli.formats.session import Session, write_session
from imucal_cli.model.calibration import Calibration, SensorCalibration
from imucal_cli.simulate.redundant import simulate_redundant_accel
from imucal_cli.simulate.triad import simulate
from imucal_cli.use.apply import FORMAT, apply_calibration
from tests.cli_helpers import IMUCAL, assert_one_line_error, run  # noqa: F401


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A simulated session and its truth calibration, as files."""
    folder = tmp_path_factory.mktemp("apply")
    session, truth = simulate(seed=7, created="2026-01-01T00:00:00Z")
    write_session(folder / "s.h5", session)
    write_calibration(folder / "truth.json", truth)
    return session, truth, folder / "s.h5", folder / "truth.json"


def read_h5(path: Path) -> dict:
    with h5py.File(path, "r") as f:
        out = {name: ds[()] for name, ds in f["calibrated"].items()}
        out["attrs"] = dict(f.attrs)
        out["units"] = {name: ds.attrs["units"] for name, ds in f["calibrated"].items()}
    return out


def write_csv(path: Path, session: Session, order: tuple[str, ...], header: str | None = None,
              extra: dict[int, str] | None = None, sep: str = ",") -> Path:  # fmt: skip
    cols = {"t": session.time, "_": np.arange(len(session.time)) * 7.0}
    for i, a in enumerate("xyz"):
        cols["a" + a] = session.accel[:, i]
        cols["g" + a] = session.gyro[:, i]
    data = np.column_stack([cols[c] for c in order])
    lines = [] if header is None else [header]
    lines += [sep.join(repr(float(v)) for v in row) for row in data]
    for at, text in sorted((extra or {}).items(), reverse=True):
        lines.insert(at, text)
    path.write_text("\n".join(lines) + "\n")
    return path


# --------------------------------------------------------------------------------------------
# Session in: exact
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("chunk_rows", [7, 1000, 6249, 65536])
def test_session_to_h5_equals_apply_exactly(sim, tmp_path, chunk_rows):
    session, truth, h5, cal_path = sim
    n = len(session.time)
    assert n % 7 not in (0, 1) and n % 1000 not in (0, 1)  # blocks that do not divide the file
    out = tmp_path / "out.h5"
    summary = apply_calibration(truth, h5, out, cal_source=str(cal_path), chunk_rows=chunk_rows)
    assert summary.samples == n and summary.sensors == ("accel", "gyro")
    assert summary.chunks == max(1, -(-n // chunk_rows) - (n % chunk_rows == 1))
    got = read_h5(out)
    np.testing.assert_array_equal(got["time"], session.time)
    np.testing.assert_array_equal(got["accel"], truth.accel.apply(session.accel))
    np.testing.assert_array_equal(got["gyro"], truth.gyro.apply(session.gyro))
    attrs = got["attrs"]
    assert attrs["format"] == FORMAT and attrs["format_version"] == 1
    assert attrs["model"] == "calibrated = matrix @ (raw - bias)"
    assert attrs["calibration"] == str(cal_path) and attrs["source"] == str(h5)
    assert attrs["sensor"] == truth.sensor
    assert got["units"] == {"time": "s", "accel": "m/s^2", "gyro": "rad/s"}
    assert not (tmp_path / "out.h5.tmp").exists()


def test_last_block_of_one_row_joins_the_previous(sim, tmp_path):
    session, truth, h5, _ = sim
    n = len(session.time)
    summary = apply_calibration(truth, h5, tmp_path / "o.h5", chunk_rows=n - 1)
    assert summary.chunks == 1
    np.testing.assert_array_equal(
        read_h5(tmp_path / "o.h5")["accel"], truth.accel.apply(session.accel)
    )


def test_redundant_four_channel_unit(tmp_path):
    session, truth = simulate_redundant_accel(seed=2, created="2026-01-01T00:00:00Z")
    assert session.accel.shape[1] == 4 and truth.gyro is None
    write_session(tmp_path / "r.h5", session)
    apply_calibration(truth, tmp_path / "r.h5", tmp_path / "o.h5", chunk_rows=50)
    got = read_h5(tmp_path / "o.h5")
    assert set(got) == {"time", "accel", "attrs", "units"}  # only the calibrated sensor
    np.testing.assert_array_equal(got["accel"], truth.accel.apply(session.accel))


def test_only_the_sensors_of_the_calibration(sim, tmp_path):
    session, truth, h5, _ = sim
    gyro_only = Calibration(gyro=truth.gyro, created=truth.created)
    apply_calibration(gyro_only, h5, tmp_path / "o.csv")
    lines = (tmp_path / "o.csv").read_text().splitlines()
    assert lines[0] == "t,gx,gy,gz"
    data = np.loadtxt(tmp_path / "o.csv", delimiter=",", skiprows=2)
    assert data.shape == (len(session.time), 4)


def test_session_to_csv_to_printed_precision(sim, tmp_path):
    session, truth, h5, cal_path = sim
    proc = run("apply", cal_path, h5, "--output", tmp_path / "o.csv")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("\n") == 1 and f"calibrated {len(session.time)} samples" in proc.stdout
    lines = (tmp_path / "o.csv").read_text().splitlines()
    assert lines[0] == "t,ax,ay,az,gx,gy,gz"  # the header first: readers take it for the names
    assert lines[1].startswith("# imucal apply: calibrated = matrix @ (raw - bias)")
    assert "m/s^2" in lines[1] and "rad/s" in lines[1] and "," not in lines[1]
    named = np.genfromtxt(tmp_path / "o.csv", delimiter=",", names=True)
    assert named.dtype.names == ("t", "ax", "ay", "az", "gx", "gy", "gz")
    np.testing.assert_array_equal(named["t"], session.time)
    data = np.loadtxt(tmp_path / "o.csv", delimiter=",", skiprows=2)
    np.testing.assert_array_equal(data[:, 0], session.time)  # time round-trips exactly
    for cols, sec, raw in ((slice(1, 4), truth.accel, session.accel),
                           (slice(4, 7), truth.gyro, session.gyro)):  # fmt: skip
        want = sec.apply(raw)
        # 10 significant digits: half a unit in the 10th digit.
        np.testing.assert_array_less(np.abs(data[:, cols] - want), 5.01e-10 * np.abs(want) + 1e-300)


def test_format_option_overrides_the_suffix(sim, tmp_path):
    _, _, h5, cal_path = sim
    proc = run("apply", cal_path, h5, "-o", tmp_path / "o.dat", "--format", "h5")
    assert proc.returncode == 0, proc.stderr
    assert h5py.is_hdf5(tmp_path / "o.dat")
    assert_one_line_error(run("apply", cal_path, h5, "-o", tmp_path / "o.dat2"), "--format")


# --------------------------------------------------------------------------------------------
# CSV in
# --------------------------------------------------------------------------------------------


def test_csv_with_columns_in_any_order(sim, tmp_path):
    session, truth, _, cal_path = sim
    csv = write_csv(tmp_path / "in.csv", session, ("gx", "gy", "gz", "_", "t", "ax", "ay", "az"))
    out = tmp_path / "o.h5"
    proc = run("apply", cal_path, csv, "-o", out, "--columns", "gx,gy,gz,_,t,ax,ay,az")
    assert proc.returncode == 0, proc.stderr
    got = read_h5(out)
    np.testing.assert_array_equal(got["time"], session.time)
    np.testing.assert_array_equal(got["accel"], truth.accel.apply(session.accel))
    np.testing.assert_array_equal(got["gyro"], truth.gyro.apply(session.gyro))


@pytest.mark.parametrize("chunk_rows", [1, 2, 64, 100000])
def test_csv_header_comments_malformed_and_chunks(sim, tmp_path, chunk_rows):
    """Header inference, tab separation, comments and malformed lines; blocks of any size.
    Blocks of 1 and 2 rows read the session's first 3200 samples of 6250 (every extra line
    below is among them; a block ends after every row or two all the same)."""
    session, truth, _, _ = sim
    if chunk_rows < 64:
        from types import SimpleNamespace

        session = SimpleNamespace(time=session.time[:3200], accel=session.accel[:3200],
                                  gyro=session.gyro[:3200])  # fmt: skip
    order = ("t", "ax", "ay", "az", "gx", "gy", "gz")
    extra = {0: "# recorded on the bench", 200: "1.0\t2.0", 1001: "# a comment", 3000: "x y z"}
    csv = write_csv(tmp_path / "in.tsv", session, order, header="time\tacc_x\tacc_y\tacc_z\t"
                    "gyr_x\tgyr_y\tgyr_z", extra=extra, sep="\t")  # fmt: skip
    out = tmp_path / "o.h5"
    summary = apply_calibration(truth, csv, out, chunk_rows=chunk_rows)
    assert summary.input_kind == "csv" and summary.samples == len(session.time)
    assert (
        summary.malformed == 2 and summary.first_malformed == "in.tsv:202"
    )  # after the comment at the top
    got = read_h5(out)
    np.testing.assert_array_equal(got["time"], session.time)
    np.testing.assert_array_equal(got["accel"], truth.accel.apply(session.accel))
    np.testing.assert_array_equal(got["gyro"], truth.gyro.apply(session.gyro))


def test_csv_without_time_uses_rate(sim, tmp_path):
    session, truth, _, cal_path = sim
    csv = write_csv(tmp_path / "in.csv", session, ("ax", "ay", "az"))
    accel_only = tmp_path / "accel.json"
    write_calibration(accel_only, Calibration(accel=truth.accel, created=truth.created))
    out = tmp_path / "o.csv"
    assert_one_line_error(run("apply", accel_only, csv, "-o", out, "--columns", "ax,ay,az"),
                          "--rate")  # fmt: skip
    for implausible in ("1e300", "0.001"):  # rows stamped 1e-300 s apart, exit 0 (audit)
        assert_one_line_error(run("apply", accel_only, csv, "-o", out, "--columns", "ax,ay,az",
                                  "--rate", implausible), "--rate", "implausible")  # fmt: skip
    assert not out.exists()
    proc = run("apply", accel_only, csv, "-o", out, "--columns", "ax,ay,az", "--rate", "50")
    assert proc.returncode == 0, proc.stderr
    data = np.loadtxt(out, delimiter=",", skiprows=2)
    np.testing.assert_array_equal(data[:, 0], np.arange(len(session.time)) / 50.0)


# --------------------------------------------------------------------------------------------
# Refusals: exit 2, one line, no output left behind
# --------------------------------------------------------------------------------------------


def test_missing_files(sim, tmp_path):
    _, _, h5, cal_path = sim
    out = tmp_path / "o.h5"
    assert_one_line_error(run("apply", cal_path, tmp_path / "none.h5", "-o", out), "none.h5",
                          "no such file")  # fmt: skip
    assert_one_line_error(run("apply", tmp_path / "none.json", h5, "-o", out), "none.json")
    assert not out.exists()


def test_channel_count_mismatch_names_both(sim, tmp_path):
    session, truth, h5, _ = sim
    _, redundant = simulate_redundant_accel(seed=2, created="2026-01-01T00:00:00Z")
    cal = tmp_path / "four.json"
    write_calibration(cal, redundant)
    proc = run("apply", cal, h5, "-o", tmp_path / "o.h5")
    assert_one_line_error(proc, "4 accel channels", "has 3", str(cal), str(h5))
    csv = write_csv(tmp_path / "in.csv", session, ("t", "ax", "ay", "az"))
    proc = run("apply", cal, csv, "-o", tmp_path / "o.h5", "--columns", "t,ax,ay,az")
    assert_one_line_error(proc, "4 accel channels", "has 3")
    assert not (tmp_path / "o.h5").exists() and not (tmp_path / "o.h5.tmp").exists()


def test_sensor_missing_from_input(sim, tmp_path):
    session, truth, _, cal_path = sim
    accel_only = Session(time=session.time, accel=session.accel, gyro=None, temperature=None,
                         segments=[], created=session.created)  # fmt: skip
    write_session(tmp_path / "a.h5", accel_only)
    assert_one_line_error(run("apply", cal_path, tmp_path / "a.h5", "-o", tmp_path / "o.h5"),
                          "no gyro data", "/raw/gyro")  # fmt: skip
    csv = write_csv(tmp_path / "in.csv", session, ("t", "ax", "ay", "az"))
    assert_one_line_error(run("apply", cal_path, csv, "-o", tmp_path / "o.h5", "--columns",
                              "t,ax,ay,az"), "no gyro columns")  # fmt: skip
    assert not (tmp_path / "o.h5").exists()


def test_other_refusals(sim, tmp_path):
    session, truth, h5, cal_path = sim
    out = tmp_path / "o.h5"
    out.write_text("keep me")
    assert_one_line_error(run("apply", cal_path, h5, "-o", out), "already exists", "--force")
    assert out.read_text() == "keep me"
    assert_one_line_error(run("apply", cal_path, h5, "-o", h5, "--force"), "is the input")
    not_session = tmp_path / "x.h5"
    with h5py.File(not_session, "w") as f:
        f.attrs["format"] = "something-else"
    assert_one_line_error(run("apply", cal_path, not_session, "-o", tmp_path / "p.h5"),
                          "not an imucal session")  # fmt: skip
    fake = tmp_path / "fake.h5"
    fake.write_text("1,2,3\n")
    assert_one_line_error(run("apply", cal_path, fake, "-o", tmp_path / "p.h5"), "not an HDF5")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    assert_one_line_error(run("apply", cal_path, empty, "-o", tmp_path / "p.h5"), "empty")
    text = tmp_path / "text.csv"
    text.write_text("a,b,c\nd,e,f\n")
    assert_one_line_error(run("apply", cal_path, text, "-o", tmp_path / "p.h5"), "no numeric")
    assert_one_line_error(run("apply", cal_path, h5, "-o", tmp_path / "p.h5", "--columns", "t"),
                          "--columns")  # fmt: skip


def test_units_that_differ_from_the_calibration(sim, tmp_path):
    session, truth, _, cal_path = sim
    other = Session(time=session.time, accel=session.accel, gyro=session.gyro, temperature=None,
                    segments=[], created=session.created, accel_units="g",
                    gyro_units="counts")  # fmt: skip
    write_session(tmp_path / "g.h5", other)
    assert_one_line_error(run("apply", cal_path, tmp_path / "g.h5", "-o", tmp_path / "o.h5"),
                          "accel in g", "made for counts")  # fmt: skip


def test_time_error_in_a_late_block_leaves_no_output(sim, tmp_path):
    session, truth, _, _ = sim
    t = session.time.copy()
    t[5000] = t[4990]
    csv = tmp_path / "in.csv"
    rows = np.column_stack([t, session.accel]).tolist()
    lines = [",".join(repr(v) for v in row) for row in rows]
    csv.write_text("\n".join(lines) + "\n")
    accel_only = Calibration(accel=truth.accel, created=truth.created)
    out = tmp_path / "o.h5"
    with pytest.raises(InputError, match="time does not increase at line 5001"):
        apply_calibration(accel_only, csv, out, columns="t,ax,ay,az", chunk_rows=1000)
    assert not out.exists() and not (tmp_path / "o.h5.tmp").exists()


# --------------------------------------------------------------------------------------------
# Constant memory
# --------------------------------------------------------------------------------------------


def test_constant_memory_on_a_long_session(tmp_path):
    """2 million samples (112 MB of raw data): the traced peak stays a few blocks' worth."""
    n, block = 2_000_000, 250_000
    path = tmp_path / "long.h5"
    rng = np.random.default_rng(1)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "imucal-session"
        f.attrs["format_version"] = 1
        f.attrs["created"] = "2026-01-01T00:00:00Z"
        raw = f.create_group("raw")
        sets = {
            "time": raw.create_dataset("time", (n,), "f8", chunks=(65536,)),
            "accel": raw.create_dataset("accel", (n, 3), "f8", chunks=(65536, 3)),
            "gyro": raw.create_dataset("gyro", (n, 3), "f8", chunks=(65536, 3)),
        }
        for start in range(0, n, block):
            stop = start + block
            sets["time"][start:stop] = np.arange(start, stop) / 1000.0
            sets["accel"][start:stop] = rng.normal(0, 2000, (block, 3))
            sets["gyro"][start:stop] = rng.normal(0, 2000, (block, 3))
    file_bytes = n * 7 * 8
    cal = Calibration(
        accel=SensorCalibration("x", "m/s^2", rng.normal(0, 10, 3), rng.normal(0, 1e-3, (3, 3))),
        gyro=SensorCalibration("x", "rad/s", rng.normal(0, 10, 3), rng.normal(0, 1e-3, (3, 3))),
    )
    out = tmp_path / "out.h5"
    calls = []
    tracemalloc.start()
    try:  # (its speed is measured in bench/speed.py: a wall-time limit fails under load)
        summary = apply_calibration(cal, path, out, progress=lambda d, t: calls.append((d, t)))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert summary.samples == n
    assert calls[-1] == (n, n) and len(calls) == summary.chunks > 20
    # One block of 65536 rows is 65536 * 7 * 8 B = 3.7 MB of input; a few copies of it.
    assert peak < 24e6, (peak, file_bytes)
    assert peak < file_bytes / 4
    with h5py.File(out, "r") as f:
        assert f["calibrated/accel"].shape == (n, 3) and f["calibrated/accel"].maxshape == (None, 3)
        assert f["calibrated/accel"].chunks is not None
        rows = slice(n - 10, n)
        with h5py.File(path, "r") as g:
            np.testing.assert_array_equal(f["calibrated/gyro"][rows],
                                          cal.gyro.apply(g["raw/gyro"][rows]))  # fmt: skip
            np.testing.assert_array_equal(f["calibrated/time"][rows], g["raw/time"][rows])


def test_nan_in_the_input_is_reported_not_hidden(tmp_path):
    import h5py

    from imucal_cli.formats.session import write_session
    from imucal_cli.simulate.triad import simulate
    from imucal_cli.use.apply import apply_calibration

    session, truth = simulate(plan="six", seed=2, created="2026-01-01T00:00:00Z")
    session.accel = session.accel.copy()
    move = session.rotation_segments()[0]  # an accel dropout while the unit is being turned
    i = move.start + 5
    session.accel[i : i + 3, 1] = np.nan
    src = tmp_path / "s.h5"
    write_session(src, session)
    summary = apply_calibration(truth, src, tmp_path / "out.h5")
    assert summary.nonfinite == 3
    with h5py.File(tmp_path / "out.h5") as f:
        assert np.isnan(f["calibrated/accel"][i : i + 3]).all()


def test_a_calibration_of_another_unit_is_written_with_a_warning(sim, tmp_path):
    """The session names its unit (`sensor`) and so does the calibration: another unit's
    biases and gains would be wrong numbers, so the output says so (a capture or import that
    names no unit is not warned about)."""
    import dataclasses
    import json

    session, _, s_path, cal_path = sim
    same = run("apply", cal_path, s_path, "-o", tmp_path / "same.h5")
    assert same.returncode == 0 and "warning" not in same.stdout, same.stdout
    for sensor, warned in (("BNO055 #18", True), (None, False), ("SIM-16bit seed 7 ", False)):
        other = tmp_path / f"other-{warned}-{sensor is None}.h5"
        write_session(other, dataclasses.replace(session, sensor=sensor))
        proc = run("apply", cal_path, other, "-o", tmp_path / "o.h5", "--force")
        assert proc.returncode == 0 and (tmp_path / "o.h5").exists()
        assert ("was made on 'sim-16bit seed 7' but" in proc.stdout
                and "is from 'BNO055 #18'" in proc.stdout) is warned, (sensor, proc.stdout)
    proc = run("apply", cal_path, tmp_path / "other-True-False.h5", "-o", tmp_path / "j.h5",
               "--json")  # fmt: skip
    warnings = json.loads(proc.stdout)["warnings"]
    assert len(warnings) == 1 and "belongs to one unit" in warnings[0]
