"""`imucal simulate`: write a simulated session and its truth calibration."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import typer

from imucal_cli.errors import InputError

from .app import app


def truth_path(session_path: Path) -> Path:
    """Where the truth goes: ``x.h5`` -> ``x.truth.json`` (beside the session)."""
    return session_path.with_suffix(".truth.json")


def default_output(plan: str, seed: int) -> Path:
    """``sim-<plan>-seed<seed>.h5``; the colon of ``random:N`` becomes a dash."""
    return Path(f"sim-{plan.strip().lower().replace(':', '-')}-seed{seed}.h5")


@app.command()
def simulate(
    plan: str = typer.Option(
        "qureshi18",
        "--plan",
        metavar="PLAN",
        help=(
            "Poses to visit: 'six' (the 6 faces of a cube), 'qureshi18' (6 faces + 12 edges "
            "at 45 degrees, Qureshi & Golnaraghi) or 'random:N' (N unlabelled poses, "
            "directions uniform on the sphere)."
        ),
    ),
    seed: int = typer.Option(
        0,
        "--seed",
        metavar="INT",
        help="Random seed (>= 0): the same seed and options give the same samples, in any units.",
    ),
    rate: float = typer.Option(100.0, "--rate", metavar="HZ", help="Sample rate, Hz."),
    hold: float = typer.Option(
        2.0,
        "--hold",
        metavar="SECONDS",
        help="Time held still in each pose, s (at least 10 samples).",
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
) -> None:
    """Simulate a calibration session of a cheap 16-bit MEMS IMU with known truth.

    Writes the session (HDF5) and the true calibration (JSON) of the simulated part.
    """
    from imucal_cli.calibration import write_calibration
    from imucal_cli.session import write_session
    from imucal_cli.simulator import simulate as run

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
    session, truth = run(
        plan=plan,
        seed=seed,
        rate_hz=rate,
        hold_s=hold,
        accel_noise=accel_noise,
        jitter_deg=jitter_deg,
        units=units,
    )
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
