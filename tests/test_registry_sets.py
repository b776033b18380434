"""The registry of units of several IMUs (issue 28 in issue 29): every IMU's sections recorded
(``sections.imu``), a lot's statistics, outliers, Cpk and drift per IMU, a unit's history with
every IMU, export/import, and a registry of revision 0002 holding sets migrated to 0003."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine, func, select

from imucal_cli.registry import store as store_module
from imucal_cli.registry.lot import OUTLIER_Z, lot_statistics
from imucal_cli.registry.queries import iter_records, list_units, unit_report
from imucal_cli.registry.record import UnitInfo, record_calibration
from imucal_cli.registry.schema import figures, sections
from imucal_cli.registry.store import open_registry
from imucal_cli.registry.transfer import export_records, import_files
from imucal_cli.use.limits import judge_calibration, limits_from_dict, unit_figures

from .cli_helpers import run
from .registry_helpers import (
    make_set_template,
    make_template,
    section_rows,
    set_unit,
    unit,
    write_as_0002,
)

LIMITS = {"product": {"name": "P"},
          "limits": {"accel": {"bias_max": 0.5, "misalignment_max_deg": 1.0}}}  # fmt: skip


@pytest.fixture(scope="module")
def set_template(tmp_path_factory) -> dict:
    return make_set_template(tmp_path_factory)


def _bias_x(sec) -> float:
    """Accel bias x in output units (matrix @ bias), computed here from a section."""
    return float((np.asarray(sec.matrix) @ np.asarray(sec.bias))[0])


def _recal(reg, template, i, drift, limits):
    cal = set_unit(template, i, drift=drift, created="2026-06-01T00:00:00Z")
    record_calibration(reg, cal, UnitInfo(cal.sensor, "P", "SETS"),
                       acceptance=judge_calibration(cal, limits), limits=limits)  # fmt: skip
    return cal


def test_every_imu_of_a_set_is_recorded(tmp_path, set_template):
    """A set's calibration gets a section per sensor of each IMU: the reference's with
    ``imu`` NULL, each other IMU's under its name, with its own figures."""
    cal = set_unit(set_template, 0)
    with open_registry(tmp_path / "r.db") as reg:
        record_calibration(reg, cal, UnitInfo("U1"))
        with reg.read() as conn:
            rows = conn.execute(select(sections.c.imu, sections.c.sensor)).all()
            n = conn.execute(select(func.count()).select_from(figures)).scalar_one()
            b_x = dict(conn.execute(
                select(sections.c.imu, figures.c.value)
                .join(sections, sections.c.id == figures.c.section_id)
                .where(sections.c.sensor == "accel", figures.c.name == "bias x")
            ).all())  # fmt: skip
    assert sorted(rows, key=lambda r: (r[0] or "", r[1])) == [
        (None, "accel"), (None, "gyro"), ("imu1", "accel"), ("imu1", "gyro"),
        ("imu2", "accel"), ("imu2", "gyro")]  # fmt: skip
    holders = [cal, *cal.imus.values()]
    assert n == sum(len(s["rows"]) for h in holders for s in unit_figures(h).values())
    assert b_x[None] == pytest.approx(_bias_x(cal.accel), rel=1e-12)
    for name in ("imu1", "imu2"):
        assert b_x[name] == pytest.approx(_bias_x(cal.imus[name].accel), rel=1e-12)
        assert b_x[name] != pytest.approx(b_x[None], rel=1e-3)  # its own, not the reference's


def test_lot_of_sets_per_imu(tmp_path, set_template):
    """A lot of 20 sets: imu1 of unit 3 stands apart (accel bias x), unit 1 is re-calibrated
    with imu2's accel bias x moved by 12 std, unit 2 re-calibrated unchanged. Each IMU's
    parameters have their own distribution (against an independent computation), outliers,
    Cpk and drift test; the reference's stay as a single IMU's (no ``imu``)."""
    limits = limits_from_dict(LIMITS, "test")
    latest = {}
    with open_registry(tmp_path / "lot.db") as reg:
        for i in range(20):
            cal = set_unit(set_template, i, apart="imu1" if i == 3 else None)
            latest[i] = cal
            record_calibration(reg, cal, UnitInfo(cal.sensor, "P", "SETS"),
                               acceptance=judge_calibration(cal, limits),
                               limits=limits)  # fmt: skip
        latest[1] = _recal(reg, set_template, 1, "imu2", limits)
        latest[2] = _recal(reg, set_template, 2, None, limits)
        stats = lot_statistics(reg, "SETS")
        history = unit_report(reg, "SN000001")["history"]
    assert stats["units"] == 20 and stats["calibrations"] == 22
    by_key = {(p.get("imu"), p["sensor"], p["name"]): p for p in stats["parameters"]}
    assert all(p["imu"] in ("imu1", "imu2") for p in stats["parameters"] if "imu" in p)
    order = [p.get("imu") for p in stats["parameters"]]
    assert order == sorted(order, key=lambda m: (m is not None, m or ""))  # reference first
    for imu in (None, "imu1", "imu2"):
        x = np.array([_bias_x(c.accel if imu is None else c.imus[imu].accel)
                      for _, c in sorted(latest.items())])  # fmt: skip
        p = by_key[(imu, "accel", "bias x")]
        assert p["n"] == 20 and p["mean"] == pytest.approx(x.mean(), rel=1e-12)
        assert p["std"] == pytest.approx(x.std(ddof=1), rel=1e-9)
        mu, sd = x.mean(), x.std(ddof=1)
        assert p["cpk"] == pytest.approx(min(0.5 - mu, mu + 0.5) / (3 * sd), rel=1e-9)
        assert p["beyond_limit"] == int((np.abs(x) > 0.5).sum())
        mad = 1.4826 * np.median(np.abs(x - np.median(x)))
        apart = {f"SN{i:06d}" for i in np.flatnonzero(np.abs(x - np.median(x)) / mad > OUTLIER_Z)}
        assert {o["serial"] for o in p["outliers"]} == apart
        assert apart == ({"SN000003"} if imu == "imu1" else set())
    apart_of = {u["serial"]: u["parameters"] for u in stats["units_apart"]}
    assert any(p.startswith("imu1 accel bias x (+") for p in apart_of["SN000003"])
    assert not any(p.startswith(("accel ", "imu2 ")) for p in apart_of["SN000003"])
    alarms = {a["serial"]: a["drifted"] for a in stats["drift"]["alarms"]}
    assert stats["drift"]["units_checked"] == 2 and set(alarms) == {"SN000001"}
    assert alarms["SN000001"] and all(d.startswith("imu2 accel b_x (z = +")
                                      for d in alarms["SN000001"])  # fmt: skip
    # the unit's history (registry show) follows every IMU and finds the same drift
    sections_of = history["sensors"][0]["sections"]
    assert list(sections_of) == ["accel", "gyro", "imu1 accel", "imu1 gyro", "imu2 accel",
                                 "imu2 gyro"]  # fmt: skip
    assert history["sensors"][0]["drifted"] == ["imu2 accel b_x"]


def test_a_lot_of_single_imus_is_as_before(tmp_path, tmp_path_factory):
    """Units of one IMU: no parameter names an IMU, each entry has exactly the documented
    fields."""
    template = make_template(tmp_path_factory)
    with open_registry(tmp_path / "r.db") as reg:
        for i in range(3):
            cal = unit(template, i)
            record_calibration(reg, cal, UnitInfo(cal.sensor, "P", "ONE"))
        stats = lot_statistics(reg, "ONE")
    fields = ["sensor", "name", "unit", "n", "mean", "std", "median", "mad", "min", "max",
              "outliers", "limit", "cpk", "beyond_limit"]  # fmt: skip
    assert stats["parameters"] and all(list(p) == fields for p in stats["parameters"])
    assert {p["sensor"] for p in stats["parameters"]} == {"accel", "gyro"}


def test_export_import_round_trips_a_set(tmp_path, set_template):
    """Records of sets exported and imported into another registry: the same sections per IMU
    (re-derived from each stored document), the same lot statistics."""
    limits = limits_from_dict(LIMITS, "test")
    with open_registry(tmp_path / "a.db") as a:
        for i in range(4):
            cal = set_unit(set_template, i)
            record_calibration(a, cal, UnitInfo(cal.sensor, "P", "SETS"),
                               acceptance=judge_calibration(cal, limits),
                               limits=limits)  # fmt: skip
        _recal(a, set_template, 1, "imu1", limits)
        with open(tmp_path / "a.jsonl", "w") as handle:
            assert export_records(a, handle) == 5
        before = lot_statistics(a, "SETS")
        original = list(iter_records(a))
    with open_registry(tmp_path / "b.db") as b:
        assert len(import_files(b, [tmp_path / "a.jsonl"], UnitInfo("")).recorded) == 5
        after = lot_statistics(b, "SETS")
        assert list(iter_records(b)) == original
    rows = section_rows(str(tmp_path / "b.db"))
    assert rows == section_rows(str(tmp_path / "a.db"))
    assert {r[1] for r in rows} == {None, "imu1", "imu2"} and len(rows) == 5 * 6
    assert after == before
    assert any(d.startswith("imu1 accel b_x") for d in after["drift"]["alarms"][0]["drifted"])


def test_a_registry_of_revision_0002_with_sets_is_migrated(tmp_path, set_template,
                                                           tmp_path_factory):  # fmt: skip
    """A registry written at revision 0002 (a set's other IMUs in its document only) holding
    two sets and a single IMU, opened by this imucal: migrated to 0003, every record read,
    the sets' other IMUs' sections derived from their documents exactly as recording them now
    gives (the same rows, the same lot statistics), the single IMU's unchanged."""
    single = unit(make_template(tmp_path_factory), 5)
    cals = [("S1", set_unit(set_template, 0)), ("S2", set_unit(set_template, 1)),
            ("ONE", single)]  # fmt: skip
    old = str(tmp_path / "old.db")
    write_as_0002(old, cals)
    with open_registry(old) as reg:
        with reg.read() as conn:
            assert MigrationContext.configure(conn).get_current_revision() == "0003"
        assert [r["serial"] for r in list_units(reg)] == ["ONE", "S1", "S2"]
        assert unit_report(reg, "S1")["calibrations"][0]["uid"] == "old1"
        migrated = lot_statistics(reg, "OLD")
    fresh = str(tmp_path / "fresh.db")
    with open_registry(fresh) as reg:
        for serial, cal in cals:
            record_calibration(reg, cal, UnitInfo(serial, lot="OLD"))
        recorded = lot_statistics(reg, "OLD")
    rows = section_rows(old)
    assert rows == section_rows(fresh)
    assert sum(1 for r in rows if r[1] is not None) == 2 * 4  # imu1, imu2: accel, gyro each
    assert all(r[6] for r in rows)  # every section with its figure rows (the reference's kept)
    assert migrated["parameters"] == recorded["parameters"]
    assert any(p.get("imu") == "imu2" and p["n"] == 2 for p in migrated["parameters"])
    assert store_module.HEAD == "0003"


def test_migration_0003_downgrades_without_losing_the_reference(tmp_path, set_template):
    """Down to 0002: the other IMUs' sections go, the reference's stay with every figure row
    (a batch copy of ``sections`` on SQLite would drop them with the old table); opened again,
    the registry is what it was."""
    path = str(tmp_path / "r.db")
    with open_registry(path) as reg:
        record_calibration(reg, set_unit(set_template, 0), UnitInfo("A"))
    before = section_rows(path)
    with open_registry(path) as reg, reg.write() as conn:
        config = Config()
        config.set_main_option("script_location",
                               str(Path(store_module.__file__).parent / "migrations"))
        config.attributes["connection"] = conn
        command.downgrade(config, "0002")
    engine = create_engine(f"sqlite:///{path}")
    with engine.connect() as conn:
        assert conn.exec_driver_sql("SELECT version_num FROM alembic_version").scalar() == "0002"
        kept = conn.exec_driver_sql("SELECT COUNT(*) FROM figures").scalar()
        assert conn.exec_driver_sql("SELECT COUNT(*) FROM sections").scalar() == 2
    engine.dispose()
    assert kept == sum(len(r[6]) for r in before if r[1] is None)
    assert section_rows(path) == before  # opened: migrated again, the others derived anew


# --------------------------------------------------------------------------------------------
# From the command line


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    """Two sets simulated (seeds 1, 2) and calibrated into a registry, the first twice."""
    folder = tmp_path_factory.mktemp("set-line")
    db = folder / "reg.db"
    for seed, serial in ((1, "U1"), (2, "U2")):
        session = folder / f"{serial}.h5"
        proc = run("simulate", "--imus", "3", "--plan", "random:12", "--seed", seed, "-o",
                   session)  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        proc = run("calibrate", session, "--registry", db, "--serial", serial, "--lot", "L")
        assert proc.returncode == 0, proc.stderr
    again = folder / "U1-again.h5"  # the same data under another name: another document
    shutil.copy(folder / "U1.h5", again)
    proc = run("calibrate", again, "--registry", db, "--serial", "U1", "--lot", "L")
    assert proc.returncode == 0, proc.stderr
    return {"folder": folder, "db": db}


def test_registry_lot_and_show_of_sets_from_the_command_line(line):
    stats = json.loads(run("registry", "lot", "L", "--registry", line["db"], "--json").stdout)
    assert stats["units"] == 2 and stats["calibrations"] == 3
    imus = {(p.get("imu"), p["sensor"]) for p in stats["parameters"]}
    assert imus == {(m, s) for m in (None, "imu1", "imu2") for s in ("accel", "gyro")}
    assert all(p["n"] == 2 for p in stats["parameters"] if p["name"] == "b_x")
    assert stats["drift"]["units_checked"] == 1 and stats["drift"]["alarms"] == []
    text = run("registry", "lot", "L", "--registry", line["db"]).stdout
    assert "\nimu1 accel\n" in text and "\nimu2 gyro\n" in text
    record = json.loads(run("registry", "show", "U1", "--registry", line["db"],
                            "--json").stdout)  # fmt: skip
    entry = record["history"]["sensors"][0]
    assert {"imu1 accel", "imu2 gyro"} <= set(entry["sections"])
    assert len(entry["sections"]["imu1 accel"]["rows"][0]["values"]) == 2
    assert entry["drifted"] == []  # the same data twice
    shown = run("registry", "show", "U1", "--registry", line["db"]).stdout
    assert "imu2 gyro: change from the reference calibration" in shown


def test_registry_export_import_of_sets_from_the_command_line(line, tmp_path):
    out = tmp_path / "all.jsonl"
    assert run("registry", "export", "--registry", line["db"], "-o", out).returncode == 0
    other = tmp_path / "other.db"
    assert run("registry", "import", out, "--registry", other).returncode == 0
    assert section_rows(str(other)) == section_rows(str(line["db"]))
    a, b = (json.loads(run("registry", "lot", "L", "--registry", db, "--json").stdout)
            for db in (line["db"], other))  # fmt: skip
    assert a == b and any("imu" in p for p in b["parameters"])
