"""Command-line interface: thin typer commands that parse, call the library and print.

Each command lives in its own module and registers itself on :data:`app`.
:func:`main` turns an :class:`~imucal_cli.errors.ImucalError` into one line on stderr and its
exit code, so a user mistake never shows a traceback.
"""

from __future__ import annotations

import os
import sys

from imucal_cli.errors import ImucalError

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


def main() -> None:
    """Console-script entry point (``imucal``): run, then exit with the command's status."""
    code = _run()
    try:
        sys.stdout.flush()
    except BrokenPipeError:  # `imucal report ... | head`: the reader has gone; so do we
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    sys.exit(code)


def _run() -> int:
    import typer

    try:
        # Not standalone: usage errors come back here, to be told on one line like every
        # other mistake (the default is a framed, multi-line box).
        code = app(standalone_mode=False)
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        print("imucal: interrupted", file=sys.stderr)
        return 130
    except typer.TyperException as exc:  # usage errors: bad option, missing argument, ...
        ctx = getattr(exc, "ctx", None)
        if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:
            print(ctx.get_help(), file=sys.stderr)  # bare `imucal`: the help, as usual
            return 2
        where = f"{ctx.command_path}: " if ctx is not None else ""
        hint = f" (see `{ctx.command_path} --help`)" if ctx is not None else ""
        print(f"imucal: error: {where}{exc.format_message()}{hint}", file=sys.stderr)
        return getattr(exc, "exit_code", 2)
    except ImucalError as exc:
        print(f"imucal: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("imucal: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return code if isinstance(code, int) else 0
