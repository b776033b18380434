"""Issue 26.1, fast cases of the importer fuzz (``bench/reliability.py`` runs hundreds per
format): every format's file, written by its own library, damaged eight ways; each read gives a
one-line ImucalError with exit 2, or rows the oracle finds to be the file's own
(``tests/format_fuzz.py``)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from imucal_cli.errors import ImucalError
from imucal_cli.formats.importers import read_recording

from .format_fuzz import MAKERS, judge, mutate, place


@pytest.mark.parametrize("name", list(MAKERS))
def test_damaged_files_are_refused_in_one_line_or_read_right(name, tmp_path):
    (tmp_path / "base").mkdir()
    base = MAKERS[name](tmp_path / "base")
    rec = read_recording(base.paths, base.fmt, **base.options)
    assert judge(base, rec, []).verdict == "handled" and len(rec.time) >= 0.9 * len(base.time)
    original = base.target.read_bytes()
    rng = np.random.default_rng(2026)
    for _ in range(8):
        data, ranges, what = mutate(original, rng)
        paths = place(base, data, tmp_path)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                got = read_recording(paths, base.fmt, **base.options)
        except ImucalError as exc:
            assert exc.exit_code == 2 and "\n" not in str(exc), (what, str(exc))
            continue
        verdict = judge(base, got, ranges)
        assert verdict.verdict == "handled", (what, verdict.detail)
