"""Host-clock stamps of a steady stream without device time (MotionCal lines) on a busy host:
bursts that waited are no gap, a pause is, a backlog keeps the rate, and a first backlog from
a device that started after the port opened is re-timed at the stream's rate when the capture
ends (module notes of imucal_cli.capture.host_clock)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from imucal_cli.capture.host_clock import HostClock, first_read_times, steady_times
from imucal_cli.capture.recorder import Recorder
from imucal_cli.capture.stream import DeviceGone, PrefixedLineProtocol
from imucal_cli.design.gaps import GAP_FACTOR, find_gaps
from imucal_cli.errors import SessionError
from imucal_cli.formats.session import SessionWriter, read_session

RATE = 100.0
LINE = b"Raw:1,2,8000,3,4,5,100,200,300\n"


def arrivals(n: int, seed: int, *, burst_every: int = 40) -> list[tuple[int, float]]:
    """Reads of a 100 Hz stream (line ``i`` sent at ``i / RATE``): (lines, host time) a read,
    as the capture logged them on a loaded host: reads every 10-30 ms, and every
    ``burst_every`` reads the bytes wait 120 ms in the kernel, two lines come, then the rest
    in one burst 80 ms later."""
    rng = np.random.default_rng(seed)
    sent = np.arange(n) / RATE
    reads, now, done, r = [], 0.0, 0, 0
    while done < n:
        r += 1
        if r % burst_every == 0:
            k = min(2, int((sent <= now + 0.12).sum()) - done)
            now += 0.12
            reads.append((max(k, 0), now))
            done += max(k, 0)
            now += 0.08
        else:
            now += rng.uniform(0.01, 0.03)
        k = int((sent <= now).sum()) - done
        reads.append((k, now))
        done += k
    return [(k, t) for k, t in reads if k > 0]


def stamp(reads, clock: HostClock | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The stamps of every line and the arrival of its read."""
    clock = HostClock() if clock is None else clock
    times = [clock.stamps(k, t) for k, t in reads]
    return np.concatenate(times), np.concatenate([np.full(k, t) for k, t in reads])


def even_spread(reads) -> np.ndarray:
    """Each read's lines spread evenly since the last read (the stamps before the clock)."""
    out, last = [], reads[0][1] - reads[0][0] / RATE
    for k, t in reads:
        out.append(last + (t - last) * np.arange(1, k + 1) / k)
        last = t
    return np.concatenate(out)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_bursts_that_waited_on_a_busy_host_leave_no_gap(seed):
    reads = arrivals(3000, seed)
    assert find_gaps(even_spread(reads))  # the pattern gave gaps spread evenly (before)
    t, arrived = stamp(reads)
    assert (np.diff(t) > 0).all() and (t <= arrived + 1e-12).all()
    assert not find_gaps(t), find_gaps(t)[:3]
    assert np.median(np.diff(t)) == pytest.approx(1 / RATE, rel=0.002)  # the period's steps
    # the stamps keep the rate: within the 0.12 s the bursts waited, over 30 s
    assert (t[-1] - t[0]) * RATE / (len(t) - 1) == pytest.approx(1.0, abs=0.15 / 30)


def test_a_pause_stays_a_gap():
    """The device stopped for 1 s (no line lost in transit: none sent): the gap is kept, at
    the pause, not spread over the lines after it."""
    reads = arrivals(1000, 4, burst_every=10**6)
    pause = [(k, t + 1.0 if t > 5.0 else t) for k, t in reads]
    t, _ = stamp(pause)
    gaps = find_gaps(t)
    assert len(gaps) == 1 and gaps[0].length_s == pytest.approx(1.0, abs=0.04)
    assert 4.9 < gaps[0].time_s < 5.1
    after = np.diff(t[gaps[0].index + 1 :])
    assert np.median(after) == pytest.approx(1 / RATE, rel=0.02)


@pytest.mark.parametrize("after_hz", [50.0, 80.0, 200.0])
def test_a_stream_whose_rate_changes_is_followed_without_a_gap(after_hz):
    """A sketch that slows down (or speeds up) after 10 s: the stamps follow its new rate,
    and the lag this builds is caught up before it could read as a pause."""
    rng = np.random.default_rng(7)
    sent = np.concatenate([np.arange(1000) / RATE, 10 + np.arange(1, 1000) / after_hz])
    reads, now, done = [], 0.0, 0
    while done < sent.size:
        now += rng.uniform(0.01, 0.03)
        k = int((sent <= now).sum()) - done
        if k:
            reads.append((k, now))
            done += k
    t, arrived = stamp(reads)
    assert not find_gaps(t) and (t <= arrived + 1e-12).all()
    assert np.median(np.diff(t[-500:])) == pytest.approx(1 / after_hz, rel=0.03)


@pytest.mark.parametrize("seed", [1, 2])
def test_at_the_end_each_run_between_pauses_is_on_the_devices_steady_clock(seed):
    """The live stamps carry the host's read jitter (here 1-3 ms RMS about the lines' true
    times: the gyro integrates over it, 2.6-3.3 times its bound on captured i2cdevlib lines);
    :func:`steady_times` puts each run between pauses on one line: a fifth of it at most (0.2 ms),
    the 1 s pause kept where it was."""
    reads = arrivals(3000, seed)
    pause = [(k, t + 1.0 if t > 12.0 else t) for k, t in reads]
    live, _ = stamp(pause)
    sent = np.arange(live.size) / RATE
    cut = int(np.argmax(np.diff(live) > 0.5)) + 1
    sent[cut:] += 1.0  # the device's own pause
    steady = steady_times(live)

    def jitter(t):  # RMS about the true times, each run's offset removed, s
        parts = [t[:cut] - sent[:cut], t[cut:] - sent[cut:]]
        return float(np.sqrt(np.mean(np.concatenate([p - p.mean() for p in parts]) ** 2)))

    assert jitter(live) > 1e-3 and jitter(steady) < 0.2 * jitter(live), (jitter(live),
                                                                         jitter(steady))
    assert (np.diff(steady) > 0).all() and len(find_gaps(steady)) == 1
    assert steady[cut] - steady[cut - 1] == pytest.approx(1.0 + 1 / RATE, abs=0.03)


def test_a_run_whose_rate_changed_keeps_its_live_stamps():
    """A sketch that slows to 80 Hz after 10 s is no steady clock: its run keeps its stamps;
    so does a run too short to fit, and the first read does not pull the line before the
    port's open."""
    t = np.concatenate([np.arange(1000) / RATE, 10 + np.arange(1, 1000) / 80.0])
    np.testing.assert_array_equal(steady_times(t), t)
    short = np.concatenate([np.arange(2000) / RATE, 30 + np.arange(20) / RATE])
    np.testing.assert_array_equal(steady_times(short)[2000:], short[2000:])
    late = np.arange(500) / RATE
    late[:100] = np.linspace(-0.5, late[99], 100)  # spread from an open 0.5 s earlier
    assert steady_times(late, first_read=100, origin=-0.5)[0] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_array_equal(steady_times(late, first_read=100, origin=0.5)[:100],
                                  late[:100])  # fmt: skip


def test_a_backlog_keeps_the_stream_rate():
    """The reader was away 5 s (the lines waited in the kernel): the 500 lines are stamped
    at the rate, ending at their arrival, and meet the lines before without a gap."""
    reads = arrivals(1500, 5, burst_every=10**6)
    cut = next(i for i, (_, t) in enumerate(reads) if t > 5.0)
    end = next(i for i, (_, t) in enumerate(reads) if t > 10.0)
    backlog = [(sum(k for k, _ in reads[cut:end]), reads[end - 1][1])]
    t, _ = stamp(reads[:cut] + backlog + reads[end:])
    assert not find_gaps(t)
    lines = slice(sum(k for k, _ in reads[:cut]), sum(k for k, _ in reads[:end]))
    assert np.diff(t[lines]).mean() == pytest.approx(1 / RATE, rel=0.01)


def test_the_first_read_is_re_timed_at_the_rate_never_before_the_origin():
    """1750 lines from a device that started 1 s after the port opened, read 18.5 s after
    the open: spread from the open they run 5.7 % slow; at the rate they end at their arrival
    and start 1 s after the open.  A spread tighter than the rate (the rate misjudged) stays."""
    spread = -0.0 + 18.5 * np.arange(1, 1751) / 1750
    again = first_read_times(spread, 0.0, 1 / RATE)
    assert again[-1] == spread[-1] and np.diff(again) == pytest.approx(1 / RATE)
    assert again[0] == pytest.approx(1.0 + 1 / RATE)
    assert first_read_times(spread, 0.0, 0.02) is spread  # would start before the open


class _Clock:
    """The host's monotonic clock, set by the source as its reads arrive."""

    def __init__(self) -> None:
        self.now = 0.05

    def __call__(self) -> float:
        return self.now


class _BusyStart:
    """A 100 Hz MotionCal device that started ``late_s`` after the port opened, read first
    ``first_s`` after the open (a busy host), then every 20 ms for ``after_s``."""

    uri = "serial:/dev/fake@115200"

    def __init__(self, clock: _Clock, late_s: float, first_s: float, after_s: float):
        self.clock, self.opened_at = clock, 0.0
        self.reads = [first_s, *np.arange(first_s + 0.02, first_s + after_s, 0.02)]
        self.sent = 0
        self.late_s = late_s

    def describe(self) -> str:
        return "/dev/fake at 115200 baud"

    def read(self) -> bytes:
        if not self.reads:
            raise DeviceGone("[Errno 5] Input/output error")
        self.clock.now = float(self.reads.pop(0))
        due = int((self.clock.now - self.late_s) * RATE + 1e-9) + 1
        k, self.sent = due - self.sent, due
        return LINE * k

    def close(self) -> None:
        pass


def test_a_capture_after_a_busy_start_has_the_streams_rate(tmp_path, monkeypatch):
    """Issue 24.7's busy start with a device that starts 1 s after the open (an Arduino
    resetting, the virtual device waiting for the flush): the first 17.5 s of lines, read at
    once, were spread over 18.5 s, and the capture's rate came out 97 Hz.  Now the session's
    times and rate are the stream's (the arrivals here are exact: to 0.1 %)."""
    clock = _Clock()
    monkeypatch.setattr(time, "monotonic", clock)
    source = _BusyStart(clock, late_s=1.0, first_s=18.5, after_s=15.0)
    rec = Recorder(tmp_path / "busy.h5", source, PrefixedLineProtocol(("motioncal",)))
    n = sum(len(b) for b in rec.blocks())
    rec.close()
    assert rec.end_kind == "device-gone" and n == source.sent
    assert rec.stats["rate_hz"] == pytest.approx(RATE, rel=1e-3)
    session = read_session(tmp_path / "busy.h5")
    assert session.sample_rate_hz == pytest.approx(RATE, rel=1e-3)
    step = np.diff(session.time)
    assert step.max() < GAP_FACTOR / RATE and step.min() > 0
    assert step[:1700].mean() == pytest.approx(1 / RATE, rel=1e-3)  # the first read's too
    assert session.time[0] >= -0.05  # not before the port opened



def test_the_writer_re_times_written_samples_in_order_only(tmp_path):
    w = SessionWriter(tmp_path / "w.h5", accel_channels=3, gyro_channels=None)
    w.append(np.arange(5.0), np.zeros((5, 3)))
    w.flush()
    with pytest.raises(SessionError, match="out of order"):
        w.retime(0, [0.0, 1.0, 2.0, 4.0])  # would meet the next sample (4 s)
    with pytest.raises(SessionError, match="out of order"):
        w.retime(0, [0.0, 2.0, 1.0])
    w.append(5.0, np.zeros(3))  # buffered, not written yet
    with pytest.raises(SessionError, match="unwritten"):
        w.retime(3, [3.5, 4.5, 4.8])
    w.retime(0, [0.5, 1.5, 2.5])
    w.close()
    np.testing.assert_array_equal(read_session(tmp_path / "w.h5").time, [0.5, 1.5, 2.5, 3, 4, 5])


@pytest.mark.parametrize("lost", [10, 28])
def test_samples_lost_for_less_than_a_pause_keep_the_live_stamps(lost):
    """Lines lost in transit for under 0.3 s (no gap: the live clock takes them as a late
    burst) are no steady clock: on one line the loss would become an interval error over the
    whole run (+0.33 % for 10 of 3000), a gyro scale error in every turn; the run keeps its
    live stamps, the error where it happened."""
    sent = np.delete(np.arange(3000) / RATE, np.arange(1000, 1000 + lost))
    reads, done, now = [], 0, 0.0
    while done < sent.size:
        now += 0.02
        k = int((sent <= now).sum()) - done
        if k:
            reads.append((k, now))
            done += k
    live, _ = stamp(reads)
    np.testing.assert_array_equal(steady_times(live), live)


@pytest.mark.parametrize(("resumed_from", "samples_lost", "retimed"),
                         [(0, 0, True), (100, 0, True), (0, 3, False)])  # fmt: skip
def test_the_end_re_time_touches_only_this_captures_whole_samples(tmp_path, resumed_from,
                                                                   samples_lost, retimed):
    """A capture that lost samples (the disk filled) keeps its stamps; a whole one is put on
    its steady clock, in a continued session only its own samples (the earlier ones are
    another capture's, on another run of the device), never before them."""
    from types import SimpleNamespace

    from imucal_cli.capture.writing import SessionWrites

    rng = np.random.default_rng(3)
    t = np.arange(600) / RATE + rng.uniform(0, 3e-3, 600)
    w = SessionWriter(tmp_path / "w.h5", accel_channels=3, gyro_channels=None)
    w.append(t, np.zeros((600, 3)))
    w.flush()
    clock = HostClock()
    clock.first_read, clock.period, clock.origin = 1, 1 / RATE, -0.1
    owner = SessionWrites()  # the recorder's writing part, with the recorder's fields
    owner.__dict__.update(protocol=SimpleNamespace(host_clock=clock), _writer=w,
                          resumed_from=resumed_from, samples_lost=samples_lost,
                          _time_offset=0.9 if resumed_from else None,
                          _device_first=None, _device_last=None)  # fmt: skip
    owner._retime_host_stamps()
    after = w.written_times()
    w.close()
    np.testing.assert_array_equal(after[:resumed_from], t[:resumed_from])
    assert (not np.array_equal(after, t)) == retimed
    if retimed:
        i = np.arange(resumed_from, 600)
        own = after[resumed_from:]
        assert np.abs(own - np.polyval(np.polyfit(i, own, 1), i)).max() < 1e-9
        assert own[0] > t[resumed_from - 1] if resumed_from else True
        assert owner._device_last == pytest.approx(own[-1] - (owner._time_offset or 0.0))


class _SetStream:
    """A 100 Hz sketch printing ``line`` (default: two IMUs' triads, no time column), read in
    the bursts of :func:`arrivals` (a loaded host)."""

    uri = "serial:/dev/fake@115200"

    def __init__(self, clock: _Clock, reads, line: bytes = b"1,2,8000,3,4,5,7,8,8001,9,10,11\n"):
        self.clock, self.opened_at, self.reads, self.line = clock, 0.0, list(reads), line

    def describe(self) -> str:
        return "/dev/fake at 115200 baud"

    def read(self) -> bytes:
        if not self.reads:
            raise DeviceGone("[Errno 5] Input/output error")
        k, self.clock.now = self.reads.pop(0)
        return self.line * k

    def close(self) -> None:
        pass


def test_several_imus_on_a_line_are_re_timed_together(tmp_path, monkeypatch):
    """Several IMUs on each host-stamped line: the end of the capture puts ``/raw`` on the
    stream's steady clock and every other IMU's times with it (one line, one time), so their
    time offsets and turns are on the same clock as the reference's."""
    from imucal_cli.capture.imu_set import SetLineProtocol, set_protocol

    clock = _Clock()
    monkeypatch.setattr(time, "monotonic", clock)
    reads = arrivals(2000, 7)
    specs = set_protocol("ax,ay,az,gx,gy,gz,ax.1,ay.1,az.1,gx.1,gy.1,gz.1", "s", 1)
    rec = Recorder(tmp_path / "set.h5", _SetStream(clock, reads), SetLineProtocol(specs))
    n = sum(len(b) for b in rec.blocks())
    rec.close()
    assert rec.end_kind == "device-gone" and n == 2000
    session = read_session(tmp_path / "set.h5")
    live, _ = stamp(reads)
    i = np.arange(n)
    line = np.polyval(np.polyfit(i, session.time, 1), i)
    assert np.abs(session.time - line).max() < 1e-6 < np.abs(live - line).max()
    other = session.imus["imu1"]
    np.testing.assert_allclose(other.time, session.time, rtol=0, atol=1e-9)
    own = SetLineProtocol(set_protocol("ax,ay,az,gx,gy,gz,ax.1,ay.1,az.1,gx.1,gy.1,gz.1,t.1",
                                       "s", 1))  # fmt: skip
    assert own.host_clock is None  # imu1's own device times are not the line's host stamps


def test_a_continued_host_stamped_capture_is_re_timed_after_the_first(tmp_path, monkeypatch):
    """``capture --resume`` of a MotionCal stream on a loaded host: the second capture's own
    samples are put on their steady clock, after the first capture's, which keep theirs."""
    clock = _Clock()
    monkeypatch.setattr(time, "monotonic", clock)
    path = tmp_path / "two.h5"
    parts = []
    for resume, seed in ((False, 8), (True, 9)):
        clock.now = 0.05
        reads = arrivals(1500, seed)
        rec = Recorder(path, _SetStream(clock, reads, LINE), PrefixedLineProtocol(("motioncal",)),
                       resume=resume)  # fmt: skip
        n = sum(len(b) for b in rec.blocks())
        rec.close()
        assert rec.end_kind == "device-gone" and n == 1500
        parts.append(read_session(path).time.copy())
    first, both = parts
    np.testing.assert_array_equal(both[:1500], first)
    own = both[1500:]
    i = np.arange(own.size)
    assert own[0] > first[-1] and np.abs(own - np.polyval(np.polyfit(i, own, 1), i)).max() < 1e-6


class _OtherPort:
    """A second 100 Hz device on a port of its own (no time column), started 0.3 s after the
    first: its lines reach the host 0-25 ms late, at random."""

    uri = "serial:/dev/fake2@115200"

    def __init__(self, clock: _Clock, seed: int) -> None:
        self.clock, self.sent, self.rng = clock, 0, np.random.default_rng(seed)

    def describe(self) -> str:
        return "/dev/fake2 at 115200 baud"

    def read(self) -> bytes:
        due = max(int((self.clock.now - 0.3 - self.rng.uniform(0, 0.025)) * RATE) + 1, 0)
        k, self.sent = max(due - self.sent, 0), max(due, self.sent)
        return b"7,8,8001,9,10,11\n" * k

    def close(self) -> None:
        pass


def test_each_port_of_a_set_is_re_timed_on_its_own_clock(tmp_path, monkeypatch):
    """One IMU per port, lines without time on a loaded host: each port's samples are put on
    their own steady clock (its jitter is its own, not the reference's)."""
    from imucal_cli.capture.imu_set import PortSet, PortsProtocol
    from imucal_cli.formats.columns import ColumnSpec

    clock = _Clock()
    monkeypatch.setattr(time, "monotonic", clock)
    ref = _SetStream(clock, arrivals(2000, 5), b"1,2,8000,3,4,5\n")
    ports = PortSet([ref, _OtherPort(clock, 6)])
    protocol = PortsProtocol(ports, ColumnSpec.parse("ax,ay,az,gx,gy,gz", "s"))
    rec = Recorder(tmp_path / "ports.h5", ports, protocol)
    n = sum(len(b) for b in rec.blocks())
    rec.close()
    assert rec.end_kind == "device-gone" and n == 2000
    session = read_session(tmp_path / "ports.h5")
    for t in (session.time, session.imus["imu1"].time):
        i = np.arange(t.size)
        assert t.size > 1500
        assert np.abs(t - np.polyval(np.polyfit(i, t, 1), i)).max() < 1e-6
        assert np.diff(t).mean() == pytest.approx(1 / RATE, rel=0.01)


def test_a_first_read_the_line_puts_a_little_before_the_open_joins_the_line():
    """A CI run at load: 200 Hz lines whose first read the steady line put 9.6 ms before the
    port's open; the first read kept its stamps (3.75 ms apart, spread from the open) and the
    run was no line (10 ms off).  Within ORIGIN_SLACK_S of the open it joins the line; far
    before it (a misjudged line) it stays."""
    from imucal_cli.capture.host_clock import ORIGIN_SLACK_S

    rate = 200.0
    t = -0.0096 + np.arange(3000) / rate
    t[:4] = np.linspace(0.0004, 0.0004 + 3 * 0.00375, 4)  # spread from the open at 0
    steady = steady_times(t, first_read=4, origin=0.0)
    i = np.arange(t.size)
    assert np.abs(steady - np.polyval(np.polyfit(i, steady, 1), i)).max() < 1e-9
    far = steady_times(t - 2 * ORIGIN_SLACK_S, first_read=4, origin=-ORIGIN_SLACK_S + 0.0096)
    np.testing.assert_array_equal(far[:4], (t - 2 * ORIGIN_SLACK_S)[:4])
