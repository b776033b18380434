"""Magnetometer data in and out: /raw/mag, mag_units and magnetic_field_uT in sessions (reader,
appending writer, validation), the mx my mz columns of capture and import."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from imucal_cli.capture.recorder import Recorder
from imucal_cli.capture.stream import LineProtocol
from imucal_cli.errors import InputError, SessionError
from imucal_cli.formats.columns import ColumnSpec
from imucal_cli.formats.importers import import_files
from imucal_cli.formats.importers.text import infer_columns, parse_columns
from imucal_cli.formats.session import (
    Segment,
    Session,
    SessionWriter,
    read_session,
    write_session,
)
from tests.cli_helpers import assert_one_line_error, run


def mag_session(n=200, units="uT", field=48.5) -> Session:
    rng = np.random.default_rng(3)
    mag = rng.normal(20.0, 5.0, (n, 3))
    mag[7] = np.nan  # the magnetometer gave no reading here
    return Session(
        time=np.arange(n) * 0.01,
        accel=rng.normal(size=(n, 3)),
        gyro=rng.normal(size=(n, 3)),
        temperature=None,
        segments=[Segment("0000", "static", 10, 60, label="face +Z up", up=[0, 0, 1.0])],
        created="2026-11-21T10:00:00Z",
        accel_units="counts",
        gyro_units="counts",
        mag=mag,
        mag_units=units,
        magnetic_field_uT=field,
    )


def test_round_trip_keeps_mag_its_units_and_the_field(tmp_path):
    s = mag_session()
    write_session(tmp_path / "m.h5", s)
    r = read_session(tmp_path / "m.h5")
    assert np.array_equal(r.mag, s.mag, equal_nan=True)
    assert r.mag_units == "uT" and r.magnetic_field_uT == 48.5
    with h5py.File(tmp_path / "m.h5") as f:
        assert f["raw/mag"].shape == (200, 3) and f.attrs["mag_units"] == "uT"
        assert f.attrs["magnetic_field_uT"] == 48.5


def test_session_without_mag_reads_none(tmp_path):
    s = mag_session()
    s.mag = s.mag_units = s.magnetic_field_uT = None
    write_session(tmp_path / "n.h5", s)
    r = read_session(tmp_path / "n.h5")
    assert r.mag is None and r.mag_units is None and r.magnetic_field_uT is None
    with h5py.File(tmp_path / "n.h5") as f:
        assert "mag" not in f["raw"] and "mag_units" not in f.attrs


def test_appending_writer_records_mag_block_by_block(tmp_path):
    path = tmp_path / "w.h5"
    with SessionWriter(path, mag_channels=3, mag_units="counts", gyro_channels=None) as w:
        for k in range(3):
            t = np.arange(10) * 0.01 + 0.1 * k
            w.append(t, accel=np.ones((10, 3)), mag=np.full((10, 3), k))
        with pytest.raises(SessionError, match="mag is missing"):
            w.append(np.array([1.0]), accel=np.ones((1, 3)))
        with pytest.raises(SessionError, match=r"mag has shape \(1, 2\)"):
            w.append(np.array([1.0]), accel=np.ones((1, 3)), mag=np.ones((1, 2)))
    r = read_session(path)
    assert r.mag.shape == (30, 3) and r.mag[25, 0] == 2 and r.mag_units == "counts"
    with SessionWriter(tmp_path / "x.h5") as w, pytest.raises(SessionError, match="got mag"):
        w.append(0.0, accel=np.ones(3), gyro=np.ones(3), mag=np.ones(3))


def test_writer_refuses_unknown_units_and_a_bad_field(tmp_path):
    with pytest.raises(InputError, match="mag_units must be one of counts, uT, nT, gauss"):
        SessionWriter(tmp_path / "a.h5", mag_channels=3, mag_units="mG")
    with pytest.raises(InputError, match="magnetic_field_uT must be a positive"):
        SessionWriter(tmp_path / "b.h5", mag_channels=3, magnetic_field_uT=-3)
    with pytest.raises(InputError, match="mag_channels must be an integer >= 3"):
        SessionWriter(tmp_path / "c.h5", mag_channels=2)


@pytest.mark.parametrize(
    "change, problem",
    [
        (lambda f: f.attrs.__setitem__("mag_units", "mG"), "'mag_units' is 'mG', expected one of"),
        (lambda f: f.attrs.__setitem__("mag_units", 3), "'mag_units' is not a string"),
        (lambda f: f.attrs.__setitem__("magnetic_field_uT", 0.0), "'magnetic_field_uT' must be"),
        (lambda f: f.attrs.__setitem__("magnetic_field_uT", "x"), "'magnetic_field_uT' must be"),
        (lambda f: _replace(f, np.zeros((200, 2))), r"/raw/mag must have shape \(N, >=3\)"),
        (lambda f: _replace(f, np.zeros((150, 3))), "/raw/mag must have shape"),
        (lambda f: _replace(f, np.zeros(200)), "/raw/mag must have shape"),
        (lambda f: _replace(f, np.array(["a"] * 200, dtype="S1")), "/raw/mag is not numeric"),
    ],
)
def test_reader_refuses_bad_mag_data_with_one_line(tmp_path, change, problem):
    path = tmp_path / "bad.h5"
    write_session(path, mag_session())
    with h5py.File(path, "r+") as f:
        change(f)
    with pytest.raises(SessionError, match=problem) as info:
        read_session(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def _replace(f, data):
    del f["raw/mag"]
    f["raw/mag"] = data


def test_other_tools_may_write_mag_as_integers(tmp_path):
    path = tmp_path / "int.h5"
    write_session(path, mag_session())
    with h5py.File(path, "r+") as f:
        del f["raw/mag"]
        f["raw/mag"] = np.arange(600, dtype=np.int16).reshape(200, 3)
    assert read_session(path).mag.dtype == np.float64


# ------------------------------------------------------------------------------ columns


def test_capture_columns_mx_my_mz():
    spec = ColumnSpec.parse("t,ax,ay,az,gx,gy,gz,mx,my,mz,temp")
    assert spec.mag == (7, 8, 9)
    block = spec.to_block(np.arange(22.0).reshape(2, 11))
    assert np.array_equal(block.mag, [[7, 8, 9], [18, 19, 20]])
    assert block.take(np.array([1])).mag.tolist() == [[18, 19, 20]]
    assert ColumnSpec.parse("t,mx,my,mz").mag == (1, 2, 3)  # a magnetometer alone
    with pytest.raises(InputError, match="magnetometer needs at least 3"):
        ColumnSpec.parse("t,ax,ay,az,mx,my")
    with pytest.raises(InputError, match="mx, my, mz"):
        ColumnSpec.parse("t,ax,ay,az,mq")


def test_recorder_writes_mag_and_its_units(tmp_path):
    lines = b"".join(
        f"{0.01 * k:.2f},1,2,3,{k},{-k},{2 * k}\n".encode() for k in range(30)
    )

    class Source:
        uri = "serial:/dev/fake@115200"
        sent = False

        def describe(self):
            return "fake"

        def read(self):
            if self.sent:
                from imucal_cli.capture.stream import DeviceGone

                raise DeviceGone("gone")
            self.sent = True
            return lines

        def close(self):
            pass

    protocol = LineProtocol(ColumnSpec.parse("t,ax,ay,az,mx,my,mz"))
    rec = Recorder(
        tmp_path / "r.h5", Source(), protocol, mag_units="counts", magnetic_field_uT=50.0
    )
    for _ in rec.blocks():
        pass
    rec.close()
    s = read_session(tmp_path / "r.h5")
    assert s.mag.shape == (30, 3) and s.mag[29].tolist() == [29, -29, 58]
    assert s.mag_units == "counts" and s.magnetic_field_uT == 50.0 and s.gyro is None


# ------------------------------------------------------------------------------ import


def test_import_columns_and_header_names_for_mag():
    assert parse_columns("t,ax,ay,az,mx,my,mz")[4:] == ["mx", "my", "mz"]
    with pytest.raises(InputError, match="magnetometer needs all three"):
        parse_columns("t,ax,ay,az,mx,my")
    assert infer_columns(["time", "acc_x", "acc_y", "acc_z", "Mag X [uT]", "mag_y", "mag_z"]) == [
        "t", "ax", "ay", "az", "mx", "my", "mz",
    ]  # fmt: skip
    assert infer_columns(["t", "mag_x", "mag_y"]) is None


def test_import_csv_with_mag_and_a_magnetometer_alone(tmp_path):
    rng = np.random.default_rng(0)
    n = 600
    accel = np.where(np.arange(n)[:, None] < 300, [0, 0, 9.8], [9.8, 0, 0])
    accel = accel + rng.normal(0, 0.01, (n, 3))
    mag = rng.normal(0, 30, (n, 3))
    rows = np.column_stack([np.arange(n) * 0.01, accel, mag])
    path = tmp_path / "m.csv"
    np.savetxt(path, rows, delimiter=",", header="t,ax,ay,az,mx,my,mz", comments="")
    s = import_files([path], mag_units="uT", magnetic_field_uT=49.0, accel_units="m/s^2")
    assert np.allclose(s.mag, mag) and s.mag_units == "uT" and s.magnetic_field_uT == 49.0
    assert s.static_segments()
    alone = tmp_path / "alone.csv"
    np.savetxt(alone, rows[:, [0, 4, 5, 6]], delimiter=",", header="t,mx,my,mz", comments="")
    s2 = import_files([alone], mag_units="gauss")
    assert s2.accel is None and s2.segments == [] and s2.mag.shape == (n, 3)
    with pytest.raises(InputError, match="--mag-units 'mG'"):
        import_files([path], mag_units="mG")


def test_cli_import_and_capture_refuse_bad_mag_options(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("t,mx,my,mz\n0,1,2,3\n0.01,1,2,3\n")
    assert_one_line_error(run("import", path, "--mag-units", "mG", "-o", tmp_path / "o.h5"),
                          "--mag-units 'mG'")  # fmt: skip
    assert_one_line_error(
        run("capture", "--port", "/dev/null", "--field-uT", "-1", "--no-prompt",
            "--duration", "1", "-o", tmp_path / "c.h5"),
        "--field-uT must be a positive",
    )  # fmt: skip
