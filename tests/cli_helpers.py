"""Running the installed `imucal` command in tests, and checking its one-line errors.

Processes a test starts in the background go through :func:`spawn`: the autouse fixture in
``conftest.py`` kills whichever is still running when its test ends (passed, failed or timed
out), and on Linux each one also gets SIGTERM when the test process itself dies (killed
from outside), so none outlives its test: a ``simulate --serve`` waiting for a reader
would otherwise wait forever.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

IMUCAL = str(Path(sys.executable).with_name("imucal"))

_STARTED: list[subprocess.Popen] = []
"""Background processes started by :func:`spawn` and not yet reaped."""

_PR_SET_PDEATHSIG = 1
_prctl = None
if sys.platform.startswith("linux"):
    try:
        import ctypes

        _prctl = ctypes.CDLL(None, use_errno=True).prctl  # loaded here, not after the fork
    except (OSError, AttributeError):
        _prctl = None


def _die_with(parent: int):
    """``preexec_fn``: SIGTERM to the child when ``parent`` dies (no import, no lock taken)."""

    def child() -> None:
        _prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:  # the parent died before prctl
            os._exit(1)

    return child


def spawn(args, **kwargs) -> subprocess.Popen:
    """:class:`subprocess.Popen` for a process that runs beside the test (see the module
    notes: it is killed when the test ends, and with the test process)."""
    if _prctl is not None:
        kwargs.setdefault("preexec_fn", _die_with(os.getpid()))
    proc = subprocess.Popen([str(a) for a in args], **kwargs)
    _STARTED.append(proc)
    return proc


def reap(*procs: subprocess.Popen) -> None:
    """Kill each process still running and collect it; every process :func:`spawn` started
    when none is named."""
    for proc in procs or list(_STARTED):
        try:
            if proc.poll() is None:
                proc.kill()
            proc.communicate(timeout=30)
        except (OSError, ValueError, subprocess.TimeoutExpired):
            pass
        if proc in _STARTED:
            _STARTED.remove(proc)


def run(*args) -> subprocess.CompletedProcess:
    """``imucal ARGS...`` in this process: :func:`imucal_cli.cli.main` with ``sys.argv`` set,
    its stdout and stderr captured, its exit status returned, as a subprocess would give them
    (without the 0.3-1 s of a new interpreter). What only a process shows (signals, a closed
    pipe, the program's exit path) is tested with :func:`run_process`."""
    import io
    import warnings
    from contextlib import redirect_stderr, redirect_stdout

    from imucal_cli.cli import main

    argv = ["imucal", *map(str, args)]
    out = io.TextIOWrapper(io.BytesIO(), encoding="utf-8", write_through=True)
    err = io.TextIOWrapper(io.BytesIO(), encoding="utf-8", write_through=True)
    saved_argv, saved_showwarning = sys.argv, warnings.showwarning
    code: object = 0
    try:
        sys.argv = argv
        with warnings.catch_warnings(), redirect_stdout(out), redirect_stderr(err):
            try:
                main()
            except SystemExit as exc:
                code = exc.code
    finally:
        sys.argv, warnings.showwarning = saved_argv, saved_showwarning
    if code is None:
        code = 0
    elif not isinstance(code, int):
        err.write(f"{code}\n")
        code = 1
    return subprocess.CompletedProcess(argv, code, _text(out), _text(err))


def _text(stream) -> str:
    stream.flush()
    return stream.buffer.getvalue().decode("utf-8", errors="replace")


def run_process(*args, **kwargs) -> subprocess.CompletedProcess:
    """``imucal ARGS...`` as a subprocess (real exit codes and streams, the program's own exit
    path)."""
    return subprocess.run([IMUCAL, *map(str, args)], capture_output=True, text=True,
                          timeout=kwargs.pop("timeout", 300), **kwargs)  # fmt: skip


def assert_one_line_error(proc, *words: str) -> None:
    """Exit 2 with one line on stderr, ``imucal: error: ...`` containing ``words``."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and err.startswith("imucal: error:"), err
    for w in words:
        assert w in err, (w, err)


class LineReader:
    """Lines of a process's text stream, read as they come, waited for by content.

    ``wait_for(predicate)`` returns the first line (from the start, or after the last one it
    returned) for which ``predicate`` is true, waiting at most ``timeout`` seconds for it: a
    test waits for what the process prints, never for a fixed time.  A thread reads the
    stream to its end; :meth:`text` is everything read once the process has ended."""

    def __init__(self, stream) -> None:
        import queue
        import threading

        self.lines: list[str] = []
        self._queue: queue.Queue = queue.Queue()
        self._seen = 0
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        try:
            for line in stream:
                self._queue.put(line)
        except (OSError, ValueError):
            pass
        self._queue.put(None)

    def _pull(self, timeout: float) -> bool:
        """One more line into :attr:`lines`; False at the end of the stream."""
        import queue

        try:
            line = self._queue.get(timeout=timeout)
        except queue.Empty:
            return True
        if line is None:
            self._queue.put(None)
            return False
        self.lines.append(line)
        return True

    def wait_for(self, predicate, timeout: float = 120.0) -> str:
        import time

        end = time.monotonic() + timeout
        while True:
            while self._seen < len(self.lines):
                line = self.lines[self._seen]
                self._seen += 1
                if predicate(line):
                    return line
            left = end - time.monotonic()
            assert left > 0, f"waited {timeout} s for a line; got:\n{''.join(self.lines)}"
            if not self._pull(min(left, 1.0)):
                raise AssertionError(f"the stream ended first; got:\n{''.join(self.lines)}")

    def text(self, timeout: float = 120.0) -> str:
        """Everything the stream carried, once it has ended."""
        self._thread.join(timeout)
        assert not self._thread.is_alive(), f"the stream did not end within {timeout} s"
        while self._pull(0.0):  # the queue ends with the end marker
            pass
        return "".join(self.lines)
