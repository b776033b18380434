"""Guided capture: tell the person at the bench what to do, and record it when it is done.

:func:`run_guided` consumes :meth:`Recorder.blocks() <imucal_cli.capture.recorder.Recorder.blocks>`
(every block is already in the session file when it arrives) and, for each step of a
:class:`~imucal_cli.plans.Plan`:

static step
    says what to do (``Put face +Z up and hold still``), shows the live signal and STILL/MOVING;
    as soon as the :class:`~imucal_cli.design.stillness.StillnessDetector` calls the unit
    still, the hold starts by itself and runs ``hold_s`` seconds under a progress bar.  Motion
    during the hold restarts it with a warning.  The finished hold is matched by its gravity
    direction to the nearest static step of the plan not yet taken (any order), refused when
    it is within ``min_separation_deg`` of a pose already taken, and the coverage of the sphere
    and the steps left are shown.  After a pose the next hold waits for the unit to move.
rotation step
    says ``Turn about +X by 90 degrees, then hold still``; waits for a still period, detects
    the start and end of the turn from the gyro (:func:`~imucal_cli.design.stillness.motion_span`)
    and records a ``rotation`` segment spanning it, with the plan's ``axis`` and ``angle_deg``.

Commands (a line each, from a :class:`KeySource`): ``r`` redo the last step taken, ``s`` skip
the current step, ``q`` finish now, Enter continue (take the next hold where the unit is now,
without waiting for it to move), a number or a step label picks the step to do next.

Segments reach the recorder only when they are final: the last step taken stays pending (so
that ``r`` can drop it) until the next one is taken or the capture ends; segments are therefore
added once, in time order, as :class:`~imucal_cli.formats.session.SessionWriter` requires.

The package is split into the state machine (:mod:`.state`, testable without a terminal:
blocks and commands in, messages, prompts and segments out), its screen (:mod:`.screen`), the
commands and their sources (:mod:`.keys`), matching holds to steps and measuring turns
(:mod:`.matching`), the gravity direction of a hold (:mod:`.direction`) and the words
(:mod:`.words`).

Output works in a terminal (a :class:`rich.live.Live` display refreshed ``refresh_hz`` times a
second, events printed above it) and without one (tests, logs: plain lines, one per event or
change of instruction, nothing per block).
"""

from __future__ import annotations

from dataclasses import replace

from rich.console import Console

from imucal_cli.plans import CaptureSummary, Plan

from .adaptive import AdaptiveOptions, AdaptiveState, Refit
from .direction import estimate_direction
from .keys import Command, KeySource, ScriptedKeys, StdinKeys, parse_command
from .options import DEFAULT_HOLD_S, GuidedOptions, Message, Prompt
from .screen import Screen
from .state import GuidedState
from .words import instruction

__all__ = [
    "DEFAULT_HOLD_S",
    "AdaptiveOptions",
    "AdaptiveState",
    "Command",
    "GuidedOptions",
    "GuidedState",
    "KeySource",
    "Message",
    "Prompt",
    "Refit",
    "ScriptedKeys",
    "StdinKeys",
    "estimate_direction",
    "instruction",
    "parse_command",
    "run_guided",
]


def run_guided(
    recorder,
    plan: Plan | None,
    *,
    console: Console,
    keys: KeySource,
    options: GuidedOptions | None = None,
    done_before: list | None = None,
    adaptive: AdaptiveOptions | None = None,
    **fields,
) -> CaptureSummary:
    """Guide a person through ``plan`` while ``recorder`` records; return what was done.

    Parameters
    ----------
    recorder : Recorder
        Provides ``blocks(tick_s)``, ``n_samples``, ``add_segment(...)``, ``stop()``,
        ``end_reason``, ``stats`` and, optionally, ``accel_units``/``gyro_units``.  Blocks must
        be yielded after they were appended (segment indices count the recorder's samples).
    plan : Plan or None
        The steps (static and rotation); None only with ``adaptive`` (every pose proposed).
    console : rich.console.Console
        Where to talk.  A terminal gets a live display; anything else plain lines.
    keys : KeySource
        Commands: ``r`` redo, ``s`` skip, ``q`` finish, Enter continue, a step number or label.
    options : GuidedOptions, optional
        The options of the capture (its defaults where not given); ``accel_units`` and
        ``gyro_units`` left None become the recorder's.
    done_before : list, optional
        Continuing a capture: the session's segments, ``(kind, label, mean raw accel or
        None)`` in time order; the steps they fulfil are done (see :meth:`GuidedState.resume`).
    adaptive : AdaptiveOptions, optional
        Capture until accuracy targets are met (:class:`AdaptiveState`): refits, proposals,
        holds that end by themselves; ``complete`` then means every target was met.
    **fields
        Any of :class:`GuidedOptions`' fields (``hold_s=2.5``), replacing ``options``' value;
        a name that is not one raises ``TypeError``.

    Returns
    -------
    CaptureSummary
        ``complete`` iff no step is missing or skipped; ``done`` in the order taken.
    """
    opt = replace(options or GuidedOptions(), **fields)
    units = {k: getattr(recorder, k, None) for k in ("accel_units", "gyro_units")
             if getattr(opt, k) is None}  # fmt: skip
    opt = replace(opt, **units) if units else opt
    if adaptive is not None:
        state = AdaptiveState(plan, opt, int(recorder.n_samples), recorder.add_segment,
                              adaptive)  # fmt: skip
    else:
        state = GuidedState(plan, opt, int(recorder.n_samples), recorder.add_segment)
    if done_before:
        state.resume(done_before)
    return drive(state, Screen(console, opt.refresh_hz), recorder, keys, opt.tick_s)


def drive(state: GuidedState, screen: Screen, recorder, keys: KeySource, tick_s: float):
    """The loop: each block to the state, then the commands typed, then the screen."""
    gen = recorder.blocks(tick_s)
    screen.start(state)
    try:
        for block in gen if state.end_reason is None else ():  # resumed when complete: no need
            state.on_block(block)
            while state.end_reason is None and (line := keys.get()) is not None:
                state.on_command(line)
            if state.end_reason is not None:
                break
            screen.show(state)
    finally:
        gen.close()
        if state.end_reason is not None:
            recorder.stop()
        screen.stop(state)
    summary = state.summary(recorder)
    screen.print_messages(state)
    return summary
