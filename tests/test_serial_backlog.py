"""A backlog read whole however slowly its parts come (imucal_cli.capture.serial_port): on a
host at load 10 the next 4 KiB of a backlog can wait longer than a read may take; the reads
then return nothing until the whole backlog has come, and it is one read (stamped as one)."""

from __future__ import annotations

import numpy as np
import pytest

from imucal_cli.capture import serial_port
from imucal_cli.capture.serial_port import DRAIN_MAX_S, DRAIN_WAIT_S, SerialSource

PART = 4095  # what the kernel's tty buffer hands out at once


class FakeTime:
    """The module's clock: ``sleep`` moves it on."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.now += s


class FakeSerial:
    """A tty whose bytes become readable at given times: ``parts`` of (time, bytes); a part
    of a backlog is readable ``refill_s`` after the one before it was read."""

    def __init__(self, clock: FakeTime, backlog: list[bytes], refill_s: float, trickle):
        self.clock, self.refill_s = clock, refill_s
        self.backlog = list(backlog)
        self.ready_at = 0.0  # when the next backlog part is readable
        self.trickle = list(trickle)  # (time, bytes) after the backlog
        self.buffer = b""
        self.timeout = 0.05

    def _fill(self) -> None:
        if not self.buffer and self.backlog and self.clock.now >= self.ready_at:
            self.buffer = self.backlog.pop(0)
        while not self.backlog and self.trickle and self.trickle[0][0] <= self.clock.now:
            self.buffer += self.trickle.pop(0)[1]

    @property
    def in_waiting(self) -> int:
        self._fill()
        return len(self.buffer)

    def read(self, n: int) -> bytes:
        self._fill()
        if not self.buffer:
            self.clock.sleep(self.timeout)
            self._fill()
        out, self.buffer = self.buffer[:n], self.buffer[n:]
        if out and not self.buffer and self.backlog:
            self.ready_at = self.clock.now + self.refill_s
        return out

    def close(self) -> None:
        pass


def source(monkeypatch, refill_s: float, parts: int = 20):
    clock = FakeTime()
    backlog = [bytes([65 + i % 26]) * PART for i in range(parts)]
    end = parts * refill_s
    trickle = [(end + 0.01 * (i + 1), b"x" * 40) for i in range(50)]
    fake = FakeSerial(clock, backlog, refill_s, trickle)
    monkeypatch.setattr(serial_port, "_time", clock)
    monkeypatch.setattr(serial_port.serial, "Serial", lambda *a, **k: fake)
    return SerialSource("/dev/fake", 115200), b"".join(backlog), clock


@pytest.mark.parametrize("refill_s", [0.02, 0.2, 0.45])
def test_a_backlog_that_comes_slowly_is_one_read(monkeypatch, refill_s):
    """20 parts of 4 KiB, each readable ``refill_s`` after the last was read (0.2 s: twice
    the patience of before, and 4 s in all, eight reads' worth): every read before returns
    nothing, and no read takes much longer than DRAIN_MAX_S (the screen stays live)."""
    src, backlog, clock = source(monkeypatch, refill_s)
    reads = []
    while len(b"".join(reads)) < len(backlog):
        before = clock.now
        reads.append(src.read())
        assert clock.now - before <= DRAIN_MAX_S + 0.06
    lengths = [len(r) for r in reads]
    assert lengths[:-1] == [0] * (len(reads) - 1), lengths  # nothing before it is whole
    assert reads[-1][: len(backlog)] == backlog, lengths
    # then the stream read as it comes: a line or two a read
    rest = [src.read() for _ in range(20)]
    assert all(len(r) < PART for r in rest) and sum(map(len, rest)) > 0


def test_a_backlog_ends_when_no_next_part_comes(monkeypatch):
    """A backlog of one full buffer and nothing behind it: returned once the next part has
    not come within DRAIN_WAIT_S."""
    src, backlog, clock = source(monkeypatch, refill_s=10.0, parts=1)
    src._serial.trickle = []
    got = b""
    while not got:
        got = src.read()
    assert got == backlog and clock.now <= DRAIN_WAIT_S + DRAIN_MAX_S


class SlowTty:
    """A 100 Hz MotionCal device on a tty: line ``i`` sent at ``i / 100`` s; a backlog over
    the kernel's buffer is handed out :data:`PART` bytes at a time, each ``refill_s`` after
    the last was read; the host goes away for ``away_s`` at ``away_at`` s (its first read
    after)."""

    LINE = b"Raw:1,2,8000,3,4,5,100,200,300\n"

    def __init__(self, clock: FakeTime, n: int, refill_s: float, away_at: float, away_s: float):
        self.clock, self.n, self.refill_s = clock, n, refill_s
        self.away_at, self.away_s = away_at, away_s
        self.pos, self.refill_at, self.timeout = 0, 0.0, 0.05

    def _sent(self) -> int:
        return min(int(self.clock.now * 100) + 1, self.n) * len(self.LINE)

    @property
    def in_waiting(self) -> int:
        waiting = self._sent() - self.pos
        if waiting > PART:
            return PART if self.clock.now >= self.refill_at else 0
        return waiting

    def read(self, k: int) -> bytes:
        if self.away_s and self.clock.now >= self.away_at:
            self.clock.now, self.away_s = self.clock.now + self.away_s, 0.0
        if not self.in_waiting:
            self.clock.sleep(self.timeout)
        k = min(k, self.in_waiting)
        if k == PART:
            self.refill_at = self.clock.now + self.refill_s
        data = (self.LINE * self.n)[self.pos : self.pos + k]
        self.pos += k
        return data

    def close(self) -> None:
        pass


def test_a_capture_reading_a_slow_backlog_does_not_time_out(tmp_path, monkeypatch):
    """The host went away for 8 s (past the 5 s read timeout) inside a read that had got a
    few lines, and the backlog's parts then came 0.2 s apart.  That read takes the backlog
    with it (before: its few lines were stamped at the host's return, after an 8 s gap, and
    the backlog crowded after them); the reads that return nothing while the backlog comes
    are no silent device (before: the capture ended); every line is kept, at the rate."""
    from imucal_cli.capture import recorder
    from imucal_cli.capture.stream import PrefixedLineProtocol
    from imucal_cli.formats.session import read_session

    clock = FakeTime()
    tty = SlowTty(clock, n=1500, refill_s=0.2, away_at=1.0, away_s=8.0)
    monkeypatch.setattr(serial_port, "_time", clock)
    monkeypatch.setattr(recorder, "_time", clock)
    monkeypatch.setattr(serial_port.serial, "Serial", lambda *a, **k: tty)
    rec = recorder.Recorder(tmp_path / "s.h5", SerialSource("/dev/fake", 115200),
                            PrefixedLineProtocol(("motioncal",)), read_timeout_s=5.0)  # fmt: skip
    for _ in rec.blocks():
        pass
    rec.close()
    assert rec.end_kind == "timeout" and rec.n_samples == 1500, rec.end_reason
    assert clock.now > 15.0 + 5.0  # it ended 5 s after the device's last line, not before
    steps = read_session(tmp_path / "s.h5").time
    assert abs(np.diff(steps)).max() < 5 / 100  # no gap, no burst: the rate throughout


@pytest.mark.parametrize("period_s", [0.010, 0.004, 0.002])
def test_a_fast_stream_after_a_backlog_gets_its_data_at_once(monkeypatch, period_s):
    """A backlog of three full buffers, then a stream whose bytes come every ``period_s``
    (200-500 Hz, or a sketch printing with no delay): the backlog comes back with the first
    read, not held while the stream trickles on (before, at 4 and 2 ms: nothing for minutes,
    and no timeout either, the source reading a backlog all the while)."""
    clock = FakeTime()
    backlog = [b"A" * PART for _ in range(3)]
    trickle = [(0.06 + period_s * (i + 1), b"x" * 40) for i in range(int(20 / period_s))]
    fake = FakeSerial(clock, backlog, 0.02, trickle)
    monkeypatch.setattr(serial_port, "_time", clock)
    monkeypatch.setattr(serial_port.serial, "Serial", lambda *a, **k: fake)
    src = SerialSource("/dev/fake", 115200)
    got = src.read()
    assert got[: 3 * PART] == b"".join(backlog) and clock.now <= DRAIN_MAX_S + 0.06
    assert not src.reading_backlog and all(src.read() for _ in range(5))


def test_a_capture_stopped_while_a_backlog_is_read_keeps_every_line(tmp_path, monkeypatch):
    """Ctrl-C, ``q`` or the plan's end while the source holds part of a backlog: those lines
    were read from the port and go into the session (before: 401 of 501 lost)."""
    from imucal_cli.capture import recorder
    from imucal_cli.capture.stream import PrefixedLineProtocol
    from imucal_cli.formats.session import read_session

    clock = FakeTime()
    tty = SlowTty(clock, n=1500, refill_s=0.2, away_at=1.0, away_s=8.0)
    monkeypatch.setattr(serial_port, "_time", clock)
    monkeypatch.setattr(recorder, "_time", clock)
    monkeypatch.setattr(serial_port.serial, "Serial", lambda *a, **k: tty)
    src = SerialSource("/dev/fake", 115200)
    rec = recorder.Recorder(tmp_path / "s.h5", src, PrefixedLineProtocol(("motioncal",)),
                            read_timeout_s=5.0)  # fmt: skip
    held = 0
    for _ in rec.blocks():
        if src.reading_backlog and not held:
            held = sum(len(p) for p in src._backlog)
            rec.stop()
    rec.close()
    assert held > 0  # the stop came while part of the backlog was held
    read_lines = tty.pos // len(SlowTty.LINE)
    assert rec.n_samples == read_lines == len(read_session(tmp_path / "s.h5").time)


class _ClosedAtTheOtherEnd:
    """A tty whose device ended its stream: one line, then pyserial's error for a port that
    is ready with no bytes."""

    timeout, in_waiting = 0.05, 0

    def __init__(self) -> None:
        self.sent = False

    def read(self, n: int) -> bytes:
        if not self.sent:
            self.sent = True
            return b"1,2,3\n"
        raise serial_port.serial.SerialException(
            "device reports readiness to read but returned no data (device disconnected or "
            "multiple access on port?)")  # fmt: skip

    def close(self) -> None:
        pass


def test_a_port_closed_at_the_other_end_is_said_plainly(monkeypatch):
    """A finished plan (or a pulled cable) showed pyserial's 'device disconnected or multiple
    access on port?'; it is said as what it is, after the bytes that came before."""
    from imucal_cli.capture.stream import DeviceGone

    monkeypatch.setattr(serial_port, "_time", FakeTime())
    monkeypatch.setattr(serial_port.serial, "Serial", lambda *a, **k: _ClosedAtTheOtherEnd())
    src = SerialSource("/dev/fake", 115200)
    assert src.read() == b"1,2,3\n"
    with pytest.raises(DeviceGone, match="^the port closed: the device stopped sending") as e:
        src.read()
    assert "multiple access" not in str(e.value)
