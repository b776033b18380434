"""Session HDF5 format: round trips, the appending SWMR writer, files from other tools, and
one test per validation error of the reader."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from imucal_cli.errors import ImucalWarning, InputError, SessionError
from imucal_cli.formats.session import (
    GRAVITY_DEFAULT,
    Segment,
    Session,
    SessionWriter,
    read_session,
    store_calibration,
    utc_now_iso,
    write_session,
)
from imucal_cli.formats.session import writer as session_writer

ROOT = Path(__file__).resolve().parents[1]
N = 100


def make_session(n: int = N, na: int = 3) -> Session:
    """A small complete session: accel, gyro, temperature, a static and a rotation segment."""
    rng = np.random.default_rng(1)
    return Session(
        time=np.arange(n) * 0.01 + 5.0,
        accel=rng.normal(size=(n, na)),
        gyro=rng.normal(size=(n, 3)),
        temperature=np.linspace(20.0, 21.0, n),
        segments=[
            Segment("0000", "static", 0, 40, label="face +Z up", up=np.array([0.0, 0.0, 1.0])),
            Segment(
                "0001", "rotation", 50, 80, label="turn about X", axis=[1.0, 0, 0], angle_deg=90.0
            ),
        ],  # fmt: skip
        created="2026-11-21T10:00:00Z",
        sensor="BNO055 #17",
        source="simulator",
        sample_rate_hz=100.0,
        gravity=9.81,
        accel_units="counts",
        gyro_units="counts",
        calibrations={"0000": '{"format": "imucal-calibration"}'},
    )


def assert_sessions_equal(a: Session, b: Session) -> None:
    for name in ("time", "accel", "gyro", "temperature"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)
    assert a.segments == b.segments
    for name in ("created", "sensor", "source", "sample_rate_hz", "gravity", "accel_units",
                 "gyro_units", "calibrations"):  # fmt: skip
        assert getattr(a, name) == getattr(b, name), name


# ------------------------------------------------------------------------------------------
# Round trips
# ------------------------------------------------------------------------------------------


def test_round_trip_complete_session(tmp_path):
    path = tmp_path / "s.h5"
    original = make_session()
    write_session(path, original)
    back = read_session(path)
    assert_sessions_equal(back, original)
    assert back.path == path
    assert [s.name for s in back.static_segments()] == ["0000"]
    assert [s.name for s in back.rotation_segments()] == ["0001"]
    assert back.segments[0].n_samples == 40


def test_round_trip_redundant_accel_only_no_segments(tmp_path):
    path = tmp_path / "s.h5"
    original = make_session(na=4)
    original.gyro = original.temperature = None
    original.segments = [original.segments[0]]
    original.sensor = original.source = original.sample_rate_hz = None
    original.accel_units = original.gyro_units = None
    original.gravity = GRAVITY_DEFAULT
    original.calibrations = {}
    write_session(path, original)
    back = read_session(path)
    assert_sessions_equal(back, original)
    assert back.accel.shape == (N, 4)
    with h5py.File(path, "r") as f:
        assert "gyro" not in f["raw"] and "temperature" not in f["raw"]
        assert set(f.attrs) == {"format", "format_version", "created", "gravity"}


def test_empty_session_round_trip(tmp_path):
    path = tmp_path / "s.h5"
    empty = Session(np.zeros(0), np.zeros((0, 3)), None, None, [], created=utc_now_iso())
    write_session(path, empty)
    back = read_session(path)
    assert back.time.shape == (0,) and back.accel.shape == (0, 3) and back.segments == []


def test_write_session_refuses_existing_file_unless_overwrite(tmp_path):
    path = tmp_path / "s.h5"
    write_session(path, make_session())
    with pytest.raises(InputError, match=f"^{path}: already exists"):
        write_session(path, make_session())
    write_session(path, make_session(n=90), overwrite=True)
    assert read_session(path).time.size == 90


def test_unknown_groups_datasets_and_attributes_are_ignored(tmp_path):
    path = tmp_path / "s.h5"
    original = make_session()
    write_session(path, original)
    with h5py.File(path, "r+") as f:
        f.attrs["operator"] = "ana"
        f["raw/pressure"] = np.ones(N)
        f["extra/thing"] = np.arange(3)
        f["segments/notes"] = np.arange(2)  # a dataset among the segment groups
        f["segments/0000"].attrs["note"] = "wobbly table"
        f["segments/0001/trace"] = np.arange(4)
        f.create_group("calibrations/0001")  # no json attribute
    assert_sessions_equal(read_session(path), original)


def test_file_written_by_another_tool_minimal(tmp_path):
    """Default libver, contiguous datasets, bytes-typed strings, int32 and MATLAB-style float
    indices, segments without optional attributes, written out of time order."""
    path = tmp_path / "other.h5"
    t = np.arange(N) * 0.02
    accel = np.tile([0.0, 0.0, 9.8], (N, 1))
    gyro = np.zeros((N, 3))
    with h5py.File(path, "w") as f:
        f.attrs["format"] = np.bytes_(b"imucal-session")
        f.attrs["format_version"] = np.int32(1)
        f.attrs["created"] = np.bytes_(b"2026-01-02T03:04:05Z")
        f.attrs["sensor"] = np.array([b"MPU-6050"])  # a 1-element array of bytes
        f["raw/time"] = t
        f["raw/accel"] = accel
        f["raw/gyro"] = gyro
        late = f.create_group("segments/0000")
        late.attrs["kind"] = np.bytes_(b"rotation")
        late.attrs["start"] = 60.0
        late.attrs["stop"] = 90.0
        early = f.create_group("segments/0001")
        early.attrs["kind"] = "static"
        early.attrs["start"] = np.int32(0)
        early.attrs["stop"] = np.int32(50)
        early.attrs["up"] = [0, 0, 2]  # not unit length: normalised on read
        assert f["raw/time"].chunks is None  # contiguous
    s = read_session(path)
    assert s.created == "2026-01-02T03:04:05Z"
    assert s.sensor == "MPU-6050" and s.source is None and s.sample_rate_hz is None
    assert s.gravity == GRAVITY_DEFAULT and s.temperature is None
    np.testing.assert_array_equal(s.time, t)
    assert [(g.name, g.kind, g.start, g.stop) for g in s.segments] == [
        ("0001", "static", 0, 50),
        ("0000", "rotation", 60, 90),
    ]
    np.testing.assert_array_equal(s.segments[0].up, [0.0, 0.0, 1.0])
    assert s.segments[1].axis is None and s.segments[1].angle_deg is None
    assert s.segments[1].label is None


def test_nan_outside_segments_is_allowed(tmp_path):
    path = tmp_path / "s.h5"
    original = make_session()
    original.accel[45] = np.nan  # between the segments
    original.gyro[10] = np.inf  # inside the static segment, but that uses accel only
    write_session(path, original)
    assert np.isnan(read_session(path).accel[45]).all()


def test_reads_one_hour_at_100_hz(tmp_path):
    # (Its speed is measured by `make bench`, not asserted here.)
    path = tmp_path / "hour.h5"
    n = 360_000
    rng = np.random.default_rng(0)
    segments = [Segment(f"{i:04d}", "static", i * 1000, i * 1000 + 800, up=[0, 0, 1])
                for i in range(300)]  # fmt: skip
    write_session(
        path,
        Session(np.arange(n) * 0.01, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), None,
                segments, created=utc_now_iso()),
    )  # fmt: skip
    s = read_session(path)
    assert s.accel.shape == (n, 3) and len(s.segments) == 300


# ------------------------------------------------------------------------------------------
# The appending writer
# ------------------------------------------------------------------------------------------


def test_writer_blocks_and_single_samples(tmp_path):
    path = tmp_path / "w.h5"
    t = np.arange(30) * 0.01
    accel = np.arange(90.0).reshape(30, 3)
    gyro = -accel
    temp = np.linspace(20, 22, 30)
    with SessionWriter(path, temperature=True, sensor="unit 3", accel_units="counts") as w:
        w.append(t[:10], accel[:10], gyro[:10], temp[:10])
        for i in range(10, 20):
            w.append(t[i], accel[i], gyro[i], temp[i])
        w.append(t[20:], accel[20:].tolist(), gyro[20:], temp[20:])
        assert w.n_samples == 30
        assert w.add_segment("static", 0, 10, label="+Z", up=(0, 0, 1)) == "0000"
        assert w.add_segment("rotation", 12, 30, axis=[0, 2, 0], angle_deg=-90) == "0001"
    s = read_session(path)
    np.testing.assert_array_equal(s.time, t)
    np.testing.assert_array_equal(s.accel, accel)
    np.testing.assert_array_equal(s.gyro, gyro)
    np.testing.assert_array_equal(s.temperature, temp)
    assert s.sensor == "unit 3" and s.accel_units == "counts" and s.source is None
    assert s.segments == [
        Segment("0000", "static", 0, 10, label="+Z", up=[0, 0, 1]),
        Segment("0001", "rotation", 12, 30, axis=[0, 1, 0], angle_deg=-90.0),
    ]


def test_writer_bytes_per_sample_is_the_row_of_its_datasets(tmp_path):
    """What one sample takes in /raw (a capture's disk headroom, at every block): the widths
    of the writer's datasets, a reopened session's its own."""
    with SessionWriter(tmp_path / "b.h5", temperature=True) as w:
        assert w.bytes_per_sample == 8 * (3 + 3 + 1 + 1)
        w.append(np.arange(5) * 0.01, np.zeros((5, 3)), np.zeros((5, 3)), np.zeros(5))
        assert w.bytes_per_sample == 8 * (3 + 3 + 1 + 1)
    with SessionWriter(tmp_path / "a.h5", gyro_channels=None) as w:
        assert w.bytes_per_sample == 8 * (3 + 1)
        w.append(np.arange(5) * 0.01, np.zeros((5, 3)))
    again = SessionWriter.reopen(tmp_path / "a.h5")
    try:
        assert again.bytes_per_sample == 8 * (3 + 1)
    finally:
        again.close()


def test_writer_file_layout(tmp_path):
    path = tmp_path / "w.h5"
    with SessionWriter(path, created="2026-11-21T10:00:00Z", gyro_channels=None) as w:
        w.append(np.arange(5) * 0.1, np.ones((5, 3)))
        w.add_segment("static", 0, 5, up=[0, 0, 1])
    # A cleanly closed file opens in plain (non-SWMR) mode and holds no recovery log.
    with h5py.File(path, "r") as f:
        assert dict(f.attrs) == {
            "format": "imucal-session",
            "format_version": 1,
            "created": "2026-11-21T10:00:00Z",
        }
        assert sorted(f) == ["raw", "segments"]
        for name in ("time", "accel"):
            ds = f["raw"][name]
            assert ds.chunks is not None and ds.maxshape[0] is None and ds.dtype == np.float64
        seg = f["segments/0000"]
        assert len(seg) == 0  # attributes only
        assert seg.attrs["up"].dtype == np.float64 and seg.attrs["up"].shape == (3,)
        assert set(seg.attrs) == {"kind", "start", "stop", "up"}


def test_writer_flushes_on_time(tmp_path, monkeypatch):
    clock = [100.0]
    monkeypatch.setattr(session_writer._time, "monotonic", lambda: clock[0])
    with SessionWriter(tmp_path / "w.h5", gyro_channels=None) as w:
        on_disk = w._file["raw/time"]
        w.append(0.0, [0, 0, 1])
        clock[0] += 0.5
        w.append(0.1, [0, 0, 1])
        assert on_disk.shape == (0,)  # buffered, flush not due
        clock[0] += 0.6
        w.append(0.2, [0, 0, 1])
        assert on_disk.shape == (3,)  # 1.1 s since the last flush


CHILD = """
import sys, time
import numpy as np
from imucal_cli.formats.session import SessionWriter

with SessionWriter(
    sys.argv[1], gyro_channels=None, sample_rate_hz=1000.0, publish_early=True
) as w:
    n = 0
    while True:
        t = (n + np.arange(10)) * 0.001
        w.append(t, np.column_stack([t, -t, np.full(10, 9.8)]))
        n += 10
        if n == 200:
            w.add_segment("static", 0, 100, label="face +Z up", up=[0, 0, 1])
        print(n, time.monotonic(), flush=True)
        time.sleep(0.005)
"""


def test_kill_9_leaves_a_readable_file(tmp_path):
    """A recorder killed with SIGKILL leaves a file that reads, missing at most ~1 s, and the
    file can be read while it is being written."""
    path = tmp_path / "killed.h5"
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True, cwd=ROOT
    )
    printed: list[tuple[int, float]] = []

    def run_until(seconds: float) -> None:
        """Read the child's progress until it has run ``seconds`` (its own clock) past the
        segment at sample 200: a flush (at least one a second) has happened since."""
        for line in proc.stdout:
            n, t = line.split()
            printed.append((int(n), float(t)))
            segment_at = next((t for n, t in printed if n >= 200), None)
            if segment_at is not None and printed[-1][1] - segment_at >= seconds:
                return
        raise AssertionError("the writer stopped")

    try:
        run_until(1.6)
        live = read_session(path)  # opens while the writer has it open
        assert live.time.size > 0 and len(live.segments) == 1
        run_until(2.6)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        out, _ = proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    printed += [(int(n), float(t)) for n, t in (line.split() for line in out.splitlines())]
    # what the child had appended more than 1.2 s (of its own running) before its last line
    # was flushed: it flushes at least once a second while appending
    last = printed[-1][1]
    must_have = max(n for n, t in printed if t < last - 1.2)

    with pytest.raises(OSError):
        h5py.File(path, "r")  # the writer's "open for writing" flag is still set
    with pytest.warns(ImucalWarning, match="did not close it.*repaired"):
        s = read_session(path)
    with h5py.File(path, "r") as plain:  # repaired: plain HDF5 opens it
        assert plain["raw/time"].shape[0] >= s.time.size
    n = s.time.size
    assert n >= must_have > 0
    np.testing.assert_allclose(s.time, np.arange(n) * 0.001)
    np.testing.assert_allclose(s.accel[:, 1], -s.time)
    assert s.sample_rate_hz == 1000.0
    assert s.segments == [Segment("0000", "static", 0, 100, label="face +Z up", up=[0, 0, 1])]


def test_writer_refuses_to_overwrite(tmp_path):
    path = tmp_path / "w.h5"
    path.write_bytes(b"precious")
    with pytest.raises(InputError, match=f"^{path}: already exists"):
        SessionWriter(path)
    assert path.read_bytes() == b"precious"
    with SessionWriter(path, overwrite=True) as w:
        w.append(0.0, [0, 0, 1], [0, 0, 0])
    assert read_session(path).time.size == 1


def test_writer_cannot_create_in_missing_directory(tmp_path):
    path = tmp_path / "nope" / "w.h5"
    with pytest.raises(InputError, match=f"^{path}: folder .* does not exist"):
        SessionWriter(path)


def _writer_with_samples(path: Path, **kwargs) -> SessionWriter:
    w = SessionWriter(path, **kwargs)
    accel = np.ones((20, 3))
    accel[15] = np.nan
    w.append(np.arange(20) * 0.01, accel, np.zeros((20, 3)))
    return w


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda w: w.append(0.1, [0, 0, 1], [0, 0, 0]),
         r"time is not strictly increasing \(sample 20: 0\.1 s after 0\.19 s\)"),
        (lambda w: w.append([0.3, 0.3], np.ones((2, 3)), np.ones((2, 3))),
         r"time is not strictly increasing \(sample 21: 0\.3 s after 0\.3 s\)"),
        (lambda w: w.append(np.nan, [0, 0, 1], [0, 0, 0]), "time is nan"),
        (lambda w: w.append(1.0, [0, 0, 1]), "gyro is missing"),
        (lambda w: w.append(1.0, [0, 0, 1], [0, 0, 0], 20.0), "does not record temperature"),
        (lambda w: w.append([1.0, 2.0], np.ones((2, 4)), np.ones((2, 3))),
         r"accel has shape \(2, 4\), expected \(2, 3\)"),
        (lambda w: w.add_segment("wiggle", 0, 5), "unknown kind 'wiggle'"),
        (lambda w: w.add_segment("static", 0, 21), r"samples \[0, 21\) are not"),
        (lambda w: w.add_segment("static", 5, 5), r"samples \[5, 5\) are not"),
        (lambda w: w.add_segment("static", 10, 15, up=[0, 0, 0]), "'up' must be 3 finite"),
        (lambda w: w.add_segment("rotation", 0, 5, up=[0, 0, 1]), "'up' does not apply"),
        (lambda w: w.add_segment("static", 0, 5, angle_deg=90), "'angle_deg' does not apply"),
        (lambda w: w.add_segment("rotation", 0, 5, angle_deg=np.inf), "'angle_deg' must be"),
        (lambda w: w.add_segment("static", 10, 18), "/raw/accel has NaN or inf at sample 15"),
        (lambda w: (w.add_segment("static", 5, 10), w.add_segment("static", 0, 4)),
         "segments must be added in time order"),
    ],
)  # fmt: skip
def test_writer_errors(tmp_path, call, message):
    path = tmp_path / "w.h5"
    with _writer_with_samples(path) as w:
        with pytest.raises(SessionError, match=f"^{path}: .*{message}") as info:
            call(w)
        assert "\n" not in str(info.value)
        assert w.n_samples == 20  # nothing of a refused block is kept
    read_session(path)  # what was accepted is a valid file


def test_writer_segment_needs_its_sensor(tmp_path):
    with SessionWriter(tmp_path / "w.h5", accel_channels=None) as w:
        w.append(0.0, gyro=[0, 0, 0])
        w.append(0.1, gyro=[0, 0, 0])
        with pytest.raises(SessionError, match="needs accel"):
            w.add_segment("static", 0, 2)
    with pytest.raises(SessionError, match="writer is closed"):
        w.append(0.2, gyro=[0, 0, 0])


# ------------------------------------------------------------------------------------------
# Reader validation: every error names the file, on one line
# ------------------------------------------------------------------------------------------


def write_good_file(path: Path) -> None:
    """A valid session written with plain h5py, as another tool would."""
    t = np.arange(N) * 0.01
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "imucal-session"
        f.attrs["format_version"] = 1
        f.attrs["created"] = "2026-11-21T10:00:00Z"
        f["raw/time"] = t
        f["raw/accel"] = np.tile([0.0, 0.0, 9.8], (N, 1))
        f["raw/gyro"] = np.zeros((N, 3))
        f["raw/temperature"] = np.full(N, 20.0)
        static = f.create_group("segments/0000")
        static.attrs.update({"kind": "static", "start": 0, "stop": 40, "up": [0.0, 0.0, 1.0]})
        rotation = f.create_group("segments/0001")
        rotation.attrs.update(
            {"kind": "rotation", "start": 50, "stop": 80, "axis": [1.0, 0, 0], "angle_deg": 90.0}
        )


def replace(f: h5py.File, name: str, data) -> None:
    del f[name]
    f[name] = data


def set_value(name: str, index, value):
    def mutate(f):
        data = f[name][()]
        data[index] = value
        replace(f, name, data)

    return mutate


def set_attr(obj: str, name: str, value):
    def mutate(f):
        f[obj].attrs[name] = value

    return mutate


def del_attr(obj: str, name: str):
    def mutate(f):
        del f[obj].attrs[name]

    return mutate


def delete(name: str):
    def mutate(f):
        del f[name]

    return mutate


BAD_FILES = {
    "format missing": (del_attr("/", "format"), "no root attribute 'format'"),
    "format wrong": (set_attr("/", "format", "hdf5-imu"), "not an imucal session (format is"),
    "format_version missing": (del_attr("/", "format_version"), "'format_version' is missing"),
    "format_version 2": (set_attr("/", "format_version", 2), "unsupported format_version 2"),
    "format_version text": (set_attr("/", "format_version", "1"), "unsupported format_version"),
    "created missing": (del_attr("/", "created"), "'created' is missing"),
    "created number": (set_attr("/", "created", 2026), "'created' is not a string"),
    "gravity negative": (set_attr("/", "gravity", -9.8), "'gravity' must be a positive number"),
    "rate text": (set_attr("/", "sample_rate_hz", "fast"), "'sample_rate_hz' must be a positive"),
    "sensor number": (set_attr("/", "sensor", 17), "'sensor' is not a string"),
    "raw missing": (delete("raw"), "/raw/time is missing"),
    "time missing": (delete("raw/time"), "/raw/time is missing"),
    "time 2-D": (lambda f: replace(f, "raw/time", np.zeros((N, 1))), "/raw/time must be 1-D"),
    "time text": (lambda f: replace(f, "raw/time", np.array([b"x"] * N)), "is not numeric"),
    "time group": (lambda f: (delete("raw/time")(f), f.create_group("raw/time")),
                   "/raw/time is not a dataset"),
    "time not increasing": (set_value("raw/time", 41, 0.40),
                            r"/raw/time is not strictly increasing (sample 41: 0.4 s after 0.4 s)"),
    "time decreasing": (set_value("raw/time", 7, 0.01), "(sample 7: 0.01 s after 0.06 s)"),
    "time nan": (set_value("raw/time", 7, np.nan), "/raw/time is nan at sample 7"),
    "time inf": (set_value("raw/time", N - 1, np.inf), f"/raw/time is inf at sample {N - 1}"),
    "accel 1-D": (lambda f: replace(f, "raw/accel", np.zeros(N)), "/raw/accel must have shape"),
    "accel rows": (lambda f: replace(f, "raw/accel", np.zeros((N - 1, 3))),
                   "/raw/accel must have shape"),
    "accel extra rows": (lambda f: replace(f, "raw/accel", np.zeros((N + 1, 3))),
                         f"/raw/accel has {N + 1} rows, /raw/time has {N}"),
    "accel 2 columns": (lambda f: replace(f, "raw/accel", np.zeros((N, 2))),
                        "/raw/accel must have shape (N, >=3)"),
    "gyro 2 columns": (lambda f: replace(f, "raw/gyro", np.zeros((N, 2))), "/raw/gyro must have"),
    "temperature 2-D": (lambda f: replace(f, "raw/temperature", np.zeros((N, 1))),
                        f"/raw/temperature must have shape ({N},)"),
    "temperature rows": (lambda f: replace(f, "raw/temperature", np.zeros(N + 2)),
                         "/raw/temperature must have shape"),
    "static without accel": (delete("raw/accel"),
                             "/segments/0000: static segment but the file has no /raw/accel"),
    "rotation without gyro": (delete("raw/gyro"),
                              "/segments/0001: rotation segment but the file has no /raw/gyro"),
    "kind missing": (del_attr("segments/0000", "kind"), "/segments/0000: attribute 'kind' is"),
    "start missing": (del_attr("segments/0001", "start"), "/segments/0001: attribute 'start'"),
    "stop missing": (del_attr("segments/0000", "stop"), "attribute 'stop' is missing"),
    "kind unknown": (set_attr("segments/0000", "kind", "wiggle"), "unknown kind 'wiggle'"),
    "kind number": (set_attr("segments/0000", "kind", 1), "unknown kind 1"),
    "start = stop": (set_attr("segments/0000", "start", 40), "start 40 is not before stop 40"),
    "start > stop": (set_attr("segments/0001", "start", 90), "start 90 is not before stop 80"),
    "start negative": (set_attr("segments/0000", "start", -1),
                       f"samples [-1, 40) are outside the recorded range [0, {N}]"),
    "stop past end": (set_attr("segments/0001", "stop", N + 1), "are outside the recorded range"),
    "start fractional": (set_attr("segments/0000", "start", 1.5),
                         "'start' must be an integer sample index, got 1.5"),
    "stop text": (set_attr("segments/0000", "stop", "40"), "'stop' must be an integer"),
    "label number": (set_attr("segments/0000", "label", 3), "'label' is not a string"),
    "up 2 numbers": (set_attr("segments/0000", "up", [0.0, 1.0]), "'up' must be 3 finite numbers"),
    "up zero": (set_attr("segments/0000", "up", [0.0, 0.0, 0.0]), "not all zero"),
    "up nan": (set_attr("segments/0000", "up", [0.0, np.nan, 1.0]), "'up' must be 3 finite"),
    "up text": (set_attr("segments/0000", "up", "z"), "'up' must be 3 finite numbers"),
    "axis zero": (set_attr("segments/0001", "axis", [0.0, 0.0, 0.0]), "'axis' must be 3 finite"),
    "axis 4 numbers": (set_attr("segments/0001", "axis", [1.0, 0, 0, 0]), "'axis' must be 3"),
    "angle nan": (set_attr("segments/0001", "angle_deg", np.nan), "'angle_deg' must be a finite"),
    "angle text": (set_attr("segments/0001", "angle_deg", "ninety"), "'angle_deg' must be"),
    "nan in static": (set_value("raw/accel", (10, 1), np.nan),
                      "/segments/0000: /raw/accel has NaN or inf at sample 10"),
    "inf in rotation": (set_value("raw/gyro", (79, 2), -np.inf),
                        "/segments/0001: /raw/gyro has NaN or inf at sample 79"),
}  # fmt: skip


@pytest.mark.parametrize("mutate, message", BAD_FILES.values(), ids=BAD_FILES.keys())
def test_reader_errors(tmp_path, mutate, message):
    path = tmp_path / "bad.h5"
    write_good_file(path)
    read_session(path)  # valid before the mutation
    with h5py.File(path, "r+") as f:
        mutate(f)
    with pytest.raises(SessionError) as info:
        read_session(path)
    text = str(info.value)
    assert text.startswith(f"{path}: ")
    assert "\n" not in text
    assert message in text


def test_reader_errors_for_files_that_are_not_sessions(tmp_path):
    cases = {
        tmp_path / "missing.h5": "no such file",
        tmp_path / "text.h5": "not an HDF5 file",
        tmp_path: "is a directory",
        tmp_path / "empty.h5": "not an HDF5 file",
    }
    (tmp_path / "text.h5").write_text("time,ax,ay,az\n0,1,2,3\n")
    (tmp_path / "empty.h5").write_bytes(b"")
    for path, message in cases.items():
        with pytest.raises(SessionError, match=f"^{path}: {message}"):
            read_session(path)
        with pytest.raises(SessionError, match=f"^{path}: "):
            store_calibration(path, "{}")


# ------------------------------------------------------------------------------------------
# Calibrations stored in a session
# ------------------------------------------------------------------------------------------


def test_store_calibration_appends_and_never_touches_raw(tmp_path):
    path = tmp_path / "s.h5"
    original = make_session()
    original.calibrations = {}
    write_session(path, original)
    assert store_calibration(path, '{"a": 1}') == "0000"
    assert store_calibration(path, '{"a": 2}') == "0001"
    assert store_calibration(path, '{"a": 3}', name="best") == "best"
    assert store_calibration(path, '{"a": 4}') == "0002"
    back = read_session(path)
    assert back.calibrations == {
        "0000": '{"a": 1}', "0001": '{"a": 2}', "0002": '{"a": 4}', "best": '{"a": 3}'
    }  # fmt: skip
    back.calibrations = {}
    assert_sessions_equal(back, original)


def test_store_calibration_large_json(tmp_path):
    path = tmp_path / "s.h5"
    write_session(path, make_session())
    text = '{"poses": [' + ", ".join(['{"residual": 0.0001}'] * 20000) + "]}"
    name = store_calibration(path, text)
    assert read_session(path).calibrations[name] == text


@pytest.mark.parametrize(
    "text, name, message",
    [
        ("{not json", None, "calibration to store is not valid JSON"),
        ("{}", "0000", "/calibrations/0000 already exists"),
        ("{}", "a/b", "'a/b' is not a valid calibration name"),
        ("{}", "", "'' is not a valid calibration name"),
    ],
)
def test_store_calibration_errors(tmp_path, text, name, message):
    path = tmp_path / "s.h5"
    write_session(path, make_session())
    with pytest.raises(SessionError, match=f"^{path}: ") as info:
        store_calibration(path, text, name)
    assert message in str(info.value)


def test_store_calibration_refuses_non_session_hdf5(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["data"] = np.arange(3)
    with pytest.raises(SessionError, match="not an imucal session"):
        store_calibration(path, "{}")
    with h5py.File(path, "r") as f:
        assert "calibrations" not in f


def test_segment_extra_attributes_round_trip(tmp_path):
    """Attributes the format does not name (e.g. a rotation's `mounting`) survive a round trip
    and are also recovered from the crash log of an unclosed writer."""
    from imucal_cli.formats.session import Segment, Session, read_session, write_session

    t = np.arange(100) / 100.0
    session = Session(
        time=t,
        accel=np.ones((100, 3)),
        gyro=np.zeros((100, 3)),
        temperature=None,
        segments=[
            Segment(
                "0000",
                "rotation",
                10,
                50,
                axis=np.array([0, 0, 1.0]),
                extra={"mounting": 2, "note": "ruler"},
            )
        ],
        created="2026-11-21T10:00:00Z",
    )
    path = tmp_path / "x.h5"
    write_session(path, session)
    seg = read_session(path).segments[0]
    assert seg.extra == {"mounting": 2, "note": "ruler"}


def test_get_attr_reads_as_h5py_and_refuses_an_oversized_attribute(tmp_path, monkeypatch):
    """``get_attr`` gives ``obj.attrs[name]`` (None when absent) and refuses an attribute
    that declares more than ``MAX_ATTRIBUTE_BYTES`` before reading it, naming it."""
    from imucal_cli.formats.session import h5open
    from imucal_cli.formats.session.h5open import get_attr

    values = {"kind": "static", "start": np.int64(5), "up": np.array([0, 0, 1.0]),
              "empty": h5py.Empty("f8")}  # fmt: skip
    path = tmp_path / "a.h5"
    with h5py.File(path, "w") as f:
        g = f.create_group("g")
        g.attrs.update(values)
        g.attrs["huge"] = np.zeros(40)
    monkeypatch.setattr(h5open, "MAX_ATTRIBUTE_BYTES", 319)  # "huge" declares 320 bytes
    with h5py.File(path, "r") as f:
        attrs = f["g"].attrs
        for k in values:
            got, want = get_attr(attrs, k, "a.h5", "/g: "), attrs[k]
            assert type(got) is type(want), k
            assert np.array_equal(got, want) if isinstance(want, np.ndarray) else (
                got.dtype == want.dtype if isinstance(want, h5py.Empty) else got == want), k
        assert get_attr(attrs, "absent", "a.h5", "/g: ") is None
        with pytest.raises(SessionError, match="a.h5: /g: attribute 'huge' declares 320 bytes"):
            get_attr(attrs, "huge", "a.h5", "/g: ")
