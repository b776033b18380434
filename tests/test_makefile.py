"""The Makefile's recipes as the shell receives them: every target the README and CI use
expands to commands ``sh`` can parse (``make bench`` once failed on a clean checkout: make's
``$(call)`` had split ``.[dev,bench]`` at its comma into a broken ``{ ...`` group)."""

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TARGETS = ["demo", "test", "test-all", "bench", "docs", "lint"]


@pytest.mark.skipif(shutil.which("make") is None, reason="make not installed")
@pytest.mark.parametrize("target", TARGETS)
def test_recipes_parse_as_shell(target):
    # -n: print, do not run; -B: every prerequisite's recipe too (the venv's installs)
    out = subprocess.run(["make", "-n", "-B", target], cwd=ROOT, capture_output=True,
                         text=True, timeout=60, check=True).stdout  # fmt: skip
    lines = [ln for ln in out.splitlines() if ln.strip()]
    assert any("install" in ln for ln in lines), out  # the venv's install is among them
    for line in lines:
        proc = subprocess.run(["sh", "-n", "-c", line], capture_output=True, text=True)
        assert proc.returncode == 0, f"make {target}: {line!r}: {proc.stderr.strip()}"


@pytest.mark.skipif(shutil.which("make") is None, reason="make not installed")
def test_bench_installs_both_extras():
    out = subprocess.run(["make", "-n", "-B", "bench"], cwd=ROOT, capture_output=True,
                         text=True, timeout=60, check=True).stdout  # fmt: skip
    assert "'.[dev,bench]'" in out, out
