"""Command-line interface: thin typer commands that parse, call the library and print.

Each command lives in its own module and registers itself on :data:`app`.
:func:`main` turns an :class:`~imucal_cli.errors.ImucalError` into one line on stderr and its
exit code, so a user mistake never shows a traceback.
"""

from __future__ import annotations

import sys

from imucal_cli.errors import ImucalError

# Importing the command modules registers their commands on ``app``.
from . import apply as _apply  # noqa: E402,F401
from . import calibrate as _calibrate  # noqa: E402,F401
from . import capture as _capture  # noqa: E402,F401
from . import export as _export  # noqa: E402,F401
from . import import_ as _import  # noqa: E402,F401
from . import noise as _noise  # noqa: E402,F401
from . import report as _report  # noqa: E402,F401
from . import simulate as _simulate  # noqa: E402,F401
from .app import app


def main() -> None:
    """Console-script entry point (``imucal``)."""
    try:
        app()
    except ImucalError as exc:
        print(f"imucal: error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        print("imucal: interrupted", file=sys.stderr)
        sys.exit(130)
