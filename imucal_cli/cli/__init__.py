"""Command-line interface: thin typer commands that parse, call the library and print.

Each command lives in its own module and registers itself on :data:`app`; the module is
imported when a command line names its command (:data:`~imucal_cli.cli.app.COMMANDS`).
:func:`main` turns an :class:`~imucal_cli.errors.ImucalError` into one line on stderr and its
exit code, so a user mistake never shows a traceback.  When stdout is a pipe whose reader has
gone (``imucal report X | head``), the rest of the output is dropped quietly and the command
still finishes and exits with its own status.
"""

from __future__ import annotations

import errno
import functools
import io
import os
import signal
import stat
import sys
import warnings
from contextlib import contextmanager

import typer

from imucal_cli.errors import ImucalError, ImucalWarning
from imucal_cli.formats.text import clean_text

# The command modules register their commands on ``app`` when a command line names them
# (``COMMANDS`` in ``app.py``).
from .app import app


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings of the library (:class:`ImucalWarning`) on one line; others as Python does."""
    if issubclass(category, ImucalWarning):
        try:
            print(f"imucal: warning: {clean_text(str(message))}", file=sys.stderr, flush=True)
        except OSError:
            pass
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


_python_showwarning = warnings.showwarning


class _PipeWriter(io.RawIOBase):
    """File descriptor 1 where a closed pipe (EPIPE) swallows the rest of the output."""

    def __init__(self, fd: int) -> None:
        super().__init__()
        self.fd = fd
        self.broken = False

    def writable(self) -> bool:
        return True

    def fileno(self) -> int:
        return self.fd

    def isatty(self) -> bool:
        return False

    def write(self, data) -> int:
        n = len(data)
        if self.broken:
            return n
        try:
            return os.write(self.fd, data)
        except BrokenPipeError:
            self.broken = True  # the reader has gone: drop the rest, the command goes on
            return n


def _guard_stdout():
    """Replace ``sys.stdout`` by an EPIPE-safe stream when it is a pipe; returns the original."""
    original = sys.stdout
    try:
        if original is not sys.__stdout__ or not stat.S_ISFIFO(os.fstat(1).st_mode):
            return None
        original.flush()
    except (AttributeError, OSError, ValueError):
        return None
    sys.stdout = io.TextIOWrapper(
        io.BufferedWriter(_PipeWriter(1)),
        encoding=original.encoding,
        errors=original.errors,
        line_buffering=original.line_buffering,
    )
    return original


_CTRL_C: list[int] = []
"""Ctrl-C presses that reached :func:`main`'s handler (typer turns the KeyboardInterrupt of
one into a silent status 130: :func:`_run` then says ``imucal: interrupted``)."""


def _on_ctrl_c(signum, frame):  # noqa: ARG001
    _CTRL_C.append(signum)
    raise KeyboardInterrupt


@contextmanager
def _ctrl_c_counted():
    """While a command runs, Ctrl-C raises KeyboardInterrupt as usual and is counted; not
    where Ctrl-C is ignored (a background job) or handled by someone else."""
    mine = signal.getsignal(signal.SIGINT) is signal.default_int_handler
    if mine:
        signal.signal(signal.SIGINT, _on_ctrl_c)
    try:
        yield
    finally:
        if mine:
            signal.signal(signal.SIGINT, signal.default_int_handler)


def main() -> None:
    """The ``imucal`` program (console script and ``python -m imucal_cli``): run the command,
    then exit with its status."""
    _CTRL_C.clear()
    warnings.showwarning = _show_warning
    warnings.simplefilter("always", ImucalWarning)
    original = _guard_stdout()
    try:
        with _ctrl_c_counted():
            code = _run()
    finally:
        if original is not None:
            try:
                sys.stdout.flush()
            finally:
                sys.stdout = original
    try:
        if sys.stdout is not None:  # None: started with stdout closed (`imucal ... >&-`)
            sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    sys.exit(code)


def _print_error(text: str) -> None:
    try:
        print(text, file=sys.stderr)
    except OSError:
        pass


def _run() -> int:
    code = _run_app()
    if code == 130 and _CTRL_C:  # typer's status for a KeyboardInterrupt: nothing was said
        _print_error("imucal: interrupted")
    return code


def _interrupted() -> int:
    _print_error("imucal: interrupted")
    _CTRL_C.clear()  # said
    return 130


@functools.cache
def _command() -> typer.core.TyperGroup:
    """``app`` as a click group, built once per process: calling ``app`` builds it again
    each time, every registered command's signature read anew (28 ms each call once every
    command is loaded, as in a process that runs many commands: the tests). The group loads
    commands into itself when a command line names them (:class:`~.app.Commands`)."""
    return typer.main.get_command(app)


def _run_app() -> int:
    try:
        # Not standalone: usage errors come back here, to be told on one line like every
        # other mistake (the default is a framed, multi-line box).
        code = _command()(prog_name="imucal", standalone_mode=False)  # also `python -m`
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        return _interrupted()
    except typer.TyperException as exc:  # usage errors: bad option, missing argument, ...
        ctx = getattr(exc, "ctx", None)
        if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:
            print(ctx.get_help(), file=sys.stderr)  # bare `imucal`: the help, as usual
            return 2
        hint = f" (see `{ctx.command_path} --help`)" if ctx is not None else ""
        message = _one_line(exc.format_message()).rstrip(".")
        print(f"imucal: error: {message}{hint}", file=sys.stderr)
        return getattr(exc, "exit_code", 2)
    except ImucalError as exc:
        _print_error(f"imucal: error: {_one_line(clean_text(str(exc)))}")
        return exc.exit_code
    except MemoryError:
        _print_error("imucal: error: not enough memory for this input")
        return 1
    except KeyboardInterrupt:
        return _interrupted()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        if exc.errno == errno.EIO:  # the terminal hung up (SIGHUP): nobody reads the output
            return 129
        raise
    return code if isinstance(code, int) else 0


def _one_line(message: str) -> str:
    """The message on one line, without a prefix the caller already gives."""
    text = " ".join(message.split())
    for prefix in ("imucal: error: ", "imucal: ", "Error: "):
        if text.startswith(prefix):
            text = text[len(prefix) :]
    return text
