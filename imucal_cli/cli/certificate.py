"""``imucal certificate SERIAL|CAL.json -o cert.html|cert.pdf``: a unit's calibration
certificate (issue 29.3)."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape

from imucal_cli.errors import InputError, SessionError
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.output import check_output, check_suffix
from imucal_cli.formats.session.digest import session_digest
from imucal_cli.registry import REGISTRY_ENV
from imucal_cli.registry.queries import calibration_of
from imucal_cli.registry.store import open_registry
from imucal_cli.use.certificate import build_certificate, write_certificate
from imucal_cli.use.limits import judge_calibration, limits_from_dict, load_limits

from .app import app
from .console import make_console
from .options import registry_option

CERTIFICATE_SUFFIXES = (".html", ".pdf")
"""What a certificate's name ends in (any case): HTML, or PDF (WeasyPrint)."""


@app.command()
def certificate(
    unit: str = typer.Argument(
        ..., metavar="SERIAL|CAL.json",
        help="A serial number (its latest calibration in --registry) or a calibration JSON.",
    ),  # fmt: skip
    output: Path = typer.Option(
        ..., "--output", "-o", metavar="CERT.html|.pdf",
        help="The certificate to write: HTML, or PDF when it ends in .pdf (WeasyPrint: "
        "pip install 'imucal-cli[pdf]').",
    ),  # fmt: skip
    registry: str | None = registry_option(
        "The registry to find SERIAL in (a SQLite file or postgresql+psycopg://...)."
    ),
    limits: Path | None = typer.Option(
        None, "--limits", metavar="PRODUCT.toml",
        help="Judge against these limits [default: those the registry recorded the verdict "
        "against; a CAL.json without --limits is not judged].",
    ),  # fmt: skip
    calibration: str | None = typer.Option(
        None, "--calibration", metavar="UID",
        help="SERIAL: this recorded calibration (imucal registry show lists them) [default: "
        "the latest].",
    ),  # fmt: skip
    serial: str | None = typer.Option(
        None, "--serial", metavar="SERIAL",
        help="CAL.json: the unit's serial [default: its sensor].",
    ),
    product: str | None = typer.Option(
        None, "--product", metavar="NAME", help="CAL.json: the product."
    ),
    lot: str | None = typer.Option(None, "--lot", metavar="LOT", help="CAL.json: the lot."),
    force: bool = typer.Option(False, "--force", help="Replace an existing OUTPUT."),
) -> None:
    """Write a unit's calibration certificate: identity (serial, product, lot, station,
    operator, times), the session's content hash, the verdict and every limit check, each
    sensor's parameters with their std and residuals, and the plots (inline PNG: the file
    stands alone). A CAL.json's session hash is computed when its session file is at hand.

    Exit status: 0 written; 2 bad input (no such unit or file, bad product file, OUTPUT exists
    without --force, matplotlib or WeasyPrint missing).
    """
    as_file = Path(unit)
    check_suffix(output, CERTIFICATE_SUFFIXES, "the certificate is HTML, or PDF")
    check_output(output, force=force, inputs=[as_file] if as_file.exists() else [])
    product_limits = None if limits is None else load_limits(limits)
    if as_file.exists() or unit.endswith(".json"):
        cal = read_calibration(as_file)
        name = serial or cal.sensor
        if not isinstance(name, str) or not name.strip():
            raise InputError(f"{unit}: the calibration names no sensor: give --serial")
        identity = {"serial": name, "product": product or (product_limits and
                    product_limits.product), "lot": lot, "station": None, "operator": None,
                    "session_sha256": _digest(cal.session, as_file)}  # fmt: skip
        inputs = [as_file]
    else:
        if not registry:
            raise InputError(f"{unit}: no such file; to find a serial give --registry PATH|URL "
                             f"(or set {REGISTRY_ENV})")  # fmt: skip
        with open_registry(registry, create=False) as reg:
            meta, cal = calibration_of(reg, unit, calibration)
        identity = {k: meta[k] for k in ("serial", "product", "lot", "station", "operator",
                                          "recorded_at", "uid", "session_sha256")}  # fmt: skip
        if product_limits is None and meta["limits"]:
            product_limits = limits_from_dict(meta["limits"], "the limits recorded with it")
        inputs = []
    acceptance = None if product_limits is None else judge_calibration(cal, product_limits)
    cert = build_certificate(cal, identity, acceptance)
    write_certificate(output, cert, force=force, inputs=inputs)
    verdict = "not judged" if acceptance is None else acceptance.verdict
    make_console().print(f"wrote {escape(str(output))} ({escape(identity['serial'])}: "
                         f"{verdict})", soft_wrap=True)  # fmt: skip


def _digest(session: str | None, cal_path: Path) -> str | None:
    """The content hash of the calibration's session, when the file is at hand (as written,
    or beside the calibration)."""
    if not session:
        return None
    for candidate in (Path(session), cal_path.parent / Path(session).name):
        if candidate.is_file():
            try:
                return session_digest(candidate)
            except SessionError:
                return None
    return None
