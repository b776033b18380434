"""`imucal capture`: record a session from a serial port (guided or unattended)."""

from __future__ import annotations

import signal
import sys
import threading
import warnings
from datetime import datetime
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from imucal_cli.capture import guided, stream
from imucal_cli.capture.imu_set import SetLineProtocol
from imucal_cli.capture.recorder import Recorder
from imucal_cli.capture.serial_port import SerialSource
from imucal_cli.capture.unattended import run_unattended
from imucal_cli.errors import ImucalError, ImucalWarning, InputError
from imucal_cli.formats.columns import ColumnSpec
from imucal_cli.formats.output import check_output, check_session_output
from imucal_cli.formats.session import MAG_UNITS, open_samples, read_session
from imucal_cli.model.session import MAX_FIELD_UT
from imucal_cli.plans import CaptureSummary, load_plan, needs_temperature

from . import completion
from .app import app
from .console import make_console, print_json
from .imu_set import capture_set, open_ports
from .options import (
    Force,
    SensorText,
    alias,
    baud_option,
    columns_option,
    duration_option,
    field_ut_option,
    hold_option,
    json_option,
    mag_units_option,
    output_option,
    plan_option,
    protocol_option,
    time_unit_option,
    units_option,
)
from .until import adaptive_options, refit_with, summary_rows, targets_of

EXIT_COMPLETE, EXIT_INCOMPLETE, EXIT_INTERRUPTED = 0, 3, 130
"""Exit statuses of the README's table: the session is complete; saved but incomplete; Ctrl-C
before anything was saved.  Nothing saved otherwise (bad input, no data at all) is an
``InputError``: 2."""


def default_output() -> Path:
    """``capture-YYYYmmdd-HHMMSS.h5`` in the current directory (local time)."""
    return Path(datetime.now().strftime("capture-%Y%m%d-%H%M%S.h5"))


# The options, in the order --help lists them -------------------------------------------------

Port = Annotated[list[str], typer.Option(
    "--port", "-p", metavar="PORT", help="Serial port (/dev/ttyUSB0, COM3, a pty); several "
    "(--port A --port B): one IMU each, the first the reference, all in one session.",
    autocompletion=completion.ports,
)]  # fmt: skip
Baud = alias(int, baud_option("Baud rate.", "-b"))
Plan = alias(str | None, plan_option(
    None, "Steps to go through (qureshi18 when guided; the same plans as imucal simulate):"
))  # fmt: skip
Output = alias(Path | None, output_option(
    "FILE.h5", "Session file to write [default: capture-<date>-<time>.h5]."
))  # fmt: skip
Columns = alias(str, columns_option(
    "Fields of a line, in order: t (device time), ax ay az (a4.. more), gx gy gz (g4..), mx my "
    "mz (magnetometer), temp, _ (skip). Without t the host clock stamps each line."
))  # fmt: skip
TimeUnit = alias(str, time_unit_option("Unit of the t field."))
Protocol = alias(str, protocol_option(
    "lines: text lines of numbers (--columns), or MotionCal/i2cdevlib lines when the first "
    "lines carry their prefix; motioncal: MotionCal's Raw:ax,ay,az,gx,gy,gz,mx,my,mz lines; "
    "i2cdevlib: i2cdevlib's a/g: (a/g/m:) lines (both counts, host-clock time); witmotion: "
    "WitMotion's binary 0x55 frames (WT901, JY901: accel, gyro, temperature as int16 counts, "
    "host-clock time).",
    completion.capture_protocols,
))  # fmt: skip
NoPrompt = Annotated[bool, typer.Option(
    "--no-prompt",
    help="Unattended (bench scripts): no keyboard; record for --duration or until every step "
    "of --plan was seen in the motion, then segment the recording by itself.",
)]  # fmt: skip
Duration = alias(float | None, duration_option(
    "Stop this long after the first sample (at the latest)."
))  # fmt: skip
AccelUnits = alias(str | None, units_option(
    "accel", "Units of the raw accel: counts, V, g, m/s^2."
))  # fmt: skip
GyroUnits = alias(str | None, units_option(
    "gyro", "Units of the raw gyro: counts, V, rad/s, deg/s."
))  # fmt: skip
MagUnits = alias(str | None, mag_units_option(
    "Units of the raw magnetometer: counts, uT, nT, gauss."
))  # fmt: skip
FieldUt = alias(float | None, field_ut_option(
    "Local geomagnetic field magnitude, microtesla (from a geomagnetic model such as the WMM "
    "for your place): the magnetometer calibration comes out in uT."
))  # fmt: skip
MinStill = Annotated[float, typer.Option(
    "--min-still", metavar="SECONDS", help="Shortest still period that counts."
)]  # fmt: skip
WaitTimeout = Annotated[float, typer.Option(
    "--wait-timeout", metavar="SECONDS", help="Give up when no line came this long."
)]  # fmt: skip
ReadTimeout = Annotated[float, typer.Option(
    "--read-timeout", metavar="SECONDS", help="End the capture when the data stops this long."
)]  # fmt: skip
Hold = alias(float | None, hold_option(
    f"Guided mode: seconds to hold each pose still [default: {guided.DEFAULT_HOLD_S:g}; with "
    "--until the shortest hold, "
    "0.5: each hold then ends by itself once more samples no longer help].", None,
))  # fmt: skip
Until = Annotated[str | None, typer.Option(
    "--until", metavar="TARGETS",
    help="Capture until the calibration is this good (1 std, worst axis), e.g. "
    "accel=0.05%,gyro=0.05% or accel.bias=0.5mg,gyro.bias=0.01deg/s,gyro.misalignment=0.05deg "
    "(terms gain, bias, misalignment): after every hold the session so far is calibrated and "
    "each target's std shown; the guide proposes the pose that helps most (without --plan) and "
    "says done when every target is met; --no-prompt stops there too.",
)]  # fmt: skip
ConfigFile = Annotated[Path | None, typer.Option(
    "--config", "-c", metavar="FILE.toml",
    help="With targets: the calibrate config the refits use, and its [targets] (--until "
    "overrides them term by term).",
)]  # fmt: skip
Resume = Annotated[Path | None, typer.Option(
    "--resume", metavar="SESSION.h5",
    help="Continue an interrupted capture into SESSION (give the same --plan): new samples are "
    "appended after its own, and the steps its segments hold count as done.",
)]  # fmt: skip
JsonOutput = alias(bool, json_option(
    "Print the summary as JSON on stdout (nothing else; guided prompts go to stderr)."
))  # fmt: skip


@app.command()
def capture(
    port: Port,
    baud: Baud = 115200,
    plan: Plan = None,
    output: Output = None,
    columns: Columns = "t,ax,ay,az,gx,gy,gz,temp",
    time_unit: TimeUnit = "s",
    protocol: Protocol = "lines",
    no_prompt: NoPrompt = False,
    duration: Duration = None,
    sensor: SensorText = None,
    accel_units: AccelUnits = None,
    gyro_units: GyroUnits = None,
    mag_units: MagUnits = None,
    field_ut: FieldUt = None,
    min_still: MinStill = 1.0,
    wait_timeout: WaitTimeout = 10.0,
    read_timeout: ReadTimeout = 5.0,
    hold: Hold = None,
    until: Until = None,
    config: ConfigFile = None,
    force: Force = False,
    resume: Resume = None,
    json_output: JsonOutput = False,
) -> None:
    """Record a calibration session from an IMU on a serial port.

    Reads text lines of numbers (commas, semicolons, spaces or tabs; MotionCal's Raw: and
    i2cdevlib's a/g: lines are recognised by themselves) or WitMotion frames, and appends the
    samples to the session as they arrive (flushed at least once a second).  Ctrl-C, SIGTERM,
    an unplugged device or a stalled stream end the capture with a valid session holding
    every sample.

    An interrupted capture goes on with --resume SESSION: the same file, the plan's progress
    taken from the segments already there.

    With --until (or a config's [targets]) the capture goes on until the calibration of what
    it recorded meets every target: complete then means every target met.

    Exit status: 0 the session is complete; 3 the session is saved but incomplete (steps of
    the plan not seen, targets not met, interrupted, device gone, data stopped, the disk full:
    stopped in time with every sample); 2 bad input (no such port, bad --columns or plan,
    time stamps in the wrong --time-unit, no data at all: nothing saved); 130 Ctrl-C before
    any data.
    """
    console = make_console(stderr=json_output)  # with --json, stdout holds the JSON alone
    err = make_console(stderr=True)

    def status(message: str) -> None:
        err.print(f"imucal: {escape(message)}", soft_wrap=True)

    check_mag_options(mag_units, field_ut)
    several = capture_set(port, columns, time_unit, protocol)  # issue 28
    stream_protocol = several if isinstance(several, SetLineProtocol) else _stream_protocol(
        protocol, lambda: ColumnSpec.parse(columns, time_unit), status)  # fmt: skip
    if protocol != "lines":  # the format fixes the units (counts)
        accel_units, gyro_units = accel_units or "counts", gyro_units or "counts"
    _check_limits({"--duration": duration, "--min-still": min_still, "--hold": hold,
                   "--wait-timeout": wait_timeout, "--read-timeout": read_timeout})  # fmt: skip
    targets, cfg = targets_of(until, config)
    if targets and resume is not None:
        raise InputError("--resume continues a plan; a capture with targets starts afresh: "
                         "leave out --resume (or --until and [targets])")
    plan_obj, guided = _plan_and_mode(plan, no_prompt, duration, targets)
    _check_temperature(plan_obj, protocol, stream_protocol)
    out = _output_path(output, resume, force)
    done_before = None if resume is None else _done_before(resume, guided is not None)
    recorder = _recorder(port, baud, out, stream_protocol, status, several, sensor=sensor,
                         accel_units=accel_units, gyro_units=gyro_units, mag_units=mag_units,
                         magnetic_field_uT=field_ut, overwrite=force, wait_timeout_s=wait_timeout,
                         read_timeout_s=read_timeout, resume=resume is not None)  # fmt: skip
    try:
        try:
            summary = _record(recorder, plan_obj, guided, console, status, duration=duration,
                              min_still_s=min_still, hold_s=hold, done_before=done_before,
                              targets=targets, cfg=cfg)  # fmt: skip
        except ImucalError as exc:  # a saved session is never "nothing saved" (exit 2)
            if not recorder.file_written:
                raise
            summary = _cut_short(recorder, plan_obj, exc, status)
    finally:
        if recorder.end_kind == "clock":  # stamps in the wrong unit: no session (exit 2)
            recorder.discard()
        else:
            recorder.close()
        _saved_stays_saved(recorder)
    _nothing_saved(recorder, out, err)
    if recorder.behind is not None:
        warnings.warn(recorder.behind, ImucalWarning, stacklevel=1)
    _warn_absent_channels(out, {"--accel-units": ("accel", accel_units),
                                "--gyro-units": ("gyro", gyro_units),
                                "--mag-units": ("mag", mag_units),
                                "--field-uT": ("mag", field_ut)})  # fmt: skip
    if json_output:
        print_json(_summary_json(out, recorder, summary))
    else:
        _print_summary(console, out, recorder, summary)
    sys.stdout.flush()
    if not _complete(recorder, summary):
        raise typer.Exit(EXIT_INCOMPLETE)


def _check_limits(limits: dict[str, float | None]) -> None:
    """Refuse a time limit that is not a positive number of seconds."""
    for name, value in limits.items():
        if value is not None and not value > 0:
            raise InputError(f"{name} must be > 0 s, got {value:g}")


def _plan_and_mode(plan: str | None, no_prompt: bool, duration: float | None, targets):
    """The plan (None: an unattended capture for a duration or until targets, or a guided one
    whose every pose the guide proposes) and the guided mode's package (None: unattended)."""
    if no_prompt:
        if plan is None and duration is None and not targets:
            raise InputError("--no-prompt needs --duration SECONDS, --plan NAME or --until "
                             "TARGETS")  # fmt: skip
        return (None if plan is None else load_plan(plan)), None
    if targets:
        return (None if plan is None else load_plan(plan)), guided
    return load_plan(plan or "qureshi18"), guided


def _check_temperature(plan, protocol: str, stream_protocol) -> None:
    """Refuse a plan that records the temperature (a warm-up) with a stream that has none."""
    if plan is None or not needs_temperature(plan):
        return
    if protocol in ("motioncal", "i2cdevlib"):
        raise InputError(f"plan {plan.name} records the temperature through the "
                         f"warm-up: {protocol} lines carry none")  # fmt: skip
    if protocol == "lines" and stream_protocol.columns.temperature is None:
        raise InputError(f"plan {plan.name} records the temperature through the warm-up: "
                         "add temp to --columns (e.g. t,ax,ay,az,gx,gy,gz,temp)")  # fmt: skip


def _recorder(ports: list[str], baud: int, out: Path, stream_protocol, status, several,
              **options):  # fmt: skip
    """The port(s) opened and a recorder on it (closed again when that fails); the
    accelerometer units, when not stated, said once the port opened (issue 10.4: errors stay
    one line).  Several ports: one IMU each (``several``: the lines' spec)."""
    if len(ports) > 1:
        source, stream_protocol = open_ports(ports, baud, several)
    else:
        source = SerialSource(ports[0], baud)
    try:
        recorder = Recorder(out, source, stream_protocol, on_status=status, **options)
    except BaseException:
        source.close()
        raise
    if options["accel_units"] is None:
        status(
            "warning: accelerometer units not stated (--accel-units counts, g or m/s^2); "
            "calibrate will infer them from the magnitude, or set them later with `imucal "
            "label SESSION --accel-units UNITS`"
        )
    return recorder


def _record(recorder, plan, guided, console: Console, status, *, duration: float | None,
            min_still_s: float, hold_s: float | None, done_before, targets, cfg):  # fmt: skip
    """Run the capture: guided (the guided package given) or unattended."""
    if guided is None:
        return run_unattended(recorder, plan, duration, min_still_s=min_still_s,
                              on_status=status, done_before=done_before, targets=targets,
                              refit=refit_with(cfg) if targets else None,
                              gravity=cfg.gravity or 9.80665)  # fmt: skip
    adaptive = adaptive_options(targets, cfg, hold_s) if targets else None
    hold = guided.DEFAULT_HOLD_S if hold_s is None else hold_s
    return guided.run_guided(recorder, plan, console=console, keys=guided.StdinKeys(),
                             hold_s=hold if adaptive is None else adaptive.min_hold_s,
                             done_before=done_before, adaptive=adaptive)  # fmt: skip


def _cut_short(recorder, plan, exc: Exception, status):
    """The summary of a capture whose mode failed after samples were saved (a segment it
    could not add): said as a warning, the session kept, incomplete (exit 3)."""
    status(f"warning: {exc}")
    missing = [] if plan is None else [s.label for s in plan.steps]
    return CaptureSummary(complete=False, done=[], skipped=[], missing=missing,
                          end_reason=str(exc), samples=recorder.n_samples,
                          stats=recorder.stats)  # fmt: skip


def _saved_stays_saved(recorder) -> None:
    """Once the session is saved and closed, Ctrl-C no longer changes the outcome: the
    summary is printed and the status is the README's for what was saved (never 130)."""
    if recorder.file_written and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, lambda signum, frame: None)


def _nothing_saved(recorder, out: Path, err: Console) -> None:
    """End a capture that has no session to show: time stamps off by a unit (what it recorded
    was discarded), or no sample came at all (no file: exit 2, as for bad input, or 130 after
    Ctrl-C, the README's statuses for nothing saved)."""
    if recorder.end_kind == "clock":  # issue 10.5: a time unit off by a factor
        kept = (f"{out} keeps only its {recorder.resumed_from} earlier samples"
                if recorder.resumed_from else "nothing saved")  # fmt: skip
        raise InputError(f"{recorder.end_reason} ({kept})")
    if recorder.file_written:
        return
    if recorder.end_kind == "timeout":
        raise InputError(recorder.end_reason)
    received = recorder.received_note()  # e.g. bytes that were no line: wrong baud rate?
    said = f"{recorder.end_reason} before any data" + (f"; {received}" if received else "")
    if recorder.end_kind != "interrupted":
        raise InputError(f"{said}: no file written")
    err.print(f"imucal: {escape(said)}: no file written", soft_wrap=True)
    raise typer.Exit(EXIT_INTERRUPTED)


PROTOCOLS = completion.CAPTURE_PROTOCOLS
"""``--protocol`` choices: what the device sends."""


def _stream_protocol(protocol: str, columns, status):
    """The capture protocol of ``--protocol`` (``columns()``: the --columns spec, parsed only
    for lines of numbers)."""
    if protocol == "lines":
        return stream.AutoLineProtocol(columns(), on_choice=status)
    if protocol == "motioncal":
        return stream.PrefixedLineProtocol(("motioncal",))
    if protocol == "i2cdevlib":
        return stream.PrefixedLineProtocol(("i2cdevlib", "i2cdevlib-mag"))
    if protocol == "witmotion":
        return stream.WitMotionProtocol()
    raise InputError(f"--protocol {protocol!r}: use {', '.join(PROTOCOLS)}")


def _output_path(output: Path | None, resume: Path | None, force: bool) -> Path:
    """The session to write: --output (new), --resume (continued) or a dated name."""
    if resume is not None:
        if output is not None and output.resolve() != resume.resolve():
            raise InputError("--resume continues SESSION in place: leave out --output")
        if force:
            raise InputError("--resume keeps what SESSION holds: leave out --force")
        if not resume.is_file():
            raise InputError(f"{resume}: no such session to resume")
        return resume
    out = output if output is not None else default_output()
    check_session_output(out, "imucal capture")
    if out.is_file() and not force:
        raise InputError(f"{out} exists: use --force to overwrite it, or --resume {out} to "
                         "continue it")  # fmt: skip
    return check_output(out, force=force)


def _done_before(path: Path, guided: bool) -> list:
    """What an interrupted session already holds: for the guided mode ``(kind, label, mean raw
    accel of a static segment or None)`` per segment, for the unattended mode the labels (None
    for an unlabelled static segment: a pose counted, not identified)."""
    session = read_session(path)
    if not guided:
        return [s.label or None for s in session.segments if s.label or s.kind == "static"]
    return [(s.kind, s.label,
             session.accel[s.start : s.stop].mean(axis=0)
             if s.kind == "static" and session.accel is not None else None)
            for s in session.segments if s.label]  # fmt: skip


def _summary_json(out: Path, recorder, summary) -> dict:
    """The summary for scripts and benches: rates and durations in device time, how the
    capture ended, and this capture's samples received, written and lost."""
    segs = recorder.segments
    n_static = sum(1 for s in segs if s["kind"] == "static")
    st = recorder.stats
    return {
        "format": "imucal-capture", "format_version": 1, "output": str(out),
        "complete": _complete(recorder, summary), "done": list(summary.done),
        "skipped": list(summary.skipped), "missing": list(summary.missing),
        "end": recorder.end_kind, "end_reason": recorder.end_reason or summary.end_reason,
        "samples": int(recorder.n_samples), "static_segments": n_static,
        "rotation_segments": len(segs) - n_static,
        "labelled_segments": sum(1 for s in segs if "label" in s),
        "lines": int(st.get("lines", 0)), "comments": int(st.get("comments", 0)),
        "malformed": int(st.get("malformed", 0)), "duration_s": float(st["duration_s"]),
        "rate_hz": float(st["rate_hz"]), "wall_s": float(st["wall_s"]),
        "samples_received": int(st["received"]), "samples_written": int(st["written"]),
        "samples_lost": int(st["lost"]), "segments_left_out": int(recorder.segments_left_out),
        "resumed_from": int(recorder.resumed_from),
        "targets": summary_rows(summary.targets),
    }  # fmt: skip


def _complete(recorder, summary) -> bool:
    """Complete: every step seen, and nothing of it lost to a full disk."""
    return bool(summary.complete) and not recorder.samples_lost and not recorder.segments_left_out


def _warn_absent_channels(out: Path, options: dict[str, tuple[str, object]]) -> None:
    """Options for a sensor the device did not send (``--mag-units`` and no magnetometer in
    the lines): a warning each (issue 24.7), once the session says which channels it has."""
    given = {flag: raw for flag, (raw, value) in options.items() if value is not None}
    if not given:
        return

    with open_samples(out) as samples:
        present = set(samples.channels)
    names = {"accel": "accelerometer", "gyro": "gyroscope", "mag": "magnetometer"}
    for raw in dict.fromkeys(given.values()):
        if raw not in present:
            flags = ", ".join(f for f, r in given.items() if r == raw)
            warnings.warn(f"{flags}: the device sent no {names[raw]} data "
                          f"(the session has no /raw/{raw}): ignored", ImucalWarning,
                          stacklevel=2)  # fmt: skip


def check_mag_options(mag_units: str | None, field_ut: float | None) -> None:
    """Refuse unknown magnetometer units or a field that is not a positive number."""
    if mag_units is not None and mag_units not in MAG_UNITS:
        raise InputError(f"--mag-units {mag_units!r}: use {', '.join(MAG_UNITS)}")
    if field_ut is not None and not (0 < field_ut <= MAX_FIELD_UT):
        raise InputError(f"--field-uT must be a positive number of microtesla, at most "
                         f"{MAX_FIELD_UT:.0f} uT, got {field_ut:g}")  # fmt: skip


def _print_summary(console: Console, out: Path, recorder, summary) -> None:
    st = recorder.stats  # after closing: what the file holds
    segs = recorder.segments
    n_static = sum(1 for s in segs if s["kind"] == "static")
    n_rot = len(segs) - n_static
    n_labelled = sum(1 for s in segs if "label" in s)
    kind = recorder.end_kind
    why = "" if kind == "done" else f": {recorder.end_reason or summary.end_reason}"
    new = " new" if recorder.resumed_from else ""
    console.print(
        f"saved {recorder.n_samples} samples to {escape(str(out))}: {n_static}{new} static and "
        f"{n_rot}{new} rotation segments ({n_labelled} labelled)",
        highlight=False,
        soft_wrap=True,
    )
    if recorder.resumed_from:
        console.print(f"  continued after the {recorder.resumed_from} samples already there, "
                      "their segments kept", highlight=False, soft_wrap=True)  # fmt: skip
    console.print(
        f"  lines {st.get('lines', 0)}, comments {st.get('comments', 0)}, malformed "
        f"{st.get('malformed', 0)}; {st.get('duration_s', 0.0):.1f} s, "
        f"{st.get('rate_hz', 0.0):.1f} Hz; ended: {kind}{escape(why)}",
        highlight=False,
        soft_wrap=True,
    )
    if recorder.segments_left_out:
        console.print(f"  {recorder.segments_left_out} segments left out: their samples could "
                      "not be written", highlight=False, soft_wrap=True)  # fmt: skip
    if summary.targets:
        for row in summary.targets:
            console.print(f"  target {escape(row.describe())}", highlight=False, soft_wrap=True)
    if _complete(recorder, summary):
        done = f" ({len(summary.done)} steps seen)" if summary.done and not summary.targets \
            else ""  # fmt: skip
        what = " (every target met)" if summary.targets else done
        console.print(f"  complete{what}", highlight=False, soft_wrap=True)
    else:
        missing = ", ".join(summary.missing)
        text = f"  incomplete: missing {missing}" if missing else "  incomplete"
        if summary.skipped:
            text += f"; skipped {', '.join(summary.skipped)}"
        console.print(escape(text), highlight=False, soft_wrap=True)
