"""The rich consoles commands print on: a terminal as usual, anything else never hard-wrapped.

Off a terminal (a pipe, a file, a CI log) rich would wrap every line at 80 columns, mid-sentence,
and grep-based scripts would miss what they look for.  :func:`make_console` gives a console that
lays tables out for 100 columns (or ``$COLUMNS`` when wider) but prints lines of text whole
(soft wrap), without colour codes.  ``NO_COLOR`` is honoured by rich itself.

A command whose output is only lines (a summary) prints them with :class:`Lines`: styled pieces
through rich on a terminal, plain text elsewhere without loading rich at all (its console is
0.02 s of a command's start-up; issue 14).
"""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console

PIPE_WIDTH = 100
"""Columns tables are laid out for when the output is not a terminal."""

Piece = str | tuple[str, str]
"""Part of a line: text, or ``(text, rich style)`` such as ``("warning", "bold yellow")``."""


class Lines:
    """Print lines of :data:`Piece` s on stdout (or stderr): through :func:`make_console` where
    rich would style them (a terminal, or ``TTY_COMPATIBLE=1`` / ``FORCE_COLOR`` set), else as
    the plain text rich would print there, without importing rich. The pieces are text, never
    markup: brackets in them are printed as they are."""

    def __init__(self, *, stderr: bool = False) -> None:
        self.stderr = stderr
        stream = sys.stderr if stderr else sys.stdout
        self._console = make_console(stderr=stderr) if _styled(stream) else None

    def __call__(self, *pieces: Piece) -> None:
        if self._console is not None:
            from rich.text import Text

            self._console.print(Text.assemble(*pieces))
            return
        print(plain_text(pieces), file=sys.stderr if self.stderr else sys.stdout)


#: What rich leaves out of text it prints: bell, backspace, vertical tab, form feed, CR.
_CONTROL = dict.fromkeys((7, 8, 11, 12, 13))


def plain_text(pieces) -> str:
    """A line of :data:`Piece` s as plain text, as rich prints it without styles: the control
    characters it drops left out, tabs expanded to its 8-column stops."""
    text = "".join(p if isinstance(p, str) else p[0] for p in pieces)
    return text.translate(_CONTROL).expandtabs(8)


def _styled(stream) -> bool:
    """Whether rich would treat ``stream`` as a terminal (its ``Console.is_terminal`` rules:
    ``TTY_COMPATIBLE``, then ``FORCE_COLOR``, then ``isatty``)."""
    tty_compatible = os.environ.get("TTY_COMPATIBLE", "")
    if tty_compatible in ("0", "1"):
        return tty_compatible == "1"
    force_color = os.environ.get("FORCE_COLOR")
    if force_color is not None:
        return force_color != ""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


def make_console(*, stderr: bool = False) -> Console:
    """A console on stdout (or stderr): plain and unwrapped when it is not a terminal."""
    from rich.console import Console

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
    import json

    import typer

    typer.echo(json.dumps(document, indent=2, allow_nan=False))
