"""The guided capture's screen: a rich live view in a terminal, plain lines elsewhere.

The screen only draws a :class:`~.state.GuidedState`: its messages (printed above the live
view, or as lines) and its prompt (the live view, or one line per change of what the person
should do).  Nothing is printed per block in plain mode, so logs stay short.
"""

from __future__ import annotations

import math
import time as _time

from rich.console import Console, Group
from rich.live import Live
from rich.progress_bar import ProgressBar
from rich.table import Table
from rich.text import Text

from imucal_cli.use.report.coverage_map import coverage_map

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
        self.told: tuple | None = None  # (step, serial) whose instruction was printed
        self.phase = ""
        self.tick: float | None = None

    # ------------------------------------------------------------------------ lifecycle
    def start(self, state: GuidedState) -> None:
        if self.console.is_terminal:
            # Transient: the last frame goes when the capture ends, the summary follows the
            # messages.  Redirected: status lines printed on stdout/stderr while the view is up
            # go above it instead of breaking it (the first frame would stay on the screen).
            self.live = Live(
                self.render(state),
                console=self.console,
                auto_refresh=False,
                transient=True,
                redirect_stdout=True,
                redirect_stderr=True,
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
        """Plain mode: each step's instruction once, the start of each hold and its countdown,
        the start of each turn."""
        p = state.prompt()
        if p.step is None:
            return
        if p.phase not in ("move", "mag") and (p.step, p.serial) != self.told:
            self.told = (p.step, p.serial)
            of = f"/{p.n_steps}" if p.n_steps else ""  # 0: open-ended (capture --until)
            self.line(f"step {p.step + 1}{of}: {p.text}", "bold")
        if p.phase == "hold":
            if self.phase != "hold":
                self.line(f"still: holding {p.hold_s:g} s ...")
                self.tick = None
            tick = countdown_tick(p.hold_s - p.held_s, p.hold_s)
            if tick is not None and tick != self.tick:
                self.tick = tick
                self.line(f"  {tick:g} s left")
        elif p.phase == "turning" and self.phase != "turning":
            self.line("turning ...")
        self.phase = p.phase

    def line(self, text: str, style: str = "") -> None:
        self.console.print(Text(text, style=style), highlight=False)

    def render(self, state: GuidedState) -> Group:
        """The live view: instruction, live signal, hold progress, plan progress, commands."""
        p = state.prompt()
        rows = Table.grid(padding=(0, 1))
        rows.add_column()
        if p.step is not None:
            of = f"/{p.n_steps}" if p.n_steps else ""
            rows.add_row(Text(f"[step {p.step + 1}{of}] {p.text}", style="bold"))
        elif p.phase in ("mag", "check"):
            rows.add_row(Text(p.text, style="bold"))
        signal = Text()
        for text, style in state.signal_line():
            signal.append(text, style=style)
        rows.add_row(signal)
        if p.phase == "hold" and state.state is not None:
            bar = Table.grid(padding=(0, 1))
            left = max(p.hold_s - p.held_s, 0.0)
            bar.add_row(
                ProgressBar(total=p.hold_s, completed=p.held_s, width=40),
                Text(f"hold still: {left:.1f} s left of {p.hold_s:g} s", style="bold"),
            )
            rows.add_row(bar)
        if state.mag is not None:
            rows.add_row(Text(state.mag.status()))
            if state.mag.ready:
                rows.add_row(Text("\n".join(coverage_map(state.mag.map_directions())[:-1]),
                                  style="cyan"))  # fmt: skip
        for row in state.view_rows():
            rows.add_row(row)
        rows.add_row(Text(state.progress_text(), style="dim"))
        rows.add_row(Text(COMMANDS, style="dim"))
        return Group(rows)


def countdown_tick(left_s: float, hold_s: float) -> float | None:
    """The countdown mark to print with ``left_s`` of a ``hold_s`` hold to go: whole seconds
    for holds up to 10 s, tens of seconds up to 2 min, minutes beyond; None at the start (the
    hold line already says it) and at the end."""
    step = 1.0 if hold_s <= 10 else 10.0 if hold_s <= 120 else 60.0
    if left_s <= 0:
        return None
    tick = math.ceil(left_s / step) * step
    return None if tick >= hold_s else tick
