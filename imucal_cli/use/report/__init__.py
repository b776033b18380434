"""Calibration report: what a stored calibration says, as a JSON-ready dict and as rich tables.

A report only *reads* results.  It takes a
:class:`~imucal_cli.model.calibration.Calibration` (from a calibration JSON, or the last one
stored under ``/calibrations`` of a session) and lays out what the solver wrote: the model and
its parameters with standard deviations, misalignment angles, the gravity-magnitude RMS before /
after / leave-one-pose-out, the per-pose residuals and how well the measured gravity directions
cover the sphere.  Nothing is re-solved or recomputed from raw data; fields a calibration does
not carry (one written by another tool has only the standard ``solver``/``units``/``bias``/
``matrix``/``residual_rms``) are listed as unavailable.

Sections written by the factorization solver (Hwangbo & Kanade; accelerometer triads and
redundant units, gyroscopes) are shown the same way, plus the frame the matrix is expressed in,
the constraint case, a linear-versus-refined table in the layout of the paper's Table I and, for
gyroscopes, each known-angle turn with its measured angle.

The package is split by concern:

- :mod:`.load`: reading calibrations (JSON, or those stored in a session);
- :mod:`.build`: :func:`build_report`, the report as a dict (the ``imucal report --json``
  output);
- :mod:`.render`: :func:`render_report`, that dict drawn on a :class:`rich.console.Console`;
- :mod:`.history`: :func:`build_history` / :func:`render_history`, drift across calibrations;
- :mod:`.fields`, :mod:`.fmt`, :mod:`.coverage_map`: tolerant field readers, number formatting
  and the text map of gravity directions.

Import from the modules (``from imucal_cli.use.report.build import build_report``): the package
itself imports none of them, so that what needs one (the acceptance limits and a lot's drift
test need :mod:`.history`) does not load them all (:mod:`.load` reads sessions: h5py).
"""
