"""`imucal calibrate`: run the configured solvers on a session and write the calibration."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

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
        False, "--force", help="Save a result that fails the physical-sense checks (with warnings)."
    ),
    store: bool = typer.Option(
        True,
        "--store/--no-store",
        help="Also store the calibration under the session's /calibrations.",
    ),
) -> None:
    """Calibrate the accelerometer of SESSION and write a calibration JSON.

    Exit status: 0 saved; 2 bad input (unreadable file, bad config, poses that cannot
    determine the model); 1 the solver did not converge or the result is outside physical
    sense (not saved unless --force).
    """
    from imucal_cli.calibrate import calibrate_session, default_output, suspect_error
    from imucal_cli.calibration import calibration_to_json, write_calibration
    from imucal_cli.config import load_config, validate
    from imucal_cli.session import read_session, store_calibration

    cfg = load_config(config)
    if model is not None:
        cfg.accel.gravity.model = model
    if gravity is not None:
        cfg.gravity = gravity
    validate(cfg, "command line" if config is None else str(config))

    sess = read_session(session)
    cal = calibrate_session(sess, cfg, name=session.name)
    problem = suspect_error(cal)
    if problem is not None and not force:
        raise problem

    out = output or default_output(session)
    write_calibration(out, cal)
    console = Console()
    if store:
        try:
            name = store_calibration(session, calibration_to_json(cal))
            stored = f" and {session}:/calibrations/{name}"
        except OSError as exc:  # read-only session: the JSON is what matters
            stored = f" (not stored in the session: {exc})"
    else:
        stored = ""
    _summary(console, cal, f"{out}{stored}")


def _summary(console: Console, cal, where: str) -> None:
    a = cal.accel
    x = a.extra
    g = x["gravity"]
    loo = x.get("rms_loo")
    held = f", held out {loo:.4f} m/s^2" if loo is not None else ""
    console.print(
        f"[bold]accel[/]: {a.solver} ({x['variant']}), {x['coverage']['n_poses']} poses, "
        f"{x['iterations']} iterations, init {x['init']}"
    )
    console.print(
        f"  |a| - g RMS: before {x['rms_before']:.4f} m/s^2 ({1000 * x['rms_before'] / g:.2f} mg) "
        f"-> after {x['rms_after']:.4f} m/s^2 ({1000 * x['rms_after'] / g:.3f} mg){held}"
    )
    units = x["units_in"]
    console.print(
        "  bias "
        + ", ".join(f"{b:.5g}" for b in a.bias)
        + f" {units}; sensitivity "
        + ", ".join(f"{s:.5g}" for s in x["sensitivity"])
        + f" {units} per m/s^2"
    )
    for w in x.get("warnings", []):
        console.print(f"  [bold yellow]warning[/]: {w}")
    console.print(f"wrote {where}")
