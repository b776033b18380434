"""`imucal calibrate`: run the configured solvers on a session and write the calibration."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape

from .app import app


@app.command()
def calibrate(
    session: Path = typer.Argument(
        ..., help="Session file (.h5) to calibrate.", show_default=False
    ),
    config: Path | None = typer.Option(
        None, "--config", "-c", help="TOML config choosing solvers and options (see README)."
    ),
    output: Path | None = typer.Option(
        None, "--output", "-o", help="Calibration JSON to write [default: SESSION with .cal.json]."
    ),
    model: str | None = typer.Option(
        None,
        "--model",
        help="Gravity solver model: 9 (triangular, eqs. 3-8) or 12 (full matrix "
        "aligned to the labelled up directions). Overrides [accel.gravity] model.",
    ),
    gravity: float | None = typer.Option(
        None, "--gravity", help="Local gravity in m/s^2 [default: the session's, else 9.80665]."
    ),
    force: bool = typer.Option(
        False,
        "--force",
        help="Replace an existing OUTPUT, and save a result that fails the physical-sense "
        "checks (with warnings).",
    ),
    store: bool = typer.Option(
        True,
        "--store/--no-store",
        help="Also store the calibration under the session's /calibrations.",
    ),
) -> None:
    """Calibrate the accelerometer of SESSION and write a calibration JSON.

    Exit status: 0 saved; 2 bad input, nothing saved (unreadable file, bad config, poses that
    cannot determine the model, OUTPUT exists without --force or is the session); 1 the
    solver did not converge or the result is outside physical sense (not saved unless --force),
    or saved but not stored in the session (the reason is printed).
    """
    from imucal_cli.formats.calibration import write_calibration
    from imucal_cli.formats.config import load_config, validate
    from imucal_cli.formats.output import check_output
    from imucal_cli.formats.session import read_session
    from imucal_cli.pipeline.calibrate import calibrate_session, default_output, suspect_error

    cfg = load_config(config)
    if model is not None:
        cfg.accel.gravity.model = model
    if gravity is not None:
        cfg.gravity = gravity
    validate(cfg, "command line" if config is None else str(config))
    out = output or default_output(session)
    inputs = [session, config]
    check_output(out, force=force, inputs=inputs)  # refuse before solving, not after

    sess = read_session(session)
    cal = calibrate_session(sess, cfg, name=session.name)
    problem = suspect_error(cal)
    if problem is not None and not force:
        raise problem

    write_calibration(out, cal, force=force, inputs=inputs)
    # Saved: from here on the exit status is 0, or 1 with the reason (never 2).
    name, failure = _store(session, cal) if store else (None, None)
    console = Console(highlight=False, soft_wrap=True)
    _summary(console, cal)
    where = f" and {session}:/calibrations/{name}" if name is not None else ""
    console.print(f"wrote {escape(str(out) + where)}")
    if failure is not None:
        Console(stderr=True, highlight=False, soft_wrap=True).print(
            f"imucal: error: saved {escape(str(out))} but could not store it in the session "
            f"({escape(str(failure))}); pass --no-store not to store it"
        )
        raise typer.Exit(1)


def _store(session: Path, cal) -> tuple[str | None, Exception | None]:
    """Store in the session; return (name, None), or (None, the error): the JSON is saved."""
    from imucal_cli.errors import ImucalError
    from imucal_cli.formats.calibration import calibration_to_json
    from imucal_cli.formats.session import store_calibration

    try:
        return store_calibration(session, calibration_to_json(cal)), None
    except (ImucalError, OSError) as exc:
        return None, exc


def _summary(console: Console, cal) -> None:
    """A few lines per calibrated sensor: what ran, the residuals, bias and sensitivity."""
    for name, sec in (("accel", cal.accel), ("gyro", cal.gyro)):
        if sec is None:
            continue
        x = sec.extra
        units = x.get("units_in", "raw units")
        how = [f"{sec.solver} ({x['variant']})" if "variant" in x else sec.solver]
        if "coverage" in x:
            how.append(f"{x['coverage']['n_poses']} poses")
        if "iterations" in x:
            how.append(f"{x['iterations']} iterations")
        if x.get("init"):
            how.append(f"init {x['init']}")
        console.print(f"[bold]{name}[/]: " + escape(", ".join(how)))
        if name == "accel" and x.get("rms_after") is not None:
            g = x["gravity"]
            before = x.get("rms_before")
            text = "  |a| - g RMS: "
            if before is not None:
                text += f"before {before:.4f} m/s^2 ({1000 * before / g:.2f} mg) -> "
            text += f"after {x['rms_after']:.4f} m/s^2 ({1000 * x['rms_after'] / g:.3f} mg)"
            if x.get("rms_loo") is not None:
                text += f", held out {x['rms_loo']:.4f} m/s^2"
            console.print(escape(text))
        turns = x.get("rotations", [])
        if turns and x.get("rotation_rms_deg") is not None:
            console.print(
                f"  {len(turns)} rotations, angle residual RMS {x['rotation_rms_deg']:.3f} deg"
            )
        elif turns:
            for rot in turns[:3]:
                console.print(
                    escape(
                        f"  {rot['label'] or rot['segment']}: "
                        f"measured {rot['measured_angle_deg']:.3f} deg, "
                        f"known {rot['known_angle_deg']:.3f} deg"
                    )
                )
        per = "m/s^2" if name == "accel" else "rad/s"
        console.print(
            escape(
                "  bias "
                + ", ".join(f"{b:.5g}" for b in sec.bias)
                + f" {units}; sensitivity "
                + ", ".join(f"{v:.5g}" for v in x.get("sensitivity", []))
                + f" {units} per {per}"
            )
        )
        for w in x.get("warnings", []):
            console.print(f"  [bold yellow]warning[/]: {escape(str(w))}")
