"""Printing report pieces so that nothing is hard-wrapped off a terminal.

In a terminal, lists and key/value blocks are framed panels and tables carry their titles and
captions.  Anywhere else (a pipe, a file: ``console.is_terminal`` is false) the same content is
printed as whole lines (``soft_wrap``) that grep finds: a title line, ``- item`` lines,
``name: value`` lines, and a table's title and caption as lines around it.
"""

from __future__ import annotations

from rich.console import Console, RenderableType
from rich.panel import Panel
from rich.table import Table
from rich.text import Text


def show_bullets(console: Console, items: list[str], title: str, style: str) -> None:
    """A titled list: a panel in a terminal, else ``title:`` and ``- item`` lines."""
    body = Text("\n".join(f"- {item}" for item in items))
    if console.is_terminal:
        console.print(Panel(body, title=title, border_style=style, expand=False))
        return
    console.print(Text(f"{title}:", style=style), soft_wrap=True)
    console.print(body, soft_wrap=True)


def show_fields(console: Console, rows: list[tuple[str, str]], title: str | None = None) -> None:
    """``name value`` rows: a grid (in a titled panel) in a terminal, else ``name: value`` lines."""
    if console.is_terminal:
        grid = Table.grid(padding=(0, 2))
        grid.add_column(style="bold")
        grid.add_column()
        for name, value in rows:
            grid.add_row(name, Text(value))
        console.print(grid if title is None else Panel(grid, title=title, expand=False))
        return
    if title is not None:
        console.print(Text(title, style="bold"), soft_wrap=True)
    for name, value in rows:
        console.print(Text(f"{name}: {value}"), soft_wrap=True)


def show_table(console: Console, table: RenderableType) -> None:
    """A table; off a terminal its title and caption are printed as whole lines around it."""
    if console.is_terminal or not isinstance(table, Table):
        console.print(table)
        return
    title, caption = table.title, table.caption
    table.title = table.caption = None
    if title:
        console.print(title if isinstance(title, Text) else Text(str(title)), soft_wrap=True)
    console.print(table)
    if caption:
        console.print(caption if isinstance(caption, Text) else Text(str(caption)), soft_wrap=True)


def show_text(console: Console, text: Text | str) -> None:
    """One line (or paragraph) of prose, never hard-wrapped off a terminal."""
    console.print(text if isinstance(text, Text) else Text(text), soft_wrap=not console.is_terminal)
