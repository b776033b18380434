"""The tables of ``imucal registry list|show|lot`` (rich)."""

from __future__ import annotations

from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from imucal_cli.registry.lot import label
from imucal_cli.use.report.history import render_history

__all__ = ["render_lot", "render_unit", "render_units"]


def render_units(rows: list[dict], name: str, console: Console) -> None:
    """``registry list``: a row per unit."""
    table = Table(title=Text(f"{len(rows)} units in {name}"), box=box.SIMPLE,
                  title_justify="left")  # fmt: skip
    for col in ("serial", "product", "lot", "calibrations", "last calibrated (UTC)", "station",
                "verdict"):  # fmt: skip
        table.add_column(col, justify="right" if col == "calibrations" else "left")
    for r in rows:
        table.add_row(Text(r["serial"]), Text(r["product"] or ""), Text(r["lot"] or ""),
                      str(r["calibrations"]), _when(r["last_created"]),
                      Text(r["last_station"] or ""), _verdict(r["last_verdict"]))  # fmt: skip
    console.print(table)


def render_unit(record: dict, console: Console) -> None:
    """``registry show``: the unit's calibrations, failed checks and history."""
    where = f"product {record['product'] or '-'}, lot {record['lot'] or '-'}"
    console.print(Text(f"unit {record['serial']}", style="bold"), Text(where))
    table = Table(box=box.SIMPLE, title=Text("calibrations (oldest first)"), title_justify="left")
    for col in ("calibrated (UTC)", "station", "operator", "verdict", "session sha256",
                "calibration"):  # fmt: skip
        table.add_column(col, no_wrap=col in ("calibrated (UTC)", "verdict", "calibration"))
    for c in record["calibrations"]:
        table.add_row(_when(c["created"])[:16], Text(c["station"] or ""),
                      Text(c["operator"] or ""), _verdict(c["verdict"]),
                      (c["session_sha256"] or "-")[:12], c["uid"])  # fmt: skip
    console.print(table)
    for c in record["calibrations"]:
        for line in c["failed"] or []:
            console.print(f"[red]failed[/] ({_when(c['created'])}): {escape(line)}",
                          soft_wrap=True)  # fmt: skip
    render_history(record["history"], console)


def _when(iso: str | None) -> str:
    return (iso or "")[:19].replace("T", " ")


def _verdict(verdict: str | None) -> Text:
    if verdict == "pass":
        return Text("pass", style="green")
    if verdict == "fail":
        return Text("FAIL", style="bold red")
    return Text("-", style="dim")


def _lot_table(sensor: str, params: list[dict]) -> Table:
    """One sensor's parameters across the lot (``sensor``: ``accel``, or ``imu1 accel`` for
    another IMU of a set): distribution, limit, Cpk, units beyond, apart."""
    table = Table(title=Text(sensor), title_justify="left", box=box.SIMPLE, pad_edge=False)
    for col in ("parameter", "unit", "n", "mean", "std", "limit", "Cpk", "beyond", "apart"):
        table.add_column(col, justify="left" if col in ("parameter", "unit") else "right",
                         no_wrap=col != "unit", max_width=18 if col == "unit" else None,
                         overflow="fold")  # fmt: skip
    for p in params:
        lim = p["limit"]
        limit = "" if lim is None else ("±" if lim["two_sided"] else "<= ") + f"{lim['maximum']:g}"
        cpk = "" if p["cpk"] is None else f"{p['cpk']:.2f}"
        low = p["cpk"] is not None and p["cpk"] < 1.33
        table.add_row(Text(p["name"]), Text(p["unit"] or ""), str(p["n"]), f"{p['mean']:.5g}",
                      "" if p["std"] is None else f"{p['std']:.3g}", limit,
                      Text(cpk, style="red" if low else ""),
                      "" if p["beyond_limit"] is None else str(p["beyond_limit"]),
                      str(len(p["outliers"])) if p["outliers"] else "")  # fmt: skip
    return table


def render_lot(stats: dict, console: Console) -> None:
    """``registry lot``: per sensor, its parameters; the units apart; the drift alarm."""
    v = stats["verdicts"]
    console.print(Text(f"lot {stats['lot']}: {stats['units']} units, {stats['calibrations']} "
                       f"calibrations; pass {v['pass']}, fail {v['fail']}, not judged "
                       f"{v['not judged']}", style="bold"))  # fmt: skip
    console.print(Text(f"limits: {stats['limits_source']}"), soft_wrap=True)
    for shown in dict.fromkeys(label(p) for p in stats["parameters"]):
        console.print(_lot_table(shown, [p for p in stats["parameters"] if label(p) == shown]))
    console.print(Text("Cpk: min(limit - mean, mean + limit) / (3 std), upper limits (limit - "
                       "mean) / (3 std); below 1.33 in red. apart: units by the "
                       f"{stats['outlier_test']}", style="dim"), soft_wrap=True)  # fmt: skip
    apart = stats["units_apart"]
    if apart:
        console.print(Text(f"{len(apart)} units stand apart from the lot:", style="bold yellow"))
        for u in apart[:50]:
            console.print(f"  {escape(u['serial'])}: {escape(', '.join(u['parameters']))}",
                          soft_wrap=True)  # fmt: skip
        if len(apart) > 50:
            console.print(f"  ... and {len(apart) - 50} more (--json lists them all)")
    drift = stats["drift"]
    alarms = drift["alarms"]
    head = (f"drift alarm: {len(alarms)} of {drift['units_checked']} re-calibrated units "
            f"({drift['test']})")  # fmt: skip
    console.print(Text(head, style="bold red" if alarms else ""), soft_wrap=True)
    for a in alarms[:50]:
        console.print(f"  {escape(a['serial'])} ({a['calibrations']} calibrations): "
                      f"{escape(', '.join(a['drifted']))}", soft_wrap=True)  # fmt: skip
    if len(alarms) > 50:
        console.print(f"  ... and {len(alarms) - 50} more (--json lists them all)")
