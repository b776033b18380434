"""``imucal registry list|show|export|import|lot``: the calibrations of every unit, kept by
serial number (docs/registry.md).  The tables are drawn by :mod:`.registry_render`."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer

from imucal_cli.errors import InputError
from imucal_cli.formats.output import check_output, check_plot_output, safe_output
from imucal_cli.registry import REGISTRY_ENV
from imucal_cli.registry.lot import drop_values, lot_statistics
from imucal_cli.registry.lot_plot import lot_figure
from imucal_cli.registry.queries import list_units, unit_report
from imucal_cli.registry.record import UnitInfo
from imucal_cli.registry.store import open_registry
from imucal_cli.registry.transfer import export_records, import_files
from imucal_cli.use.limits import load_limits

from .app import app, help_width
from .console import make_console
from .options import json_option, registry_option
from .registry_render import render_lot, render_unit, render_units

registry_app = typer.Typer(
    name="registry",
    no_args_is_help=True,
    rich_markup_mode=None,
    context_settings={"help_option_names": ["-h", "--help"], "terminal_width": help_width(),
                      "max_content_width": help_width()},  # fmt: skip
    help="The calibrations of every unit by serial number: list, show a unit's history and "
    "drift, export and import records, a lot's statistics. The registry is a SQLite file or "
    f"a PostgreSQL URL (--registry, or ${REGISTRY_ENV}); imucal calibrate --registry records "
    "into it. Each command's options: imucal registry COMMAND --help; the limits file, the "
    "statistics and the certificate: docs/registry.md.",
)
app.add_typer(registry_app, name="registry")

_REGISTRY_HELP = "The registry: a SQLite file or postgresql+psycopg://user@host/db."


def _open(registry: str | None, *, create: bool = False):
    if not registry:
        raise InputError(f"no registry: give --registry PATH|URL (or set {REGISTRY_ENV})")
    return open_registry(registry, create=create)


def _echo_json(document) -> None:
    typer.echo(json.dumps(document, indent=2, allow_nan=False))


@registry_app.command("list")
def list_(
    registry: str | None = registry_option(_REGISTRY_HELP),
    product: str | None = typer.Option(
        None, "--product", metavar="NAME", help="Only the units of this product."
    ),
    lot: str | None = typer.Option(
        None, "--lot", metavar="LOT", help="Only the units of this lot."
    ),
    json_output: bool = json_option("Print the units as JSON (imucal-registry-list)."),
) -> None:
    """List the units: serial, product, lot, calibrations, the latest one's time, station and
    verdict.

    Exit status: 0 listed; 2 bad input (no such registry, not a registry).
    """
    with _open(registry) as reg:
        rows = list_units(reg, product=product, lot=lot)
        name = reg.name
    if json_output:
        _echo_json({"format": "imucal-registry-list", "format_version": 1, "registry": name,
                    "units": rows})  # fmt: skip
        return
    render_units(rows, name, make_console())


@registry_app.command("show")
def show(
    serial: str = typer.Argument(..., metavar="SERIAL", help="The unit's serial number."),
    registry: str | None = registry_option(_REGISTRY_HELP),
    json_output: bool = json_option(
        "Print the unit's record as JSON (imucal-registry-unit: calibrations and history)."
    ),
) -> None:
    """Show a unit: every calibration (when, where, who, verdict, session hash) and the history
    of its parameters with today's drift report (as imucal report A B: a change beyond 3
    combined std from the reference calibration is flagged).

    Exit status: 0 shown; 2 bad input (no such registry or unit).
    """
    with _open(registry) as reg:
        record = unit_report(reg, serial)
    if json_output:
        _echo_json(record)
        return
    render_unit(record, make_console())


@registry_app.command("export")
def export(
    registry: str | None = registry_option(_REGISTRY_HELP),
    output: Path | None = typer.Option(
        None, "--output", "-o", metavar="FILE.jsonl",
        help="Write here (JSON Lines: a header, then one record per line) [default: stdout].",
    ),  # fmt: skip
    serial: list[str] | None = typer.Option(
        None, "--serial", metavar="SERIAL", help="Only this unit (repeatable)."
    ),
    lot: str | None = typer.Option(
        None, "--lot", metavar="LOT", help="Only the units of this lot."
    ),
    force: bool = typer.Option(False, "--force", help="Replace an existing OUTPUT."),
) -> None:
    """Export records: each calibration with its metadata (serial, product, lot, station,
    operator, times, session hash, verdict, limits) and the whole calibration, one JSON
    object per line; imucal registry import reads it back.

    Exit status: 0 written; 2 bad input (no such registry, OUTPUT exists without --force).
    """
    if output is not None:
        check_output(output, force=force)
    with _open(registry) as reg:
        if output is None:
            export_records(reg, sys.stdout, serials=serial or None, lot=lot)
            return
        with safe_output(output, force=force) as out, out.open("w") as handle:
            n = export_records(reg, handle, serials=serial or None, lot=lot)
    typer.echo(f"wrote {n} records to {output}", err=True)


@registry_app.command("import")
def import_(
    files: list[Path] = typer.Argument(
        ..., metavar="CAL.json|EXPORT.jsonl",
        help="Calibration files (recorded under their sensor, or --serial) and registry "
        "exports (every record kept as it was).",
    ),  # fmt: skip
    registry: str | None = registry_option(_REGISTRY_HELP + " Made if missing."),
    serial: str | None = typer.Option(
        None, "--serial", metavar="SERIAL",
        help="The unit of a calibration file [default: its sensor].",
    ),
    product: str | None = typer.Option(
        None, "--product", metavar="NAME", help="Calibration files: product."
    ),
    lot: str | None = typer.Option(None, "--lot", metavar="LOT", help="Calibration files: lot."),
    station: str | None = typer.Option(
        None, "--station", metavar="NAME", help="Calibration files: station."
    ),
    operator: str | None = typer.Option(
        None, "--operator", metavar="NAME", help="Calibration files: operator."
    ),
    limits: Path | None = typer.Option(
        None, "--limits", metavar="PRODUCT.toml",
        help="Judge each calibration file against these limits (the verdict is recorded).",
    ),  # fmt: skip
    json_output: bool = json_option("Print what was recorded as JSON (imucal-registry-import)."),
) -> None:
    """Record existing calibrations: calibration JSON files (imucal calibrate's, or any file
    imucal report reads) and registry exports. A calibration already recorded for its unit is
    skipped.

    Exit status: 0 recorded; 2 bad input (unreadable file, a calibration naming no sensor
    without --serial, a bad product file; the files before it are recorded).
    """
    if serial is not None and len(files) > 1:
        raise InputError("--serial names one unit: give one calibration file with it")
    product_limits = None if limits is None else load_limits(limits)
    with _open(registry, create=True) as reg:
        result = import_files(reg, files, UnitInfo(serial or "", product, lot, station, operator),
                              limits=product_limits)  # fmt: skip
        name = reg.name
    if json_output:
        _echo_json({"format": "imucal-registry-import", "format_version": 1, "registry": name,
                    "recorded": [_done(r) for r in result.recorded],
                    "skipped": [_done(r) for r in result.skipped]})  # fmt: skip
        return
    typer.echo(f"recorded {len(result.recorded)} calibrations in {name}"
               + (f", {len(result.skipped)} already there" if result.skipped else ""))


def _done(r) -> dict:
    return {"serial": r.serial, "uid": r.uid, "recorded_at": r.recorded_at,
            "verdict": r.verdict}  # fmt: skip


@registry_app.command("lot")
def lot(
    lot_name: str = typer.Argument(..., metavar="LOT", help="The lot."),
    registry: str | None = registry_option(_REGISTRY_HELP),
    limits: Path | None = typer.Option(
        None, "--limits", metavar="PRODUCT.toml",
        help="Judge the lot against these limits [default: those its units were judged "
        "against].",
    ),  # fmt: skip
    plot: Path | None = typer.Option(
        None, "--plot", metavar="FILE.png",
        help="Also draw each parameter's distribution across the lot, with its limits "
        "(needs matplotlib: pip install 'imucal-cli[plot]').",
    ),  # fmt: skip
    force: bool = typer.Option(False, "--force", help="Replace an existing --plot file."),
    json_output: bool = json_option("Print the statistics as JSON (imucal-registry-lot)."),
) -> None:
    """A lot's statistics over each unit's latest calibration: every parameter's distribution,
    its process capability against the limits (Cpk), the units that stand apart (modified
    z-score of median and MAD beyond 3.5, Iglewicz & Hoaglin), and the drift alarm: units whose
    re-calibration moved a parameter beyond 3 combined std (imucal report's history test).

    Exit status: 0 shown; 2 bad input (no such registry or lot, bad product file, --plot exists
    without --force or matplotlib missing).
    """
    product_limits = None if limits is None else load_limits(limits)
    if plot is not None:
        check_output(check_plot_output(plot), force=force)
    with _open(registry) as reg:
        stats = lot_statistics(reg, lot_name, limits=product_limits, values=plot is not None)
    if plot is not None:
        lot_figure(stats, plot, force=force)
        drop_values(stats)  # the values were for the plot only
    if json_output:
        _echo_json(stats)
        return
    render_lot(stats, make_console())
    if plot is not None:
        typer.echo(f"wrote {plot}")
