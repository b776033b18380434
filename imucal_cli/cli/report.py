"""`imucal report`: show what a calibration says (it reads results, it never re-solves)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from imucal_cli.errors import InputError
from imucal_cli.formats.output import check_output, check_plot_output
from imucal_cli.use.plots import report_figure
from imucal_cli.use.report.build import build_report
from imucal_cli.use.report.history import build_history, render_history
from imucal_cli.use.report.load import load_all_for_history, load_for_report
from imucal_cli.use.report.render import render_report

from .app import app
from .console import make_console
from .options import ForcePlot, argument, json_option, plot_option


@app.command()
def report(
    paths: list[Path] = argument(
        "CAL.json|SESSION.h5",
        "A calibration JSON, or a session .h5 (its last stored calibration is shown). "
        "Several: the history of each sensor across them.",
    ),
    json_output: bool = json_option(
        "Print the report (or the history) as JSON on stdout (nothing else), not tables."
    ),
    plot: Path | None = plot_option(
        "Also draw |a| per pose before/after, residuals, rotation angle errors and the "
        "pose directions to a PNG (needs matplotlib: pip install 'imucal-cli[plot]')."
    ),
    force: ForcePlot = False,
    history: bool = typer.Option(
        False, "--history",
        help="Show how the parameters of each sensor drift across its calibrations (every "
        "calibration stored in a session counts); implied by several paths.",
    ),  # fmt: skip
) -> None:
    """Report a calibration: parameters ± std, RMS before/after/held-out, poses, coverage.

    Shows the figures the solver stored; nothing is re-solved. For the factorization solver
    also the frame of the matrix, linear vs refined values (bias, gain, every pair's angle, as
    in Hwangbo & Kanade's Table I) and, for gyroscopes, each known-angle turn.

    A calibration from another tool (only bias, matrix, residual_rms) is shown with what it lacks.

    With several paths (or --history): calibrations are grouped by their sensor field; for
    each sensor with two or more, its parameters over time, the change from the first and a
    "drifted" flag when a change exceeds 3 combined standard deviations; calibrations made
    with another solver, model, units or gravity are not compared with each other.

    Exit status: 0 shown; 2 bad input (missing or malformed file, a session without a stored
    calibration, --plot with several calibrations or without matplotlib).
    """
    # Imported here so the other commands and `imucal --help` do not load the report stack.

    if history or len(paths) > 1:
        if plot is not None:
            raise InputError("--plot draws one calibration: give one path without --history")
        _show(build_history(load_all_for_history(paths)), json_output, render_history)
        return
    if plot is not None:
        check_output(check_plot_output(plot), force=force, inputs=paths)
    cal = load_for_report(paths[0])
    result = build_report(cal)
    if plot is not None:
        report_figure(result, plot, force=force, inputs=paths)
    _show(result, json_output, render_report)
    if plot is not None and not json_output:
        typer.echo(f"wrote {plot}")


def _show(result: dict, json_output: bool, render) -> None:
    """A report (or history) as JSON on stdout, or drawn by ``render``."""
    if json_output:
        typer.echo(json.dumps(result, indent=2))
    else:
        render(result, make_console())
