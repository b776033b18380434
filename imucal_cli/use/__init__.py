"""Using a calibration once it exists: ``apply`` (calibrated data), ``export`` (other tools'
formats), ``noise`` (Allan deviation), ``report`` (tables and history) and ``plots``. These
read results; they never re-solve."""
