"""What the registry's tests share: a real calibration to vary (of one IMU, or of a set of
several), writer processes (the bench's ``python -m bench.registry writer``), a registry
written as revision 0002 wrote it, and the checks that a registry holds what its writers said,
whole."""

from __future__ import annotations

import copy
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import sqlalchemy as sa
from alembic import command
from alembic.config import Config
from sqlalchemy import func, select

from bench.registry import serial_of, variant, verify
from imucal_cli.formats.calibration import calibration_to_json
from imucal_cli.model.calibration import Calibration
from imucal_cli.registry import store as store_module
from imucal_cli.registry.record import pack
from imucal_cli.registry.schema import calibrations, documents, figures, sections
from imucal_cli.registry.store import open_registry
from imucal_cli.use.limits import unit_figures

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


def make_set_template(tmp_path_factory) -> dict:
    """A real calibration of a set of 3 IMUs (``imucal simulate --imus 3 --plan random:12``,
    then ``calibrate``): ``doc`` (a dict) and ``path``; for a module-scoped fixture."""
    folder = tmp_path_factory.mktemp("set-template")
    session = folder / "set.h5"
    proc = run("simulate", "--imus", "3", "--plan", "random:12", "-o", session)
    assert proc.returncode == 0, proc.stderr
    out = folder / "set.cal.json"
    proc = run("calibrate", session, "-o", out)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(out.read_text())
    assert sorted(doc["imus"]) == ["imu1", "imu2"]
    return {"doc": doc, "path": out}


def set_unit(template: dict, index: int, *, apart: str | None = None,
             drift: str | None = None, created: str | None = None) -> Calibration:  # fmt: skip
    """Calibration of the set ``index`` (``SN...``): each IMU's sections varied from the
    template's as :func:`bench.registry.variant` varies one IMU's (each IMU its own draw);
    ``apart``/``drift``: the IMU (``"reference"``, ``"imu1"``, ...) whose accel bias x stands
    40 lot std apart / moved by 12 of its std (a re-calibration at ``created``)."""
    doc = copy.deepcopy(template["doc"])
    cal = variant(doc, serial_of(index), index, apart=apart == "reference",
                  drift=12.0 if drift == "reference" else 0.0, created=created)  # fmt: skip
    out = cal.to_dict()
    for k, (name, entry) in enumerate(doc["imus"].items(), start=1):
        alone = {"format": doc["format"], "format_version": doc["format_version"],
                 **{s: entry[s] for s in ("accel", "gyro") if entry.get(s)}}  # fmt: skip
        varied = variant(alone, serial_of(index), 1000 * k + index, apart=apart == name,
                         drift=12.0 if drift == name else 0.0, created=created).to_dict()
        out["imus"][name].update({s: varied[s] for s in ("accel", "gyro") if s in varied})
    return Calibration.from_dict(out, source=serial_of(index))


def write_as_0002(url: str, cals: list[tuple[str, Calibration]]) -> None:
    """A registry migrated to revision 0002 only, holding ``cals`` (``(serial, calibration)``)
    as imucal wrote them at that revision: the unit, the calibration, its document, and the
    sections of the reference IMU only (no ``imu`` column: a set's other IMUs were in the
    document alone)."""
    engine = sa.create_engine(store_module.registry_url(url))
    old_sections = sa.table("sections", *[sa.column(c) for c in (
        "id", "calibration_id", "sensor", "solver", "units", "units_in", "basis", "layout",
        "values", "stds")])  # fmt: skip
    old_figures = sa.table("figures", *[sa.column(c) for c in (
        "section_id", "name", "unit", "value", "std", "tracked")])  # fmt: skip
    with engine.begin() as conn:
        config = Config()
        folder = Path(store_module.__file__).parent / "migrations"
        config.set_main_option("script_location", str(folder))
        config.attributes["connection"] = conn
        command.upgrade(config, "0002")
        for n, (serial, cal) in enumerate(cals, start=1):
            doc = calibration_to_json(cal)
            conn.execute(sa.text("INSERT INTO units (id, serial, lot, first_recorded, "
                                 "last_recorded) VALUES (:n, :s, 'OLD', :c, :c)"),
                         {"n": n, "s": serial, "c": cal.created})  # fmt: skip
            conn.execute(sa.text("INSERT INTO calibrations (id, uid, unit_id, created, "
                                 "recorded_at, document_sha256) VALUES (:n, :u, :n, :c, :c, "
                                 ":sha)"),
                         {"n": n, "u": f"old{n}", "c": cal.created,
                          "sha": hashlib.sha256(doc.encode()).hexdigest()})  # fmt: skip
            conn.execute(sa.text("INSERT INTO documents (calibration_id, document) VALUES "
                                 "(:n, :d)"), {"n": n, "d": doc})  # fmt: skip
            for sensor, sec in unit_figures(cal).items():
                layout, values, stds = pack(sec["rows"])
                section_id = conn.execute(old_sections.insert().values(
                    calibration_id=n, sensor=sensor, solver=sec["solver"], units=sec["units"],
                    units_in=sec["units_in"], basis=sec["basis"], layout=layout,
                    values=values, stds=stds).returning(old_sections.c.id)
                ).scalar_one()  # fmt: skip
                conn.execute(old_figures.insert(), [
                    {"section_id": section_id, "name": r["name"], "unit": r["unit"],
                     "value": r["value"], "std": r["std"], "tracked": r["tracked"]}
                    for r in sec["rows"]])  # fmt: skip
        if conn.dialect.name == "postgresql":  # the ids given above: move the sequences on
            for table in ("units", "calibrations"):
                conn.execute(sa.text(f"SELECT setval('{table}_id_seq', 100)"))
    engine.dispose()


def section_rows(url: str) -> list[tuple]:
    """Every section of a registry by its calibration's document hash: ``(document sha256,
    imu, sensor, layout, values, stds, its figure rows (name, value), sorted)``, sorted."""
    with open_registry(url, create=False) as reg, reg.read() as conn:
        rows = conn.execute(
            select(calibrations.c.document_sha256, sections.c.imu, sections.c.sensor,
                   sections.c.layout, sections.c["values"], sections.c.stds, sections.c.id)
            .join(calibrations, calibrations.c.id == sections.c.calibration_id)
        ).all()  # fmt: skip
        figs: dict[int, list] = {}
        for section_id, name, value in conn.execute(
                select(figures.c.section_id, figures.c.name, figures.c.value)):  # fmt: skip
            figs.setdefault(section_id, []).append((name, value))
    rows = [(*r[:6], tuple(sorted(figs.get(r[6], [])))) for r in rows]
    return sorted((tuple(r) for r in rows), key=lambda r: (r[0], r[1] or "", r[2]))
