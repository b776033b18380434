"""`imucal calibrate`: run the configured solvers on a session and write the calibration."""

from __future__ import annotations

import json
import resource
import time
from functools import partial
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn
from rich.table import Table

from imucal_cli.calibrate.accel.partial import calibration_prior
from imucal_cli.calibrate.batch import (
    Figures,
    Stored,
    calibrate_file,
    calibrate_many,
    warn_other_unit,
)
from imucal_cli.calibrate.gyro.partial import calibration_prior as gyro_calibration_prior
from imucal_cli.calibrate.session import load_accel, load_gyro
from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import calibration_to_json
from imucal_cli.formats.config import load_config, validate
from imucal_cli.model.accel import AccelCalibration
from imucal_cli.model.gyro import GyroCalibration
from imucal_cli.model.mag import Readings
from imucal_cli.model.parts import By

from .acceptance import REJECTED, prepare, print_lines, worst
from .app import app
from .console import Piece, make_console, print_json, print_line
from .imu_set import set_lines, set_warnings
from .options import gravity_option, json_option, output_option, registry_option, session_argument


@app.command()
def calibrate(
    sessions: list[Path] = session_argument(
        "Session file(s) (.h5) to calibrate; several: each to SESSION.cal.json, one summary "
        "table."
    ),
    config: Path | None = typer.Option(
        None, "--config", "-c", metavar="FILE.toml",
        help="TOML config choosing solvers and options (every key: docs/config.md).",
    ),  # fmt: skip
    output: Path | None = output_option(
        "FILE.json", "Calibration JSON to write [default: SESSION with .cal.json]."
    ),
    model: str | None = typer.Option(
        None, "--model", metavar="9|12",
        help="Gravity solver model: 9 (triangular, eqs. 3-8) or 12 (full matrix "
        "aligned to the labelled up directions). Overrides [accel.gravity] model.",
    ),  # fmt: skip
    gravity: float | None = gravity_option(
        "Local gravity in m/s^2 [default: the session's, else 9.80665]."
    ),
    force: bool = typer.Option(
        False, "--force",
        help="Replace an existing OUTPUT, and save a result that fails the physical-sense "
        "checks (with warnings).",
    ),  # fmt: skip
    store: bool = typer.Option(
        True, "--store/--no-store",
        help="Also store the calibration under the session's /calibrations.",
    ),  # fmt: skip
    accel: Path | None = typer.Option(
        None, "--accel", metavar="CAL.json",
        help="Use this earlier accelerometer calibration (a calibration JSON, or a session .h5 "
        "with a stored one) instead of calibrating the accelerometer: a gyro-only session.",
    ),  # fmt: skip
    prior: Path | None = typer.Option(
        None, "--prior", metavar="CAL.json",
        help="An earlier accelerometer calibration of this unit (a calibration JSON, or a "
        "session .h5 with a stored one) as the prior of a session whose poses cannot fix the "
        "whole model (a vehicle's log, poses on one or two faces): what they do not determine "
        "is held at its values and std instead of the nominal ones, and marked assumed; its "
        "gyro's matrix likewise, for a gyro whose turns cannot determine it (the bias is "
        "measured by the still periods).",
    ),  # fmt: skip
    warmup: list[Path] | None = typer.Option(
        None, "--warmup", metavar="WARMUP.h5",
        help="A still recording of the same unit through a warm-up or cool-down (repeatable): "
        "its temperature curve gives each channel's bias as a polynomial in temperature "
        "(bias_tempco; at least 10 C of span). Capture one with --plan warmup:MINUTES.",
    ),  # fmt: skip
    also: list[Path] | None = typer.Option(
        None, "--with", metavar="OTHER.h5",
        help="Another session of the same unit at another temperature (repeatable): its still "
        "periods and turns join SESSION's, so that the temperature model spans them all.",
    ),  # fmt: skip
    jobs: int = typer.Option(
        1, "--jobs", "-j", metavar="N", help="Several sessions: worker processes (0: one per CPU)."
    ),
    json_output: bool = json_option(
        "Print the result as JSON on stdout (nothing else): where it was written and the "
        "calibration itself; several sessions: one entry each (schemas: docs/commands.md)."
    ),
    limits: Path | None = typer.Option(
        None, "--limits", metavar="PRODUCT.toml",
        help="Judge the unit against its product's acceptance limits ([limits.accel] bias_max, "
        "gain_error_max_pct, misalignment_max_deg, noise_max, residual_rms_max, "
        f"held_out_rms_max; docs/registry.md): pass, or fail naming the figures (exit {REJECTED})."
    ),  # fmt: skip
    registry: str | None = registry_option(
        "Also record the calibration in this registry (a SQLite file, made if missing, or "
        "postgresql+psycopg://user@host/db): serial, product, lot, station, operator, the "
        "session's content hash, the verdict and the whole calibration."
    ),
    serial: str | None = typer.Option(
        None, "--serial", metavar="SERIAL",
        help="--registry: the unit's serial [default: the session's sensor].",
    ),
    product: str | None = typer.Option(
        None, "--product", metavar="NAME",
        help="--registry: the unit's product [default: the --limits file's].",
    ),
    lot: str | None = typer.Option(
        None, "--lot", metavar="LOT", help="--registry: the unit's lot."
    ),
    station: str | None = typer.Option(
        None, "--station", envvar="IMUCAL_STATION", metavar="NAME",
        help="--registry: the calibration station (or $IMUCAL_STATION).",
    ),  # fmt: skip
    operator: str | None = typer.Option(
        None, "--operator", envvar="IMUCAL_OPERATOR", metavar="NAME",
        help="--registry: who calibrated (or $IMUCAL_OPERATOR).",
    ),  # fmt: skip
) -> None:
    """Calibrate the sensors of SESSION the config asks for and write a calibration JSON.

    A sensor the session cannot determine (too few turns for the gyro, too little of the sphere
    for the magnetometer) is left out, saying why and what to capture, and the others are
    saved: a partial calibration ("complete": false and "left_out" in the JSON).  A solver
    named in the config makes its sensor required.

    Exit status: 0 saved (complete or partial); 2 bad input, nothing saved (unreadable file,
    bad config, a session that cannot determine any sensor, or a required one; OUTPUT exists
    without --force or is the session); 1 the solver did not converge or the result is outside
    physical sense (not saved unless --force), or saved but not stored in the session (the
    reason is printed; or, with --registry, not recorded); 4 saved, and outside the limits of
    --limits (the unit is rejected: the failed figures are named; recorded with --registry).
    Several sessions: the worst of theirs (2, then 1, then 4).
    """
    cfg = _config(config, model, gravity)
    unit = prepare(sessions, registry=registry, limits=limits, serial=serial, product=product,
                   lot=lot, station=station, operator=operator)  # fmt: skip
    try:
        _calibrate(sessions, cfg, config, output, force, store, accel, warmup, also, jobs,
                   json_output, unit, prior)  # fmt: skip
    finally:
        if unit is not None:
            unit.close()


def _calibrate(sessions, cfg, config, output, force, store, accel, warmup, also, jobs,
               json_output, unit, prior_path=None) -> None:  # fmt: skip
    """``calibrate`` once the options are checked (``unit``: the limits and the registry)."""
    accel_cal = None
    if accel is not None:
        accel_cal = load_accel(accel)
    for session in sessions:
        warn_other_unit(session, accel, "--accel")
        warn_other_unit(session, prior_path, "--prior")
    prior = gyro_prior = None
    if prior_path is not None:
        if accel is not None:
            raise InputError("--prior and --accel exclude each other: --accel uses an earlier "
                             "calibration as it is, --prior lets this session's poses refine it")
        prior = calibration_prior(load_accel(prior_path), str(prior_path))
        gyro = load_gyro(prior_path)
        if gyro is not None:
            gyro_prior = gyro_calibration_prior(gyro, str(prior_path))
    if len(sessions) > 1:
        _one_file_options(output, warmup, also, prior_path)
        raise typer.Exit(_many(sessions, cfg, jobs, force, store, json_output, accel_cal, unit))
    inputs = [config, accel, prior_path, *(warmup or []), *(also or [])]
    _one(sessions[0], cfg, output, force, store, json_output, accel_cal, inputs=inputs,
         warmup=warmup, also=also, unit=unit, prior=prior, gyro_prior=gyro_prior)  # fmt: skip


def _one_file_options(output: Path | None, warmup, also, prior=None) -> None:
    """Refuse the options that go with one SESSION when several are given."""
    if prior is not None:
        raise InputError("--prior goes with one SESSION (calibrate each log of the unit on "
                         "its own)")  # fmt: skip
    if warmup or also:
        raise InputError("--warmup and --with go with one SESSION (give the other sessions of "
                         "the unit with --with)")  # fmt: skip
    if output is not None:
        raise InputError("--output names one file: with several sessions each goes to "
                         "SESSION.cal.json")  # fmt: skip


def _one(session: Path, cfg, output: Path | None, force: bool, store: bool, json_output: bool,
         accel, *, inputs: list, warmup, also, unit=None, prior=None,
         gyro_prior=None) -> None:  # fmt: skip
    """Calibrate one session, write (and store) it, judge and record it (``unit``), and say
    what came out."""
    cal, out, stored = calibrate_file(
        session, cfg, output=output, force=force, store=store, inputs=inputs, accel=accel,
        warmup=warmup, also=also, prior=prior, gyro_prior=gyro_prior,
    )  # fmt: skip
    # Saved: from here on the exit status is 0, 4 (rejected) or 1 with the reason (never 2).
    code, doc, lines = (0, {}, []) if unit is None else unit.finish(cal, session)
    if json_output:
        print_json({**_result_json(cal, out, stored), **doc})
    else:
        _summary(partial(print_line, make_console()), cal, f"{out}{stored.words()}")
        print_lines(lines)
    if stored.failed:
        print_line(
            make_console(stderr=True),
            f"imucal: error: saved {out} but could not store it in the session "
            f"({stored.why_not}); pass --no-store not to store it"
        )
        code = code or 1
    if code:
        raise typer.Exit(code)


def _config(config: Path | None, model: str | None, gravity: float | None):
    """The config file (or the defaults) with ``--model`` and ``--gravity`` over it, checked."""
    cfg = load_config(config)
    if model is not None:
        cfg.accel.gravity.model = model
    if gravity is not None:
        cfg.gravity = gravity
    validate(cfg, "command line" if config is None else str(config))
    return cfg


def _result_json(cal, out: Path, stored: Stored) -> dict:
    """The ``imucal-calibrate`` document (docs/commands.md)."""
    warnings = [w for s in (cal.accel, cal.gyro, cal.mag) if s
                for w in s.warnings or []]  # fmt: skip
    warnings += set_warnings(cal)
    left_out = dict(cal.left_out or {})
    warnings += list(left_out.values())
    return {"format": "imucal-calibrate", "format_version": 1, "output": str(out),
            "stored": stored.where, "not_stored": stored.why_not,
            "complete": not left_out and cal.complete is not False,
            "left_out": left_out, "warnings": warnings,
            "calibration": json.loads(calibration_to_json(cal))}  # fmt: skip


def _many(
    sessions: list[Path], cfg, jobs: int, force: bool, store: bool, json_output: bool = False,
    accel=None, unit=None,
) -> int:
    """Calibrate several sessions with a progress bar; one table; the worst exit status."""
    console = make_console(stderr=json_output)
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    c_children = usage.ru_utime + usage.ru_stime
    t0, c0 = time.perf_counter(), time.process_time()
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task("calibrating", total=len(sessions))
        results = calibrate_many(
            sessions, cfg, jobs=jobs, force=force, store=store, accel=accel,
            progress=lambda _r: bar.advance(task),
        )  # fmt: skip
    wall = time.perf_counter() - t0
    after = {}  # session -> (code, doc, lines): judged and recorded (--limits, --registry)
    if unit is not None:
        after = {r.session: unit.finish_saved(Path(r.session), Path(r.output))
                 for r in results if r.exit_code == 0 and r.output}  # fmt: skip
    codes = [after[r.session][0] if r.session in after else r.exit_code for r in results]
    if json_output:
        rows = [{"session": r.session, "exit_code": code, "error": r.error,
                 "figures": r.figures.to_dict() if r.figures else {},
                 **after.get(r.session, (0, {}, []))[1]}
                for r, code in zip(results, codes, strict=True)]  # fmt: skip
        print_json({"format": "imucal-calibrate-many", "format_version": 1, "results": rows})
        return worst(codes)
    console.print(_results_table(len(sessions), results))
    failed = [r for r in results if r.exit_code]
    for r in failed:
        console.print(f"[red]failed[/]: {escape(r.error or '')}", soft_wrap=True)
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = time.process_time() - c0 + usage.ru_utime + usage.ru_stime - c_children
    console.print(
        f"{len(results) - len(failed)} saved, {len(failed)} failed in {wall:.1f} s, "
        f"{cpu:.1f} s CPU ({len(results) / max(cpu, 1e-9):.1f} sessions per CPU second)"
    )
    for session, (_code, _doc, lines) in after.items():
        console.print(f"[bold]{escape(session)}[/]", soft_wrap=True)
        for line in lines:
            console.print(f"  {line}", soft_wrap=True)
    return worst(codes)



def _results_table(n_sessions: int, results) -> Table:
    """One row per calibrated session: saved, partly saved or failed, the accel and gyro RMS
    residuals, the magnetometer's where any session has one, and the warnings counted."""
    table = Table(title=f"{n_sessions} sessions")
    with_mag = any(r.figures and "mag" in r.figures.solvers for r in results)
    columns = ["session", "result", "accel |a|-g RMS, m/s^2", "gyro turn RMS, deg"]
    columns += ["mag |B| RMS", "mag quality"] if with_mag else []
    for col in (*columns, "warnings"):
        table.add_column(col)
    for r in results:
        f = r.figures or Figures()
        cells = [
            escape(r.session),  # a file name, not markup
            ("[green]saved[/]" if f.complete else
             f"[yellow]saved, {', '.join(f.left_out)} left out[/]")
            if r.exit_code == 0 else f"[red]failed ({r.exit_code})[/]",
            "" if f.accel_rms_after is None else f"{f.accel_rms_after:.4f}",
            "" if f.gyro_rms_deg is None else f"{f.gyro_rms_deg:.3f}",
        ]
        if with_mag:
            cells += [
                "" if f.mag_rms_after is None else f"{f.mag_rms_after:.4g} {f.mag_units}",
                f.mag_quality or "",
            ]
        table.add_row(*cells, "" if r.figures is None else str(f.warnings))
    return table


BOLD, WARN = "bold", "bold yellow"


def _summary(line, cal, where: str) -> None:
    """A few lines per calibrated sensor: what ran, the residuals, bias and sensitivity;
    ``line(*pieces)`` prints a line (:func:`.console.print_line`)."""
    for name, sec in (("accel", cal.accel), ("gyro", cal.gyro)):
        if sec is not None:
            _section_lines(line, name, sec)
    if cal.gyro_note:
        line(("gyro", BOLD), f": {cal.gyro_note}")
    if cal.accel_note:
        line(("warning", WARN), f": {cal.accel_note}")
    if cal.mag is not None:
        for pieces in mag_summary(cal.mag):
            line(*pieces)
    elif cal.mag_note:
        line(("warning", WARN), f": {cal.mag_note}")
    if cal.temperature_note:
        line(("temperature", BOLD), f": {cal.temperature_note}")
    clock = cal.sample_clock
    if clock is not None and clock.ppm is not None:
        done = _clock_done(clock, gyro_saved=cal.gyro is not None)
        line(
            ("sample clock", BOLD),
            f": {clock.ppm:+.1f} ± {clock.ppm_std:.1f} ppm (device s per true s - 1, "
            f"over {clock.duration_s:.0f} s; {done})",
        )
    elif clock is not None and clock.note:
        line(("sample clock", BOLD), f": {clock.note}")
    for text in set_lines(cal):  # several IMUs (issue 28)
        line(text)
    partial = {name: sec.partial for name, sec in cal.sections().items()
               if sec is not None and sec.partial is not None}  # issue 27.3
    assumed = [name for name, part in partial.items() if part.assumed]
    leaning = [name for name, part in partial.items() if not part.assumed]
    if cal.left_out or partial:  # issue 24.2: saved, but not every sensor of the session is in it
        said = [f"{', '.join(cal.left_out)} left out"] if cal.left_out else []
        said += [f"{', '.join(assumed)} in part assumed"] if assumed else []
        said += [f"{', '.join(leaning)} in part on its prior"] if leaning else []
        where += f" (partial: {'; '.join(said)}, see above)"
    line(f"wrote {where}")


def _clock_done(clock, *, gyro_saved: bool) -> str:
    """What the sample clock's estimate changed: the gyro only when it was applied and a
    gyro was calibrated (issue 24.4: nothing is said about a correction that did not act)."""
    if clock.applied is False:
        return f"within {clock.threshold_ppm or 0.0:.3g} ppm of none: not corrected"
    return "gyro corrected" if gyro_saved else "no gyro calibrated, so nothing corrected"


def _section_lines(line, name: str, sec) -> None:
    """The accelerometer's or gyro's lines of the summary."""
    units = sec.units_in or "raw units"
    how = [f"{sec.solver} ({sec.variant})" if sec.variant is not None else sec.solver]
    if isinstance(sec, AccelCalibration) and sec.coverage is not None:
        how.append(f"{sec.coverage.n_poses} poses")
    fit = sec.fit
    if fit is not None and fit.iterations is not None:
        how.append(f"{fit.iterations} iterations")
    if fit is not None and fit.init:
        how.append(f"init {fit.init}")
    line((name, BOLD), ": " + ", ".join(how))
    if sec.choice is not None and sec.choice.by is By.AUTO:
        line("  solver chosen: " + sec.choice.reason)
    if isinstance(sec, AccelCalibration) and sec.rms_after is not None:
        g, before = sec.gravity, sec.rms_before
        text = "  |a| - g RMS: "
        if before is not None:
            text += f"before {before:.4f} m/s^2 ({1000 * before / g:.2f} mg) -> "
        text += f"after {sec.rms_after:.4f} m/s^2 ({1000 * sec.rms_after / g:.3f} mg)"
        if sec.rms_loo is not None:
            text += f", held out {sec.rms_loo:.4f} m/s^2"
        line(text)
    turns = (sec.rotations or []) if isinstance(sec, GyroCalibration) else []
    if turns and sec.rotation_rms_deg is not None:
        line(f"  {len(turns)} rotations, angle residual RMS {sec.rotation_rms_deg:.3f} deg")
    elif turns:
        for rot in turns[:3]:
            line(
                f"  {rot.label or rot.segment}: "
                f"measured {rot.measured_angle_deg:.3f} deg, "
                f"known {rot.known_angle_deg:.3f} deg"
            )
    per = "m/s^2" if name == "accel" else "rad/s"
    line(
        "  bias "
        + ", ".join(f"{b:.5g}" for b in sec.bias)
        + f" {units}; sensitivity "
        + ", ".join(f"{v:.5g}" for v in sec.sensitivity or [])
        + f" {units} per {per}"
    )
    _temperature_line(line, sec, units)
    _partial_lines(line, sec)
    for w in sec.warnings or []:
        line("  ", ("warning", WARN), f": {w}")


def _partial_lines(line, sec) -> None:
    """Which parameters the session measured and which are assumed (issue 27.3): never a
    prior's value said as a measurement."""
    part = sec.partial
    if part is None:
        return
    rows = {p.name: p for p in sec.parameters or []}

    def said(names):
        return ", ".join(f"{n} {rows[n].value:.5g} ± {rows[n].std:.3g} {rows[n].unit}"
                         if n in rows else n for n in names) or "none"  # fmt: skip

    line("  ", ("measured", BOLD), f" by this session: {said(part.measured or [])}")
    if part.assumed:
        line("  ", ("assumed", WARN), f" (not measured: the prior's value and std): "
             f"{said(part.assumed)}; prior: {part.prior}")  # fmt: skip
    else:  # each narrowed by the data, but not every combination of them
        line("  ", ("on the prior", WARN), ": no parameter alone, but the combinations "
             f"these poses cannot fix (their std include the prior's); prior: {part.prior}")
    if part.capture:
        line(f"  to measure the rest: {part.capture}")


def mag_summary(sec) -> list[tuple[Piece, ...]]:
    """The magnetometer's lines (each a tuple of :data:`.console.Piece`): what ran, |B|
    residuals, inclination, hard iron, axes, the quality verdict and the warnings."""
    rd = sec.readings or Readings()
    how = [sec.solver, f"{rd.motion or 0} motion readings + {rd.poses or 0} poses"]
    missing = rd.left_out.nonfinite if rd.left_out is not None else None
    if missing:
        how[-1] += f" ({missing} rows without a value left out)"
    if sec.fit is not None and sec.fit.iterations:
        how.append(f"{sec.fit.iterations} iterations")
    how.append("aligned to the accelerometer" if sec.aligned else "own axes (not aligned)")
    lines: list[tuple[Piece, ...]] = [(("mag", BOLD), ": " + ", ".join(how))]
    field = sec.field_uT
    unit = "uT" if field else "x local field"
    text = f"  |B| residual RMS {sec.rms_after:.4g} {unit}"
    if field:
        text += f" ({100 * sec.rms_after / field:.2f} % of {field:g} uT)"
    if sec.rms_held_out is not None:
        text += f", held out {sec.rms_held_out:.4g} {unit}"
    if sec.inclination_deg is not None:
        text += f"; inclination {sec.inclination_deg:.2f} ± {sec.inclination_std_deg:.2f} deg"
    lines.append((text,))
    if not field:
        est = sec.field_estimate_uT
        lines.append((
            "  field magnitude unknown: output in units of the local field (|B| = 1)"
            + (f", about {est:.3g} uT" if est else "")
            + "; give [mag] field_uT for uT",
        ))  # fmt: skip
    text = "  hard iron " + ", ".join(f"{b:.5g}" for b in sec.bias) + f" {sec.units_in}"
    if sec.axes:
        text += "; axes " + ", ".join(sec.axes)
    lines.append((text,))
    q = sec.quality
    if q is not None:
        figs = ", ".join(
            (f"{c.name} {c.value_pct:.1f} %" if c.value_pct is not None else f"{c.name} -")
            + ("" if c.held_pct is None else f" (|B| there held to {c.held_pct:.2g} %)")
            for c in q.checks or []
        )  # fmt: skip
        verdict: Piece = "pass" if q.verdict == "pass" else ("recapture", WARN)
        lines.append(("  quality: ", verdict, f" ({figs})"))
    for w in sec.warnings or []:
        lines.append(("  ", ("warning", WARN), f": {w}"))
    return lines


def _temperature_line(line, sec, units: str) -> None:
    """The bias temperature model of a section, when it has one."""
    model = sec.temperature_model
    if model is None or sec.bias_tempco is None:
        return
    lo, hi = model.range_c
    line(
        f"  temperature: bias polynomial of degree {', '.join(map(str, model.degree))} per "
        f"channel about {sec.temperature_ref:.1f} C, fitted over {lo:.1f} .. {hi:.1f} C "
        f"({model.source}); {units} per C^k" + _prior_words(model)
    )


def _prior_words(model) -> str:
    """Where the joint fit carries the terms the poses cannot fit from a prior, say so."""
    used = model.prior_tempco_mg_per_c
    if not used:
        return ""
    what = " and ".join({2: "quadratic", 3: "cubic"}[d] for d in model.prior_degrees or [3])
    value = "/".join(f"{v:.2g}" for v in used) if len(set(used)) > 1 else f"{used[0]:g}"
    return f"; {what} from a prior, accel_tempco_mg_per_c = {value} mg/C"
