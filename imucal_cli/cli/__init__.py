"""Command-line interface: thin typer commands that parse, call the library and print.

Each command lives in its own module and registers itself on :data:`app`.
:func:`main` turns an :class:`~imucal_cli.errors.ImucalError` into one line on stderr and its
exit code, so a user mistake never shows a traceback.  When stdout is a pipe whose reader has
gone (``imucal report X | head``), the rest of the output is dropped quietly and the command
still finishes and exits with its own status.
"""

from __future__ import annotations

import errno
import io
import os
import stat
import sys
import warnings
from contextlib import contextmanager

from imucal_cli.errors import ImucalError, ImucalWarning

# Importing the command modules registers their commands on ``app``.
from . import apply as _apply  # noqa: E402,F401
from . import calibrate as _calibrate  # noqa: E402,F401
from . import capture as _capture  # noqa: E402,F401
from . import export as _export  # noqa: E402,F401
from . import import_ as _import  # noqa: E402,F401
from . import label as _label  # noqa: E402,F401
from . import noise as _noise  # noqa: E402,F401
from . import report as _report  # noqa: E402,F401
from . import simulate as _simulate  # noqa: E402,F401
from .app import app


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings of the library (:class:`ImucalWarning`) on one line; others as Python does."""
    if issubclass(category, ImucalWarning):
        from imucal_cli.formats.text import clean_text

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


def _reuse_freed_memory() -> None:
    """Serve numpy's temporaries (a few hundred kB to a few MB per block of samples) from
    memory the process freed before, instead of fresh pages from the kernel each time: glibc
    maps every allocation over 128 kB anew, and zeroing those pages cost 0.1-0.3 s of CPU over
    a day-long ``apply`` or ``noise`` and 0.05 s of a calibration (issue 14).  glibc only;
    elsewhere nothing changes."""
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    m_trim_threshold, m_mmap_threshold = -1, -3  # glibc's malloc.h
    mallopt(m_mmap_threshold, 32 << 20)
    mallopt(m_trim_threshold, 64 << 20)


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
    import signal

    mine = signal.getsignal(signal.SIGINT) is signal.default_int_handler
    if mine:
        signal.signal(signal.SIGINT, _on_ctrl_c)
    try:
        yield
    finally:
        if mine:
            signal.signal(signal.SIGINT, signal.default_int_handler)


def main() -> None:
    """Console-script entry point (``imucal``): run, then exit with the command's status."""
    _reuse_freed_memory()
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


def run() -> None:
    """The ``imucal`` program: :func:`main`, then leave without tearing the interpreter down.

    Python's exit frees every module and object one by one (40 ms of a 0.5 s calibration,
    issue 14); the operating system frees a process's memory at once. The exit handlers still
    run and the output is flushed. Python exits as usual where that would differ: while a
    thread other than daemons runs (Python waits for it), an HDF5 file is still open (the
    library flushes it at exit), the status is not a number, or a profiler or debugger is
    attached (it reports after the program returns). :func:`main` itself raises
    ``SystemExit`` as usual, for callers in the same process (the tests)."""
    try:
        main()
    except SystemExit as exc:
        code = exc.code
    else:
        code = 0
    _ignore_ctrl_c()  # the command is over: leaving is not interrupted
    if type(code) is not int or _threads_running() or sys.getprofile() or sys.gettrace():
        sys.exit(code)
    import atexit

    atexit._run_exitfuncs()  # what a normal exit runs next (weakref finalizers among them)
    if _hdf5_files_open():
        sys.exit(code)  # the handlers have run (and are cleared): HDF5 closes its files
    try:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:  # None: started with the descriptor closed
                stream.flush()
    except (OSError, ValueError):
        sys.exit(code)  # as Python reports a failed flush at exit
    os._exit(code)


def _ignore_ctrl_c() -> None:
    import signal

    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _threads_running() -> bool:
    """Whether a thread other than the main one, and not a daemon, is still running (a normal
    exit waits for it)."""
    threading = sys.modules.get("threading")
    if threading is None:
        return False
    main_thread = threading.main_thread()
    return any(t is not main_thread and not t.daemon and t.is_alive()
               for t in threading.enumerate())  # fmt: skip


def _hdf5_files_open() -> bool:
    """Whether an HDF5 file is still open in this process (h5py imported and a file id live)."""
    h5py = sys.modules.get("h5py")
    if h5py is None:
        return False
    try:
        # A file stays open while any of its objects does (a dataset kept after its File was
        # dropped): count those too (not OBJ_ALL types: h5py keeps datatypes of its own).
        kinds = h5py.h5f.OBJ_FILE | h5py.h5f.OBJ_DATASET | h5py.h5f.OBJ_GROUP | h5py.h5f.OBJ_ATTR
        return h5py.h5f.get_obj_count(h5py.h5f.OBJ_ALL, kinds) > 0
    except Exception:  # noqa: BLE001  unsure: exit as usual
        return True


def _print_error(text: str) -> None:
    try:
        print(text, file=sys.stderr)
    except OSError:
        pass


@contextmanager
def _only_the_named_command(argv: list[str]):
    """While typer runs, register only the command that ``argv`` names first (``imucal
    calibrate ...``): typer builds the options of every registered command on each run, 10 ms
    for all of them, 1 ms for one (issue 14.4). A command line that starts with anything else
    (``--help``, a misspelt command) sees them all."""
    full = list(app.registered_commands)
    named = [c for c in full if len(argv) > 1 and _command_name(c) == argv[1]]
    if named:
        app.registered_commands = named
    try:
        yield
    finally:
        app.registered_commands = full


def _command_name(info) -> str:
    """The name typer gives a registered command (its own, else the function's, dashed)."""
    return info.name or info.callback.__name__.replace("_", "-")


def _run() -> int:
    code = _run_app()
    if code == 130 and _CTRL_C:  # typer's status for a KeyboardInterrupt: nothing was said
        _print_error("imucal: interrupted")
    return code


def _interrupted() -> int:
    _print_error("imucal: interrupted")
    _CTRL_C.clear()  # said
    return 130


def _run_app() -> int:
    import typer

    try:
        # Not standalone: usage errors come back here, to be told on one line like every
        # other mistake (the default is a framed, multi-line box).
        with _only_the_named_command(sys.argv):
            code = app(standalone_mode=False)
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
        from imucal_cli.formats.text import clean_text

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
