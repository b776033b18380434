"""The calibrate steps between session I/O and the solvers: one module per solver family,
sharing the pose statistics and checks of :mod:`imucal_cli.pipeline.common`."""
