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
    """``imucal ARGS...`` as a subprocess (real exit codes and streams)."""
    return subprocess.run([IMUCAL, *map(str, args)], capture_output=True, text=True, timeout=120)


def assert_one_line_error(proc, *words: str) -> None:
    """Exit 2 with one line on stderr, ``imucal: error: ...`` containing ``words``."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and err.startswith("imucal: error:"), err
    for w in words:
        assert w in err, (w, err)
