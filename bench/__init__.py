"""Benchmarks: accuracy against truth and the Cramér-Rao bound, and timing (``make bench``)."""
