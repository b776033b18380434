"""The serial port a capture reads (pyserial): :class:`SerialSource`.

It reads in batches (a first byte, then what came within a few milliseconds), and a backlog
whole: after a host that did not read for a while (busy, starting up, suspended) the kernel
hands the waiting bytes out a tty buffer (4 KiB) at a time, and a drain cut into reads would
give lines without a time of their own arrival times far closer together than they were sent
(issue 24.3/24.7: a MotionCal stream's holds ran ten times too fast and the guided capture
took none of them).  A backlog that takes longer than :data:`DRAIN_MAX_S` to read (each part
of it waits for a CPU on a loaded host) is read over several calls, which return nothing until
the whole of it has come: the capture's screen stays live, and the backlog is still one read
(a drain cut after its first part, as on a host at load 10, stamped that part over the time
the host was away and the rest as if it had come at once: poses 2 and 3 of six were lost).
"""

from __future__ import annotations

import errno
import time as _time

import serial
from serial.tools import list_ports

from imucal_cli.capture.stream import DeviceGone
from imucal_cli.errors import InputError

__all__ = ["DRAIN_MAX_BYTES", "DRAIN_MAX_S", "DRAIN_WAIT_S", "SerialSource", "available_ports"]

DRAIN_MAX_S = 0.5
"""Longest a read keeps reading a backlog, s (the capture's screen stays live); the next reads
go on with it."""

DRAIN_MAX_BYTES = 4 << 20
"""Most bytes a read returns while it drains a backlog."""

DRAIN_WAIT_S = 0.5
"""After a read that filled the tty buffer, how long the next part of a backlog may take, s
(the kernel's flip buffers or a sender blocked on the full line refill it when they get a
CPU: 15-30 ms at load 16 on 2 cores, longer with disk I/O)."""

AWAY_S = 0.25
"""A read that took this much longer than its own waits was stopped or starved inside it (a
busy host, SIGSTOP): the bytes it got are as old as those that came meanwhile, so what waits
is read with them, a backlog of any size (else the few lines it got would be stamped at the
host's return and the backlog after them crowded into the next read)."""

TTY_BUFFER_BYTES = 4000
"""A read this long found the kernel's tty buffer (4 KiB) full: more of a backlog follows."""


class SerialSource:
    """A serial port read with pyserial, in batches.

    Parameters
    ----------
    port : str
        Device path (``/dev/ttyUSB0``, ``/dev/ttyACM0``, ``COM3``, a pseudo-terminal).
    baud : int
        Baud rate.
    timeout_s : float
        Longest a :meth:`read` waits for a first byte.
    batch_s : float
        After a first byte, wait this long for more before returning, so that a fast stream
        is read in batches of a few milliseconds (few system calls, low CPU).

    Raises
    ------
    InputError
        No such port (the message lists the available ones), permission denied, or the port
        cannot be opened or configured.
    """

    def __init__(self, port: str, baud: int, timeout_s: float = 0.05, batch_s: float = 0.005):
        if not isinstance(baud, int) or baud <= 0:
            raise InputError(f"baud rate must be a positive integer, got {baud!r}")
        self.port, self.baud, self.batch_s = str(port), int(baud), float(batch_s)
        self.timeout_s = float(timeout_s)
        # No byte can have been sent to this reader before its open began (a busy host can
        # take tens of ms between the open and its return, while the device already sends)
        opening = _time.monotonic()
        try:
            self._serial = serial.Serial(self.port, self.baud, timeout=timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise _open_error(self.port, self.baud, exc) from None
        self.opened_at = opening  #: when the port's open began (host monotonic clock), s
        self._gone: DeviceGone | None = None  # the device went after the last bytes returned
        self._backlog: list[bytes] = []  # a backlog read so far, returned once it is whole
        self._refill_since: float | None = None  # waiting for the next part of it since, s

    @property
    def uri(self) -> str:
        """The session's ``source`` attribute: ``serial:/dev/ttyUSB0@115200``."""
        return f"serial:{self.port}@{self.baud}"

    def describe(self) -> str:
        """``"/dev/ttyUSB0 at 115200 baud"`` for messages."""
        return f"{self.port} at {self.baud} baud"

    @property
    def reading_backlog(self) -> bool:
        """Whether a backlog is being read (the last read returned b"" with part of it)."""
        return bool(self._backlog)

    def take_backlog(self) -> bytes:
        """The part of a backlog read so far and still held (the capture ends while it is
        read): returned, so that nothing read from the port is lost."""
        held, self._backlog, self._refill_since = b"".join(self._backlog), [], None
        return held

    def read(self) -> bytes:
        """Bytes received so far, or b"" after ``timeout_s`` with none.

        A backlog (the host did not read for a while) is returned whole: the serial buffer
        hands out a few kilobytes a read, and a drain cut into reads would give its lines
        arrival times far closer together than they were sent (host-clock stamps, the sample
        clock's estimate).  A read takes at most about :data:`DRAIN_MAX_S` of it and returns
        b"" while more of it is still coming; the next reads go on with it.

        Raises
        ------
        DeviceGone
            The port cannot be read any more (unplugged, pseudo-terminal closed); bytes read
            before it went are returned first, this is raised at the next read.
        """
        if self._gone is not None:
            raise self._gone
        ser, got, entered = self._serial, b"", _time.monotonic()
        try:
            if self._backlog:  # a backlog being read: go on with it
                return self._drain(b"")
            waiting = ser.in_waiting
            if waiting:
                got = ser.read(waiting)
                return self._drain(got, entered)
            got = ser.read(1)
            if not got:
                return b""
            _time.sleep(self.batch_s)
            waiting = ser.in_waiting
            if waiting:
                got += ser.read(waiting)
            return self._drain(got, entered)
        except (OSError, TypeError, AttributeError) as exc:  # SerialException is an OSError
            self._gone = DeviceGone(_gone_reason(exc))
            got, self._backlog = b"".join(self._backlog) + got, []
            if got:
                return got
            raise self._gone from None

    def _drain(self, data: bytes, entered: float | None = None) -> bytes:
        """``data`` and, when it filled the kernel's tty buffer (a backlog) or the read that
        got it (begun at ``entered``) was away (:data:`AWAY_S`), the rest of the backlog: read
        until no more comes within :data:`DRAIN_WAIT_S` (the next part comes a moment after a
        read: the kernel's flip buffers, a sender blocked on the full line) or only the
        trickle of a stream read as it comes; at most :data:`DRAIN_MAX_BYTES`.  After
        :data:`DRAIN_MAX_S` the backlog is kept for the next call and b"" returned."""
        if len(data) < TTY_BUFFER_BYTES and not self._backlog and not self._was_away(entered):
            return data
        ser, end = self._serial, _time.monotonic() + DRAIN_MAX_S
        parts = [*self._backlog, data]
        size, cut = sum(len(p) for p in parts), False
        try:
            while size < DRAIN_MAX_BYTES:
                now = _time.monotonic()
                if now >= end:
                    cut = True  # the screen's turn: the next call goes on
                    break
                if self._refill_since is None:
                    self._refill_since = now
                patience = self._refill_since + DRAIN_WAIT_S - now
                waiting = self._wait_waiting(min(patience, end - now))
                if not waiting:
                    cut = _time.monotonic() < self._refill_since + DRAIN_WAIT_S
                    break  # the backlog ended (no next part in time), or go on next call
                self._refill_since = None
                more = ser.read(waiting)
                parts.append(more)
                size += len(more)
                if len(more) < TTY_BUFFER_BYTES // 4:
                    break  # caught up: the backlog's full parts ended, the stream as it comes
                    # (a fast stream's next bytes come sooner than any wait: never held back)
        except (OSError, TypeError, AttributeError):
            cut = False  # the device went while draining: what was read is kept, next read says
        if cut:
            self._backlog = parts
            return b""
        self._backlog, self._refill_since = [], None
        return b"".join(parts)

    def _was_away(self, entered: float | None) -> bool:
        """Whether the read begun at ``entered`` took :data:`AWAY_S` past its own waits and
        more bytes wait now."""
        if entered is None:
            return False
        waits = self.timeout_s + self.batch_s
        return _time.monotonic() - entered > waits + AWAY_S and bool(self._serial.in_waiting)

    def _wait_waiting(self, limit_s: float) -> int:
        """Bytes waiting, polled for up to ``limit_s`` until there are some (0: none came)."""
        end = _time.monotonic() + limit_s
        while True:
            waiting = self._serial.in_waiting
            if waiting or _time.monotonic() >= end:
                return waiting
            _time.sleep(0.001)

    def close(self) -> None:
        """Close the port (never raises)."""
        try:
            self._serial.close()
        except Exception:  # noqa: BLE001 - the device may be gone already
            pass


def _open_error(port: str, baud: int, exc: BaseException) -> InputError:
    code = getattr(exc, "errno", None)
    text = " ".join(str(exc).split())
    if code == errno.ENOENT or "No such file" in text or "FileNotFoundError" in text:
        ports = available_ports()
        listed = ", ".join(ports) if ports else "none found"
        return InputError(f"{port}: no such serial port (available: {listed})")
    if code in (errno.EACCES, errno.EPERM) or "Permission denied" in text:
        return InputError(
            f"{port}: permission denied: add your user to the group that owns the port "
            "(often 'dialout': sudo usermod -aG dialout $USER, then log in again)"
        )
    if code == errno.EBUSY or "busy" in text.lower():
        return InputError(f"{port}: the port is busy (another program has it open)")
    if isinstance(exc, ValueError):
        return InputError(f"{port}: cannot use baud rate {baud} ({text})")
    return InputError(f"{port}: cannot open the serial port ({text})")


def available_ports() -> list[str]:
    """Device paths of the serial ports the system lists (USB adapters, built-in UARTs)."""
    try:
        return sorted(p.device for p in list_ports.comports())
    except Exception:  # noqa: BLE001 - listing is a courtesy in an error message
        return []


#: pyserial's words for a port whose other end closed or was unplugged (a read that found
#: the port ready but no bytes), and what they mean for a capture.
_CLOSED_WORDS = "returned no data"
_CLOSED_SAID = "the port closed: the device stopped sending, was unplugged or was reset"


def _gone_reason(exc: BaseException) -> str:
    """One line for why the port went (pyserial's 'device reports readiness to read but
    returned no data (device disconnected or multiple access on port?)' is a port closed
    at its other end: a device that ended its stream, or a cable pulled)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return _CLOSED_SAID if _CLOSED_WORDS in text else text
