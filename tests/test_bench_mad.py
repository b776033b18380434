"""``bench mad``'s comparison of the held-out transitions (issue 24.5): MaD Lab's figures
recorded per transition, and the paired difference shown beside the verdict."""

from __future__ import annotations

import numpy as np
import pytest

from bench.mad import MAD_LOO_DEG, paired


def test_the_recorded_reference_is_mad_labs_figure():
    assert len(MAD_LOO_DEG) == 12
    assert abs(np.sqrt(np.mean(np.square(MAD_LOO_DEG))) - 0.6716) < 1e-4


def test_the_paired_difference_is_the_difference_of_mean_squares():
    theirs = np.asarray(MAD_LOO_DEG)
    ours = theirs + 0.2
    diff, se = paired(ours, theirs)
    assert diff == pytest.approx(np.mean(ours**2) - np.mean(theirs**2))
    d = ours**2 - theirs**2
    assert se == pytest.approx(np.std(d, ddof=1) / np.sqrt(12)) and diff > 3 * se


def test_transitions_that_do_not_pair_are_refused():
    with pytest.raises(ValueError, match="11 transitions against 12"):
        paired(np.ones(11), np.asarray(MAD_LOO_DEG))
