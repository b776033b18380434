"""The typer application object.  Command modules import ``app`` and register themselves.

Help is plain text (``rich_markup_mode=None``): square brackets in help texts (``[default:
...]``, ``[[step]]``, ``pip install 'imucal-cli[plot]'``) are shown as written.  In a terminal
it is wrapped to the terminal (at most 100 columns); anywhere else (a pipe, a file) it is not
wrapped at all, so every option's help is one line for grep.
"""

from __future__ import annotations

import importlib
import shutil
import sys

import typer
from typer.core import TyperGroup

from imucal_cli import __version__

NO_WRAP_WIDTH = 100_000
"""Help width when stdout is not a terminal: nothing is wrapped."""

EXIT_CODES = (
    (
        0,
        "done: the result was written or printed (capture: the session is complete; "
        "calibrate: saved, complete or partial: `complete` in its JSON)",
    ),
    (
        1,
        "calibrate: the solver failed or the result is outside physical sense (not saved "
        "unless --force), or saved but not stored in the session or the registry",
    ),
    (2, "bad input or usage: nothing was written"),
    (
        3,
        "capture: the session is saved but incomplete (steps missing, interrupted, device "
        "gone, data stopped)",
    ),
    (
        4,
        "calibrate --limits: saved, but the unit is outside its product's limits (rejected; "
        "the failed figures are named)",
    ),
    (130, "interrupted (Ctrl-C) before anything was saved"),
)
"""The exit statuses of every command (the same table is in docs/commands.md)."""


def exit_codes_help() -> str:
    """The exit-status table for --help (``\\b``: click keeps the lines as they are)."""
    return "Exit status:\n\n\b\n" + "\n".join(f"{code:>5}  {what}" for code, what in EXIT_CODES)


def help_width() -> int:
    """Columns for --help: the terminal's (at most 100), or no wrapping off a terminal."""
    try:
        terminal = sys.stdout.isatty()
    except (AttributeError, ValueError):
        terminal = False
    if not terminal:
        return NO_WRAP_WIDTH
    return min(shutil.get_terminal_size().columns, 100)


def _metavar_only(argument_class) -> None:
    """In the help, an argument with a metavar (``SESSION.h5``) is shown by it alone: not also
    by its Python type (``SESSION.h5 <path>``), and in the usage line as click writes it
    (``SESSION.h5``, ``FILE...``; not ``{SESSION.h5}``)."""
    display = getattr(argument_class, "display_type_rich", None)
    usage = getattr(argument_class, "_usage_display_name", None)
    if display is None or getattr(display, "imucal_patched", False):
        return

    def display_type(self, ctx):
        return None if self.metavar else display(self, ctx)

    def usage_name(self):
        if not self.metavar or usage is None:
            return usage(self) if usage is not None else self.metavar
        name = self.metavar if self.required else f"[{self.metavar}]"
        return name + ("..." if self.nargs != 1 else "")

    display_type.imucal_patched = True
    argument_class.display_type_rich = display_type
    if usage is not None:
        argument_class._usage_display_name = usage_name


_metavar_only(getattr(typer.core, "TyperArgument", object))


def _version(value: bool) -> None:
    if value:
        typer.echo(f"imucal {__version__}")
        raise typer.Exit(0)


COMMANDS = {
    "apply": "apply", "calibrate": "calibrate", "capture": "capture",
    "certificate": "certificate", "export": "export", "import": "import_", "label": "label",
    "noise": "noise", "report": "report", "simulate": "simulate", "registry": "registry",
}  # fmt: skip
"""Every command of ``imucal`` (in the order ``--help`` lists them) and the module of this
package that registers it on :data:`app`."""


class Commands(TyperGroup):
    """The root's commands, each command's module imported when a command line names it
    (click's "lazily loading subcommands"): ``imucal registry lot`` loads the registry's
    libraries, not also those of calibrate, capture and simulate. ``--help``, completion and
    a misspelt command (typer's "Did you mean") load them all."""

    def list_commands(self, ctx) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx, cmd_name: str):
        if cmd_name not in self.commands and cmd_name in COMMANDS:
            self.load([cmd_name])
        return super().get_command(ctx, cmd_name)

    def resolve_command(self, ctx, args: list[str]):
        if args and args[0] not in COMMANDS:
            self.load(COMMANDS)  # typer suggests a name among those loaded
        return super().resolve_command(ctx, args)

    def format_commands(self, ctx, formatter) -> None:
        self.load(COMMANDS)
        super().format_commands(ctx, formatter)

    def load(self, names) -> None:
        """Import the modules of the commands ``names`` and add what they registered."""
        missing = [n for n in names if n not in self.commands]
        if not missing:
            return
        for name in missing:
            importlib.import_module(f"{__package__}.{COMMANDS[name]}")
        built = typer.main.get_command(app).commands  # typer's own build of what is registered
        for name in COMMANDS:
            if name not in self.commands and name in built:
                self.commands[name] = built[name]


def load_commands() -> None:
    """Import every command's module (what ``app.registered_commands`` and
    ``typer.main.get_command(app)`` then hold: all of them)."""
    for module in COMMANDS.values():
        importlib.import_module(f"{__package__}.{module}")


app = typer.Typer(
    name="imucal",
    cls=Commands,
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    context_settings={
        "help_option_names": ["-h", "--help"],
        "terminal_width": help_width(),
        "max_content_width": help_width(),
    },
)


ROOT_HELP = (
    "Calibrate MEMS accelerometers, gyroscopes and magnetometers with no rate table: simulate "
    "or capture a session, calibrate it, report the result.\n\n"
    "Commands print results for people; those that print results take --json for scripts "
    "(schemas: docs/commands.md). Shell completion: imucal --install-completion.\n\n"
    + exit_codes_help()
)


@app.callback(help=ROOT_HELP)
def _root(
    version: bool = typer.Option(
        False,
        "--version",
        "-V",
        callback=_version,
        is_eager=True,
        help="Print the version and exit.",
    ),
) -> None:
    """The root: only --version (each command is a module of this package)."""
