"""The virtual device served in a thread of the test process.

``imucal simulate --serve ARGS`` is :func:`imucal_cli.simulate.device.serve` behind typer's
option parsing.  A test that examines the capture (its process, signals, file and output) and
not the device's process serves the same pseudo-terminal, lines and faults from a thread here:
no interpreter is started for the device (2-3 s of CPU each on a loaded 2-core machine).  The
command itself (its options, output, signals, Enter at its terminal) is tested as a process:
``test_simulator``, ``test_serve_signals``, ``test_guided_e2e``, ``test_imu_set_capture``,
``test_capture_until`` (the person), ``test_registry_cli``, and in ``test_virtual`` and
``test_capture_live`` the whole session end to end, the command's JSON and the served
warm-up and clock error.  ``tests/test_served.py`` checks that :func:`serve_options` gives
:func:`serve` what the command gives it.
"""

from __future__ import annotations

import queue
import threading

from imucal_cli.cli.simulate import SERVE_HOLD_S
from imucal_cli.simulate.device import ServeResult, serve

_RUNNING: list[ThreadServer] = []
"""Servers started and not yet stopped: :func:`stop_all` (conftest, after every test)."""

#: ``simulate`` options with a value: the keyword of :func:`serve` and its type.
VALUES = {
    "--plan": ("plan", str), "--rate": ("rate_hz", float), "--baud": ("baud", int),
    "--seed": ("seed", int), "--hold": ("hold_s", float), "--move": ("move_s", float),
    "--units": ("units", str), "--protocol": ("protocol", str),
    "--duration": ("duration_s", float), "--stall-after": ("stall_after_s", float),
    "--vanish-after": ("vanish_after_s", float), "--malformed-every": ("malformed_every", int),
}  # fmt: skip
#: ``simulate`` options of a set of IMUs (issue 28): the argument of the command's
#: :func:`imucal_cli.cli.simulate_set.serve_options`, which puts them in ``plan_options``.
SET_VALUES = {"--imus": ("imus", int), "--imu-rotation": ("rotation_deg", float),
              "--imu-offset": ("offset_ms", float), "--serve-imu": ("member", int)}  # fmt: skip
#: ``simulate`` switches: the keyword of :func:`serve` and its value.
SWITCHES = {"--loop": ("loop", True), "--garbage": ("garbage", True),
            "--no-temp": ("temperature", False)}  # fmt: skip


def serve_options(args) -> dict:
    """:func:`serve`'s keywords for ``imucal simulate --serve ARGS`` (the command's defaults:
    plan qureshi18, holds of ``SERVE_HOLD_S``); an option not listed here is an error, so a
    test that needs it serves through the process."""
    import inspect

    from imucal_cli.cli.simulate import simulate
    from imucal_cli.cli.simulate_set import serve_options as set_options

    options = {"plan": "qureshi18", "hold_s": SERVE_HOLD_S}
    command = inspect.signature(simulate).parameters  # the set's defaults: the command's
    members = {"imus": 1, "rotation_deg": command["imu_rotation"].default,
               "offset_ms": command["imu_offset"].default, "member": None}  # fmt: skip
    args = [str(a) for a in args]
    while args:
        flag = args.pop(0)
        if flag in SWITCHES:
            key, value = SWITCHES[flag]
            options[key] = value
        elif flag in VALUES and args:
            key, kind = VALUES[flag]
            options[key] = kind(args.pop(0))
        elif flag in SET_VALUES and args:
            key, kind = SET_VALUES[flag]
            members[key] = kind(args.pop(0))
        else:
            raise ValueError(f"tests/served.py does not serve {flag!r}: use the process")
    if members["imus"] > 1:
        options["plan_options"] = set_options(**members)
    return options


class ThreadServer:
    """``imucal simulate --serve ARGS`` in a thread: :attr:`path` is its device, :attr:`lines`
    its status messages (what the command prints on stderr), waited for with
    :meth:`wait_for`."""

    def __init__(self, *args) -> None:
        self._cancel = threading.Event()
        self.result: ServeResult | None = None
        self.error: BaseException | None = None
        self.lines: list[str] = []
        self._said = threading.Condition()
        paths: queue.Queue = queue.Queue()
        options = serve_options(args)

        def run() -> None:
            try:
                self.result = serve(announce=paths.put, cancel=self._cancel, status=self._say,
                                    **options)  # fmt: skip
            except BaseException as exc:  # noqa: BLE001 - shown by the test that waits
                self.error = exc
                paths.put(None)
            finally:
                self._say(None)

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()
        _RUNNING.append(self)
        try:
            self.path = paths.get(timeout=120)
        except queue.Empty:
            self.kill()
            raise AssertionError("the device gave no path within 120 s") from None
        assert self.path is not None, f"the device did not start: {self.error!r}"

    def _say(self, message: str | None) -> None:
        with self._said:
            self.lines.append("" if message is None else f"imucal: {message}\n")  # "": the end
            self._said.notify_all()

    def wait_for(self, words: str, timeout: float = 120.0) -> None:
        """Until the device says ``words`` (a pose it started, ...)."""
        with self._said:
            ok = self._said.wait_for(lambda: any(words in line for line in self.lines)
                                     or "" in self.lines, timeout)  # fmt: skip
        assert ok and any(words in line for line in self.lines), (words, self.lines)

    def finish(self, timeout: float = 120.0) -> dict:
        """Wait for the serve to end (the plan, its duration, or the reader closing the port);
        what it sent, as ``simulate --serve`` reports it."""
        self._thread.join(timeout)
        if self._thread.is_alive():
            self.kill()
            raise AssertionError(f"the device did not end within {timeout} s")
        if self in _RUNNING:
            _RUNNING.remove(self)
        assert self.error is None and self.result is not None, repr(self.error)
        r = self.result
        return {"lines": r.lines, "malformed": r.malformed, "garbage": r.garbage_bytes}

    def kill(self) -> None:
        """End the serve now (as a signal ends the process) and wait for the thread."""
        self._cancel.set()
        self._thread.join(60)
        if self in _RUNNING:
            _RUNNING.remove(self)
        assert not self._thread.is_alive(), "the device did not end within 60 s of cancel"

    stop = kill


def stop_all() -> None:
    """End every server a test started and left running (a failed test, a forgotten stop)."""
    for server in list(_RUNNING):
        server.kill()
