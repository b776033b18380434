"""The typer application object.  Command modules import ``app`` and register themselves."""

import typer

app = typer.Typer(
    name="imucal",
    help=(
        "Calibrate MEMS accelerometers and gyroscopes with no rate table: "
        "simulate or capture a session, calibrate it, report the result."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
)
