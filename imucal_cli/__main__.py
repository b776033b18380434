from imucal_cli.cli import run

run()
