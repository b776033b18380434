"""Options that several commands share, defined once (``capture`` and ``simulate``)."""

from __future__ import annotations

import typer

from imucal_cli.plans import plan_help


def plan_option(default: str | None, lead: str):
    """``--plan NAME|FILE.toml``: every registry plan with its summary (one list for all)."""
    return typer.Option(default, "--plan", metavar="NAME|FILE.toml", help=f"{lead} {plan_help()}")


def hold_option(what: str, note: str = "", then: str = ""):
    """``--hold SECONDS``: how long each pose is held still (``note`` in brackets after the
    unit, ``then`` a further sentence)."""
    more = f" ({note})" if note else ""
    return typer.Option(
        2.0, "--hold", metavar="SECONDS", help=f"{what}, s{more}.{' ' + then if then else ''}"
    )
