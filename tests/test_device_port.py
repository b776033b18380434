"""The virtual device's port (``simulate --serve``): a reader that is slow to configure the port
or to read loses nothing, and the device counts only what the reader got.  A loaded machine
looks like that to the device; these tests make it slow on purpose."""

from __future__ import annotations

import os
import queue
import select
import sys
import threading
import time

import pytest

from imucal_cli.simulate.device import serve

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")


def _serve_in_thread(**options):
    paths: queue.Queue = queue.Queue()
    result: dict = {}

    def run() -> None:
        result["served"] = serve("six", 100.0, 115200, hold_s=0.5, move_s=0.3, wait_reader_s=60,
                                 announce=paths.put, **options)  # fmt: skip

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return paths.get(timeout=60), thread, result


def _read_all(fd: int, pause_s: float) -> bytes:
    """Read until the device goes, pausing after each read (a slow reader)."""
    data = bytearray()
    while True:
        select.select([fd], [], [], 30)
        try:
            chunk = os.read(fd, 65536)
        except OSError:  # EIO: the master side closed
            break
        if not chunk:
            break
        data += chunk
        time.sleep(pause_s)
    return bytes(data)


def test_a_late_flush_and_a_slow_reader_lose_nothing():
    import termios

    path, thread, result = _serve_in_thread(vanish_after_s=1.5)
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        time.sleep(1.0)  # configures the port late, then flushes its input as pyserial does
        termios.tcflush(fd, termios.TCIFLUSH)
        time.sleep(1.0)  # and reads late, slowly: what was sent after the flush is all there
        data = _read_all(fd, pause_s=0.3)
    finally:
        os.close(fd)
    thread.join(timeout=60)
    served = result["served"]
    lines = data.decode().splitlines()
    assert lines[0].startswith("# imucal virtual IMU: plan six")  # the first line survived
    assert served.end == "vanished" and served.lines == len(lines) - 1 >= 100
    assert all(line.count(",") == 7 for line in lines[1:])  # whole lines only


def test_a_reader_that_never_flushes_is_not_kept_waiting_long():
    path, thread, result = _serve_in_thread(duration_s=0.5)
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        data = _read_all(fd, pause_s=0.0)
    finally:
        os.close(fd)
    thread.join(timeout=60)
    lines = data.decode().splitlines()
    assert lines[0].startswith("# imucal virtual IMU") and result["served"].end == "duration"
    assert result["served"].lines == len(lines) - 1 > 0


def test_a_caller_in_another_thread_ends_the_serve():
    """``serve(cancel=...)`` (tests/served.py serves so): a looping serve, which would stream
    for ever, ends when the event is set, says so, and counts every line the reader got."""
    cancel = threading.Event()
    path, thread, result = _serve_in_thread(cancel=cancel, loop=True)
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    data = bytearray()
    try:
        end = time.monotonic() + 60
        while data.count(b"\n") < 50 and time.monotonic() < end:  # streaming: then cancel
            select.select([fd], [], [], 1.0)
            data += os.read(fd, 65536)
        cancel.set()
        data += _read_all(fd, pause_s=0.0)  # the rest, until the serve closes the port
    finally:
        os.close(fd)
    thread.join(timeout=60)
    assert not thread.is_alive()
    served, lines = result["served"], data.decode().splitlines()
    assert served.end == "cancelled" and len(lines) >= 50
    assert served.lines == len(lines) - 1 and all(line.count(",") == 7 for line in lines[1:])
