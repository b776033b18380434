"""Options that several commands share, defined once (``capture`` and ``simulate``: ``--plan``)."""

from __future__ import annotations

import typer

from imucal_cli.plans import plan_help

from . import completion


def plan_option(default: str | None, lead: str):
    """``--plan NAME|FILE.toml``: every registry plan with its summary (one list for all)."""
    return typer.Option(
        default,
        "--plan",
        metavar="NAME|FILE.toml",
        help=f"{lead} {plan_help()}",
        autocompletion=completion.plans,
    )
