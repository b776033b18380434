"""Benchmark ``adaptive``, its logs (issue 27.4): logs recorded for another reason calibrate
what they determine (issue 27.3).

Four simulated logs (the first on the adaptive capture's parts, the others on as many parts
of their own: :data:`SEED_STRIDE`), with 2-degree placement error and no labels and no
segments (a real log has neither: ``imucal calibrate`` finds the still periods itself):

- a vehicle on flat-ish ground: 4 stops of 10 s pitched 0, +3, -2 and +5 degrees about y, free
  turns about the vertical (45-180 degrees) between them;
- a vehicle on a hilly road (the plan of ``tests/test_partial_design.py``): 4 stops of 10 s
  pitched 0, +15, -10 and +25 degrees, two turns about z and one about y between them;
- a robot pitching about y: 5 still periods of 3 s, each reached by a pitch turn from the last
  (+20, -45, +70 and -30 degrees: pitched 0, 20, -25, 45 and 15 degrees).
- a vehicle yawing slowly on flat ground (issue 27): 3 stops of 10 s, between them turns about
  the vertical of +30 and -25 degrees over 10 s each (3 deg/s on average, 5.6 at the peak): a
  variance alone takes them for still periods, and their rate for the gyro's bias.

Each is written as a session file and calibrated on the product's path
(:func:`~imucal_cli.calibrate.batch.calibrate_file`, what ``imucal calibrate`` calls, with the
config a user of the part writes: ``[gyro] nominal_sensitivity`` = 16.4 LSB per deg/s, the
datasheet's), and its calibration JSON read back.  Per log, sensor and parameter: in how many
seeds it is measured (the rest: assumed, held at the nominal prior), the RMS error of the
measured values against the truth beside their median stated std (in mg, % of the gain, deg,
deg/s) and the ratio of the two, how often their 95 % intervals (1.96 std) hold the truth, and
in how many of those parts the section's std were scaled up by the data's scatter beyond their
noise (a warning of the calibration: a still period that moved, a drift).  Beside it, what each
log's design determines at all (the Fisher information's null space at the truth,
:mod:`imucal_cli.planning.determined`): the fit holds at the prior what the information leaves
undetermined, and may hold more (the gyro's matrix, which a few turns determine in part).

Checks: every log calibrates both sensors, and the measured parameters' 95 % intervals cover
at least 95 % less 3 binomial std, per sensor over the logs.  More than 97 % is said and not
failed: the nominal prior (gains 3 %, bias 60 mg) is wider than the simulated parts spread, and
the measured accelerometer parameters' std carry its share (docs/accuracy.md, "partial
designs").
"""

from __future__ import annotations

import hashlib
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from imucal_cli.calibrate.batch import calibrate_file
from imucal_cli.calibrate.gyro.partial import NAMES as GYRO_NAMES
from imucal_cli.errors import ImucalError
from imucal_cli.estimators.accel.partial import NAMES as ACCEL_NAMES
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.config import config_from_dict
from imucal_cli.formats.session import Session, write_session
from imucal_cli.planning import information as di
from imucal_cli.planning.determined import accel_determination, gyro_determination
from imucal_cli.simulate.play import simulate_plan

G0 = 9.80665
CREATED = "2026-01-01T00:00:00Z"

#: The simulated part's datasheet gyro gain, 16.4 LSB per deg/s, in counts per rad/s: what a
#: user of the part writes as ``[gyro] nominal_sensitivity``.
GYRO_NOMINAL = 16.4 * 180 / np.pi
CONFIG = {"gyro": {"nominal_sensitivity": GYRO_NOMINAL}}
NAMES = {"accel": ACCEL_NAMES, "gyro": GYRO_NAMES}

#: Log ``k`` runs on parts ``seed + SEED_STRIDE * k``: with the same seed two logs would share
#: the part and the noise, and their gyro biases (still periods of the same samples) would be
#: the same numbers twice.
SEED_STRIDE = 1000


def pitched(deg: float) -> list[float]:
    """The body's up (unit) when pitched ``deg`` degrees about y."""
    t = np.radians(deg)
    return [round(float(np.sin(t)), 4), 0.0, round(float(np.cos(t)), 4)]


def plan_toml(name: str, steps: list[tuple]) -> str:
    """A TOML plan: ``("static", up or None)`` and ``("rotation", axis, angle_deg or None)``
    steps (None: held where the unit is; a free angle)."""
    out = [f'name = "{name}"']
    for step in steps:
        out += ["[[step]]", f'kind = "{step[0]}"']
        if step[0] == "static" and step[1] is not None:
            out.append(f"up = {list(step[1])}")
        if step[0] == "rotation":
            out.append(f"axis = {list(step[1])}")
            if step[2] is not None:
                out.append(f"angle_deg = {step[2]}")
    return "\n".join(out) + "\n"


#: A vehicle's log on a hilly road: still on ground pitched 0, +15, -10 and +25 degrees
#: (about y), turns (driving) between them.
VEHICLE = plan_toml("vehicle", [
    ("static", pitched(0)), ("rotation", (0, 0, 1), None), ("static", pitched(15)),
    ("rotation", (0, 0, 1), None), ("static", pitched(-10)), ("rotation", (0, 1, 0), None),
    ("static", pitched(25))])  # fmt: skip

VEHICLE_FLAT = plan_toml("vehicle on flat-ish ground", [
    ("static", pitched(0)), ("rotation", (0, 0, 1), None), ("static", pitched(3)),
    ("rotation", (0, 0, 1), None), ("static", pitched(-2)), ("rotation", (0, 0, 1), None),
    ("static", pitched(5))])  # fmt: skip

ROBOT = plan_toml("robot pitching about y", [
    ("static", (0, 0, 1)), *[s for a in (20, -45, 70, -30)
                             for s in (("rotation", (0, 1, 0), a), ("static", None))]])  # fmt: skip


SLOW_YAW = plan_toml("vehicle yawing slowly", [
    ("static", (0, 0, 1)), ("rotation", (0, 0, 1), 30), ("static", None),
    ("rotation", (0, 0, 1), -25), ("static", None)])  # fmt: skip


@dataclass(frozen=True)
class Log:
    """A simulated log: its name in the tables, TOML plan, still periods' length (s) and the
    length of each move or turn (s; the simulator's ``move_s``, a turn's least)."""

    name: str
    plan: str
    hold_s: float
    move_s: float = 1.5


LOGS = (Log("vehicle, flat (0/+3/-2/+5 deg)", VEHICLE_FLAT, 10.0),
        Log("vehicle, hills (0/+15/-10/+25 deg)", VEHICLE, 10.0),
        Log("robot, pitching about y", ROBOT, 3.0),
        Log("vehicle, slow yaw (10 s turns)", SLOW_YAW, 10.0, move_s=10.0))  # fmt: skip


def simulate_log(folder: Path, text: str, seed: int, *, labels: bool = False,
                 segments: bool = True, **options) -> tuple[Session, object]:  # fmt: skip
    """Simulate the TOML plan ``text`` (written into ``folder``) on part ``seed``; the
    session's labels (each still period's ``up``) stripped unless ``labels``, its segments
    dropped unless ``segments`` (an imported log has none).  ``options``: of
    :func:`~imucal_cli.simulate.play.simulate_plan`."""
    plan = Path(folder) / f"plan-{hashlib.sha1(text.encode()).hexdigest()[:12]}.toml"
    if not plan.exists():
        plan.write_text(text)
    session, truth = simulate_plan(str(plan), seed=seed, created=CREATED, **options)
    if not segments:
        session = replace(session, segments=[])
    elif not labels:
        session = replace(session, segments=[replace(s, up=None) for s in session.segments])
    return session, truth


def truth_values(sensor: str, truth) -> dict[str, float]:
    """The truth of each parameter of a partial section (``status`` rows), in its units."""
    sec = getattr(truth, sensor)
    if sensor == "accel":
        angles = [sec.misalignment_deg[k] for k in ("xy", "xz", "yz")]
        values = np.r_[sec.bias, sec.sensitivity, angles]
    else:
        values = np.r_[sec.bias, np.asarray(sec.matrix, float).ravel()]
    return dict(zip(NAMES[sensor], map(float, values), strict=True))


def natural(sensor: str, name: str, truth) -> tuple[float, str]:
    """The factor from a parameter's JSON units (counts, counts per m/s^2, rad/s per count)
    to the table's, and the table's unit."""
    gains = np.asarray(getattr(truth, sensor).sensitivity, float)
    if name.startswith("b_"):
        g = gains["xyz".index(name[-1])]
        return (1000.0 / (g * G0), "mg") if sensor == "accel" else (np.degrees(1.0) / g, "deg/s")
    if name.startswith("s_"):
        return 100.0 / gains["xyz".index(name[-1])], "% of the gain"
    if name.startswith("a_"):
        return 1.0, "deg"
    return 100.0 * GYRO_NOMINAL, "% of 1/gain"  # a gyro matrix term, rad/s per count


@dataclass(frozen=True)
class Graded:
    """One parameter of one log's calibration against the truth (the table's units);
    ``scaled``: its section's std were scaled up by the data's scatter beyond their noise (a
    warning: a still period that moved, a drift)."""

    log: str
    seed: int
    sensor: str
    name: str
    measured: bool
    error: float
    std: float
    unit: str
    solver: str
    scaled: bool


def grade(log: str, seed: int, cal, truth) -> list[Graded]:
    """Each parameter of the calibration's accel and gyro sections (a row without ``status``:
    measured, as the solvers that determine the whole model write it)."""
    out = []
    for sensor in ("accel", "gyro"):
        sec = getattr(cal, sensor)
        if sec is None:
            continue
        truth_of = truth_values(sensor, truth)
        scaled = any("scaled by" in w for w in sec.warnings or [])
        for p in sec.parameters or []:
            if p.name not in truth_of or p.std is None:
                continue
            factor, unit = natural(sensor, p.name, truth)
            out.append(Graded(log, seed, sensor, p.name, p.status != "assumed",
                              (p.value - truth_of[p.name]) * factor, p.std * factor, unit,
                              sec.solver, scaled))  # fmt: skip
    return out


def calibrate_log(session: Session, folder: Path, tag: str):
    """The session written as a file and calibrated as ``imucal calibrate FILE --no-store``
    does with the part's config; its JSON read back."""
    path = folder / f"{tag}.h5"
    write_session(path, session, overwrite=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the log's warnings are the report's business
        _, out, _ = calibrate_file(path, config_from_dict(CONFIG), output=folder / f"{tag}.json",
                                   force=True, store=False)  # fmt: skip
    return read_calibration(out)


def run_logs(seeds, folder: Path, say: Callable[[str], None] = lambda _: None
             ) -> tuple[list[Graded], dict[str, list[str]], dict[str, tuple]]:  # fmt: skip
    """Every log on every part: the graded parameters, each log's failures (why), and each
    log's first design (for :func:`null_space_table`)."""
    graded: list[Graded] = []
    lost: dict[str, list[str]] = {log.name: [] for log in LOGS}
    designs: dict[str, tuple] = {}
    for k, log in enumerate(LOGS):
        for seed in (s + SEED_STRIDE * k for s in seeds):
            session, truth = simulate_log(folder, log.plan, seed, segments=False,
                                          hold_s=log.hold_s, move_s=log.move_s)  # fmt: skip
            if log.name not in designs:
                labelled, _ = simulate_log(folder, log.plan, seed, hold_s=log.hold_s,
                                           move_s=log.move_s)  # fmt: skip
                designs[log.name] = design_of_log(labelled, truth)
            try:
                cal = calibrate_log(session, folder, f"log{k}-{seed}")
            except ImucalError as exc:
                lost[log.name].append(f"part {seed}: {exc}")
                continue
            graded += grade(log.name, seed, cal, truth)
            for sensor in ("accel", "gyro"):
                if getattr(cal, sensor) is None:
                    why = (cal.left_out or {}).get(sensor)
                    lost[log.name].append(f"part {seed}: no {sensor} ({why})")
        say(f"  {log.name}: {len(seeds)} parts, {len(lost[log.name])} not calibrated")
    return graded, lost, designs


# --------------------------------------------------------------------------------------------
# The tables
# --------------------------------------------------------------------------------------------


def _cover(rows: list[Graded]) -> np.ndarray:
    return np.array([abs(r.error) <= 1.96 * r.std for r in rows], bool)


def fitted_rows(graded: list[Graded], n_seeds: int) -> tuple[list[tuple], list[str]]:
    """Per log, sensor and parameter measured in some seed: its row of the table; and per log
    and sensor, the line naming the parameters assumed in every seed."""
    rows, assumed = [], []
    for log in LOGS:
        for sensor in ("accel", "gyro"):
            mine = [g for g in graded if g.log == log.name and g.sensor == sensor]
            never = []
            for name in NAMES[sensor]:
                m = [g for g in mine if g.name == name and g.measured]
                if not m:
                    never.append(name)
                    continue
                err = np.array([g.error for g in m])
                std = np.array([g.std for g in m])
                rms, med = float(np.sqrt(np.mean(err**2))), float(np.median(std))
                hits = _cover(m)
                rows.append((log.name, sensor, name, f"{len(m)}/{n_seeds}",
                             f"{rms:.3g} {m[0].unit}", f"{med:.3g}", f"{rms / med:.2f}",
                             f"{hits.sum()}/{hits.size} ({100 * hits.mean():.0f} %)",
                             f"{sum(g.scaled for g in m)}"))  # fmt: skip
            if mine:
                solvers = sorted({g.solver for g in mine})
                assumed.append(f"  {log.name}, {sensor} ({', '.join(solvers)}): assumed in "
                               f"every part: {', '.join(never) or 'none'}")  # fmt: skip
    return rows, assumed


def logs_table(console: Console, graded: list[Graded], lost: dict[str, list[str]],
               n_seeds: int) -> dict[str, bool]:  # fmt: skip
    """Print the fitted rows; the checks (module notes)."""
    table = Table(title=f"Logs recorded for another reason, {n_seeds} parts each, no labels: "
                        "what `imucal calibrate` measures (the rest assumed at the nominal "
                        "prior)")  # fmt: skip
    for col in ("log", "sensor", "parameter", "measured in", "RMS error", "median std",
                "error/std", "95 % covering", "std scaled"):  # fmt: skip
        table.add_column(col, justify="left" if col in ("log", "sensor", "parameter") else "right")
    rows, assumed = fitted_rows(graded, n_seeds)
    for r in rows:
        table.add_row(*r)
    console.print(table)
    for line in assumed:
        console.print(line, highlight=False)
    checks = {}
    failed = [w for why in lost.values() for w in why]
    for w in failed[:5]:
        console.print(f"  not calibrated: {w}", highlight=False)
    checks[f"every log calibrated both sensors ({len(failed)} failures)"] = not failed
    for sensor in ("accel", "gyro"):
        hits = _cover([g for g in graded if g.sensor == sensor and g.measured])
        if not hits.size:
            checks[f"logs, {sensor}: no parameter measured"] = False
            continue
        floor = 0.95 - 3 * np.sqrt(0.95 * 0.05 / hits.size)
        cover = float(hits.mean())
        said = " (above 97 %: conservative)" if cover > 0.97 else ""
        checks[f"logs, {sensor}: measured intervals cover {100 * cover:.1f} % of {hits.size} "
               f">= {100 * floor:.1f} %{said}"] = cover >= floor  # fmt: skip
    return checks


def design_of_log(session: Session, truth) -> tuple:
    """A simulated log's design at its truth (its segments, the simulator's true ups and
    turns): the fit, poses, turns and noise of :mod:`imucal_cli.planning.information`."""
    fit = di.Fit(truth.accel.matrix, truth.accel.bias, truth.gyro.matrix, truth.gyro.bias,
                 truth.accel.gravity)  # fmt: skip
    statics = session.static_segments()
    rate = float(session.sample_rate_hz)
    poses = [di.Pose(np.asarray(u, float), s.n_samples)
             for u, s in zip(truth.accel.true_up, statics, strict=True)]  # fmt: skip
    by_name = {s.name: s for s in session.rotation_segments()}  # the plan's turns, not moves
    planned = [by_name[name] for name in truth.gyro.turn_segments]
    turns = [di.Turn(k, k + 1, np.asarray(axis, float), np.radians(angle), seg.n_samples / rate)
             for k, (axis, angle, seg) in enumerate(zip(truth.gyro.true_axis,
                                                        truth.gyro.true_angle_deg, planned,
                                                        strict=True))]  # fmt: skip

    def still_noise(raw: np.ndarray) -> float:
        return float(np.median([raw[s.start : s.stop].std(axis=0).mean() for s in statics]))

    noise = di.Noise(still_noise(session.accel), still_noise(session.gyro), rate)
    return fit, poses, turns, noise


def null_space_table(console: Console, designs: dict[str, tuple]) -> None:
    """What each log's design determines at all (the first part's), whatever a prior says."""
    table = Table(
        title="What each log determines (the Fisher information's null space at "
        "the truth, the first part; the gyro with the accelerometer known)"
    )
    for col in ("log", "sensor", "determined", "combinations of the rest"):
        table.add_column(col)
    for name, (fit, poses, turns, noise) in designs.items():
        for sensor, d in (("accel", accel_determination(fit, poses, noise)),
                          ("gyro", gyro_determination(fit, poses, turns, noise))):  # fmt: skip
            combos = "; ".join(" + ".join(f"{v:.2g} {k}" for k, v in c.items() if abs(v) > 0.1)
                               for c in d.combinations) or "-"  # fmt: skip
            table.add_row(name, sensor, ", ".join(d.determined) or "-", combos)
    console.print(table)


def run(console: Console, seeds) -> dict[str, bool]:
    """The logs' tables; their checks (module notes)."""
    with tempfile.TemporaryDirectory() as tmp:
        graded, lost, designs = run_logs(
            list(seeds), Path(tmp), say=lambda s: console.print(s, highlight=False)
        )
    checks = logs_table(console, graded, lost, len(seeds))
    null_space_table(console, designs)
    return checks
