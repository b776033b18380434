"""`imucal simulate`: write a simulated session and its truth calibration."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import typer

from imucal_cli.errors import InputError

from . import completion
from .app import app
from .console import print_json
from .options import plan_option

SERVE_HOLD_S = 4.0
"""--serve's hold per pose when --hold is not given, s: capture's default hold (2 s) plus time for
the stillness detector to see the unit settle after a turn."""


def _enter_presses():
    """A poll ``() -> bool`` that is True once per Enter typed on stdin, or None when stdin cannot
    be read without stopping the process (a terminal of a background job: SIGTTIN)."""
    import os
    import sys

    try:
        if sys.stdin is None or sys.stdin.closed:
            return None
        if sys.stdin.isatty() and os.tcgetpgrp(sys.stdin.fileno()) != os.getpgrp():
            return None
    except (OSError, ValueError, AttributeError):
        return None
    from imucal_cli.capture.guided.keys import StdinKeys

    keys = StdinKeys()
    return lambda: keys.get() is not None


def _written_poses_or_turns(flag: str, plan: str, serve: bool) -> None:
    """Refuse ``flag`` (a temperature ramp, a clock error) but for written sessions of the pose
    and hand-rotation plans, the experiments that model it."""
    from imucal_cli.plans import find_plan

    spec = find_plan(plan)[0]
    if serve or spec is None or spec.simulator not in ("poses", "rotations"):
        raise InputError(f"{flag} works for written sessions of plans six, qureshi18, "
                         "random:N, warmup:MINUTES, qureshi-axes and free:N")  # fmt: skip


def _mag_plan(plan: str, serve: bool, thermal_or_clock: bool) -> None:
    """Refuse --mag but for written sessions of the pose plans (six, qureshi18, random:N)."""
    from imucal_cli.plans import find_plan

    spec = find_plan(plan)[0]
    if serve or spec is None or spec.simulator != "poses" or spec.key == "warmup":
        raise InputError(
            "--mag simulates pose plans written to a file (six, qureshi18, random:N), not "
            f"{'--serve' if serve else repr(plan)}"
        )
    if thermal_or_clock:
        raise InputError("--mag does not combine with --ramp or --clock-ppm")


def truth_path(session_path: Path) -> Path:
    """Where the truth goes: ``x.h5`` -> ``x.truth.json`` (beside the session)."""
    return session_path.with_suffix(".truth.json")


def default_output(plan: str, seed: int) -> Path:
    """``sim-<plan>-seed<seed>.h5``; the colon of ``random:N`` becomes a dash."""
    return Path(f"sim-{plan.strip().lower().replace(':', '-')}-seed{seed}.h5")


@app.command()
def simulate(
    ctx: typer.Context,
    plan: str = plan_option(
        "qureshi18",
        "What the virtual IMU goes through (the same plans as imucal capture; --serve streams "
        "them live):",
    ),
    seed: int = typer.Option(
        0,
        "--seed",
        metavar="INT",
        help="Random seed (>= 0): the same seed and options give the same samples, in any units.",
    ),
    rate: float = typer.Option(100.0, "--rate", metavar="HZ", help="Sample rate, Hz."),
    hold: float | None = typer.Option(
        None,
        "--hold",
        metavar="SECONDS",
        help="Time held still in each pose, s (at least 10 samples) [default: 2; with --serve 4, "
        "so that a capture with its default 2 s hold has time to see the unit settle].",
    ),
    accel_noise: float = typer.Option(
        0.01,
        "--accel-noise",
        metavar="M/S^2",
        help="Accelerometer white noise, m/s^2 per axis per sample (std).",
    ),
    jitter_deg: float = typer.Option(
        2.0,
        "--jitter-deg",
        metavar="DEG",
        help=(
            "Placement error: RMS angle, degrees, between each pose's true and labelled up "
            "direction (the heading about the vertical is random anyway)."
        ),
    ),
    units: str = typer.Option(
        "counts",
        "--units",
        metavar="counts|m/s^2",
        help=(
            "Raw units: 'counts' (16-bit integers, 8192 LSB/g, 16.4 LSB per deg/s) or 'm/s^2' "
            "(a part of nominal gain 1; gyro in rad/s; no quantisation)."
        ),
        autocompletion=completion.simulate_units,
    ),
    output: Path | None = typer.Option(
        None,
        "--output",
        "-o",
        metavar="FILE.h5",
        help=(
            "Session file to write (default: sim-<plan>-seed<seed>.h5); the truth goes "
            "beside it as <name>.truth.json."
        ),
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    rotations_per_axis: int = typer.Option(
        18,
        "--rotations-per-axis",
        metavar="N",
        help="qureshi-axes: hand turns per axis, each a different angle (the paper used 18).",
    ),
    peak_rate: float = typer.Option(
        150.0,
        "--peak-rate",
        metavar="DEG/S",
        help=(
            "qureshi-axes, free:N: largest peak rate of a turn, deg/s (each turn's peak is "
            "drawn in 50-100 % of it; smooth smootherstep profiles)."
        ),
    ),
    still: float = typer.Option(
        5.0,
        "--still",
        metavar="SECONDS",
        help="qureshi-axes, free:N: still period before and after each turn, s.",
    ),
    sigma_counts: float = typer.Option(
        0.7,
        "--sigma-counts",
        metavar="COUNTS",
        help=(
            "hk-redundant: Gaussian noise per channel per sample, ADC counts, before rounding to "
            "integer codes (the paper used 0.7 and 1.5)."
        ),
    ),
    orientations: int | None = typer.Option(
        None,
        "--orientations",
        metavar="N",
        help="hk-redundant: number of orientations (default 20 random, or 18 with --labelled).",
    ),
    samples: int = typer.Option(
        10, "--samples", metavar="N", help="hk-redundant: readings held still per orientation."
    ),
    labelled: bool = typer.Option(
        False,
        "--labelled",
        help=(
            "hk-redundant: put the block on its 6 faces and 12 edges and record each pose's up "
            "direction, instead of unlabelled random directions."
        ),
    ),
    mountings: int = typer.Option(
        2,
        "--mountings",
        metavar="N",
        help="hk-gyro: IMU mountings in the iron (1..8), each swept about 3 orthogonal faces.",
    ),
    serve: bool = typer.Option(
        False,
        "--serve",
        help=(
            "Instead of writing a file, be a virtual serial IMU: open a pseudo-terminal, print "
            "its device path, and stream the plan in real time as text lines "
            "t,ax,ay,az,gx,gy,gz,temp (t in s, raw counts) for 'imucal capture --port PATH'."
        ),
    ),
    baud: int = typer.Option(
        115200, "--baud", metavar="N", help="--serve: emulated baud rate (bytes are paced)."
    ),
    protocol: str = typer.Option(
        "lines",
        "--protocol",
        metavar="NAME",
        help="--serve: what a line is: lines (t,ax,ay,az,gx,gy,gz,temp), motioncal (MotionCal's "
        "Raw:ax,ay,az,gx,gy,gz,mx,my,mz, a magnetometer in the earth's field) or i2cdevlib "
        "(a/g:<TAB>ax...gz), counts without a time, as those Arduino sketches print them.",
        autocompletion=completion.serve_protocols,
    ),
    loop: bool = typer.Option(False, "--loop", help="--serve: repeat the plan."),
    step: bool = typer.Option(
        False,
        "--step",
        help="--serve: hold each pose until Enter is pressed in this terminal (without it the "
        "plan runs on a timer, --hold per pose, and Enter moves to the next pose early).",
    ),
    duration: float | None = typer.Option(
        None, "--duration", metavar="SECONDS", help="--serve: stop streaming after this long."
    ),
    ramp: str | None = typer.Option(
        None, "--ramp", metavar="FROM:TO[:linear]",
        help="The part's temperature runs from FROM to TO degrees C through the session (a "
        "warm-up, or :linear for a hair-dryer or chamber ramp); its biases follow it and the "
        "truth holds temperature_ref and bias_tempco.",
    ),
    clock_ppm: float | None = typer.Option(
        None, "--clock-ppm", metavar="PPM",
        help="The part's sample clock runs PPM parts per million fast (negative: slow): the "
        "session records its device times and the host's arrival times (/raw/host_time).",
    ),
    temp: bool = typer.Option(
        True, "--temp/--no-temp", help="--serve: print the temperature field (8 or 7 fields)."
    ),
    mag: bool = typer.Option(
        False,
        "--mag",
        help=(
            "Pose plans (six, qureshi18, random:N): add a magnetometer (an AK8963-like part: "
            "hard and soft iron, axes x/y swapped and z reversed relative to the accelerometer) "
            "and tumble the unit through random attitudes between the holds (--tumble)."
        ),
    ),
    field_ut: float = typer.Option(
        48.0, "--field-uT", metavar="UT", help="--mag: local field magnitude, microtesla."
    ),
    inclination: float = typer.Option(
        60.0,
        "--inclination-deg",
        metavar="DEG",
        help="--mag: inclination of the field below the horizontal, degrees (-90..90).",
    ),
    mag_units: str = typer.Option(
        "counts",
        "--mag-units",
        metavar="counts|uT|nT|gauss",
        help="--mag: raw magnetometer units (counts: 0.15 uT per LSB, integers).",
    ),
    mag_noise: float = typer.Option(
        0.4, "--mag-noise", metavar="UT", help="--mag: white noise per axis per sample, uT."
    ),
    mag_layout: str = typer.Option(
        "ak8963",
        "--mag-layout",
        metavar="ak8963|aligned",
        help="--mag: the magnetometer's axes relative to the accelerometer's.",
    ),
    field_unknown: bool = typer.Option(
        False,
        "--field-unknown",
        help="--mag: leave the field magnitude out of the session (no magnetic_field_uT).",
    ),
    tumble: float = typer.Option(
        4.0,
        "--tumble",
        metavar="SECONDS",
        help="--mag: tumble through random attitudes this long between holds (0: plain moves).",
    ),
    move: float = typer.Option(
        1.5, "--move", metavar="SECONDS", help="--serve: time each turn between poses takes, s."
    ),
    garbage: bool = typer.Option(
        False,
        "--garbage",
        help="--serve, test fault: random bytes instead of lines (as a wrong baud rate shows).",
    ),
    stall_after: float | None = typer.Option(
        None,
        "--stall-after",
        metavar="SECONDS",
        help="--serve, test fault: stop sending after this long, keep the port open.",
    ),
    vanish_after: float | None = typer.Option(
        None,
        "--vanish-after",
        metavar="SECONDS",
        help="--serve, test fault: close the port after this long (the device is unplugged).",
    ),
    malformed_every: int | None = typer.Option(
        None,
        "--malformed-every",
        metavar="N",
        help="--serve, test fault: every N-th line loses its last two fields.",
    ),
    json_output: bool = typer.Option(
        False,
        "--json",
        help="Print what was written (or, with --serve, sent) as JSON on stdout; with --serve "
        "the device path still comes first, on its own line.",
    ),
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
    from imucal_cli.plans import load_plan

    def given(name: str) -> bool:
        source = ctx.get_parameter_source(name)
        return source is not None and source.name != "DEFAULT"

    load_plan(plan)  # an unknown plan is refused first, with the list of plans
    options = {
        "accel_noise": accel_noise, "jitter_deg": jitter_deg, "still_s": still,
        "rotations_per_axis": rotations_per_axis if given("rotations_per_axis") else None,
        "peak_rate_dps": peak_rate, "sigma_counts": sigma_counts, "orientations": orientations,
        "samples": samples, "labelled": labelled, "mountings": mountings,
    }  # fmt: skip
    thermal = None
    if ramp is not None:
        from imucal_cli.simulate.temperature import parse_ramp

        _written_poses_or_turns("--ramp", plan, serve)
        thermal = parse_ramp(ramp)
    clock = None
    if clock_ppm is not None:
        from imucal_cli.simulate.clock import check_ppm

        _written_poses_or_turns("--clock-ppm", plan, serve)
        clock = check_ppm(clock_ppm)
    if mag:
        _mag_plan(plan, serve, thermal is not None or clock is not None)
    if given("protocol") and not serve:
        raise InputError("--protocol is what --serve prints: add --serve")
    if serve:
        _serve(
            plan, rate, baud, json_output, seed=seed, hold_s=SERVE_HOLD_S if hold is None else hold,
            move_s=move, step=step, units=units, plan_options=options,
            temperature=temp, loop=loop, duration_s=duration, garbage=garbage,
            stall_after_s=stall_after, vanish_after_s=vanish_after,
            malformed_every=malformed_every, protocol=protocol,
        )  # fmt: skip
        return
    from imucal_cli.formats.calibration import write_calibration
    from imucal_cli.formats.output import check_output
    from imucal_cli.formats.session import write_session
    from imucal_cli.simulate.play import simulate_plan

    out = output if output is not None else default_output(plan, seed)
    truth_out = truth_path(out)
    if out.resolve() == truth_out.resolve():
        raise InputError(f"{out}: the session name must not end in .truth.json")
    for p in (out, truth_out):
        check_output(p, force=force)
    if mag:
        from imucal_cli.simulate.magnetometer import simulate_mag

        session, truth = simulate_mag(
            plan, seed, field_uT=field_ut, inclination_deg=inclination, mag_units=mag_units,
            mag_noise=mag_noise, layout=mag_layout, field_known=not field_unknown, tumble_s=tumble,
            rate_hz=rate, hold_s=hold, accel_noise=accel_noise, jitter_deg=jitter_deg,
            units=units,
        )  # fmt: skip
    else:
        session, truth = simulate_plan(
            plan, seed=seed, units=units, rate_hz=rate if given("rate") else None, hold_s=hold,
            move_s=move, temperature=thermal, clock_scale=clock, **options,
        )  # fmt: skip
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
             "accel_units": session.accel_units, "gyro_units": session.gyro_units}
        )  # fmt: skip
        return
    typer.echo(
        f"wrote {out}: {n_static} poses, {n} samples ({n / rate:.1f} s at {rate:g} Hz), "
        f"{session.accel_units}"
        + (f"; magnetometer in {session.mag_units}" if session.mag is not None else "")
    )
    typer.echo(f"wrote {truth_out}: true calibration of {session.sensor}")


def _serve(plan: str, rate: float, baud: int, json_output: bool, **options) -> None:
    import sys

    from imucal_cli.simulate.device import serve

    def announce(path: str) -> None:
        print(path, flush=True)

    def status(message: str) -> None:
        print(f"imucal: {message}", file=sys.stderr, flush=True)

    enter = _enter_presses()
    if options.get("step") and enter is None:
        raise InputError("--step needs Enter from this terminal: run --serve in the foreground")
    how = ("each pose is held until you press Enter here" if options.get("step") else
           f"the plan runs on a timer, each pose held {options['hold_s']:g} s"
           + ("; Enter here moves to the next pose now" if enter else ""))  # fmt: skip
    status(how)
    result = serve(plan, rate, baud, announce=announce, status=status, next_pose=enter,
                   **options)  # fmt: skip
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
