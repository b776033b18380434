"""The registry on SQLite (issue 29.1, 29.4, 29.5): records whole, migrations from an older
schema, several writer processes at once, a writer killed mid-transaction, export/import, and
a lot's statistics against an independent computation."""

from __future__ import annotations

import hashlib
import json
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import create_engine, func, select, text

from bench.registry import serial_of
from imucal_cli.errors import ConfigError
from imucal_cli.formats.calibration import calibration_to_json
from imucal_cli.model.calibration import Calibration
from imucal_cli.registry import store as store_module
from imucal_cli.registry.lot import OUTLIER_Z, cpk, lot_statistics
from imucal_cli.registry.queries import iter_records, list_units, unit_report
from imucal_cli.registry.record import UnitInfo, record_calibration
from imucal_cli.registry.schema import calibrations, figures, metadata, sections, units
from imucal_cli.registry.store import RegistryError, open_registry
from imucal_cli.registry.transfer import export_records, import_files
from imucal_cli.use.limits import judge_calibration, limits_from_dict, unit_figures
from imucal_cli.use.report.history import build_history

from .cli_helpers import assert_one_line_error
from .registry_helpers import assert_whole, make_template, recorded_lines, unit, writer

LIMITS = {"product": {"name": "P"},
          "limits": {"accel": {"bias_max": 0.5, "misalignment_max_deg": 1.0,
                               "nominal_sensitivity": 835.0,
                               "gain_error_max_pct": 4.0}}}  # fmt: skip


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> dict:
    return make_template(tmp_path_factory)


def _script_config() -> Config:
    config = Config()
    folder = Path(store_module.__file__).parent / "migrations"
    config.set_main_option("script_location", str(folder))
    return config


def test_a_record_is_kept_whole_and_read_back(tmp_path, template):
    limits = limits_from_dict(LIMITS, "test")
    with open_registry(tmp_path / "r.db") as reg:
        cals = [unit(template, i) for i in range(3)]
        for i, cal in enumerate(cals):
            done = record_calibration(reg, cal, UnitInfo(cal.sensor, "P", "L1", "st",
                                                         "ann"),
                                      session_sha256="ab" * 32,
                                      acceptance=judge_calibration(cal, limits),
                                      limits=limits)  # fmt: skip
            assert done.new and done.serial == f"SN{i:06d}"
        again = record_calibration(reg, cals[0], UnitInfo(cals[0].sensor))
        assert not again.new  # the same calibration of the same unit: kept once
        rows = list_units(reg, lot="L1")
        assert [r["serial"] for r in rows] == ["SN000000", "SN000001", "SN000002"]
        assert all(r["calibrations"] == 1 and r["last_station"] == "st" for r in rows)
        record = unit_report(reg, "SN000001")
        meta = record["calibrations"][0]
        assert meta["session_sha256"] == "ab" * 32 and meta["operator"] == "ann"
        assert meta["verdict"] == judge_calibration(cals[1], limits).verdict
        assert meta["limits"] == limits.to_dict()
        exported = list(iter_records(reg))
        assert json.dumps(exported[1]["calibration"], indent=2) == calibration_to_json(cals[1])
        assert exported[1]["document_sha256"] == hashlib.sha256(
            calibration_to_json(cals[1]).encode()).hexdigest()  # fmt: skip
        with reg.read() as conn:  # every figure of the calibration, one row each
            n = conn.execute(select(func.count()).select_from(figures)).scalar_one()
        assert n == 3 * sum(len(s["rows"]) for s in unit_figures(cals[0]).values())


def test_bad_names_and_missing_registries_are_one_line_errors(tmp_path, template):
    cal = unit(template, 0)
    with open_registry(tmp_path / "r.db") as reg:
        for bad in ("", "a\x1b[31mb", "x" * 201):
            with pytest.raises(RegistryError):
                record_calibration(reg, cal, UnitInfo(bad))
        with pytest.raises(RegistryError, match="no unit"):
            unit_report(reg, "nobody")
    with pytest.raises(RegistryError, match="no such file"):
        open_registry(tmp_path / "missing.db", create=False)
    (tmp_path / "junk.db").write_bytes(b"not a database at all" * 100)
    with pytest.raises(RegistryError, match="not an imucal registry"):
        open_registry(tmp_path / "junk.db")
    with pytest.raises(RegistryError, match="only SQLite files and PostgreSQL"):
        open_registry("mysql://u@h/db")


def test_another_programs_database_is_never_written_into(tmp_path, template):
    """Audit: a SQLite file of another program (its own tables) was taken for a new registry:
    even ``registry list`` put it in WAL mode and added imucal's tables to it.  Now every
    command refuses it, the file byte for byte as it was; an empty file is a registry only for
    the commands that make one."""
    import sqlite3

    other = tmp_path / "app.db"
    with sqlite3.connect(other) as db:
        db.execute("CREATE TABLE users (name TEXT)")
    before = other.read_bytes()
    for create in (False, True):
        with pytest.raises(RegistryError, match=r"another program \(tables users\)"):
            open_registry(other, create=create)
    assert other.read_bytes() == before
    empty = tmp_path / "empty.db"
    empty.touch()
    with pytest.raises(RegistryError, match="an empty database, not an imucal registry"):
        open_registry(empty, create=False)
    assert empty.read_bytes() == b""
    with open_registry(empty) as reg:  # import and calibrate --registry make one in it
        record_calibration(reg, unit(template, 0), UnitInfo("U1"))
    with open_registry(empty, create=False) as reg:
        assert [u["serial"] for u in list_units(reg)] == ["U1"]


def test_a_full_disk_is_not_called_another_file(tmp_path):
    """Audit: on a full disk (here a file-size limit: the WAL's -shm file cannot grow), every
    registry command said 'disk I/O error (not an imucal registry?)' of a sound registry."""
    import resource
    import subprocess

    from .cli_helpers import IMUCAL

    open_registry(tmp_path / "r.db").close()
    for name in ("r.db-wal", "r.db-shm"):
        (tmp_path / name).unlink(missing_ok=True)

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (512, 512))

    proc = subprocess.run([IMUCAL, "registry", "list", "--registry", str(tmp_path / "r.db")],
                          capture_output=True, text=True, timeout=300, preexec_fn=limit)
    assert_one_line_error(proc, "a full disk")
    assert "not an imucal registry" not in proc.stderr


def test_without_psycopg_a_postgresql_registry_says_which_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "psycopg", None)  # import psycopg -> ImportError
    with pytest.raises(RegistryError, match=r"psycopg 3: pip install 'imucal-cli\[postgresql\]'"):
        open_registry("postgresql://u@127.0.0.1:1/db")


def test_a_registry_of_a_newer_imucal_is_refused(tmp_path):
    open_registry(tmp_path / "r.db").close()
    engine = create_engine(f"sqlite:///{tmp_path / 'r.db'}")
    with engine.begin() as conn:
        conn.execute(text("UPDATE alembic_version SET version_num = '0099'"))
    engine.dispose()
    with pytest.raises(RegistryError, match="revision 0099 is newer than this imucal knows"):
        open_registry(tmp_path / "r.db")


def test_migrations_match_the_schema(tmp_path):
    """The tables the migrations make are those schema.py declares (nothing missing, nothing
    different), and store.HEAD is the newest revision."""
    assert ScriptDirectory.from_config(_script_config()).get_current_head() == store_module.HEAD
    open_registry(tmp_path / "r.db").close()
    engine = create_engine(f"sqlite:///{tmp_path / 'r.db'}")
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), metadata)
    engine.dispose()
    assert diff == [], diff


def test_a_registry_of_the_older_schema_is_migrated_with_its_records(tmp_path, template):
    """A registry written at revision 0001 (no acceptance columns), with a unit in it, is
    brought to the newest schema when opened: the unit and its calibration are still there,
    read as not judged, and new records carry verdicts."""
    path = tmp_path / "old.db"
    engine = create_engine(f"sqlite:///{path}")
    cal = unit(template, 7)
    doc = calibration_to_json(cal)
    with engine.begin() as conn:
        config = _script_config()
        config.attributes["connection"] = conn
        command.upgrade(config, "0001")
        columns = {r[1] for r in conn.exec_driver_sql("PRAGMA table_info(calibrations)")}
        assert "verdict" not in columns  # really the old schema
        conn.execute(text("INSERT INTO units (id, serial, product, lot, first_recorded, "
                          "last_recorded) VALUES (1, 'OLD-1', 'P', 'L0', '2025-01-01T00:00:00Z', "
                          "'2025-01-01T00:00:00Z')"))  # fmt: skip
        conn.execute(text("INSERT INTO calibrations (id, uid, unit_id, created, recorded_at, "
                          "document_sha256) VALUES (1, 'u1', 1, :c, '2025-01-01T00:00:00Z', "
                          ":sha)"), {"c": cal.created, "sha": hashlib.sha256(doc.encode())
                                     .hexdigest()})  # fmt: skip
        conn.execute(text("INSERT INTO documents (calibration_id, document) VALUES (1, :d)"),
                     {"d": doc})  # fmt: skip
    engine.dispose()
    with open_registry(path) as reg:
        with reg.read() as conn:
            assert MigrationContext.configure(conn).get_current_revision() == store_module.HEAD
        rows = list_units(reg)
        assert [(r["serial"], r["last_verdict"]) for r in rows] == [("OLD-1", None)]
        assert unit_report(reg, "OLD-1")["calibrations"][0]["uid"] == "u1"
        limits = limits_from_dict(LIMITS, "test")
        new = unit(template, 8)
        verdict = judge_calibration(new, limits)
        done = record_calibration(reg, new, UnitInfo("NEW-1", lot="L0"), acceptance=verdict,
                                  limits=limits)  # fmt: skip
        assert done.verdict in ("pass", "fail")
        assert {r["serial"]: r["last_verdict"] for r in list_units(reg)}["NEW-1"] == done.verdict


def test_downgrade_to_0001_keeps_every_record(tmp_path, template):
    """Down to 0001 (``alembic downgrade``): the acceptance columns go, every unit, document,
    section and figure row stays (a batch copy of ``calibrations`` on SQLite, foreign keys on,
    would drop the old table and cascade to them); opened again, the registry is migrated up
    and reads as before, its verdicts gone with their columns."""
    path = tmp_path / "r.db"
    limits = limits_from_dict(LIMITS, "test")
    with open_registry(path) as reg:
        for i in range(2):
            cal = unit(template, 20 + i)
            record_calibration(reg, cal, UnitInfo(f"D-{i}", lot="L"),
                               acceptance=judge_calibration(cal, limits), limits=limits)

    def counts():
        engine = create_engine(f"sqlite:///{path}")
        with engine.connect() as conn:
            out = {t: conn.exec_driver_sql(f"SELECT COUNT(*) FROM {t}").scalar()
                   for t in ("units", "calibrations", "documents", "sections", "figures")}
            cols = {r[1] for r in conn.exec_driver_sql("PRAGMA table_info(calibrations)")}
        engine.dispose()
        return out, cols

    before, cols = counts()
    assert before["figures"] > 0 and "verdict" in cols
    with open_registry(path) as reg, reg.write() as conn:
        config = _script_config()
        config.attributes["connection"] = conn
        command.downgrade(config, "0001")
    after, cols = counts()
    assert after == before
    assert not cols & {"verdict", "failed", "limits"}
    with open_registry(path) as reg:
        assert [r["serial"] for r in list_units(reg)] == ["D-0", "D-1"]
        assert unit_report(reg, "D-1")["calibrations"][0]["uid"]
    assert counts()[0] == before


def _writers_at_once(url: str, template: dict, per: int, make_first: bool) -> None:
    """4 writer processes of ``per`` units each at once: everything they recorded is there."""
    if make_first:
        open_registry(url).close()
    procs = [writer(url, template["path"], per * i, per) for i in range(4)]
    expected = {}
    for proc, lines in procs:
        assert proc.wait(timeout=600) == 0
        expected.update(recorded_lines(lines.text().splitlines()))
    recal = sum(1 for i in range(4 * per) if i % 50 == 1)  # bench.registry.plan: twice
    assert len(expected) == 4 * per + recal
    assert_whole(url, expected)


def test_four_writer_processes_at_once_lose_nothing(tmp_path, template):
    """Also when none of them finds the registry made: they create and migrate it at once."""
    _writers_at_once(str(tmp_path / "r.db"), template, 6, make_first=False)


@pytest.mark.slow
def test_four_writer_processes_at_once_lose_nothing_many(tmp_path, template):
    _writers_at_once(str(tmp_path / "r.db"), template, 100, make_first=True)


@pytest.mark.parametrize("make_first", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_a_writer_killed_mid_transaction_leaves_the_registry_whole(tmp_path, template,
                                                                   make_first):  # fmt: skip
    """SIGKILL while a record is half written (its calibration row in, its figures not): the
    half record is not there, the ones before are whole, the file passes SQLite's integrity
    check, and the next writer writes (the lock died with the process)."""
    url = str(tmp_path / "r.db")
    if make_first:
        open_registry(url).close()
    proc, lines = writer(url, template["path"], 10, 10, "L", "--hang-after", "4")  # no re-cal
    lines.wait_for(lambda line: line.startswith("mid-write"))
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    before = recorded_lines(lines.text().splitlines())
    assert len(before) == 4
    assert_whole(url, before)
    engine = create_engine(f"sqlite:///{url}")
    with engine.connect() as conn:
        assert conn.exec_driver_sql("PRAGMA integrity_check").scalar() == "ok"
    engine.dispose()
    proc, lines = writer(url, template["path"], 110, 3)
    assert proc.wait(timeout=120) == 0
    after = recorded_lines(lines.text().splitlines())
    assert len(after) == 3
    assert_whole(url, {**before, **after})


def test_export_then_import_into_another_registry_recreates_every_record(tmp_path, template):
    limits = limits_from_dict(LIMITS, "test")
    with open_registry(tmp_path / "a.db") as a:
        for i in range(4):
            cal = unit(template, i)
            record_calibration(a, cal, UnitInfo(cal.sensor, "P", "L1", "s1", "o"),
                               session_sha256=f"{i:064d}",
                               acceptance=judge_calibration(cal, limits),
                               limits=limits)  # fmt: skip
        out = tmp_path / "a.jsonl"
        with open(out, "w") as handle:
            assert export_records(a, handle) == 4
        original = list(iter_records(a))
    with open_registry(tmp_path / "b.db") as b:
        result = import_files(b, [out], UnitInfo(""))
        assert len(result.recorded) == 4 and not result.skipped
        assert list(iter_records(b)) == original  # uids, times, verdicts, limits, documents
        again = import_files(b, [out], UnitInfo(""))
        assert len(again.skipped) == 4 and not again.recorded


def test_import_of_calibration_files_judges_them(tmp_path, template):
    cal = unit(template, 3)
    path = tmp_path / "c.json"
    path.write_text(calibration_to_json(cal))
    strict = limits_from_dict({"limits": {"accel": {"residual_rms_max": 1e-9}}}, "strict")
    with open_registry(tmp_path / "r.db") as reg:
        result = import_files(reg, [path], UnitInfo("", lot="L9", station="old"), limits=strict)
        assert [(r.serial, r.verdict) for r in result.recorded] == [("SN000003", "fail")]
        assert list_units(reg)[0]["lot"] == "L9"


def _largest_figures(doc: dict, sensor: str, nominal: float) -> dict[str, float]:
    """Each limited figure's largest value over the axes, computed here from the calibration
    JSON as the product file's comments define it (the limit's key -> value)."""
    sec = doc[sensor]
    m, b = np.asarray(sec["matrix"]), np.asarray(sec["bias"])
    if sensor == "accel":
        sigma = np.asarray(sec["noise"]["per_sample_std"])
    else:
        sigma = np.full(3, sec["gyro_noise_raw"])
    out = {
        "bias_max": np.abs(m @ b).max(),  # the reading at zero input, output units
        "gain_error_max_pct": 100 * np.abs(np.asarray(sec["sensitivity"]) / nominal - 1).max(),
        "misalignment_max_deg": max(abs(v) for v in sec["misalignment_deg"].values()),
        "noise_max": np.sqrt((m**2) @ sigma**2).max(),  # raw white noise through the matrix
        "residual_rms_max": sec["residual_rms"],
    }
    if sec.get("rms_loo") is not None:
        out["held_out_rms_max"] = sec["rms_loo"]
    return out


@pytest.mark.parametrize("sensor, nominal", [("accel", 835.0), ("gyro", 939.7)])
def test_every_limit_bounds_its_figure(template, sensor, nominal):
    """Each key of a [limits.SENSOR] table, 1 % above the unit's figure (computed here) passes,
    1 % below fails naming the figure; a limit whose figure the calibration does not state
    (the gyro's held-out RMS) fails saying so."""
    cal = unit(template, 0)
    doc = json.loads(calibration_to_json(cal))
    figures = _largest_figures(doc, sensor, nominal)
    names = {"bias_max": "bias", "gain_error_max_pct": "gain error",
             "misalignment_max_deg": "misalignment", "noise_max": "noise",
             "residual_rms_max": "residual rms", "held_out_rms_max": "held-out rms"}  # fmt: skip
    for key, value in figures.items():
        for factor, passes in ((1.01, True), (0.99, False)):
            table = {key: value * factor, "nominal_sensitivity": nominal}
            limits = limits_from_dict({"limits": {sensor: table}}, "p.toml")
            verdict = judge_calibration(cal, limits)
            assert verdict.passed is passes, (key, factor, verdict.failed)
            largest = max(verdict.checks, key=lambda c: abs(c.value))
            assert largest.value is not None
            assert abs(largest.value) == pytest.approx(value, rel=1e-9), key
            if not passes:
                assert len(verdict.failed) >= 1
                assert all(line.startswith(f"{sensor} ") for line in verdict.failed)
                assert names[key] in verdict.failed[0], (key, verdict.failed)
    if sensor == "gyro":
        limits = limits_from_dict({"limits": {"gyro": {"held_out_rms_max": 1.0}}}, "p.toml")
        verdict = judge_calibration(cal, limits)
        assert not verdict.passed and "not stated" in verdict.failed[0]
    limits = limits_from_dict({"limits": {"mag": {"bias_max": 1.0}}}, "p.toml")
    assert judge_calibration(cal, limits).failed == ["mag bias: not calibrated (limit 1)"]


def test_limits_files_are_checked():
    for bad, words in [({"limits": {}}, "no limits"),
                       ({"limits": {"accel": {"bias_max": -1}}}, "positive"),
                       ({"limits": {"accel": {"bias_maximum": 1}}}, "unknown key"),
                       ({"limits": {"baro": {"bias_max": 1}}}, "unknown sensor"),
                       ({"limits": {"accel": {"gain_error_max_pct": 1}}}, "nominal_sensitivity"),
                       ({"product": {"name": 3}, "limits": {"accel": {"bias_max": 1}}},
                        "text")]:  # fmt: skip
        with pytest.raises(ConfigError, match=words):
            limits_from_dict(bad, "f.toml")


# --------------------------------------------------------------------------------------------
# A lot


def _lot(tmp_path, template, n=40):
    """A lot of ``n`` units: unit 3 stands apart (accel bias x), units 1 and 2 re-calibrated,
    unit 1 drifted (12 std), unit 2 not."""
    limits = limits_from_dict(LIMITS, "test")
    reg = open_registry(tmp_path / "lot.db")
    cals = {}
    for i in range(n):
        cal = unit(template, i, apart=i == 3)
        cals[i] = [cal]
        record_calibration(reg, cal, UnitInfo(cal.sensor, "P", "LOT"),
                           acceptance=judge_calibration(cal, limits), limits=limits)  # fmt: skip
    for i, drift in ((1, 12.0), (2, 0.0)):
        cal = unit(template, i, drift=drift, created="2026-06-01T00:00:00Z")
        cals[i].append(cal)
        record_calibration(reg, cal, UnitInfo(cal.sensor, "P", "LOT"),
                           acceptance=judge_calibration(cal, limits), limits=limits)  # fmt: skip
    return reg, cals, limits


def test_lot_statistics_against_an_independent_computation(tmp_path, template):
    reg, cals, limits = _lot(tmp_path, template)
    with reg:
        stats = lot_statistics(reg, "LOT")
    assert stats["units"] == 40 and stats["calibrations"] == 42
    assert stats["limits"] == limits.to_dict()  # the recorded limits by default
    latest = [c[-1] for _, c in sorted(cals.items())]
    by_name = {(p["sensor"], p["name"]): p for p in stats["parameters"]}
    # bias x in m/s^2: matrix @ bias of each unit's latest calibration, computed here
    x = np.array([(np.asarray(c.accel.matrix) @ np.asarray(c.accel.bias))[0] for c in latest])
    p = by_name[("accel", "bias x")]
    assert p["n"] == 40 and p["mean"] == pytest.approx(x.mean(), rel=1e-12)
    assert p["std"] == pytest.approx(x.std(ddof=1), rel=1e-9)
    mu, sd = x.mean(), x.std(ddof=1)
    assert p["cpk"] == pytest.approx(min(0.5 - mu, mu + 0.5) / (3 * sd), rel=1e-9)
    assert p["beyond_limit"] == int((np.abs(x) > 0.5).sum())
    # the unit planted 40 lot-std away stands apart, by the modified z-score, and only it
    mad = 1.4826 * np.median(np.abs(x - np.median(x)))
    expected = {f"SN{i:06d}" for i in np.flatnonzero(np.abs(x - np.median(x)) / mad > OUTLIER_Z)}
    assert {o["serial"] for o in p["outliers"]} == expected == {"SN000003"}
    # gain error from the sensitivities and the limits' nominal, % per axis
    g = np.array([100 * (c.accel.to_dict()["sensitivity"][1] / 835.0 - 1) for c in latest])
    assert by_name[("accel", "gain error y")]["mean"] == pytest.approx(g.mean(), rel=1e-9)
    # drift: the history's own test on each re-calibrated unit gives the same alarms
    alarms = {a["serial"]: a for a in stats["drift"]["alarms"]}
    assert stats["drift"]["units_checked"] == 2 and set(alarms) == {"SN000001"}
    history = build_history(cals[1])
    assert history["sensors"][0]["drifted"] == ["accel b_x"]
    assert alarms["SN000001"]["drifted"][0].startswith("accel b_x (z = +")
    assert build_history(cals[2])["sensors"][0]["drifted"] == []


def _without(cal, *, gyro: bool = True, accel_parameter: str | None = None):
    """``cal`` without its gyro section, or without one of its accel parameters: a section
    of another layout (other figures packed)."""
    doc = cal.to_dict()
    if not gyro:
        doc.pop("gyro")
    if accel_parameter is not None:
        doc["accel"]["parameters"] = [p for p in doc["accel"]["parameters"]
                                      if p["name"] != accel_parameter]  # fmt: skip
    return Calibration.from_dict(doc, source=cal.sensor)


def test_lot_of_several_layouts_against_the_figures_table(tmp_path, template):
    """The lot unpacks the sections' packed figures a matrix per sensor and layout: in a lot
    whose units have different figures (some without a gyro section, some whose accel
    section lacks b_z, a unit re-calibrated into another layout, one calibrated before its
    first record's time), every parameter is over exactly the units whose latest calibration
    has it, the same as the ``figures`` table (one row per figure) gives, read here on its own
    with SQL."""
    reg = open_registry(tmp_path / "mixed.db")
    for i in range(30):
        cal = unit(template, i, apart=i == 3)
        if i % 5 == 1:
            cal = _without(cal, gyro=False)
        elif i % 7 == 2:
            cal = _without(cal, accel_parameter="b_z")
        record_calibration(reg, cal, UnitInfo(cal.sensor, "P", "MIX"))
    for i, created, change in ((4, "2026-06-01T00:00:00Z", {"accel_parameter": "b_z"}),
                               (7, "2026-06-01T00:00:00Z", {"gyro": False}),
                               (8, "2025-01-01T00:00:00Z", {}),  # older: not the latest
                               (9, "2026-06-01T00:00:00Z", {})):  # fmt: skip
        record_calibration(reg, _without(unit(template, i, created=created), **change),
                           UnitInfo(serial_of(i), "P", "MIX"))  # fmt: skip
    with reg:
        stats = lot_statistics(reg, "MIX")
        with reg.read() as conn:
            cal_rows = conn.execute(
                select(calibrations.c.id, units.c.serial, calibrations.c.created)
                .join(units, units.c.id == calibrations.c.unit_id).where(units.c.lot == "MIX")
            ).all()  # fmt: skip
            latest = {}
            for cal_id, serial, _ in sorted(cal_rows, key=lambda r: (r[2], r[0])):
                latest[serial] = cal_id
            rows = conn.execute(
                select(sections.c.calibration_id, sections.c.sensor, figures.c.name,
                       figures.c.unit, figures.c.value)
                .join(sections, sections.c.id == figures.c.section_id)
                .where(sections.c.calibration_id.in_(list(latest.values())))
            ).all()  # fmt: skip
    serial_of_cal = {cal_id: serial for serial, cal_id in latest.items()}
    expected: dict[tuple, dict[str, float]] = {}
    for cal_id, sensor, name, unit_, value in rows:
        if value is not None and np.isfinite(value):
            expected.setdefault((sensor, name, unit_), {})[serial_of_cal[cal_id]] = value
    got = {(p["sensor"], p["name"], p["unit"]): p for p in stats["parameters"]}
    assert set(got) == set(expected)
    assert stats["units"] == 30 and stats["calibrations"] == 34
    n_of = {key[:2]: p["n"] for key, p in got.items()}
    # latest without b_z: units 2 and 23 (i % 7 == 2), 4 (re-calibrated so); 9 re-calibrated
    # with it; without a gyro: 1, 6, 11, 16, 21, 26 (i % 5 == 1), 7 (re-calibrated so)
    assert n_of[("accel", "b_z")] == 27 and n_of[("accel", "b_x")] == 30
    assert n_of[("gyro", "b_x")] == 23
    for key, by_serial in expected.items():
        x = np.array([by_serial[s] for s in latest if s in by_serial])  # the units' order
        p = got[key]
        assert p["n"] == x.size, key
        assert p["mean"] == pytest.approx(x.mean(), rel=1e-12, abs=1e-15), key
        assert p["median"] == pytest.approx(np.median(x), rel=1e-12, abs=1e-15), key
        assert (p["min"], p["max"]) == (x.min(), x.max()), key
        if x.size > 1:
            assert p["std"] == pytest.approx(x.std(ddof=1), rel=1e-9, abs=1e-15), key
        for o in p["outliers"]:
            assert by_serial[o["serial"]] == o["value"], key
    assert {o["serial"] for o in got[next(k for k in got if k[:2] == ("accel", "bias x"))][
        "outliers"]} == {"SN000003"}  # fmt: skip
    assert stats["drift"]["units_checked"] == 4
    # the re-calibrations measure the same part again (the same draw), into another layout
    # (4: no b_z; 7: no gyro), or the same (8, 9): the parameters both calibrations hold are
    # compared and none moved
    assert stats["drift"]["alarms"] == []


def test_cpk_of_one_sided_and_two_sided_limits():
    x = np.array([1.0, 2.0, 3.0])
    assert cpk(x, 5.0, two_sided=False) == pytest.approx((5 - 2) / 3)
    assert cpk(x, 5.0, two_sided=True) == pytest.approx((5 - 2) / 3)
    assert cpk(-x, 5.0, two_sided=True) == pytest.approx((5 - 2) / 3)
    assert cpk(x + 10, 5.0, two_sided=True) < 0  # the mean beyond the limit
    assert cpk(np.array([1.0]), 5.0, True) is None


def test_no_such_lot(tmp_path, template):
    reg, _, _ = _lot(tmp_path, template, n=3)
    with reg, pytest.raises(RegistryError, match="no unit in lot"):
        lot_statistics(reg, "other")

