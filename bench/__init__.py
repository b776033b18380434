"""Benchmarks: accuracy against truth and the Cramér-Rao bound, and timing (``make bench``)."""

import imucal_cli  # noqa: F401  (first: sets single-threaded BLAS before numpy loads)
