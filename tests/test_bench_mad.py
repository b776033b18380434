"""``bench mad``'s verdict on the held-out transitions (issue 24.5): paired, on the same
transitions, "worse" only beyond what their number can tell from chance."""

from __future__ import annotations

import numpy as np

from bench.mad import MAD_LOO_DEG, not_worse


def test_the_recorded_reference_is_mad_labs_figure():
    assert len(MAD_LOO_DEG) == 12
    assert abs(np.sqrt(np.mean(np.square(MAD_LOO_DEG))) - 0.6716) < 1e-4


def test_worse_on_every_transition_is_worse():
    theirs = np.asarray(MAD_LOO_DEG)
    ok, diff, se = not_worse(theirs + 0.2, theirs)
    assert not ok and diff > 1.645 * se > 0


def test_equal_or_better_is_not_worse():
    theirs = np.asarray(MAD_LOO_DEG)
    assert not_worse(theirs, theirs + 1e-9)[0]
    assert not_worse(0.9 * theirs, theirs)[0]


def test_a_difference_the_transitions_cannot_resolve_is_not_worse():
    """Errors that differ by noise of 0.05 deg per transition, one way or the other, with a
    mean difference well inside its standard error."""
    theirs = np.asarray(MAD_LOO_DEG)
    swing = 0.05 * np.where(np.arange(12) % 2 == 0, 1.0, -1.0)
    ok, diff, se = not_worse(theirs + swing, theirs)
    assert ok and abs(diff) < se
