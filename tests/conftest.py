"""Fixtures for every test."""

from __future__ import annotations

import os

# One BLAS thread, as the `imucal` program runs (imucal_cli/__init__.py), set before any test
# module imports numpy: the solvers' matrices are small, and two OpenBLAS threads that spin
# while the other core is busy make a test up to 10x slower on a loaded 2-core machine.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import signal  # noqa: E402

import pytest  # noqa: E402

# Tests that press Ctrl-C in a process they start need SIGINT's default action there. A shell
# starts a background job (`make test &`, a CI step run in the background) with SIGINT ignored,
# every process inherits that, and Python then leaves Ctrl-C ignored, as `imucal` rightly does in
# a background job: those tests would see a capture that cannot be interrupted.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

from .cli_helpers import reap  # noqa: E402
from .served import stop_all  # noqa: E402


@pytest.fixture(autouse=True)
def _reap_background_processes():
    """No process a test started with ``cli_helpers.spawn``, and no device a test served
    in a thread (``served.ThreadServer``), outlives the test."""
    yield
    reap()
    stop_all()
