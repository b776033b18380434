"""The rich consoles commands print on: a terminal as usual, anything else never hard-wrapped.

Off a terminal (a pipe, a file, a CI log) rich would wrap every line at 80 columns, mid-sentence,
and grep-based scripts would miss what they look for.  :func:`make_console` gives a console that
lays tables out for 100 columns (or ``$COLUMNS`` when wider) but prints lines of text whole
(soft wrap), without colour codes.  ``NO_COLOR`` is honoured by rich itself.

A summary's lines are :data:`Piece` s printed with :func:`print_line`: text, or text with a
rich style, never markup (brackets and file names are printed as they are).
"""

from __future__ import annotations

import json
import os

import typer
from rich.console import Console
from rich.text import Text

PIPE_WIDTH = 100
"""Columns tables are laid out for when the output is not a terminal."""

Piece = str | tuple[str, str]
"""Part of a line: text, or ``(text, rich style)`` such as ``("warning", "bold yellow")``."""


def print_line(console: Console, *pieces: Piece) -> None:
    """One line of :data:`Piece` s on ``console``: text, never markup or emoji codes."""
    console.print(Text.assemble(*pieces))


def make_console(*, stderr: bool = False) -> Console:
    """A console on stdout (or stderr): plain and unwrapped when it is not a terminal."""
    console = Console(stderr=stderr, highlight=False)
    if console.is_terminal:
        return console
    try:
        columns = int(os.environ.get("COLUMNS", "0"))
    except ValueError:
        columns = 0
    return Console(
        stderr=stderr,
        width=max(PIPE_WIDTH, columns),
        soft_wrap=True,
        highlight=False,
        color_system=None,
    )


def print_json(document) -> None:
    """A JSON document on stdout, alone (``--json``): indented, keys in their order, strict
    (NaN and infinities are not JSON: they must have been turned into ``null`` before)."""
    typer.echo(json.dumps(document, indent=2, allow_nan=False))
