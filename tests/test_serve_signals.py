"""``simulate --serve`` ends on a signal: the first SIGTERM or Ctrl-C lets it stop at its next
step and say what it sent; a second ends the process at once, whatever it is waiting for (a
served device orphaned by a killed test or script must never linger)."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

_CHILD = """
import os, signal, sys, time
from imucal_cli.simulate.pseudo_terminal import stop_on_signals
stop = {"kind": None}
with stop_on_signals(stop):
    os.kill(os.getpid(), signal.SIGTERM)
    print("first:", stop["kind"], flush=True)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(60)
    print("still running", flush=True)
"""


def test_a_second_signal_ends_the_serve_at_once():
    proc = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert proc.stdout.splitlines() == ["first: signal"], (proc.stdout, proc.stderr)
    assert proc.returncode == -signal.SIGTERM, proc.stderr
