"""Running the installed `imucal` command in tests, and checking its one-line errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

IMUCAL = str(Path(sys.executable).with_name("imucal"))


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
