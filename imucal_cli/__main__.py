"""The ``imucal`` program: ``python -m imucal_cli`` and the console script (``program``).

Ctrl-C may come at any moment, also while the command-line layer is still being imported
(typer, rich: a good part of a second on a busy machine): it ends the program with
``imucal: interrupted`` and status 130, never with a traceback.  Only what happens before the
first line of this package runs is out of reach: a Ctrl-C during the interpreter's own
start-up, or while the import system is still looking for ``imucal_cli``, ends the program as
Python does (status 130, silently or with Python's ``KeyboardInterrupt`` traceback; see
DEVELOPERS.md).
"""

import os
import signal
import sys


def _interrupted() -> None:
    try:
        print("imucal: interrupted", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass
    os._exit(130)


def _end_on_ctrl_c(signum, frame) -> None:  # noqa: ARG001 - a signal handler's signature
    _interrupted()


def program() -> None:
    """Import the command-line layer and run the command (:func:`imucal_cli.cli.main`).

    While it imports, Ctrl-C ends the program from the signal handler itself: raised as
    ``KeyboardInterrupt`` it may land in the import system's own callbacks, which Python
    reports ("Exception ignored in ... _get_module_lock") and drops, so the program went on
    (a fresh clone, with no compiled modules, imports slowly enough to hit it)."""
    previous = signal.getsignal(signal.SIGINT)
    if previous is signal.default_int_handler:
        signal.signal(signal.SIGINT, _end_on_ctrl_c)
    try:
        from imucal_cli.cli import main
    except KeyboardInterrupt:
        _interrupted()
    if previous is signal.default_int_handler:
        signal.signal(signal.SIGINT, previous)  # the command takes Ctrl-C over from here
    try:
        main()
    except KeyboardInterrupt:  # before the command took Ctrl-C over, or after it returned
        _interrupted()
    except SystemExit:
        _status_decided()
        raise


def _status_decided() -> None:
    """The command is done and its status decided: a Ctrl-C from here on changes nothing.
    Python's shutdown (a second or so on a busy machine: h5py, threads) would otherwise end
    the process by SIGINT itself: a saved capture or calibration would exit as killed by
    Ctrl-C (130 in the shell) instead of its own status."""
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except (ValueError, OSError):  # not the main thread, or no such signal here
        pass


if __name__ == "__main__":
    program()
