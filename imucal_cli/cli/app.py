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
from typer.core import TyperCommand, TyperGroup

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

SUMMARIES = {
    "apply": "Apply a calibration to every sample: calibrated = matrix @ (raw - bias).",
    "calibrate": "Calibrate the sensors of SESSION the config asks for and write a calibration "
                 "JSON.",
    "capture": "Record a calibration session from an IMU on a serial port.",
    "certificate": "Write a unit's calibration certificate: identity (serial, product, lot, "
                   "station, operator, times), the session's content hash, the verdict and every "
                   "limit check, each sensor's parameters with their std and residuals, and the "
                   "plots (inline PNG: the file stands alone).",
    "export": "Export a calibration for firmware, ROS, estimators or scripts.",
    "import": "Import recorded samples into a session and find its still poses and rotations.",
    "label": "Set or correct the labels of SESSION: faces from the measured directions, one "
             "segment by hand, the sensor, units and gravity.",
    "noise": "Noise figures of a still recording for your filter: Allan deviation per axis.",
    "report": "Report a calibration: parameters ± std, RMS before/after/held-out, poses, "
              "coverage.",
    "simulate": "Simulate a calibration session of a cheap 16-bit MEMS IMU with known truth.",
    "registry": "The calibrations of every unit by serial number: list, show a unit's history "
                "and drift, export and import records, a lot's statistics.",
}  # fmt: skip
"""The first sentence of each command's help: what the root's ``--help`` lists for a command
whose module is not loaded (the short help is made from this sentence as from the whole help:
``tests/test_cli_conformance.py`` compares them)."""


class Commands(TyperGroup):
    """The root's commands, each command's module imported when a command line names it
    (click's "lazily loading subcommands"): ``imucal registry lot`` loads the registry's
    libraries, not also those of calibrate, capture and simulate. The root's ``--help`` lists
    the commands not loaded by their :data:`SUMMARIES`; completion and a misspelt command
    (typer's "Did you mean") load them all."""

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
        """The list of commands as typer writes it, each command's short help made from its
        :data:`SUMMARIES` sentence where its module is not loaded: ``imucal --help`` imports
        no command (0.1-0.2 s of CPU, 1.5-2 s when it imported them all)."""
        commands = [(name, self.commands.get(name) or self.stand_in(name)) for name in COMMANDS]
        commands = [(name, cmd) for name, cmd in commands if not cmd.hidden]
        if not commands:
            return
        limit = formatter.width - 6 - max(len(name) for name, _ in commands)
        rows = [(name, cmd.get_short_help_str(limit)) for name, cmd in commands]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    @staticmethod
    def stand_in(name: str) -> TyperCommand:
        """Command ``name`` as the root's help lists it, its module not imported."""
        return TyperCommand(name=name, help=SUMMARIES[name])

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
