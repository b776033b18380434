"""The guided capture's screen: a rich live view in a terminal, plain lines elsewhere.

The screen only draws a :class:`~.state.GuidedState`: its messages (printed above the live
view, or as lines) and its prompt (the live view, or one line per change of what the person
should do).  Nothing is printed per block in plain mode, so logs stay short.
"""

from __future__ import annotations

import time as _time

from rich.console import Console, Group
from rich.live import Live
from rich.progress_bar import ProgressBar
from rich.table import Table
from rich.text import Text

from .state import GuidedState

COMMANDS = "commands: r redo, s skip, q finish, Enter continue"


class Screen:
    """Draws a guided capture on ``console``.

    Parameters
    ----------
    console : rich.console.Console
        A terminal gets a live view refreshed ``refresh_hz`` times a second; anything else
        plain lines.
    refresh_hz : float
        Live refresh rate.
    """

    def __init__(self, console: Console, refresh_hz: float = 10.0) -> None:
        self.console = console
        self.refresh_hz = refresh_hz
        self.live: Live | None = None
        self.last_render = 0.0
        self.plain_key: tuple | None = None

    # ------------------------------------------------------------------------ lifecycle
    def start(self, state: GuidedState) -> None:
        if self.console.is_terminal:
            self.live = Live(
                self.render(state),
                console=self.console,
                auto_refresh=False,
                transient=False,
                redirect_stdout=False,
                redirect_stderr=False,
            )
            self.live.start()
        self.show(state, force=True)

    def stop(self, state: GuidedState) -> None:
        """Draw the last frame and leave the live view."""
        if self.live is not None:
            self.live.update(self.render(state), refresh=True)
            self.live.stop()
            self.live = None
        self.print_messages(state)

    # ------------------------------------------------------------------------ drawing
    def show(self, state: GuidedState, force: bool = False) -> None:
        """Print new messages, then update the live view (or the plain instruction line)."""
        self.print_messages(state)
        if self.live is not None:
            now = _time.monotonic()
            if force or now - self.last_render >= 1.0 / self.refresh_hz:
                self.last_render = now
                self.live.update(self.render(state), refresh=True)
        else:
            self.plain_prompt(state)

    def print_messages(self, state: GuidedState) -> None:
        target = self.live.console if self.live is not None else self.console
        for message in state.drain():
            target.print(Text(message.text, style=message.style), highlight=False)

    def plain_prompt(self, state: GuidedState) -> None:
        """Plain mode: print the instruction once per change of what the person should do."""
        p = state.prompt()
        if p.step is None:
            return
        key = (p.step, p.phase, p.serial)
        if key == self.plain_key:
            return
        self.plain_key = key
        if p.phase == "move":
            return  # the message after the pose already says to turn the unit
        if p.phase == "hold":
            line = Text(f"still: holding {p.hold_s:g} s ...")
        elif p.phase == "turning":
            line = Text("turning ...")
        else:
            line = Text(f"step {p.step + 1}/{p.n_steps}: {p.text}", style="bold")
        self.console.print(line, highlight=False)

    def render(self, state: GuidedState) -> Group:
        """The live view: instruction, live signal, hold progress, plan progress, commands."""
        p = state.prompt()
        rows = Table.grid(padding=(0, 1))
        rows.add_column()
        if p.step is not None:
            rows.add_row(Text(f"[step {p.step + 1}/{p.n_steps}] {p.text}", style="bold"))
        signal = Text()
        for text, style in state.signal_line():
            signal.append(text, style=style)
        rows.add_row(signal)
        if p.phase == "hold" and state.state is not None:
            bar = Table.grid(padding=(0, 1))
            bar.add_row(
                ProgressBar(total=p.hold_s, completed=p.held_s, width=40),
                Text(f"{p.held_s:.1f}/{p.hold_s:g} s"),
            )
            rows.add_row(bar)
        rows.add_row(Text(state.progress_text(), style="dim"))
        rows.add_row(Text(COMMANDS, style="dim"))
        return Group(rows)
