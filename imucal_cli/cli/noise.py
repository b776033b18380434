"""`imucal noise`: Allan deviation of a still recording; random walk and bias instability."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich import box
from rich.console import Console
from rich.table import Table
from rich.text import Text

from imucal_cli.formats.output import check_output, check_plot_output
from imucal_cli.formats.session import open_samples
from imucal_cli.use.noise import analyse_noise, figures, imu_calibration, load_calibration
from imucal_cli.use.plots import noise_figure
from imucal_cli.use.report.out import show_table

from .app import app
from .console import make_console
from .options import ForcePlot, calibration_option, json_option, plot_option, session_argument


@app.command()
def noise(
    session: Path = session_argument("A still recording (.h5), e.g. from capture --plan still:20."),
    calibration: Path | None = calibration_option(
        "Calibration JSON (or a session holding one) turning raw channels into SI; needed for "
        "counts or V.",
        "-c",
    ),
    plot: Path | None = plot_option("Also draw the Allan deviation curves (needs matplotlib)."),
    json_output: bool = json_option(
        "Print the figures and curves as JSON on stdout (nothing else)."
    ),
    force: ForcePlot = False,
    imu: str | None = typer.Option(
        None, "--imu", metavar="NAME",
        help="A session of several IMUs: measure IMU NAME (its /imus/NAME samples; the "
        "reference also as 'reference') [default: the reference]. A calibration of the set "
        "gives that IMU's own sections.",
    ),
) -> None:
    """Noise figures of a still recording for your filter: Allan deviation per axis.

    Accelerometer: velocity random walk (m/s/sqrt(s), ug/sqrt(Hz)) and bias instability
    (m/s^2, ug); gyroscope: angle random walk (rad/sqrt(s), deg/sqrt(h)) and bias instability
    (deg/h); rate random walk where the curve shows a +1/2 slope.  Uses the longest static
    segment of SESSION, or the whole recording when it has none.  A session of several IMUs:
    the reference, or the IMU --imu names (the output names the IMU measured).  Exit status:
    0 done; 2 bad input (raw units without --calibration, a recording too short or not still,
    an IMU the session or the calibration does not hold).
    """
    inputs = [session, calibration]
    if plot is not None:
        check_output(check_plot_output(plot), force=force, inputs=inputs)
    with open_samples(session, imu) as samples:
        cal = None if calibration is None else load_calibration(calibration)
        if cal is not None:
            cal = imu_calibration(cal, samples)  # a set's: the IMU measured's (issue 28)
        result = analyse_noise(samples, cal)
    if plot is not None:
        noise_figure(result, plot, force=force, inputs=inputs)
    if json_output:
        typer.echo(json.dumps(result.to_dict(), indent=2))
        return
    console = make_console()
    _render(console, result)
    if plot is not None:
        typer.echo(f"wrote {plot}")


# Columns of the tables (--json has every unit).
_SHOWN = {
    "vrw_m_s_per_sqrt_s", "vrw_ug_per_sqrt_hz", "bias_instability_ug", "rrw_m_s2_per_sqrt_s",
    "arw_rad_per_sqrt_s", "arw_deg_per_sqrt_h", "bias_instability_deg_h", "rrw_deg_h_per_sqrt_h",
}  # fmt: skip
_HOW = {
    "accel": "VRW (velocity random walk; m/s/sqrt(s) = (m/s^2)/sqrt(Hz)): -1/2 slope line at "
    "tau = 1 s; bias instab.: minimum / 0.664 (< : an upper bound); RRW: +1/2 line at 3 s",
    "gyro": "ARW (angle random walk): -1/2 slope line at tau = 1 s; bias instab.: minimum / "
    "0.664 (< : an upper bound); RRW (rate random walk): +1/2 line at tau = 3 s",
}


def _render(console: Console, result) -> None:
    """One table per sensor: a row per axis, a column per figure with its unit."""
    sensor = f" ({result.sensor})" if result.sensor else ""
    if result.imu is not None:  # a set: which of its IMUs
        sensor = (f" IMU {result.imu}{sensor}, of {len(result.imus)} "
                  f"({', '.join(result.imus)}; --imu NAME for another)")  # fmt: skip
    console.print(
        Text(f"{result.session}{sensor}: {result.span}, {result.limits()}"), soft_wrap=True
    )
    for s in result.sensors:
        table = Table(
            title=Text(f"{s.kind}: Allan deviation figures, raw -> {s.units} by {s.basis}"),
            box=box.SIMPLE,
            title_justify="left",
        )
        table.add_column("axis")
        rows = [f for f in figures(s.kind) if f[0] in _SHOWN]
        for _, _, _, unit, title in rows:
            table.add_column(f"{title}\n{unit}", justify="right", no_wrap=True)
        table.add_column("min at\ns", justify="right")
        for name, a in zip(s.axes, s.noise, strict=True):
            cells = [name]
            for _, attr, factor, _, _ in rows:
                value = getattr(a, attr)
                text = "—" if value is None else f"{value * factor:.3g}"
                if attr == "bias_instability" and a.bias_instability_bound and value is not None:
                    text = "< " + text
                cells.append(text)
            cells.append(f"{a.bias_instability_tau_s:.3g}")
            table.add_row(*map(Text, cells))
        notes = sorted({note for a in s.noise for note in a.notes})
        table.caption = Text("\n".join([_HOW[s.kind], *notes]))
        table.caption_justify = "left"
        show_table(console, table)
    for w in result.warnings:
        console.print(Text.assemble(("warning", "bold yellow"), f": {w}"), soft_wrap=True)
