"""Issue 24.3 in the library: a busy host or a full disk cannot break a capture.

The recorder fed by scripted sources (no real time beyond a few tenths of a second): a backlog
read at once or a host that did not read for a while is a valid stream (the time-unit check,
the read timeout); rates and durations come from device time; a nearly full disk ends the
capture in time, with every sample and every segment; a write that fails all the same loses
no segment silently; time stamps in the wrong unit leave nothing behind.  The same through
``imucal simulate --serve`` and ``imucal capture`` is in ``test_capture_live.py``.
"""

from __future__ import annotations

import time

import h5py
import numpy as np
import pytest

from imucal_cli.capture import checks
from imucal_cli.capture import recorder as recorder_module
from imucal_cli.capture.checks import CLOCK_TOLERANCE, clock_problem, headroom
from imucal_cli.capture.recorder import Recorder
from imucal_cli.capture.stream import LineProtocol, PrefixedLineProtocol
from imucal_cli.formats.columns import ColumnSpec
from imucal_cli.formats.session import read_session
from imucal_cli.formats.session.writer import chunk_rows

from .test_capture import ScriptedSource, lines_of


def _proto(unit: str = "s") -> LineProtocol:
    return LineProtocol(ColumnSpec.parse("t,ax,ay,az,gx,gy,gz", unit))


def _lines(n: int, rate: float = 100.0, scale: float = 1.0) -> list[bytes]:
    """``n`` still lines at ``rate`` Hz, time stamps ``scale`` times seconds."""
    return [f"{k / rate * scale:.4f},{k % 7},1,8000,2,3,4\n".encode() for k in range(n)]


# --------------------------------------------------------------------------------------------
# The time-unit check
# --------------------------------------------------------------------------------------------


def test_a_backlog_is_a_valid_stream_for_the_time_check():
    """12 s of samples waited while the capture started (the port open for 15 s, the first
    arrival 3 s ago): the device time races ahead of the host's since the first arrival by 5x,
    yet it cannot have sent more than the port was open, and its rate is the device's."""
    assert clock_problem(15.0, 1501, since_open_s=15.0, since_first_s=3.0, unit="s") is None
    # a reader that fell behind by a buffer: much less device time than host time, within 10x
    assert clock_problem(2.0, 201, since_open_s=8.0, since_first_s=6.0, unit="s") is None


@pytest.mark.parametrize(("stamps", "unit", "fits"), [
    (1000.0, "s", "ms"),    # ms stamps read as s: 1000x the host's time, 0.1 Hz
    (1000.0, "ms", "us"),   # us stamps read as ms
    (1e-3, "ms", "s"),      # s stamps read as ms: 100 kHz
])  # fmt: skip
def test_a_wrong_time_unit_is_named(stamps, unit, fits):
    device_s = 10.0 * stamps  # 10 s of a 100 Hz stream, as read
    said = clock_problem(device_s, 1001, since_open_s=10.5, since_first_s=10.0, unit=unit)
    assert said is not None and f"--time-unit {fits}" in said, said


def test_ms_read_as_s_at_1khz_is_caught_by_the_host_clock():
    """A 1 kHz device's ms stamps read as s look like 1 Hz (a rate the device-side check lets
    through): only the host's clock tells it, even with a backlog."""
    said = clock_problem(3000.0, 3001, since_open_s=5.0, since_first_s=3.0, unit="s")
    assert said is not None and "--time-unit ms" in said
    assert CLOCK_TOLERANCE < 1000 ** 0.5  # one unit fits, never two


class BacklogSource(ScriptedSource):
    """A port opened ``waited_s`` ago: the first read returns that much backlog at once, then
    the stream comes in real time (10 lines every 0.1 s)."""

    def __init__(self, lines, waited_s: float, rate: float = 100.0):
        n0 = int(waited_s * rate)
        chunks = [b"".join(lines[:n0])] + [
            b"".join(lines[i : i + 10]) for i in range(n0, len(lines), 10)
        ]
        super().__init__(chunks, on_read=lambda i: i > 1 and time.sleep(0.1))
        self.opened_at = time.monotonic() - waited_s


def test_recorder_reads_a_start_up_backlog_without_aborting(tmp_path, monkeypatch):
    """Issue 24.3: 'the device's time stamps advanced 9.17 s in 3 s of host time', exit 2, on
    a host too busy to start reading at once.  The backlog is read and the stream recorded;
    the rate and duration in the summary are the device's (not 4,016 Hz)."""
    monkeypatch.setattr(recorder_module, "CLOCK_CHECK_S", 0.4)
    lines = _lines(1000)
    rec = Recorder(tmp_path / "r.h5", BacklogSource(lines, waited_s=6.0), _proto())
    for _ in rec.blocks():
        if rec.n_samples >= 700:
            rec.stop()
    rec.close()
    assert rec.end_kind == "done", rec.end_reason
    stats = rec.stats
    assert stats["rate_hz"] == pytest.approx(100.0, rel=1e-6)
    assert stats["duration_s"] == pytest.approx((rec.n_samples - 1) / 100.0, rel=1e-6)
    assert stats["received"] == stats["written"] == rec.n_samples and stats["lost"] == 0
    assert stats["wall_s"] < stats["duration_s"]  # the backlog came in at once
    assert read_session(tmp_path / "r.h5").sample_rate_hz == pytest.approx(100.0, rel=1e-6)


def test_recorder_ends_on_a_wrong_unit_even_after_a_backlog(tmp_path, monkeypatch):
    monkeypatch.setattr(recorder_module, "CLOCK_CHECK_S", 0.4)
    rec = Recorder(tmp_path / "r.h5", BacklogSource(_lines(1000, scale=1000.0), 2.0), _proto())
    for _ in rec.blocks():
        pass
    assert rec.end_kind == "clock" and "--time-unit ms" in rec.end_reason
    rec.discard()
    assert not (tmp_path / "r.h5").exists()  # no session of wrong time stamps


def test_a_discarded_resume_keeps_what_the_session_held(tmp_path, monkeypatch):
    monkeypatch.setattr(recorder_module, "CLOCK_CHECK_S", 0.4)
    chunks, _ = lines_of()
    first = Recorder(tmp_path / "r.h5", ScriptedSource(chunks[:6]), _proto())
    for _ in first.blocks():
        pass
    first.add_segment("static", 0, 100, label="face +Z up", up=[0, 0, 1])
    first.close()
    before = read_session(tmp_path / "r.h5")
    rec = Recorder(tmp_path / "r.h5", BacklogSource(_lines(1000, scale=1000.0), 2.0), _proto(),
                   resume=True)  # fmt: skip
    for _ in rec.blocks():
        pass
    assert rec.end_kind == "clock"
    rec.discard()
    after = read_session(tmp_path / "r.h5")
    np.testing.assert_array_equal(after.time, before.time)
    assert [s.label for s in after.segments] == ["face +Z up"]
    assert after.sample_rate_hz == pytest.approx(before.sample_rate_hz)


def test_a_host_that_did_not_read_finds_the_samples_waiting(tmp_path):
    """The read timeout is judged after a read that brought nothing: a capture suspended (or
    starved of CPU) longer than --read-timeout reads what waited, it does not end."""
    chunks, n = lines_of()

    def on_read(i):
        if i == 3:
            time.sleep(0.6)  # the host away twice the read timeout

    rec = Recorder(tmp_path / "r.h5", ScriptedSource(chunks, on_read=on_read), _proto(),
                   read_timeout_s=0.3)  # fmt: skip
    for _ in rec.blocks():
        pass
    rec.close()
    assert rec.end_kind == "device-gone" and rec.n_samples == n


# --------------------------------------------------------------------------------------------
# Host-stamped lines
# --------------------------------------------------------------------------------------------


def test_host_stamped_backlog_spreads_from_the_ports_open():
    """MotionCal lines carry no time: 400 lines that waited 4 s since the port opened are
    stamped over those 4 s (100 Hz), not crowded into the last 0.4 s (1 kHz, before)."""
    lines = b"".join(b"Raw:1,2,8000,3,4,5,100,200,300\n" for _ in range(400))
    proto = PrefixedLineProtocol(("motioncal",))
    proto.set_origin(-4.0)
    block = proto.feed(lines, 0.0)
    assert len(block) == 400
    assert np.diff(block.time).mean() == pytest.approx(0.01, rel=1e-6)
    assert block.time[-1] == pytest.approx(0.0)


# --------------------------------------------------------------------------------------------
# The disk
# --------------------------------------------------------------------------------------------


def test_headroom_holds_the_next_samples_in_whole_chunks_the_segments_and_closing():
    need = headroom(100.0, 0.5, chunk_rows=64, chunk_bytes=4608, segments_to_come=3, pending=50)
    rows = 50 + 100.0 * checks.MIN_GAP_S  # a short gap: at least MIN_GAP_S of samples
    chunks = int(np.ceil(rows / 64)) + 1
    assert need == chunks * 4608 + 3 * checks.SEGMENT_BYTES + checks.CLOSE_BYTES
    busy = headroom(100.0, 4.0, chunk_rows=64, chunk_bytes=4608, segments_to_come=3)
    assert busy > need  # a host that checks every 4 s needs room for 6 s of samples


def test_chunks_shrink_on_a_nearly_full_disk():
    assert chunk_rows(None, 72) == 1024 and chunk_rows(10 << 30, 72) == 1024
    assert chunk_rows(96 << 10, 72) == 64  # a chunk of 1024 rows alone would fill 96 KiB
    rows = chunk_rows(4 << 20, 72)
    assert 64 < rows < 1024 and rows & (rows - 1) == 0


class FreeSpace:
    """The file system's free space as the writer sees it (its chunk size, its room),
    shrinking as the file grows."""

    def __init__(self, monkeypatch, path, free: int) -> None:
        from imucal_cli.formats.session import writer as writer_module

        self.path, self.free = path, free
        monkeypatch.setattr(writer_module, "free_bytes", lambda folder: self.left())

    def left(self) -> int:
        return self.free - (self.path.stat().st_size if self.path.exists() else 0)


def test_a_nearly_full_disk_stops_in_time_with_every_sample_and_segment(tmp_path, monkeypatch):
    """The free space falls below what the rest needs: the capture stops at once (before any
    write can fail), every sample received is in the closed file, and the segments added
    afterwards (an unattended capture segments at its end) are there too."""
    path = tmp_path / "r.h5"
    FreeSpace(monkeypatch, path, free=160 * 1024)
    chunks, _ = lines_of(per_chunk=20)
    rec = Recorder(path, ScriptedSource(chunks), _proto())
    for _ in rec.blocks():
        pass
    assert rec.end_kind == "disk-full" and "stopped in time" in rec.end_reason
    n = rec.n_samples
    assert 0 < n < sum(c.count(b"\n") for c in chunks)
    for k in range(0, n - 20, 20):
        rec.add_segment("static", k, k + 10, label=f"hold {k}", up=[0, 0, 1])
    rec.close()
    assert rec.samples_lost == 0 and rec.segments_left_out == 0
    with h5py.File(path, "r") as plain:  # closed cleanly
        assert plain["raw/time"].shape == (n,)
    session = read_session(path)
    assert len(session.time) == rec.protocol.stats["samples"] == n
    assert len(session.segments) == len(range(0, n - 20, 20))


def test_a_backlog_larger_than_the_disk_keeps_what_fits_and_counts_the_rest(
    tmp_path, monkeypatch
):
    """A capture that starts late finds more samples waiting than the disk can ever hold:
    the first are written as long as closing still fits, the rest counted as lost (said, and
    exit 3), never a failed write that leaves the file without them."""
    path = tmp_path / "r.h5"
    FreeSpace(monkeypatch, path, free=80 * 1024)
    lines = _lines(3000, rate=1000.0)
    rec = Recorder(path, ScriptedSource([b"".join(lines)]), _proto())
    for _ in rec.blocks():
        pass
    rec.close()
    assert rec.end_kind == "disk-full" and "could not be written (no room" in rec.end_reason
    assert "stopped in time" not in rec.end_reason
    held = read_session(path)
    assert 0 < len(held.time) == rec.n_samples and rec.samples_lost == 3000 - rec.n_samples
    np.testing.assert_allclose(held.time, np.arange(rec.n_samples) / 1000.0, atol=1e-9)
    with h5py.File(path, "r"):
        pass


def test_segments_over_samples_a_full_disk_lost_are_left_out(tmp_path, monkeypatch):
    """Another program filled the disk: the samples that could not be written are counted,
    and a segment over them is left out (counted), never an error (a saved file exits 3,
    not 2)."""
    from .test_safety import FullDisk

    disk = FullDisk(monkeypatch, reserve_frees=False)
    chunks, _ = lines_of(per_chunk=50)
    monkeypatch.setattr(recorder_module, "FLUSH_INTERVAL_S", 0.0)
    def on_read(i):
        if i == 8:
            disk.full = True

    rec = Recorder(tmp_path / "r.h5", ScriptedSource(chunks, on_read=on_read), _proto())
    for _ in rec.blocks():
        pass
    assert rec.end_kind == "disk-full" and rec.samples_lost > 0
    kept = rec.n_samples
    assert rec.add_segment("static", 0, 50, label="early", up=[0, 0, 1]) is not None
    assert rec.add_segment("static", kept - 10, kept + 40, label="lost", up=[0, 0, 1]) is None
    disk.full = False
    rec.close()
    assert rec.segments_left_out == 1
    session = read_session(tmp_path / "r.h5")
    assert len(session.time) == kept and [s.label for s in session.segments] == ["early"]


# --------------------------------------------------------------------------------------------
# The serial port
# --------------------------------------------------------------------------------------------


class FakeSerial:
    """pyserial's Serial as a backlog looks to it: ``parts`` handed out one per read (a tty
    buffer at a time), then the device gone (``in_waiting`` raises, as for a closed pty)."""

    def __init__(self, parts: list[bytes]) -> None:
        self.parts = list(parts)

    @property
    def in_waiting(self) -> int:
        if not self.parts:
            raise OSError(5, "Input/output error")
        return len(self.parts[0])

    def read(self, n: int) -> bytes:
        return self.parts.pop(0)[:n] if self.parts else b""


def _port(parts: list[bytes]):
    from imucal_cli.capture.serial_port import SerialSource

    source = SerialSource.__new__(SerialSource)
    source._serial, source.batch_s, source._gone = FakeSerial(parts), 0.001, None
    source._backlog, source._refill_since, source.timeout_s = [], None, 0.05
    return source


def test_a_backlog_is_read_whole_and_nothing_is_lost_when_the_device_goes():
    """A backlog handed out 4 KiB at a time comes back as one read (one arrival time for its
    lines); the device closing during the drain loses none of the bytes read (before: the
    read raised and dropped them, 2 of 2772 lines in one capture of three at load)."""
    from imucal_cli.capture.stream import DeviceGone

    parts = [bytes([65 + k]) * 4095 for k in range(5)] + [b"tail\n"]
    source = _port(parts)
    data = source.read()
    assert data == b"".join(parts)  # all of it, and the device went after it
    with pytest.raises(DeviceGone):
        source.read()



class _SlowLine:
    """2000 lines of a 100 Hz device arriving over ``pace`` times their device time (a line
    too slow for them: 20 lines a read, the host clock moved on as they arrive)."""

    uri = "serial:/dev/fake@115200"

    def __init__(self, monkeypatch, pace: float) -> None:
        self.now, self.lines, self.pace = 100.0, _lines(2000), pace
        monkeypatch.setattr(time, "monotonic", lambda: self.now)

    def describe(self):
        return "/dev/fake at 115200 baud"

    def read(self):
        if not self.lines:
            from imucal_cli.capture.stream import DeviceGone

            raise DeviceGone("[Errno 5] Input/output error")
        chunk, self.lines = self.lines[:20], self.lines[20:]
        self.now += 0.2 * self.pace
        return b"".join(chunk)

    def close(self):
        pass


@pytest.mark.parametrize(("pace", "said"), [(1.33, True), (1.02, False)])
def test_a_line_that_falls_behind_its_stream_is_said(tmp_path, monkeypatch, pace, said):
    """400 Hz at 115200 baud: 20.5 s of device time arrived over 27.2 s, and the capture said
    only '400.0 Hz'; a real device drops or slows what it cannot send.  The recorder says how
    far behind the line fell (a small lag is no fall)."""
    rec = Recorder(tmp_path / "slow.h5", _SlowLine(monkeypatch, pace), _proto())
    for _ in rec.blocks():
        pass
    rec.close()
    assert rec.n_samples == 2000 and rec.stats["rate_hz"] == pytest.approx(100.0, rel=1e-6)
    if said:
        assert "% of the pace" in rec.behind and "raise --baud" in rec.behind
    else:
        assert rec.behind is None
    assert checks.fell_behind(5.0, 9.0, 100.0) is None  # too short to tell
    assert checks.fell_behind(60.0, 63.0, 100.0) is None  # under 10 %
