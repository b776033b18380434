"""What the registry's tests share: a real calibration to vary, writer processes (the bench's
``python -m bench.registry writer``), and the checks that a registry holds what its writers
said, whole."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

from sqlalchemy import func, select

from bench.registry import serial_of, variant, verify
from imucal_cli.registry.schema import calibrations, documents, figures, sections
from imucal_cli.registry.store import open_registry

from .cli_helpers import LineReader, run, spawn

ROOT = Path(__file__).resolve().parents[1]
SESSION = ROOT / "sessions" / "qureshi18-seed1.h5"


def calibrate_copy(folder: Path, *args) -> tuple[Path, Path]:
    """A copy of the shipped qureshi18 session calibrated with ``imucal calibrate`` (and
    ``args``); the session and its calibration JSON."""
    session = folder / "unit.h5"
    shutil.copy(SESSION, session)
    out = folder / "unit.cal.json"
    proc = run("calibrate", session, "-o", out, *args)
    assert proc.returncode in (0, 4), proc.stderr
    return session, out


def make_template(tmp_path_factory) -> dict:
    """A real calibration (qureshi18, accel + gyro): ``doc`` (a dict) and ``path`` (its file);
    for a module-scoped fixture."""
    folder = tmp_path_factory.mktemp("template")
    _, out = calibrate_copy(folder)
    return {"doc": json.loads(out.read_text()), "path": out}


def unit(template: dict, index: int, **kwargs):
    """Calibration of unit ``index`` (``SN...``), varied from the template (bench.registry)."""
    return variant(template["doc"], serial_of(index), index, **kwargs)


def writer(url: str, template_path: Path, first: int, count: int, lot: str = "L",
           *extra: str):  # fmt: skip
    """A writer process (spawned: killed when the test ends) and a reader of its lines."""
    proc = spawn([sys.executable, "-m", "bench.registry", "writer", url, template_path, first,
                  count, lot, *extra], cwd=ROOT, stdout=subprocess.PIPE,
                 stdin=subprocess.PIPE, text=True)  # fmt: skip
    return proc, LineReader(proc.stdout)


def recorded_lines(lines: list[str]) -> dict[str, tuple[str, str]]:
    """``{uid: (sha256, serial)}`` of a writer's ``recorded`` lines."""
    out = {}
    for line in lines:
        if line.startswith("recorded "):
            _, uid, sha, serial = line.strip().split(" ", 3)
            out[uid] = (sha, serial)
    return out


def assert_whole(url: str, expected: dict[str, tuple[str, str]]) -> None:
    """The registry holds exactly ``expected`` (uids, document hashes, serials), every
    calibration with its document, sections and figures, no orphan row."""
    ok, what = verify(url, expected)
    assert ok, what
    with open_registry(url, create=False) as reg, reg.read() as conn:
        n_cal = conn.execute(select(func.count()).select_from(calibrations)).scalar_one()
        n_doc = conn.execute(select(func.count()).select_from(documents)).scalar_one()
        orphans = conn.execute(
            select(func.count()).select_from(figures)
            .where(~select(sections.c.id).where(sections.c.id == figures.c.section_id).exists())
        ).scalar_one()  # fmt: skip
    assert n_cal == n_doc == len(expected) and orphans == 0, (n_cal, n_doc, orphans)
