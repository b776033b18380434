"""Commands typed at the bench, and where they come from (stdin, or a script in tests).

``r`` redo the last step taken, ``s`` skip the current step, ``q`` finish now, Enter continue,
a number or a step label picks the step to do next.
"""

from __future__ import annotations

import queue
import sys
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Protocol

from imucal_cli.plans import Plan


@dataclass(frozen=True)
class Command:
    """A parsed command line.

    Attributes
    ----------
    action : str
        ``"continue"`` (empty line), ``"redo"`` (``r``), ``"skip"`` (``s``), ``"quit"``
        (``q``), ``"pick"`` (a step number, 1-based, or a step label) or ``"unknown"``.
    step : int or None
        For ``"pick"``: the step index (0-based).
    text : str
        The line as typed.
    """

    action: str
    step: int | None = None
    text: str = ""


def parse_command(text: str, plan: Plan) -> Command:
    """Parse one command line against ``plan``.

    ``r``/``redo``, ``s``/``skip``, ``q``/``quit``, empty: continue; ``3``: step 3 (1-based);
    otherwise a step label, exact (case-insensitive) or the only label that contains ``text``.
    """
    raw = text
    t = " ".join(str(text).split()).lower()
    if t == "":
        return Command("continue", text=raw)
    for action in ("redo", "skip", "quit"):
        if t in (action, action[0]):
            return Command(action, text=raw)
    if t.isdigit():
        i = int(t) - 1
        if 0 <= i < len(plan.steps):
            return Command("pick", i, raw)
        return Command("unknown", text=raw)
    labels = [s.label.lower() for s in plan.steps]
    exact = [i for i, lab in enumerate(labels) if lab == t]
    hits = exact or [i for i, lab in enumerate(labels) if t in lab]
    if len(hits) == 1 or (exact and hits):
        return Command("pick", hits[0], raw)
    return Command("unknown", text=raw)


class KeySource(Protocol):
    """Where commands come from.  ``get()`` never blocks: one command line, or None."""

    def get(self) -> str | None:
        """The next command line (without its newline), or None when there is none."""
        ...


class StdinKeys:
    """Command lines from a text stream (stdin), read by a background thread.

    Works with a terminal (type a command, then Enter) and with a pipe.  The thread is a
    daemon: it never keeps the program alive.

    Parameters
    ----------
    stream : text file, optional
        Default ``sys.stdin``.
    """

    def __init__(self, stream=None) -> None:
        self._stream = sys.stdin if stream is None else stream
        self._queue: queue.SimpleQueue[str] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._read, name="imucal-keys", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        try:
            for line in self._stream:
                self._queue.put(line.rstrip("\r\n"))
        except (OSError, ValueError):
            pass

    def get(self) -> str | None:
        """The next line typed, or None."""
        try:
            return self._queue.get_nowait()
        except queue.Empty:
            return None


class ScriptedKeys:
    """Commands for tests, released in order, each when its condition holds.

    Parameters
    ----------
    items : iterable
        Each item is a command string (released on the next :meth:`get`), or a pair
        ``(condition, command)``: ``condition`` an int (released once ``n_samples()`` reaches
        it) or a callable returning True when the command is due.
    n_samples : callable, optional
        Current sample count (e.g. ``lambda: recorder.n_samples``); needed for int conditions.

    Attributes
    ----------
    released : list of str
        The commands handed out so far.
    """

    def __init__(
        self,
        items: Iterable[str | tuple[int | Callable[[], bool], str]],
        *,
        n_samples: Callable[[], int] | None = None,
    ) -> None:
        self._items = list(items)
        self._n_samples = n_samples
        self.released: list[str] = []

    def get(self) -> str | None:
        """The next command if its condition holds, else None."""
        if not self._items:
            return None
        item = self._items[0]
        if isinstance(item, str):
            due, command = True, item
        else:
            cond, command = item
            if callable(cond):
                due = bool(cond())
            else:
                if self._n_samples is None:
                    raise ValueError("ScriptedKeys: int conditions need n_samples")
                due = self._n_samples() >= int(cond)
        if not due:
            return None
        self._items.pop(0)
        self.released.append(command)
        return command

    @property
    def pending(self) -> int:
        """Commands not yet released."""
        return len(self._items)
