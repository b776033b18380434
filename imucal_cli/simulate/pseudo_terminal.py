"""The pseudo-terminal the virtual IMU of ``imucal simulate --serve`` streams on (:mod:`.device`):
:class:`Port` (its master side; a reader's open, flush and close seen through POLLHUP and packet
mode; the end waits for the reader to read what was sent) and the signals that stop a serve
(:func:`stop_on_signals`).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import select
import signal
import struct
import termios
import threading
import time as _time
import tty

SETTLE_S = 0.3
"""Wait after a reader opened the port before the first byte, where the reader's flush of its
input cannot be seen (no packet mode)."""

FLUSH_WAIT_S = 2.0
"""Longest wait for a new reader to flush its input before the first byte, s."""

DRAIN_QUIET_S = 0.3
"""How long the reader's input queue must stay empty before everything sent counts as read, s."""

READER_POLL_S = 0.02
"""Interval at which the master's hang-up is looked at while no reader has the port open, s:
poll() returns at once while POLLHUP is set (it cannot wait for it to clear), so the wait for
a reader sleeps between looks rather than spinning a core."""


@contextlib.contextmanager
def stop_on_signals(stop: dict):
    """While serving (in the main thread), SIGINT and SIGTERM set ``stop["kind"]`` to
    ``"signal"``, so the serve ends at its next step and says what it sent; a second signal
    ends the process at once (the default action), whatever it is waiting for. The previous
    handlers are restored after."""
    old_handlers = {}
    if threading.current_thread() is threading.main_thread():

        def handler(signum, frame):  # noqa: ARG001
            if stop["kind"] == "signal":  # asked twice: no more waiting
                signal.signal(signum, signal.SIG_DFL)
                os.kill(os.getpid(), signum)
            stop["kind"] = "signal"

        for signum in (signal.SIGINT, signal.SIGTERM):
            old_handlers[signum] = signal.signal(signum, handler)
    try:
        yield
    finally:
        for signum, old in old_handlers.items():
            signal.signal(signum, old)


def asked_to_stop(stop: dict) -> str:
    """``"signal"`` (SIGINT or SIGTERM, :func:`stop_on_signals`), ``"cancelled"`` (the
    caller's ``cancel`` event) or ``""``."""
    if stop["kind"] is not None:
        return stop["kind"]
    cancel = stop.get("cancel")
    return "cancelled" if cancel is not None and cancel.is_set() else ""


def _int_ioctl(fd: int, request: int, value: int = 0) -> int:
    return struct.unpack("i", fcntl.ioctl(fd, request, struct.pack("i", value)))[0]


class Port:
    """The pseudo-terminal: its master side (ours) and the path of its slave side (the
    reader's).  The slave is closed at once: a reader's open is seen as the end of the master's
    POLLHUP, its close as POLLHUP again.  In packet mode (while waiting for the reader) a flush of
    the reader's input shows on the master as a ``TIOCPKT_FLUSHREAD`` status byte."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)  # flushes: before packet mode, so that flush is not the reader's
        self.path = os.ttyname(slave)
        os.close(slave)
        self.poller = select.poll()
        self.poller.register(self.master, select.POLLHUP)
        self.packets = _packet_mode(self.master, True)

    def wait_for_reader(self, stop: dict, wait_reader_s: float | None) -> str:
        """Wait until a reader opened the port and flushed its input; "" or why it gave up."""
        waited = _time.monotonic()
        while any(ev & select.POLLHUP for _, ev in self.poller.poll(0)):
            if asked_to_stop(stop):
                return asked_to_stop(stop)
            if wait_reader_s is not None and _time.monotonic() - waited > wait_reader_s:
                return "no-reader"
            _time.sleep(READER_POLL_S)  # POLLHUP set: poll() would not wait
        if not self.packets:
            _time.sleep(SETTLE_S)
            return ""
        status = select.poll()
        status.register(self.master, select.POLLPRI | select.POLLIN)
        end = _time.monotonic() + FLUSH_WAIT_S
        while _time.monotonic() < end and not asked_to_stop(stop):
            events = status.poll(50)
            if any(ev & select.POLLHUP for _, ev in events):
                break  # the reader closed again: the stream sees it at once
            if events and _flushed(self.master):
                break
        self.packets = _packet_mode(self.master, False)
        return ""

    def drain(self, limit_s: float) -> int:
        """Wait until the reader has read every byte written (at most ``limit_s``, or until it
        closes the port); the number of bytes it has not read (lost when the port closes).

        The reader's input queue (FIONREAD) holds at most 4 KiB: a slow reader's backlog waits
        in the kernel's buffers behind it and refills it as it is read, so the queue must stay
        empty for :data:`DRAIN_QUIET_S` before everything counts as read."""
        end = _time.monotonic() + limit_s
        empty_since = None
        while True:
            unread = self._unread()
            now = _time.monotonic()
            gone = any(ev & select.POLLHUP for _, ev in self.poller.poll(0))
            if unread:
                empty_since = None
            elif empty_since is None:
                empty_since = now
            if gone or now >= end or (empty_since is not None
                                      and now - empty_since >= DRAIN_QUIET_S):  # fmt: skip
                return unread
            _time.sleep(0.01)

    def _unread(self) -> int:
        """Bytes waiting in the reader's input queue.  The slave is opened only for the query:
        held open, it would hide the reader's close (POLLHUP)."""
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return 0
        try:
            return _int_ioctl(fd, termios.FIONREAD)
        except OSError:
            return 0
        finally:
            os.close(fd)

    def close(self) -> None:
        os.close(self.master)


def _packet_mode(master: int, on: bool) -> bool:
    """Switch the master's packet mode; whether it is on."""
    request = getattr(termios, "TIOCPKT", None)
    if request is None:
        return False
    try:
        _int_ioctl(master, request, int(on))
    except OSError:
        return False
    return on


def _flushed(master: int) -> bool:
    """Read the master's pending packets: did one say the reader flushed its input?"""
    flush = getattr(termios, "TIOCPKT_FLUSHREAD", 1)
    try:
        packet = os.read(master, 4096)
    except OSError:
        return False
    return bool(packet) and packet[0] != 0 and bool(packet[0] & flush)
