"""`imucal simulate`: write a simulated session and its truth calibration."""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import warnings
from pathlib import Path
from typing import Annotated

import typer

from imucal_cli.capture.guided.keys import StdinKeys
from imucal_cli.errors import ImucalWarning, InputError
from imucal_cli.formats.calibration import write_calibration
from imucal_cli.formats.output import check_output, check_session_output
from imucal_cli.formats.session import write_session
from imucal_cli.plans import find_plan, load_plan
from imucal_cli.simulate.clock import check_ppm
from imucal_cli.simulate.device import serve
from imucal_cli.simulate.live import serve_person
from imucal_cli.simulate.magnetometer import simulate_mag
from imucal_cli.simulate.play import simulate_plan
from imucal_cli.simulate.temperature import parse_ramp

from . import completion
from .app import app
from .console import print_json
from .options import (
    alias,
    baud_option,
    duration_option,
    field_ut_option,
    force_option,
    hold_option,
    json_option,
    mag_units_option,
    output_option,
    plan_option,
    protocol_option,
    rate_option,
)
from .simulate_checks import check_numbers
from .simulate_set import (
    ImuOffset,
    ImuRotation,
    Imus,
    ServeImu,
    check_set_options,
    serve_options,
    simulate_imus,
)

SERVE_HOLD_S = 4.0
"""--serve's hold per pose when --hold is not given, s: capture's default hold (2 s) plus time for
the stillness detector to see the unit settle after a turn."""


def _enter_presses():
    """A poll ``() -> bool`` that is True once per Enter typed on stdin, or None when stdin cannot
    be read without stopping the process (a terminal of a background job: SIGTTIN)."""
    try:
        if sys.stdin is None or sys.stdin.closed:
            return None
        if sys.stdin.isatty() and os.tcgetpgrp(sys.stdin.fileno()) != os.getpgrp():
            return None
    except (OSError, ValueError, AttributeError):
        return None

    keys = StdinKeys()
    return lambda: keys.get() is not None


def _poses_or_turns(flag: str, plan: str) -> None:
    """Refuse ``flag`` (a temperature ramp, a clock error) but for the pose and hand-rotation
    plans, the experiments that model it (written or served)."""
    spec = find_plan(plan)[0]
    if spec is None or spec.simulator not in ("poses", "rotations"):
        raise InputError(f"{flag} works for plans six, qureshi18, random:N, warmup:MINUTES, "
                         "qureshi-axes and free:N")  # fmt: skip


def _mag_plan(plan: str, thermal_or_clock: bool) -> None:
    """Refuse --mag but for the pose plans (six, qureshi18, random:N), written or served."""
    spec = find_plan(plan)[0]
    if spec is None or spec.simulator != "poses" or spec.key == "warmup":
        raise InputError("--mag simulates pose plans (six, qureshi18, random:N), written or "
                         f"served, not {plan!r}")  # fmt: skip
    if thermal_or_clock:
        raise InputError("--mag does not combine with --ramp or --clock-ppm")


def truth_path(session_path: Path) -> Path:
    """Where the truth goes: ``x.h5`` -> ``x.truth.json`` (beside the session)."""
    return session_path.with_suffix(".truth.json")


def default_output(plan: str, seed: int) -> Path:
    """``sim-<plan>-seed<seed>.h5``; the colon of ``random:N`` becomes a dash."""
    return Path(f"sim-{plan.strip().lower().replace(':', '-')}-seed{seed}.h5")


# The options, in the order --help lists them -------------------------------------------------

Plan = alias(str, plan_option(
    None, "What the virtual IMU goes through (the same plans as imucal capture; --serve streams "
    "them live):",
))  # fmt: skip
Seed = Annotated[int, typer.Option(
    "--seed", metavar="INT",
    help="Random seed (>= 0): the same seed and options draw the same part, poses and noise "
    "(the samples agree to the last bits of the arithmetic on another CPU, one count at most).",
)]  # fmt: skip
Rate = alias(float, rate_option("Sample rate, Hz."))
Hold = alias(float | None, hold_option(
    "Time held still in each pose, s (at least 10 samples) [default: 2; with --serve 4, so "
    "that a capture with its default 2 s hold has time to see the unit settle].", None,
))  # fmt: skip
AccelNoise = Annotated[float, typer.Option(
    "--accel-noise", metavar="M/S^2",
    help="Accelerometer white noise, m/s^2 per axis per sample (std).",
)]  # fmt: skip
JitterDeg = Annotated[float, typer.Option(
    "--jitter-deg", metavar="DEG",
    help="Placement error: RMS angle, degrees, between each pose's true and labelled up "
    "direction (the heading about the vertical is random anyway).",
)]  # fmt: skip
Units = Annotated[str, typer.Option(
    "--units", metavar="counts|m/s^2", autocompletion=completion.simulate_units,
    help="Raw units: 'counts' (16-bit integers, 8192 LSB/g, 16.4 LSB per deg/s) or 'm/s^2' "
    "(a part of nominal gain 1; gyro in rad/s; no quantisation).",
)]  # fmt: skip
Output = alias(Path | None, output_option(
    "FILE.h5", "Session file to write (default: sim-<plan>-seed<seed>.h5); the truth goes "
    "beside it as <name>.truth.json.",
))  # fmt: skip
Force = alias(bool, force_option("Overwrite existing output files."))

# the experiments' own options
RotationsPerAxis = Annotated[int, typer.Option(
    "--rotations-per-axis", metavar="N",
    help="qureshi-axes: hand turns per axis, each a different angle (the paper used 18).",
)]  # fmt: skip
PeakRate = Annotated[float, typer.Option(
    "--peak-rate", metavar="DEG/S",
    help="qureshi-axes, free:N: largest peak rate of a turn, deg/s (each turn's peak is drawn "
    "in 50-100 % of it; smooth smootherstep profiles).",
)]  # fmt: skip
Still = Annotated[float, typer.Option(
    "--still", metavar="SECONDS",
    help="qureshi-axes, free:N: still period before and after each turn, s.",
)]  # fmt: skip
SigmaCounts = Annotated[float, typer.Option(
    "--sigma-counts", metavar="COUNTS",
    help="hk-redundant: Gaussian noise per channel per sample, ADC counts, before rounding to "
    "integer codes (the paper used 0.7 and 1.5).",
)]  # fmt: skip
Orientations = Annotated[int | None, typer.Option(
    "--orientations", metavar="N",
    help="hk-redundant: number of orientations (default 20 random, or 18 with --labelled).",
)]  # fmt: skip
Samples = Annotated[int, typer.Option(
    "--samples", metavar="N", help="hk-redundant: readings held still per orientation."
)]  # fmt: skip
Labelled = Annotated[bool, typer.Option(
    "--labelled",
    help="hk-redundant: put the block on its 6 faces and 12 edges and record each pose's up "
    "direction, instead of unlabelled random directions.",
)]  # fmt: skip
Mountings = Annotated[int, typer.Option(
    "--mountings", metavar="N",
    help="hk-gyro: IMU mountings in the iron (1..8), each swept about 3 orthogonal faces.",
)]  # fmt: skip

# --serve
Serve = Annotated[bool, typer.Option(
    "--serve",
    help="Instead of writing a file, be a virtual serial IMU: open a pseudo-terminal, print "
    "its device path, and stream the plan in real time as text lines t,ax,ay,az,gx,gy,gz,temp "
    "(t in s, raw counts) for 'imucal capture --port PATH'.",
)]  # fmt: skip
Baud = alias(int, baud_option("--serve: emulated baud rate (bytes are paced)."))
Protocol = alias(str, protocol_option(
    "--serve: what a line is: lines (t,ax,ay,az,gx,gy,gz,temp), motioncal (MotionCal's "
    "Raw:ax,ay,az,gx,gy,gz,mx,my,mz, a magnetometer in the earth's field) or i2cdevlib "
    "(a/g:<TAB>ax...gz), counts without a time, as those Arduino sketches print them.",
    completion.serve_protocols,
))  # fmt: skip
Loop = Annotated[bool, typer.Option("--loop", help="--serve: repeat the plan while its reader "
                                     "stays (the serve ends when the reader closes the port).")]
Step = Annotated[bool, typer.Option(
    "--step",
    help="--serve: hold each pose until Enter is pressed in this terminal (without it the "
    "plan runs on a timer, --hold per pose, and Enter moves to the next pose early).",
)]  # fmt: skip
Duration = alias(float | None, duration_option("--serve: stop streaming after this long."))
PersonOpt = Annotated[bool, typer.Option(
    "--person",
    help="--serve: instead of a plan, a simulated person holds the unit and follows the guide "
    "of 'imucal capture' read on stdin (pipe the capture's output in): a reaction time of "
    "0.5-1 s, turns of 1-2 s, each pose placed with --jitter-deg RMS error; the part of --seed.",
)]  # fmt: skip

# a temperature ramp, a clock error
Ramp = Annotated[str | None, typer.Option(
    "--ramp", metavar="FROM:TO[:linear]",
    help="The part's temperature runs from FROM to TO degrees C through the session (a "
    "warm-up, or :linear for a hair-dryer or chamber ramp); its biases follow it and the "
    "truth holds temperature_ref and bias_tempco. With --serve the temp field follows it.",
)]  # fmt: skip
ClockPpm = Annotated[float | None, typer.Option(
    "--clock-ppm", metavar="PPM",
    help="The part's sample clock runs PPM parts per million fast (negative: slow): the "
    "session records its device times and the host's arrival times (/raw/host_time); with "
    "--serve the lines carry its time stamps.",
)]  # fmt: skip
GSensitivity = Annotated[float | None, typer.Option(
    "--g-sensitivity", metavar="LEVEL",
    help="A g-sensitive gyro: each entry of its g-sensitivity matrix drawn within +-this (rad/s "
    "per m/s^2 of specific force, e.g. 5e-4); the truth holds g_sensitivity.",
)]  # fmt: skip
Temp = Annotated[bool, typer.Option(
    "--temp/--no-temp", help="--serve: print the temperature field (8 or 7 fields)."
)]  # fmt: skip

# --mag
Mag = Annotated[bool, typer.Option(
    "--mag",
    help="Pose plans (six, qureshi18, random:N): add a magnetometer (an AK8963-like part: hard "
    "and soft iron, axes x/y swapped and z reversed relative to the accelerometer) and tumble "
    "the unit through random attitudes between the holds (--tumble); with --serve each line "
    "carries mx,my,mz after the gyro (capture --columns t,ax,ay,az,gx,gy,gz,mx,my,mz,temp).",
)]  # fmt: skip
FieldUt = alias(float, field_ut_option("--mag: local field magnitude, microtesla."))
Inclination = Annotated[float, typer.Option(
    "--inclination-deg", metavar="DEG",
    help="--mag: inclination of the field below the horizontal, degrees (-90..90).",
)]  # fmt: skip
MagUnits = alias(str, mag_units_option(
    "--mag: raw magnetometer units (counts: 0.15 uT per LSB, integers).",
    metavar="counts|uT|nT|gauss",
))  # fmt: skip
MagNoise = Annotated[float, typer.Option(
    "--mag-noise", metavar="UT", help="--mag: white noise per axis per sample, uT."
)]  # fmt: skip
MagLayout = Annotated[str, typer.Option(
    "--mag-layout", metavar="ak8963|aligned",
    help="--mag: the magnetometer's axes relative to the accelerometer's.",
)]  # fmt: skip
FieldUnknown = Annotated[bool, typer.Option(
    "--field-unknown",
    help="--mag: leave the field magnitude out of the session (no magnetic_field_uT).",
)]  # fmt: skip
Tumble = Annotated[float, typer.Option(
    "--tumble", metavar="SECONDS",
    help="--mag: tumble through random attitudes this long between holds (0: plain moves).",
)]  # fmt: skip

# --serve: the moves and the test faults
Move = Annotated[float, typer.Option(
    "--move", metavar="SECONDS", help="--serve: time each turn between poses takes, s."
)]  # fmt: skip
Garbage = Annotated[bool, typer.Option(
    "--garbage",
    help="--serve, test fault: random bytes instead of lines (as a wrong baud rate shows).",
)]  # fmt: skip
StallAfter = Annotated[float | None, typer.Option(
    "--stall-after", metavar="SECONDS",
    help="--serve, test fault: stop sending after this long, keep the port open.",
)]  # fmt: skip
VanishAfter = Annotated[float | None, typer.Option(
    "--vanish-after", metavar="SECONDS",
    help="--serve, test fault: close the port after this long (the device is unplugged).",
)]  # fmt: skip
MalformedEvery = Annotated[int | None, typer.Option(
    "--malformed-every", metavar="N",
    help="--serve, test fault: every N-th line loses its last two fields.",
)]  # fmt: skip
JsonOutput = alias(bool, json_option(
    "Print what was written (or, with --serve, sent) as JSON on stdout; with --serve the "
    "device path still comes first, on its own line."
))  # fmt: skip


@app.command()
def simulate(
    ctx: typer.Context,
    plan: Plan = "qureshi18",
    seed: Seed = 0,
    rate: Rate = 100.0,
    hold: Hold = None,
    accel_noise: AccelNoise = 0.01,
    jitter_deg: JitterDeg = 2.0,
    units: Units = "counts",
    output: Output = None,
    force: Force = False,
    rotations_per_axis: RotationsPerAxis = 18,
    peak_rate: PeakRate = 150.0,
    still: Still = 5.0,
    sigma_counts: SigmaCounts = 0.7,
    orientations: Orientations = None,
    samples: Samples = 10,
    labelled: Labelled = False,
    mountings: Mountings = 2,
    serve: Serve = False,
    baud: Baud = 115200,
    protocol: Protocol = "lines",
    loop: Loop = False,
    step: Step = False,
    duration: Duration = None,
    person: PersonOpt = False,
    ramp: Ramp = None,
    clock_ppm: ClockPpm = None,
    g_sensitivity: GSensitivity = None,
    temp: Temp = True,
    mag: Mag = False,
    field_ut: FieldUt = 48.0,
    inclination: Inclination = 60.0,
    mag_units: MagUnits = "counts",
    mag_noise: MagNoise = 0.4,
    mag_layout: MagLayout = "ak8963",
    field_unknown: FieldUnknown = False,
    tumble: Tumble = 4.0,
    move: Move = 1.5,
    garbage: Garbage = False,
    stall_after: StallAfter = None,
    vanish_after: VanishAfter = None,
    malformed_every: MalformedEvery = None,
    json_output: JsonOutput = False,
    imus: Imus = 1,
    imu_rotation: ImuRotation = 5.0,
    imu_offset: ImuOffset = 10.0,
    serve_imu: ServeImu = None,
) -> None:
    """Simulate a calibration session of a cheap 16-bit MEMS IMU with known truth.

    Writes the session (HDF5) and the true calibration (JSON) of the simulated part; with
    --serve, streams it live on a pseudo-terminal instead (every plan; ends after the plan,
    --duration, or on Ctrl-C/SIGTERM).  Test faults of --serve: --garbage (random bytes, as a
    wrong baud rate), --stall-after SECONDS, --vanish-after SECONDS (close the port),
    --malformed-every N.

    Exit status: 0 written (or streamed); 2 bad input (unknown plan, bad option, existing
    output without --force).
    """
    check_numbers(dict(locals()))  # every number in its physical range, before anything runs
    given = _given(ctx)
    if person:
        _check_person(serve, given)
        _serve_person(seed=seed, rate_hz=rate, baud=baud, units=units, accel_noise=accel_noise,
                      jitter_deg=jitter_deg, temperature=temp, duration_s=duration,
                      json_output=json_output)  # fmt: skip
        return
    thermal, clock = _checked(plan, serve, ramp, clock_ppm, mag, given("protocol"))
    check_set_options(imus, plan, given)  # several IMUs (issue 28)
    _warn_without_mag(mag, given)
    options = {
        "accel_noise": accel_noise, "jitter_deg": jitter_deg, "still_s": still,
        "rotations_per_axis": rotations_per_axis if given("rotations_per_axis") else None,
        "peak_rate_dps": peak_rate, "sigma_counts": sigma_counts, "orientations": orientations,
        "samples": samples, "labelled": labelled, "mountings": mountings,
    }  # fmt: skip
    if g_sensitivity is not None:
        if not 0 < g_sensitivity <= 0.1 or mag:
            raise InputError("--g-sensitivity must be in (0, 0.1] rad/s per m/s^2, without --mag")
        options["g_sensitivity"] = g_sensitivity
    if serve:
        if mag:  # the same part and samples as --mag writes; the hold is the device's
            if protocol != "lines":
                raise InputError(f"--protocol {protocol} prints its own magnetometer (or none): "
                                 "leave out --mag")  # fmt: skip
            options["mag"] = {
                "field_uT": field_ut, "inclination_deg": inclination, "mag_units": mag_units,
                "mag_noise": mag_noise, "layout": mag_layout, "field_known": not field_unknown,
                "tumble_s": tumble,
            }  # fmt: skip
        extras = {"temperature": thermal, "clock_scale": clock}
        options.update({k: v for k, v in extras.items() if v is not None})
        options.update(serve_options(imus, imu_rotation, imu_offset, serve_imu))
        _serve(plan, rate, baud, json_output, seed=seed, units=units, move_s=move, step=step,
               hold_s=SERVE_HOLD_S if hold is None else hold, plan_options=options,
               temperature=temp, loop=loop, duration_s=duration, garbage=garbage,
               stall_after_s=stall_after, vanish_after_s=vanish_after,
               malformed_every=malformed_every, protocol=protocol)  # fmt: skip
        return
    out, truth_out = _outputs(output, plan, seed, force)
    if imus > 1:
        session, truth = simulate_imus(
            imus, plan, seed, rate=rate, hold=hold, accel_noise=accel_noise,
            jitter_deg=jitter_deg, units=units, move=move, rotation_deg=imu_rotation,
            offset_ms=imu_offset,
        )  # fmt: skip
    elif mag:
        session, truth = _simulate_mag(
            plan, seed, units, rate, hold, accel_noise, jitter_deg, field_uT=field_ut,
            inclination_deg=inclination, mag_units=mag_units, mag_noise=mag_noise,
            layout=mag_layout, field_known=not field_unknown, tumble_s=tumble,
        )  # fmt: skip
    else:
        session, truth = _simulate_plan(plan, seed, units, rate if given("rate") else None,
                                        hold, move, thermal, clock, options)  # fmt: skip
    _write(out, truth_out, session, truth, force, plan, seed, json_output)


#: What --person does not combine with: the plan's options and the test faults.
NOT_WITH_PERSON = ("plan", "hold", "output", "loop", "step", "ramp", "clock_ppm",
                   "g_sensitivity", "mag", "protocol", "move", "garbage", "stall_after",
                   "vanish_after", "malformed_every")  # fmt: skip


def _check_person(serve: bool, given) -> None:
    """--person streams live, following the guide: refuse what belongs to a plan or a file."""
    if not serve:
        raise InputError("--person holds a live unit: add --serve")
    for name in NOT_WITH_PERSON:
        if given(name):
            flag = "--" + name.replace("_", "-")
            raise InputError(f"--person follows the guide, not a plan: leave out {flag}")


def _serve_person(json_output: bool, **options) -> None:
    """``--serve --person``: the device path on stdout, then the stream until the reader
    closes the port; what was sent (as --serve says it)."""

    def status(message: str) -> None:
        print(f"imucal: {message}", file=sys.stderr, flush=True)

    result = serve_person(announce=lambda path: print(path, flush=True), status=status,
                          **options)  # fmt: skip
    _sent(result, json_output)


def _given(ctx: typer.Context):
    """``given(name)``: whether the option ``name`` was on the command line (not its default)."""

    def given(name: str) -> bool:
        source = ctx.get_parameter_source(name)
        return source is not None and source.name != "DEFAULT"

    return given


def _checked(plan: str, serve: bool, ramp: str | None, clock_ppm: float | None, mag: bool,
             protocol: bool):  # fmt: skip
    """Refuse what does not go together, an unknown plan first (with the list of plans);
    return the temperature ramp and the clock scale asked for (None: not asked)."""
    load_plan(plan)
    thermal = None
    if ramp is not None:
        _poses_or_turns("--ramp", plan)
        thermal = parse_ramp(ramp)
    clock = None
    if clock_ppm is not None:
        _poses_or_turns("--clock-ppm", plan)
        clock = check_ppm(clock_ppm)
    if mag:
        _mag_plan(plan, thermal is not None or clock is not None)
    if protocol and not serve:
        raise InputError("--protocol is what --serve prints: add --serve")
    return thermal, clock


#: The options of the simulated magnetometer, as ``--help`` names them.
MAG_OPTIONS = {"field_ut": "--field-uT", "inclination": "--inclination-deg",
               "mag_units": "--mag-units", "mag_noise": "--mag-noise",
               "mag_layout": "--mag-layout", "field_unknown": "--field-unknown",
               "tumble": "--tumble"}  # fmt: skip


def _warn_without_mag(mag: bool, given) -> None:
    """Options of the magnetometer given without ``--mag`` change nothing: say so (issue
    24.7)."""
    unused = [flag for name, flag in MAG_OPTIONS.items() if given(name)]
    if unused and not mag:
        verb = "goes" if len(unused) == 1 else "go"
        warnings.warn(f"{', '.join(unused)} {verb} with --mag (a simulated magnetometer): "
                      "ignored without it", ImucalWarning, stacklevel=2)  # fmt: skip


def _outputs(output: Path | None, plan: str, seed: int, force: bool) -> tuple[Path, Path]:
    """The session and its truth beside it, both checked before anything is simulated."""
    out = check_session_output(output if output is not None else default_output(plan, seed),
                               "imucal simulate")  # fmt: skip
    truth_out = truth_path(out)
    if out.resolve() == truth_out.resolve():
        raise InputError(f"{out}: the session name must not end in .truth.json")
    for p in (out, truth_out):
        check_output(p, force=force)
    return out, truth_out


def _simulate_mag(plan: str, seed: int, units: str, rate: float, hold: float | None,
                  accel_noise: float, jitter_deg: float, **mag):  # fmt: skip
    """A pose plan with a magnetometer (``--mag``); without --hold the simulator's own hold."""
    held = {} if hold is None else {"hold_s": hold}
    return simulate_mag(plan, seed, **mag, rate_hz=rate, accel_noise=accel_noise,
                        jitter_deg=jitter_deg, units=units, **held)  # fmt: skip


def _simulate_plan(plan: str, seed: int, units: str, rate: float | None, hold: float | None,
                   move: float, thermal, clock, options: dict):  # fmt: skip
    """Any plan, by the experiment that plays it."""
    return simulate_plan(plan, seed=seed, units=units, rate_hz=rate, hold_s=hold, move_s=move,
                         temperature=thermal, clock_scale=clock, **options)  # fmt: skip


def _write(out: Path, truth_out: Path, session, truth, force: bool, plan: str, seed: int,
           json_output: bool) -> None:  # fmt: skip
    """Write the session and its truth, and say what was written."""
    rate = float(session.sample_rate_hz)
    truth = dataclasses.replace(truth, session=out.name)
    write_session(out, session, overwrite=force)
    write_calibration(truth_out, truth, force=force)
    n_static = sum(1 for s in session.segments if s.kind == "static")
    n = len(session.time)
    if json_output:
        print_json(
            {"format": "imucal-simulate", "format_version": 1, "output": str(out),
             "truth": str(truth_out), "plan": plan, "seed": seed, "sensor": session.sensor,
             "samples": n, "duration_s": n / rate, "sample_rate_hz": rate,
             "static_segments": n_static, "rotation_segments": len(session.segments) - n_static,
             "accel_units": session.accel_units, "gyro_units": session.gyro_units,
             "imus": [session.reference_name, *session.imus]}
        )  # fmt: skip
        return
    typer.echo(
        f"wrote {out}: {n_static} poses, {n} samples ({n / rate:.1f} s at {rate:g} Hz), "
        f"{session.accel_units}"
        + (f"; magnetometer in {session.mag_units}" if session.mag is not None else "")
        + (f"; {len(session.imus) + 1} IMUs ({session.reference_name} in /raw, "
           f"{', '.join(session.imus)} in /imus)" if session.imus else "")
    )
    typer.echo(f"wrote {truth_out}: true calibration of {session.sensor}")


def _serve(plan: str, rate: float, baud: int, json_output: bool, **options) -> None:
    def announce(path: str) -> None:
        print(path, flush=True)

    pending: list[str] = []  # how the plan is paced: said once the serve starts

    def status(message: str) -> None:
        while pending:  # after the plan's checks: a refused plan is one line
            print(f"imucal: {pending.pop()}", file=sys.stderr, flush=True)
        print(f"imucal: {message}", file=sys.stderr, flush=True)

    enter = _enter_presses()
    if options.get("step") and enter is None:
        raise InputError("--step needs Enter from this terminal: run --serve in the foreground")
    how = ("each pose is held until you press Enter here" if options.get("step") else
           f"the plan runs on a timer, each pose held {options['hold_s']:g} s"
           + ("; Enter here moves to the next pose now" if enter else ""))  # fmt: skip
    pending.append(how)
    result = serve(plan, rate, baud, announce=announce, status=status, next_pose=enter,
                   **options)  # fmt: skip
    _sent(result, json_output)


def _sent(result, json_output: bool) -> None:
    """What the virtual port sent: JSON or the ``# sent ...`` line."""
    if json_output:
        document = {"format": "imucal-serve", "format_version": 1, "path": result.path,
                    "lines": result.lines, "malformed": result.malformed,
                    "garbage_bytes": result.garbage_bytes, "seconds": result.seconds,
                    "end": result.end}  # fmt: skip
        print(json.dumps(document), flush=True)
        return
    print(
        f"# sent {result.lines} lines, {result.malformed} malformed, "
        f"{result.garbage_bytes} garbage bytes, {result.seconds:.2f} s, end {result.end}",
        flush=True,
    )
