"""`imucal simulate`: write a simulated session and its truth calibration."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import typer

from imucal_cli.errors import InputError

from .app import app
from .options import hold_option, plan_option


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
    hold: float = hold_option(
        "Time held still in each pose",
        "at least 10 samples",
        "The still periods of hwangbo-iron and hk-gyro default to 3 s.",
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
    ),
    output: Path | None = typer.Option(
        None,
        "--output",
        "-o",
        metavar="PATH.h5",
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
    loop: bool = typer.Option(False, "--loop", help="--serve: repeat the plan."),
    duration: float | None = typer.Option(
        None, "--duration", metavar="SECONDS", help="--serve: stop streaming after this long."
    ),
    temp: bool = typer.Option(
        True, "--temp/--no-temp", help="--serve: print the temperature field (8 or 7 fields)."
    ),
    move: float = typer.Option(1.5, "--move", hidden=True),
    garbage: bool = typer.Option(False, "--garbage", hidden=True),
    stall_after: float | None = typer.Option(None, "--stall-after", hidden=True),
    vanish_after: float | None = typer.Option(None, "--vanish-after", hidden=True),
    malformed_every: int | None = typer.Option(None, "--malformed-every", hidden=True),
) -> None:
    """Simulate a calibration session of a cheap 16-bit MEMS IMU with known truth.

    Writes the session (HDF5) and the true calibration (JSON) of the simulated part; with
    --serve, streams it live on a pseudo-terminal instead (every plan; ends after the plan,
    --duration, or on Ctrl-C/SIGTERM).  Test faults of --serve: --garbage (random bytes, as a
    wrong baud rate), --stall-after S, --vanish-after S (close the port), --malformed-every N.
    """
    from imucal_cli.plans import load_plan

    def given(name: str) -> bool:
        source = ctx.get_parameter_source(name)
        return source is not None and source.name != "DEFAULT"

    load_plan(plan)  # an unknown plan is refused first, with the list of plans
    options = {
        "hold_s": hold if given("hold") else None,  # a plan's own default otherwise
        "accel_noise": accel_noise, "jitter_deg": jitter_deg, "still_s": still,
        "rotations_per_axis": rotations_per_axis if given("rotations_per_axis") else None,
        "peak_rate_dps": peak_rate, "sigma_counts": sigma_counts, "orientations": orientations,
        "samples": samples, "labelled": labelled, "mountings": mountings,
    }  # fmt: skip
    if serve:
        _serve(
            plan, rate, baud, seed=seed, move_s=move, units=units, temperature=temp,
            loop=loop, duration_s=duration, garbage=garbage, stall_after_s=stall_after,
            vanish_after_s=vanish_after, malformed_every=malformed_every,
            hold_s=options.pop("hold_s"), plan_options=options,
        )  # fmt: skip
        return
    from imucal_cli.formats.calibration import write_calibration
    from imucal_cli.formats.session import write_session
    from imucal_cli.simulate.play import simulate_plan

    out = output if output is not None else default_output(plan, seed)
    truth_out = truth_path(out)
    if out.resolve() == truth_out.resolve():
        raise InputError(f"{out}: the session name must not end in .truth.json")
    if not out.parent.is_dir():
        raise InputError(f"{out}: directory {out.parent} does not exist")
    if not force:
        for p in (out, truth_out):
            if p.exists():
                raise InputError(f"{p} exists: use --force to overwrite it")
    session, truth = simulate_plan(
        plan, seed=seed, units=units, rate_hz=rate if given("rate") else None, move_s=move,
        **options,
    )  # fmt: skip
    rate = float(session.sample_rate_hz)
    truth = dataclasses.replace(truth, session=out.name)
    write_session(out, session, overwrite=force)
    n_static = sum(1 for s in session.segments if s.kind == "static")
    n = len(session.time)
    typer.echo(
        f"wrote {out}: {n_static} poses, {n} samples ({n / rate:.1f} s at {rate:g} Hz), "
        f"{session.accel_units}"
    )
    write_calibration(truth_out, truth)
    typer.echo(f"wrote {truth_out}: true calibration of {session.sensor}")


def _serve(plan: str, rate: float, baud: int, **options) -> None:
    import sys

    from imucal_cli.simulate.device import serve

    def announce(path: str) -> None:
        print(path, flush=True)

    def status(message: str) -> None:
        print(f"imucal: {message}", file=sys.stderr, flush=True)

    result = serve(plan, rate, baud, announce=announce, status=status, **options)
    print(
        f"# sent {result.lines} lines, {result.malformed} malformed, "
        f"{result.garbage_bytes} garbage bytes, {result.seconds:.2f} s, end {result.end}",
        flush=True,
    )
