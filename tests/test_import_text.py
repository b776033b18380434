"""The text reader of `imucal import` (formats/importers/text.py): the array scanner gives
exactly what the line-by-line reader gives (counts, line numbers, header, values), on messy
files of every kind; the line numbers of malformed lines and of time errors are right."""

from __future__ import annotations

import numpy as np
import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.importers.recording import ImportStats
from imucal_cli.formats.importers.text import read_table
from imucal_cli.formats.importers.text_scan import scan_ascii as _scan_ascii
from imucal_cli.formats.importers.text_scan import scan_lines as _scan_lines

TOKENS = ["abc", "1.2.3", "-", "nan", "1e999", "1,,2", " ,", "1 2,3", "+5", ".5", "5.", "1e5",
          "e", "x#", "a b", "-.5", "1E-3", "#"]  # fmt: skip


def messy_text(rng: np.random.Generator) -> str:
    """A random text table: header, comments, blank lines, odd tokens, short and long rows,
    any line break and separator."""
    nf = int(rng.integers(2, 6))
    comma = rng.random() < 0.5
    sep = "," if comma else str(rng.choice([" ", "\t", "  "]))
    lines = [sep.join(["t", "ax", "ay", "az", "gx"][:nf])] if rng.random() < 0.5 else []
    for i in range(int(rng.integers(0, 40))):
        r = rng.random()
        if r < 0.05:
            lines.append("")
        elif r < 0.1:
            lines.append(f"  # comment {i}")
        elif r < 0.15:
            lines.append(sep.join(["1"] * int(rng.integers(1, 7))))
        elif r < 0.2:
            lines.append(str(rng.choice(TOKENS)))
        else:
            fields = []
            for _ in range(nf):
                u = rng.random()
                if u < 0.85:
                    fields.append(f"{rng.normal():.{int(rng.integers(1, 17))}g}")
                elif u < 0.9:
                    fields.append(f" {rng.normal() * 1e3:.6e} " if comma else "7")
                else:
                    fields.append(str(rng.choice(TOKENS)))
            lines.append(sep.join(fields))
    eol = str(rng.choice(["\n", "\r\n", "\r"]))
    return eol.join(lines) + (eol if rng.random() < 0.7 else "")


def same_scan(a, b) -> None:
    for key in ("n_lines", "header", "blank", "comments", "header_fields"):
        assert getattr(a, key) == getattr(b, key), key
    for key in ("numbers", "lengths", "bad"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
    if len(a.numbers):
        n = int(np.argmax(np.bincount(a.lengths)))
        keep = a.lengths == n
        np.testing.assert_array_equal(a.rows(keep, n), b.rows(keep, n))  # bit for bit


def test_array_scanner_equals_line_reader_on_messy_files():
    rng = np.random.default_rng(2026)
    fast = 0
    for _ in range(600):
        text = messy_text(rng)
        skip_rows = int(rng.integers(0, 3))
        comma = [None, False, True][int(rng.integers(0, 3))]
        skip = frozenset([int(rng.integers(0, 4))]) if rng.random() < 0.3 else frozenset()
        if not text.strip():
            continue
        reference = _scan_lines(text.splitlines(), skip_rows, comma, skip)
        scan = _scan_ascii(text.encode(), skip_rows, comma, skip)
        if scan is not None:
            fast += 1
            same_scan(scan, reference)
    assert fast > 300  # the array path serves files with header, comments, odd rows too


def test_values_are_read_exactly_as_python_reads_them():
    rng = np.random.default_rng(5)
    values = np.r_[rng.normal(size=500) * 10.0 ** rng.integers(-30, 30, 500), 0.1, 1 / 3]
    text = "\n".join(f"{i},{float(v)!r},{v:.17e},{v:.6g}" for i, v in enumerate(values)) + "\n"
    scan = _scan_ascii(text.encode(), 0, None, frozenset())
    rows = scan.rows(np.ones(len(values), bool), 4)
    expected = [[float(p) for p in line.split(",")] for line in text.splitlines()]
    np.testing.assert_array_equal(rows, np.array(expected))


def test_malformed_lines_are_counted_with_their_line_numbers(tmp_path):
    path = tmp_path / "r.csv"
    rows = [f"{i * 0.01:.2f},{i},2,3" for i in range(200)]
    rows[50] = "0.50,1,2"  # a field short
    rows[120] = "1.20,1,oops,3"  # text
    rows[121] = "1.21,1,2,nan"  # not finite
    path.write_bytes(("t,ax,ay,az\r\n# a comment\r\n" + "\r\n".join(rows) + "\r\n").encode())
    stats = ImportStats()
    data, lines, header = read_table(path, None, 0, stats)
    assert header == ["t", "ax", "ay", "az"]
    assert (stats.lines, stats.header, stats.comments, stats.malformed) == (202, 1, 1, 3)
    assert stats.first_malformed == "r.csv:53"  # the short row: line 3 + 50
    assert data.shape == (197, 4) and lines[0] == 3 and lines[-1] == 202
    assert 53 not in lines and 123 not in lines and 124 not in lines


def test_non_ascii_files_read_line_by_line_alike(tmp_path):
    rows = "\n".join(f"{i},{i * 2}.5,{-i}e-3" for i in range(50))
    plain, fancy = tmp_path / "plain.csv", tmp_path / "fancy.csv"
    plain.write_text("t,ax,ay\n" + rows + "\n")
    fancy.write_text("\ufefft [s],ax [m/s²],ay\n" + rows + "\n", encoding="utf-8")
    a = read_table(plain, None, 0, ImportStats())
    b = read_table(fancy, None, 0, ImportStats())
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert b[2] == ["t [s]", "ax [m/s²]", "ay"]


@pytest.mark.parametrize("content", ["", "  \n\n \t\n"])
def test_empty_files_are_refused(tmp_path, content):
    path = tmp_path / "e.csv"
    path.write_text(content)
    with pytest.raises(InputError, match="empty file"):
        read_table(path, None, 0, ImportStats())


def test_a_long_run_of_digits_fails_in_one_pass(tmp_path):
    """A field of 20,000 digits that ends in a stray byte (the fuzzer's long line and garbage on
    one line): malformed at once.  The number pattern used to try every split of the digits
    (quadratic: about 10 s here, minutes for 200,000 digits)."""
    import time

    from imucal_cli.formats.importers.text import NUMBER

    field = "9" * 20_000 + "\udcff"
    start = time.process_time()
    assert NUMBER.match(field) is None and NUMBER.match("9" * 20_000 + "x1") is None
    path = tmp_path / "long.csv"
    rows = [f"{i * 0.01:.2f},{i},2,3" for i in range(200)]
    rows[7] = "0.07," + field
    path.write_bytes(("t,ax,ay,az\n" + "\n".join(rows) + "\n").encode("utf-8", "surrogateescape"))
    stats = ImportStats()
    data, _, _ = read_table(path, None, 0, stats)
    assert time.process_time() - start < 1.0
    assert stats.malformed == 1 and data.shape == (199, 4)
    assert NUMBER.match("9" * 20_000) and NUMBER.match("12.5e-3") and not NUMBER.match("1.2.3")


# The array scanner reads a file in pieces (text_scan.SCAN_PIECE bytes, each ending after a line
# break): any piece size must give exactly what one scan of the whole file gives.  Tiny pieces
# cut a file at nearly every line: headers, comments and malformed lines before and after the
# first numeric line, skipped rows, the separator decided by a line in an earlier piece.
PIECES = (1, 16, 37, 64)
WHOLE = 1 << 40


def same_or_none(a, b) -> None:
    assert (a is None) == (b is None)
    if a is not None:
        same_scan(a, b)


def read_result(path, piece, monkeypatch, *args):
    """What read_table gives (data, line numbers, header, every counter) or the error it
    raises, with the given piece size."""
    import dataclasses

    from imucal_cli.formats.importers import text_scan

    monkeypatch.setattr(text_scan, "SCAN_PIECE", piece)
    stats = ImportStats()
    try:
        data, lines, header = read_table(path, *args[:2], stats, *args[2:])
    except InputError as e:
        return "error", str(e), dataclasses.asdict(stats)
    return data.tobytes(), data.shape, lines.tolist(), header, dataclasses.asdict(stats)


@pytest.mark.parametrize("n_files", [60, pytest.param(300, marks=pytest.mark.slow)])
def test_scanning_in_pieces_equals_scanning_whole_on_messy_files(n_files):
    rng = np.random.default_rng(1411)
    served = 0
    for _ in range(n_files):
        raw = messy_text(rng).encode()
        skip_rows = int(rng.integers(0, 3))
        comma = [None, False, True][int(rng.integers(0, 3))]
        skip = frozenset([int(rng.integers(0, 4))]) if rng.random() < 0.3 else frozenset()
        if rng.random() < 0.1:
            raw = b"\xef\xbb\xbf" + raw
        whole = _scan_ascii(raw, skip_rows, comma, skip, piece=WHOLE)
        served += whole is not None
        for piece in PIECES:
            same_or_none(_scan_ascii(raw, skip_rows, comma, skip, piece=piece), whole)
    assert served > n_files // 2


def test_reading_in_pieces_equals_reading_whole_on_the_tests_files(tmp_path, monkeypatch):
    rows = [f"{i * 0.01:.2f},{i},2,3" for i in range(200)]
    rows[50], rows[120], rows[121] = "0.50,1,2", "1.20,1,oops,3", "1.21,1,2,nan"
    rows[7] = "0.07," + "9" * 2_000 + "\udcff"
    values = "\n".join(f"{i},{i * 2}.5,{-i}e-3" for i in range(50)) + "\n"
    files = {
        "crlf.csv": "t,ax,ay,az\r\n# a comment\r\n" + "\r\n".join(rows[8:]) + "\r\n",
        "long.csv": "t,ax,ay,az\n" + "\n".join(rows) + "\n",
        "plain.csv": "t,ax,ay\n" + values,
        "bom.csv": "\ufefft [s],ax [m/s²],ay\n" + values,
        "empty.csv": "",
        "blank.csv": "  \n\n \t\n",
        "mac.csv": "t ax ay\r\r1 2 3\r4 5 6\rx y\r7 8 9",
        "lone_cr.csv": "t ax ay\n1 2 3\n4 5\r6\n",
        "lone_cr_last.csv": "t ax ay\n1 2 3\n4 5 6\r7 8 9",  # the last piece has no LF
        "text.csv": "a,b\nc,d\n\n",
        "late.csv": "\n\n# c\n\nt;x\n" * 5 + "1 2 3 4\n" * 3 + "x y z w\n1 2 3\n" + "5 6 7 8\n",
        "counts.csv": "1 2\n3 4 5\n6 7\n8 9 10 11\n",
    }
    for name, text in files.items():
        path = tmp_path / name
        path.write_bytes(text.encode("utf-8", "surrogateescape"))
        for args in [(None, 0), (None, 2), (4, 0, False), (3, 1, None, frozenset([1]))]:
            whole = read_result(path, WHOLE, monkeypatch, *args)
            for piece in PIECES:
                assert read_result(path, piece, monkeypatch, *args) == whole, (name, args, piece)


@pytest.mark.parametrize("n_files", [40, pytest.param(300, marks=pytest.mark.slow)])
def test_reading_in_pieces_equals_reading_whole_on_fuzzed_recordings(tmp_path, monkeypatch,
                                                                     n_files):
    """Files mutated as the import fuzzer mutates them (bench/reliability.py)."""
    from bench.reliability import _mutate, base_recording

    _, lines = base_recording(tmp_path)
    lines = lines[:60]  # short files: tiny pieces make many scans
    rng = np.random.default_rng(20261127)
    path = tmp_path / "f.csv"
    served = 0
    for n in range(n_files):
        text, _, _ = _mutate(lines, rng)
        path.write_bytes(text.encode("utf-8", "surrogateescape"))
        n_fields, skip_rows, comma, skip = [
            (None, 0, None, frozenset()), (7, 0, None, frozenset()), (None, 1, True, frozenset()),
            (7, 0, None, frozenset([0])),
        ][n % 4]  # fmt: skip
        args = (n_fields, skip_rows, comma, skip)
        whole = read_result(path, WHOLE, monkeypatch, *args)
        raw = path.read_bytes()
        scan_whole = _scan_ascii(raw, skip_rows, comma, skip, piece=WHOLE)
        served += scan_whole is not None
        for piece in PIECES[1:] if n % 3 else PIECES:
            assert read_result(path, piece, monkeypatch, *args) == whole, (n, text[:200], piece)
            same_or_none(_scan_ascii(raw, skip_rows, comma, skip, piece=piece), scan_whole)
    assert served > n_files // 3  # not all read line by line (non-ASCII, a lone CR)


def test_the_number_pattern_takes_plain_decimals_and_fails_long_runs_at_once():
    """A field is a plain decimal (no ``1_000``); a long run of digits ending in a stray byte
    fails in one pass (the older backtracking pattern took seconds on 20,000 digits)."""
    from imucal_cli.formats.importers.text import NUMBER

    assert NUMBER.match("-1.5e3") and NUMBER.match(".5") and not NUMBER.match("1_000")
    assert NUMBER.match("1" * 20000 + "x") is None
