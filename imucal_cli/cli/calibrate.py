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
    from imucal_cli.formats.calibration import calibration_to_json, write_calibration
    from imucal_cli.formats.config import load_config, validate
    from imucal_cli.formats.session import read_session, store_calibration
    from imucal_cli.pipeline.calibrate import calibrate_session, default_output, suspect_error

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
        console.print(f"[bold]{name}[/]: " + ", ".join(how))
        if name == "accel" and x.get("rms_after") is not None:
            g = x["gravity"]
            before = x.get("rms_before")
            text = "  |a| - g RMS: "
            if before is not None:
                text += f"before {before:.4f} m/s^2 ({1000 * before / g:.2f} mg) -> "
            text += f"after {x['rms_after']:.4f} m/s^2 ({1000 * x['rms_after'] / g:.3f} mg)"
            if x.get("rms_loo") is not None:
                text += f", held out {x['rms_loo']:.4f} m/s^2"
            console.print(text)
        turns = x.get("rotations", [])
        if turns and x.get("rotation_rms_deg") is not None:
            console.print(
                f"  {len(turns)} rotations, angle residual RMS {x['rotation_rms_deg']:.3f} deg"
            )
        elif turns:
            for rot in turns[:3]:
                console.print(
                    f"  {rot['label'] or rot['segment']}: "
                    f"measured {rot['measured_angle_deg']:.3f} deg, "
                    f"known {rot['known_angle_deg']:.3f} deg"
                )
        per = "m/s^2" if name == "accel" else "rad/s"
        console.print(
            "  bias "
            + ", ".join(f"{b:.5g}" for b in sec.bias)
            + f" {units}; sensitivity "
            + ", ".join(f"{v:.5g}" for v in x.get("sensitivity", []))
            + f" {units} per {per}"
        )
        for w in x.get("warnings", []):
            console.print(f"  [bold yellow]warning[/]: {w}")
    if cal.extra.get("gyro_note"):
        console.print(f"[bold]gyro[/]: {cal.extra['gyro_note']}")
    console.print(f"wrote {where}")
