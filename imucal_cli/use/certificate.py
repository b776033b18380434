"""A calibration certificate per unit (issue 29.3): HTML from a Jinja2 template
(``templates/certificate.html``), and PDF from the same HTML through WeasyPrint (no browser).

What it shows: the unit's identity (serial, product, lot, station, operator, times, registry
record), the session's content hash and the calibration's SHA-256, the verdict and every check
against the limits, each sensor's parameters with their std and its residuals, and the plots
(the report's figure, and each limited figure as a fraction of its limit) inline as PNG data, so
the file stands alone.  Every string from a file is escaped by the template (autoescape).

A unit of several IMUs (a set, issue 28) gets one certificate listing every IMU: the set's
IMUs with each one's rotation into the reference's calibrated frame and time offset (with
their std), then each IMU's sensors as the reference's are shown, all as ``imucal report``
reads them (:func:`~imucal_cli.use.report.imus.imus_report`; nothing is re-solved).  The limits
judge every IMU's sections (as ``calibrate --limits`` does: the other IMUs' checks named
``imu1 accel``, ...): the unit passes when every IMU does.
"""

from __future__ import annotations

import base64
import hashlib
import io
import math
import os
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from jinja2 import Environment, PackageLoader, select_autoescape

from imucal_cli import __version__
from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import calibration_to_json
from imucal_cli.formats.output import write_output
from imucal_cli.formats.session.digest import DIGEST_NAME
from imucal_cli.formats.text import clean_text
from imucal_cli.model.calibration import Calibration

from .limits import LIMIT_KEYS, Acceptance
from .plots import draw_report, pyplot
from .report.build import build_report

__all__ = ["PDF_HINT", "build_certificate", "render_html", "render_pdf", "write_certificate"]

PDF_HINT = "a PDF certificate needs WeasyPrint: pip install 'imucal-cli[pdf]' (or write .html)"
TITLES = {"accel": "Accelerometer", "gyro": "Gyroscope", "mag": "Magnetometer"}


def _fmt(value: Any) -> str:
    """A number with 6 significant digits, ``-`` when absent."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, int | float):
        return f"{value:.6g}"
    return str(value)


def build_certificate(
    cal: Calibration,
    identity: dict[str, Any],
    acceptance: Acceptance | None,
    *,
    plots: bool = True,
) -> dict[str, Any]:
    """Everything the certificate shows, as a dict (the template's context).

    Parameters
    ----------
    cal
        The calibration, as read.
    identity
        ``serial`` (required), ``product``, ``lot``, ``station``, ``operator``,
        ``recorded_at``, ``uid``, ``session_sha256`` (each may be None).
    acceptance
        The verdict against the limits, or None (not judged).
    plots
        Draw the plots (matplotlib); without it the certificate says there are none.
    """
    report = build_report(cal)
    ident = {k: None if v is None else clean_text(str(v)) for k, v in identity.items()}
    ident.setdefault("session", report.get("session"))
    ident["created"] = cal.created
    ident["document_sha256"] = hashlib.sha256(calibration_to_json(cal).encode()).hexdigest()
    sensors = [_sensor(kind, sec) for kind, sec in report["sensors"].items()]
    out: dict[str, Any] = {
        "identity": ident,
        "issued": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "toolkit": __version__,
        "digest_name": DIGEST_NAME,
        "acceptance": None if acceptance is None else _acceptance(acceptance),
        "sensors": sensors,
        "left_out": sorted((report.get("left_out") or {}).items()),
        "reference_name": (cal.reference_name or "reference") if report.get("imus") else None,
        "imus": _imus(report),
        "plots": [],
        "plots_note": "no plots: the calibration carries no per-pose or per-rotation data",
    }
    if plots:
        out["plots"] = _plots(report, acceptance)
    return out


def _sensor(kind: str, sec: dict[str, Any]) -> dict[str, Any]:
    params = [dict(p) for p in sec["parameters"]]
    for m in sec.get("misalignment_deg") or []:
        params.append({"name": f"misalignment {m['axes']}", "value": m["angle"], "std": m["std"],
                       "unit": "deg"})  # fmt: skip
    sens = sec.get("sensitivity") or {}
    for i, v in enumerate(sens.get("values") or []):
        std = (sens.get("std") or [None] * 3)[i] if sens.get("std") else None
        params.append({"name": f"sensitivity {'xyz'[i] if i < 3 else i}", "value": v,
                       "std": std, "unit": sens.get("unit")})  # fmt: skip
    rms = sec.get("rms") or {}
    unit = rms.get("unit") or sec.get("units_out") or ""
    residuals = [{"name": name, "value": rms.get(key), "unit": unit}
                 for key, name in (("before", "RMS before calibration"),
                                   ("after", "RMS after calibration"),
                                   ("held_out", "RMS held out (each pose left out)"),
                                   ("residual_rms", "solver residual RMS"))
                 if rms.get(key) is not None]  # fmt: skip
    if rms.get("quantity"):
        residuals = [{**r, "name": f"{r['name']} ({rms['quantity']})"} for r in residuals]
    return {
        "kind": kind, "title": TITLES.get(kind, kind), "solver": sec.get("solver"),
        "variant": sec.get("variant"), "units_in": sec.get("units_in"),
        "units_out": sec.get("units_out"), "parameters": params, "residuals": residuals,
        "warnings": [clean_text(str(w)) for w in sec.get("warnings") or []],
    }  # fmt: skip


def _imus(report: dict[str, Any]) -> list[dict[str, Any]]:
    """A set's other IMUs as the report reads them (``imus``; nothing re-solved): each one's
    place in the set (rotation into the reference's calibrated frame, time offset, with their
    std) and its sections as the reference's are shown."""
    out = []
    for name, imu in (report.get("imus") or {}).items():
        std = imu.get("rotation_std_deg")
        offset, offset_std = imu.get("time_offset_s"), imu.get("time_offset_std_s")
        out.append({
            "name": clean_text(str(name)),
            "rotation_deg": imu.get("rotation_deg"),
            "rotation_std_deg": ", ".join(_fmt(v) for v in std) if std else None,
            "time_offset_ms": None if offset is None else 1e3 * offset,
            "time_offset_std_ms": None if offset_std is None else 1e3 * offset_std,
            "sensors": [_sensor(kind, sec) for kind, sec in imu["sensors"].items()],
            "left_out": sorted((imu.get("left_out") or {}).items()),
            "warnings": [clean_text(str(w)) for w in imu.get("warnings") or []],
        })  # fmt: skip
    return out


def _acceptance(acceptance: Acceptance) -> dict[str, Any]:
    doc = acceptance.to_dict()
    for check in doc["checks"]:
        check["two_sided"] = LIMIT_KEYS[check["limit"]].two_sided
    return doc


def _png(fig) -> str:
    """The figure as a PNG data URI (inline: the certificate is one file; a PNG, not SVG, so
    that a browser or WeasyPrint lays out the page in a second, not tens of them)."""
    buffer = io.BytesIO()
    try:
        fig.savefig(buffer, format="png", dpi=90)
    finally:
        pyplot().close(fig)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _plots(report: dict[str, Any], acceptance: Acceptance | None) -> list[dict[str, str]]:
    plots = []
    if acceptance is not None and acceptance.checks:
        plots.append({"title": "Each limited figure as a fraction of its limit",
                      "png": _png(_limits_figure(acceptance))})  # fmt: skip
    try:
        fig = draw_report(report, where="the certificate")
    except InputError as exc:
        if "nothing to plot" not in str(exc):
            raise
    else:
        plots.append({"title": "Residuals, rotations and directions (imucal report --plot)",
                      "png": _png(fig)})  # fmt: skip
    return plots


def _limits_figure(acceptance: Acceptance):
    plt = pyplot()
    checks = [c for c in acceptance.checks if c.value is not None]
    names = [f"{c.sensor} {c.figure}" for c in checks]
    ratios = [abs(c.value) / c.maximum if LIMIT_KEYS[c.key].two_sided else c.value / c.maximum
              for c in checks]  # fmt: skip
    fig, ax = plt.subplots(figsize=(7.5, 0.24 * len(checks) + 1.2), layout="constrained")
    colors = ["tab:green" if c.passed else "tab:red" for c in checks]
    ax.barh(range(len(checks)), ratios, color=colors)
    ax.axvline(1.0, color="black", lw=1)
    ax.set_yticks(range(len(checks)), names, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("|value| / limit (1: at the limit)")
    return fig


def _environment() -> Environment:
    env = Environment(loader=PackageLoader("imucal_cli.use", "templates"),
                      autoescape=select_autoescape(["html"]))  # fmt: skip
    env.globals["fmt"] = _fmt
    return env


def render_html(certificate: dict[str, Any]) -> str:
    """The certificate as one HTML page (CSS and plots inline)."""
    return _environment().get_template("certificate.html").render(**certificate)


def render_pdf(html: str) -> bytes:
    """The HTML rendered to PDF by WeasyPrint (pure Python over Pango; no browser).

    Raises
    ------
    InputError
        WeasyPrint is not installed (:data:`PDF_HINT`).
    """
    try:
        from weasyprint import HTML
    except (ImportError, OSError):
        raise InputError(PDF_HINT) from None
    return HTML(string=html).write_pdf()


def write_certificate(path: str | os.PathLike, certificate: dict[str, Any], *,
                      force: bool = False, inputs=()) -> Path:  # fmt: skip
    """Write the certificate: PDF when ``path`` ends in ``.pdf``, else HTML."""
    html = render_html(certificate)
    if Path(path).suffix.lower() == ".pdf":
        return write_output(path, render_pdf(html), force=force, inputs=inputs)
    return write_output(path, html, force=force, inputs=inputs)
