"""Fixtures for every test."""

from __future__ import annotations

import pytest

from .cli_helpers import reap


@pytest.fixture(autouse=True)
def _reap_background_processes():
    """No process a test started with ``cli_helpers.spawn`` outlives the test."""
    yield
    reap()
