"""The calibrate step: a session and a config in, a typed calibration out. ``registry`` (the
solver interface and the one choice of every sensor), the sensors' steps (``accel/``,
``gyro/``, ``mag``, ``thermal``, ``clock``: each turns the session into its design, runs the
chosen estimator and builds its section), ``session`` (the facade: every sensor's outcome)
and ``batch`` (many sessions); shared: the pose statistics and checks of
:mod:`imucal_cli.calibrate.common`, a unit's factorization, the channel checks."""
