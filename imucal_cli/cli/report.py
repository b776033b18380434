"""`imucal report`: show what a calibration says (it reads results, it never re-solves)."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console

from .app import app


@app.command()
def report(
    path: Path = typer.Argument(
        ...,
        help="A calibration JSON, or a session .h5 (its last stored calibration is shown).",
        show_default=False,
    ),
    json_output: bool = typer.Option(
        False,
        "--json",
        help="Print the report as JSON on stdout (nothing else) instead of tables.",
    ),
) -> None:
    """Report a calibration: parameters ± std, RMS before/after/held-out, poses, coverage.

    Shows the figures the solver stored; nothing is re-solved. For the factorization solver
    also the frame of the matrix, linear vs refined values (bias, gain, every pair's angle, as
    in Hwangbo & Kanade's Table I) and, for gyroscopes, each known-angle turn.

    A calibration from another tool (only bias, matrix, residual_rms) is shown with what it lacks.
    """
    # Imported here so the other commands and `imucal --help` do not load the report stack.
    from imucal_cli.report import build_report, load_for_report, render_report

    cal = load_for_report(path)
    result = build_report(cal)
    if json_output:
        typer.echo(json.dumps(result, indent=2))
    else:
        render_report(result, Console())
