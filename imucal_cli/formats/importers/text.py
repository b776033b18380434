"""Reading numbers from text files: the shared core of the text importers (``csv``,
``imu_tk``) and of ``imucal apply`` on CSV input.

Column specs name the fields of a line (:func:`parse_columns`, or :func:`infer_columns` from a
header line).  Lines starting with ``#`` are comments; non-numeric lines before the first sample
are header lines; any other line that does not give the expected numbers is malformed: skipped
and counted, never fatal unless nothing is left.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.inputs import read_head, read_input
from imucal_cli.numerics.segmented import stacked_rows

from .recording import ImportStats

__all__ = [
    "FIELDS",
    "HEADER_ALIASES",
    "check_time",
    "first_fields",
    "header_columns",
    "infer_columns",
    "parse_columns",
    "parse_numbers",
    "read_table",
    "skipped_fields",
    "is_delimited",
    "split_fields",
    "split_lines",
]

FIELDS = ("t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz", "temp")
"""Field names of a column spec; ``_`` skips a field."""

#: Header names (lower case, without spaces, dashes and brackets) and the field they mean.
HEADER_ALIASES: dict[str, str] = {}
for _field, _names in {
    "t": ("t", "time", "timestamp", "times", "time_s", "t_s", "sec", "seconds"),
    "temp": ("temp", "temperature", "temp_c"),
}.items():
    for _name in _names:
        HEADER_ALIASES[_name] = _field
for _axis in "xyz":
    # EuRoC MAV / TUM-VI imu0/data.csv: w_RS_S_x [rad s^-1], a_RS_S_x [m s^-2]
    HEADER_ALIASES[f"a_rs_s_{_axis}"] = "a" + _axis
    HEADER_ALIASES[f"w_rs_s_{_axis}"] = "g" + _axis
    for _name in ("a{}", "acc_{}", "acc{}", "accel_{}", "accel{}", "acceleration_{}", "acc_{}_raw"):
        HEADER_ALIASES[_name.format(_axis)] = "a" + _axis
    for _name in ("g{}", "gyr_{}", "gyr{}", "gyro_{}", "gyro{}", "gyroscope_{}", "gyr_{}_raw"):
        HEADER_ALIASES[_name.format(_axis)] = "g" + _axis
    for _name in ("m{}", "mag_{}", "mag{}", "magn_{}", "magnetometer_{}", "mag_{}_raw"):
        HEADER_ALIASES[_name.format(_axis)] = "m" + _axis


# --------------------------------------------------------------------------------------------
# Column specs
# --------------------------------------------------------------------------------------------


def parse_columns(text: str) -> list[str | None]:
    """Parse a column spec: comma-separated field names, ``_`` for a skipped field.

    Parameters
    ----------
    text : str
        E.g. ``"t,ax,ay,az,gx,gy,gz"`` or ``"_,ax,ay,az"``; names from :data:`FIELDS`,
        case-insensitive, spaces ignored.

    Returns
    -------
    list of (str or None)
        One entry per field of a line: its name, or None for ``_``.

    Raises
    ------
    InputError
        An unknown or repeated name, an empty field, or an accelerometer, gyroscope or
        magnetometer with some but not all of its three axes.
    """
    names = [part.strip().lower() for part in str(text).split(",")]
    if not names or any(not n for n in names):
        raise InputError(f"--columns {text!r}: empty field name (use _ to skip a field)")
    out: list[str | None] = []
    for n in names:
        if n == "_":
            out.append(None)
            continue
        if n not in FIELDS:
            raise InputError(
                f"--columns {text!r}: unknown field {n!r} (use {', '.join(FIELDS)} or _)"
            )
        if n in out:
            raise InputError(f"--columns {text!r}: field {n!r} appears twice")
        out.append(n)
    for sensor, what in (("a", "accelerometer"), ("g", "gyroscope"), ("m", "magnetometer")):
        have = [f"{sensor}{x}" in out for x in "xyz"]
        if any(have) and not all(have):
            raise InputError(
                f"--columns {text!r}: the {what} needs all three of {sensor}x,{sensor}y,{sensor}z"
            )
    if "ax" not in out and "gx" not in out and "mx" not in out:
        raise InputError(
            f"--columns {text!r}: names no accelerometer (ax,ay,az), gyroscope or magnetometer"
        )
    return out


def infer_columns(header: Sequence[str]) -> list[str | None] | None:
    """Fields from a header line's names, or None when it names no sensor axis.

    Names are matched case-insensitively after dropping units in brackets and turning spaces
    and dashes into ``_`` (``"Acc X [m/s^2]"`` -> ``acc_x``); unknown names become skipped
    fields.  A sensor with fewer than three recognised axes is ignored.
    """
    out: list[str | None] = []
    for raw in header:
        name = re.sub(r"[\[(].*?[\])]", "", raw).strip().strip("\"'").lower()
        name = re.sub(r"[\s\-]+", "_", name)
        f = HEADER_ALIASES.get(name)
        out.append(f if f is not None and f not in out else None)
    for sensor in "agm":
        axes = [f"{sensor}{x}" for x in "xyz"]
        if not all(a in out for a in axes):
            out = [None if f in axes else f for f in out]
    if not any(f in ("ax", "gx", "mx") for f in out):
        return None
    return out


def header_columns(header: Sequence[str] | None, src: str) -> list[str | None]:
    """The fields a header line names (:func:`infer_columns`), or the error saying to pass
    ``--columns``.

    Raises
    ------
    InputError
        No header, or one that names no sensor axis.
    """
    spec = infer_columns(header) if header else None
    if spec is None:
        raise InputError(
            f"{src}: cannot tell which field is which (no header naming the axes): "
            "pass --columns, e.g. --columns t,ax,ay,az,gx,gy,gz"
        )
    return spec


# --------------------------------------------------------------------------------------------
# Reading text
# --------------------------------------------------------------------------------------------


#: A number as a recording writes it: ASCII digits, an optional sign, point and exponent.
#: Python's float() also takes ``1_000.5``, non-ASCII digits (``"١٢"``), ``inf`` and ``nan``:
#: none of those is a sample (issue 11.2, found by the import fuzzer).  The digits after the
#: point are matched only after a point: ``[0-9]+\.?[0-9]*`` splits a run of n digits n ways
#: before it fails on what follows, so a 200,000-digit field ending in a stray byte took
#: minutes (found by the 10,000-file fuzzer); this form fails in one pass.
NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")
#: What may surround a line: ASCII blanks and the line break (a vertical tab, U+2028 or another
#: control character inside a line makes it malformed, never two lines or a cut number).
BLANK = " \t\r\n"
#: What may surround a field inside a line: spaces and tabs.  A carriage return inside a line
#: is no blank: ``-305,-4,\r19`` lost a character where the CR stands (issue 26), never a
#: field of 19.
FIELD_BLANK = " \t"
#: The separators of a delimited line: a comma or a semicolon (as ``capture`` reads them).
DELIMITERS = ",;"
_DELIMITER = re.compile(r"[,;]")
#: Blank-separated fields: a run of spaces, or one tab with spaces around it.  Two tabs with
#: only spaces between are two separators around an empty field (issue 26), so the line is
#: malformed instead of losing a column.
_BLANK_SEPARATOR = re.compile(r" *\t *| +")
_TWO_TABS = re.compile(rb"\t *\t")


def is_delimited(line: str) -> bool:
    """Whether a line's fields are separated by commas or semicolons (else by blanks)."""
    return "," in line or ";" in line


def split_fields(line: str, comma: bool) -> list[str]:
    """The fields of a line: separated by commas or semicolons (``comma``), spaces and tabs
    around them ignored, or else by blanks (:data:`_BLANK_SEPARATOR`).  An empty field (two
    separators in a row) is kept as ``""``, so that the line is malformed, never one of its
    numbers taken for the next column's."""
    if comma:
        return [p.strip(FIELD_BLANK) for p in _DELIMITER.split(line)]
    return _BLANK_SEPARATOR.split(line.strip(FIELD_BLANK))


def split_lines(text: str) -> list[str]:
    """Lines split at ``\n`` (``\r\n`` too; at ``\r`` only in a file without ``\n``, as a
    classic Mac file).  ``str.splitlines`` would also split at a vertical tab, a form feed,
    U+0085, U+2028 and U+2029, and a lone ``\r``, and keep the halves of a cut number as two
    lines."""
    lines = text.split("\n" if "\n" in text or "\r" not in text else "\r")
    if lines and lines[-1] == "":
        lines.pop()
    return [line[:-1] if line.endswith("\r") else line for line in lines]


def skipped_fields(spec) -> frozenset[int]:
    """Positions of the ``_`` (skipped) fields of a column spec (None: no spec yet)."""
    if spec is None:
        return frozenset()
    return frozenset(j for j, name in enumerate(spec) if name is None)


def parse_numbers(parts: list[str], skip: frozenset[int] = frozenset()) -> list[float] | None:
    """The fields of a line as numbers, or None when one is not a finite number. Fields at
    the positions in ``skip`` (``_`` in a column spec) may hold anything; they read as 0."""
    values = []
    for j, part in enumerate(parts):
        if j in skip:
            values.append(0.0)
        elif NUMBER.match(part):
            values.append(float(part))
        else:
            return None
    if not all(np.isfinite(values)):  # 1e999
        return None
    return values


#: A recording read whole is bounded by this (a day at 1 kHz as CSV is about 7 GB).
MAX_RECORDING_BYTES = 16 << 30


def _read_bytes(path: Path) -> bytes:
    """The bytes of a recording: a regular file (a FIFO would block), bounded in size."""
    return read_input(path, what="recording", max_bytes=MAX_RECORDING_BYTES)


def first_fields(path: Path, skip_rows: int = 0) -> list[str] | None:
    """The fields of the first line after ``skip_rows`` that is not blank or a comment (None:
    no such line in the first 64 KiB, or the file cannot be read: the reader will say why)."""
    try:
        head = read_head(path, 65536, what="recording")
    except InputError:
        return None
    lines = split_lines(head.decode("utf-8", errors="replace").lstrip("\ufeff"))
    for line in lines[skip_rows:-1] if len(head) == 65536 else lines[skip_rows:]:
        line = line.strip(BLANK)
        if line and not line.startswith("#"):
            return split_fields(line, is_delimited(line))
    return None


def read_lines(path: Path, raw: bytes | None = None) -> list[str]:
    """The lines of a text file (UTF-8, undecodable bytes replaced).

    Raises
    ------
    InputError
        Missing, unreadable or empty file, or a directory.
    """
    text = (_read_bytes(path) if raw is None else raw).decode("utf-8", errors="replace")
    if not text.strip():
        raise InputError(f"{path}: empty file")
    return split_lines(text)


def read_table(
    path: Path,
    n_fields: int | None,
    skip_rows: int,
    stats: ImportStats,
    comma: bool | None = None,
    skip: frozenset[int] = frozenset(),
) -> tuple[np.ndarray, np.ndarray, list[str] | None]:
    """Numeric rows of a text file.

    Lines before ``skip_rows`` and non-numeric lines before the first numeric one are header
    lines; blank and ``#`` lines are counted; any later line that does not give ``n_fields``
    finite numbers (fields in ``skip`` may hold anything and read as 0) is malformed: counted,
    the first one's ``file:line`` kept, and skipped.  ``comma`` None: fields are separated by
    commas when the first line read has one, else by white space.

    The file is scanned with array operations, in pieces (:func:`_scan_ascii`); files that are
    not plain ASCII, or hold a token that is not a number where a number is due, are read line
    by line (:func:`_scan_lines`), with the same result.

    Returns
    -------
    data : ndarray, shape (K, n_fields)
    lines : ndarray of int, shape (K,)
        1-based line number of each row.
    header : list of str or None
        The fields of the last header line.

    Raises
    ------
    InputError
        Missing, unreadable or empty file, no numeric rows, no row with ``n_fields`` fields.
        ``n_fields`` None: the most common field count of the numeric rows.
    """
    raw = _read_bytes(path)
    scan = _scan_ascii(raw, skip_rows, comma, skip)
    if scan is None:
        scan = _scan_lines(read_lines(path, raw), skip_rows, comma, skip)
    stats.lines += scan.n_lines
    stats.header += scan.header
    stats.blank += scan.blank
    stats.comments += scan.comments
    if not len(scan.numbers):
        raise InputError(f"{path}: no numeric rows (only header or text lines)")
    lengths = scan.lengths
    if n_fields is None:
        n_fields = int(np.argmax(np.bincount(lengths)))
    keep = lengths == n_fields
    if not keep.any():
        found = ", ".join(str(v) for v in np.unique(lengths)[:5].tolist())
        raise InputError(
            f"{path}: no row has the {n_fields} fields the columns name (rows have {found}); "
            "fix --columns"
        )
    bad = np.concatenate([scan.bad, scan.numbers[~keep]])
    if len(bad):
        stats.malformed += len(bad)
        if stats.first_malformed is None:
            stats.first_malformed = f"{path.name}:{int(bad.min())}"
    return scan.rows(keep, n_fields), scan.numbers[keep], scan.header_fields


@dataclass
class _Scan:
    """What one pass over a text file found (both scanners fill it alike).

    ``numbers`` (1-based line numbers) and ``lengths`` (field counts) of the numeric rows;
    ``bad``: line numbers of non-numeric lines after the first numeric one; ``rows(keep, n)``:
    the kept numeric rows as an array (K, n)."""

    n_lines: int
    header: int
    blank: int
    comments: int
    header_fields: list[str] | None
    numbers: np.ndarray
    lengths: np.ndarray
    bad: np.ndarray
    rows: Callable[[np.ndarray, int], np.ndarray]


def _scan_lines(
    lines: list[str], skip_rows: int, comma: bool | None, skip: frozenset[int]
) -> _Scan:
    """Line by line: the reference reader, for any text."""
    header = blank = comments = 0
    header_fields: list[str] | None = None
    rows: list[list[float]] = []
    numbers: list[int] = []
    bad: list[int] = []
    seen_data = False
    for i, raw in enumerate(lines):
        line = raw.lstrip("\ufeff").strip(BLANK)
        if i < skip_rows:
            header += 1
            continue
        if not line:
            blank += 1
            continue
        if line.startswith("#"):
            comments += 1
            continue
        if comma is None:
            comma = is_delimited(line)
        parts = split_fields(line, comma)
        values = parse_numbers(parts, skip)
        if values is None:
            if not seen_data:
                header += 1
                header_fields = parts
            else:
                bad.append(i + 1)
            continue
        seen_data = True
        rows.append(values)
        numbers.append(i + 1)

    def take(keep: np.ndarray, n: int) -> np.ndarray:
        out = np.array([r for r, k in zip(rows, keep, strict=True) if k], dtype=np.float64)
        return out.reshape(-1, n)

    return _Scan(
        n_lines=len(lines),
        header=header,
        blank=blank,
        comments=comments,
        header_fields=header_fields,
        numbers=np.asarray(numbers, dtype=np.int64),
        lengths=np.asarray([len(r) for r in rows], dtype=np.int64),
        bad=np.asarray(bad, dtype=np.int64),
        rows=take,
    )


# Byte classes of the array scanner; white space and line breaks first (content is > _CR).
_SPACE, _LF, _CR, _OTHER, _COMMA, _HASH, _DIGIT, _INVALID = range(8)
_CLASS = np.full(256, _INVALID, dtype=np.uint8)
_CLASS[32:127] = _OTHER
_CLASS[[ord(" "), ord("\t")]] = _SPACE
_CLASS[ord("\n")] = _LF
_CLASS[ord("\r")] = _CR
_CLASS[[ord(","), ord(";")]] = _COMMA  # a semicolon delimits as a comma does (as capture)
_CLASS[np.frombuffer(b"0123456789+-.eE", np.uint8)] = _DIGIT
_CLASS[ord("#")] = _HASH
_BOM = b"\xef\xbb\xbf"
_CLASS_TABLE = _CLASS.tobytes()  # the same classes as a bytes.translate table


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start indices and one-past-end indices of the runs of True in ``mask``."""
    edge = np.flatnonzero(mask[1:] != mask[:-1]) + 1
    if mask[0]:
        edge = np.r_[0, edge]
    if mask[-1]:
        edge = np.r_[edge, len(mask)]
    return edge[0::2], edge[1::2]


@dataclass
class _Lines:
    """The lines of a file scanned as bytes: ``breaks`` (offsets of the line breaks), each
    line's ``start`` and ``end`` offsets (end exclusive, without its break), their count."""

    breaks: np.ndarray
    start: np.ndarray
    end: np.ndarray
    n: int


@dataclass
class _Tokens:
    """The tokens of a file (runs of content: white space separated, or but commas): their
    ``start``/``end`` offsets, ``line``, ``field`` (index on its line) and each line's field
    count ``length``."""

    start: np.ndarray
    end: np.ndarray
    line: np.ndarray
    field: np.ndarray
    length: np.ndarray


#: Bytes of a file scanned at once by :func:`_scan_ascii` (each piece then cut just after a line
#: break): bounds the scanner's per-byte and per-token temporaries, several times the piece,
#: whatever the file's size (issue 14.1: 26 MiB of them for a 3.3 MB file scanned whole).
SCAN_PIECE = 512 << 10


def _scan_ascii(
    raw: bytes, skip_rows: int, comma: bool | None, skip: frozenset[int], piece: int | None = None
) -> _Scan | None:
    """The whole file with array operations (no Python loop per line), in pieces.

    Same result as :func:`_scan_lines`; None (use that) when the file is not plain ASCII
    (other line breaks, undecodable bytes) or a token where a number is due is not a number
    NumPy's parser reads alike (then the line-by-line reader decides).

    Pieces of about ``piece`` bytes (None: :data:`SCAN_PIECE`), each ending just after a line
    break, are scanned in turn (:func:`_scan_piece`) and joined: the result is the one a scan
    of the whole file at once gives, for any piece size.
    """
    if raw.startswith(_BOM):
        raw = raw[len(_BOM) :]
    if len(raw) == 0:
        return None
    has_lf = b"\n" in raw
    brk = b"\n" if has_lf else b"\r"  # a file without LF breaks at CR (classic Mac)
    size = max(1, SCAN_PIECE if piece is None else piece)
    pieces: list[_Piece] = []
    at = line0 = 0
    seen = False  # a numeric line in an earlier piece
    while at < len(raw):
        cut = raw.find(brk, at + size - 1)
        stop = len(raw) if cut < 0 else cut + 1
        text = raw if (at, stop) == (0, len(raw)) else raw[at:stop]
        part = _scan_piece(text, line0, skip_rows, comma, skip, seen, has_lf)
        if part is None:
            return None
        pieces.append(part)
        comma = part.comma
        seen = seen or len(part.scan.numbers) > 0
        line0 += part.scan.n_lines
        at = stop
    if not any(p.content for p in pieces):
        return None
    return _join_pieces([p.scan for p in pieces])


@dataclass
class _Piece:
    """A piece of a file scanned: its ``scan`` (line numbers those of the whole file), the
    ``comma`` separator decided so far (None: no candidate line yet), and whether the piece
    holds any ``content`` (anything but white space and line breaks)."""

    scan: _Scan
    comma: bool | None
    content: bool


def _join_pieces(scans: list[_Scan]) -> _Scan:
    """The scans of consecutive pieces of a file as one scan of the whole file."""
    if len(scans) == 1:
        return scans[0]
    counts = np.cumsum([0] + [len(s.numbers) for s in scans])
    fields = [s.header_fields for s in scans if s.header_fields is not None]

    def take(keep: np.ndarray, n_fields: int) -> np.ndarray:
        out = np.zeros((np.count_nonzero(keep), n_fields))
        row = 0
        for s, a, b in zip(scans, counts[:-1], counts[1:], strict=True):
            k = int(np.count_nonzero(keep[a:b]))
            if k:
                out[row : row + k] = s.rows(keep[a:b], n_fields)
                row += k
        return out

    return _Scan(
        n_lines=sum(s.n_lines for s in scans),
        header=sum(s.header for s in scans),
        blank=sum(s.blank for s in scans),
        comments=sum(s.comments for s in scans),
        header_fields=fields[-1] if fields else None,
        numbers=np.concatenate([s.numbers for s in scans]),
        lengths=np.concatenate([s.lengths for s in scans]),
        bad=np.concatenate([s.bad for s in scans]),
        rows=take,
    )


def _scan_piece(
    raw: bytes, line0: int, skip_rows: int, comma: bool | None, skip: frozenset[int],
    seen: bool, has_lf: bool,
) -> _Piece | None:  # fmt: skip
    """One piece of a file (whole lines, ``line0`` lines before it), as :func:`_scan_ascii`.

    ``seen``: an earlier piece has a numeric line (every non-numeric candidate line is then
    malformed, none a header line); ``has_lf``: the file has an LF (a lone CR is then no line
    break: None).  None when the piece is not plain ASCII or NumPy's parser does not read its
    numbers alike."""
    b = np.frombuffer(raw, dtype=np.uint8)
    cls = np.frombuffer(raw.translate(_CLASS_TABLE), dtype=np.uint8)  # not np.take: 8 B a byte
    if cls.max() == _INVALID:
        return None
    lines = _lines_of(b, cls, has_lf)
    if lines is None:
        return None
    # Runs of content (white space separated); the first of a line says what the line is.
    content = cls > _CR
    rs, re_ = _runs(content)
    r_line = np.searchsorted(lines.breaks, rs)
    first = np.diff(r_line, prepend=-1) != 0
    kind = np.zeros(lines.n, dtype=np.int8)  # 0 blank, 1 comment, 2 candidate
    kind[r_line[first]] = np.where(cls[rs[first]] == _HASH, 1, 2)
    after = np.arange(line0, line0 + lines.n) >= skip_rows
    candidate = (kind == 2) & after
    cand_lines = np.flatnonzero(candidate)
    if comma is None and len(cand_lines):
        j = cand_lines[0]
        comma = bool(np.any(cls[lines.start[j] : lines.end[j]] == _COMMA))
    tokens = _tokens(cls, content, lines, (rs, re_, r_line), comma)
    ok, keep_tok = _numeric_lines(cls, content, tokens, candidate, comma, skip)
    if not comma and b"\t" in raw:  # two tabs around an empty field: the line is malformed
        empty = [m.start() for m in _TWO_TABS.finditer(raw)]
        if empty:
            ok[np.searchsorted(lines.breaks, empty)] = False
            keep_tok &= ok[tokens.line]
    values = _parse_values(raw, tokens, keep_tok, comma)
    if values is None:
        return None
    v_line, v_field = tokens.line[keep_tok], tokens.field[keep_tok]
    ok[v_line[~np.isfinite(values)]] = False
    numeric = np.flatnonzero(ok)
    first_data = -1 if seen else numeric[0] if len(numeric) else lines.n
    head = cand_lines[cand_lines < first_data]
    later = cand_lines[cand_lines > first_data]
    header_fields = None
    if len(head):
        j = head[-1]
        header_fields = split_fields(raw[lines.start[j] : lines.end[j]].decode().strip(), comma)
    v_keep = ok[v_line]
    scan = _Scan(
        n_lines=lines.n,
        header=min(max(skip_rows - line0, 0), lines.n) + len(head),
        blank=int(np.count_nonzero((kind == 0) & after)),
        comments=int(np.count_nonzero((kind == 1) & after)),
        header_fields=header_fields,
        numbers=numeric + (line0 + 1),
        lengths=tokens.length[numeric].astype(np.int64),
        bad=later[~ok[later]] + (line0 + 1),
        rows=_rows_taker(lines.n, numeric, v_line[v_keep], v_field[v_keep], values[v_keep]),
    )
    return _Piece(scan, comma, len(rs) > 0)


def _lines_of(b: np.ndarray, cls: np.ndarray, has_lf: bool) -> _Lines | None:
    """Line breaks as :func:`split_lines` makes them: LF, CR LF (the CR is then white space),
    and a lone CR only in a file without LF (classic Mac; ``has_lf``: the file, of which ``b``
    may be a piece, has an LF).  None when a lone CR stands among LF lines: it could cut a
    number in two (the line-by-line reader makes that line malformed)."""
    n = len(b)
    breaks = np.flatnonzero(cls == _LF)
    cr = np.flatnonzero(cls == _CR)
    if len(cr):
        lone = cr[(cr + 1 == n) | (b[np.minimum(cr + 1, n - 1)] != ord("\n"))]
        if len(lone) and has_lf:
            return None
        breaks = np.union1d(breaks, lone)
    n_lines = len(breaks) + int(len(breaks) == 0 or breaks[-1] != n - 1)
    return _Lines(breaks, np.r_[0, breaks + 1][:n_lines], np.r_[breaks, n][:n_lines], n_lines)


def _tokens(cls: np.ndarray, content: np.ndarray, lines: _Lines, runs, comma: bool) -> _Tokens:
    """The tokens: the runs of content themselves (``runs``: their starts, ends and lines),
    or, with ``comma``, runs of content but commas, each field counted between commas."""
    if comma:
        is_comma = cls == _COMMA
        ts, te = _runs(content & ~is_comma)
        t_line = np.searchsorted(lines.breaks, ts)
        commas = np.flatnonzero(is_comma)
        before = np.searchsorted(commas, lines.start)
        length = np.searchsorted(commas, lines.end) - before + 1
        field = np.searchsorted(commas, ts) - before[t_line]
    else:
        ts, te, t_line = runs
        length = np.bincount(t_line, minlength=lines.n)
        field = np.arange(len(ts)) - np.searchsorted(t_line, t_line)
    return _Tokens(ts, te, t_line, field, length)


def _numeric_lines(
    cls: np.ndarray, content: np.ndarray, tokens: _Tokens, candidate: np.ndarray, comma: bool,
    skip: frozenset[int],
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Which candidate lines are numeric (each field but the skipped ones one number token:
    no character that cannot be in a number, with commas no field empty or split), and which
    tokens hold their numbers."""
    t_line, field = tokens.line, tokens.field
    used = candidate[t_line]  # tokens that must be numbers: not in a skipped field
    if skip:
        used &= ~np.isin(field, list(skip))
    ok = candidate.copy()
    odd = content & (cls != _DIGIT)
    odd = np.flatnonzero(odd & (cls != _COMMA) if comma else odd)
    del content, cls  # the per-byte arrays are done with: less held at the peak below
    if len(odd):
        odd_token = np.searchsorted(tokens.start, odd, side="right") - 1
        ok[t_line[odd_token[used[odd_token]]]] = False
        del odd_token
    del odd
    if comma:
        u_line, u_field = t_line[used], field[used]
        repeated = (u_line[1:] == u_line[:-1]) & (u_field[1:] == u_field[:-1])
        ok[u_line[1:][repeated]] = False
        need = tokens.length - np.searchsorted(np.array(sorted(skip), dtype=np.int64),
                                               tokens.length)  # fmt: skip
        ok &= np.bincount(u_line, minlength=len(candidate)) == need
    return ok, used & ok[t_line]


def _parse_values(raw: bytes, tokens: _Tokens, keep: np.ndarray, comma: bool) -> np.ndarray | None:
    """The numbers of the ``keep`` tokens, in file order: every other token (header, comment
    and malformed lines, skipped fields) blanked and the text parsed once; None when NumPy's
    parser does not read one number per kept token."""
    if not keep.any():
        return np.zeros(0)
    text = raw.replace(b",", b" ").replace(b";", b" ") if comma else raw
    drop = np.flatnonzero(~keep)
    if len(drop):
        blanked = np.frombuffer(text, dtype=np.uint8).copy()
        blanked[stacked_rows(tokens.start[drop], tokens.end[drop])[0]] = ord(" ")
        text = blanked.tobytes()
    try:
        values = np.fromstring(text, sep=" ")  # text mode: not deprecated
    except ValueError:
        return None
    if len(values) != np.count_nonzero(keep):
        return None
    return values


def _rows_taker(
    n_lines: int, numeric: np.ndarray, v_line: np.ndarray, v_field: np.ndarray, values: np.ndarray
) -> Callable[[np.ndarray, int], np.ndarray]:
    """``take(keep, n_fields)``: the kept numeric lines' values as an array (K, n_fields)."""

    def take(keep: np.ndarray, n_fields: int) -> np.ndarray:
        row_of_line = np.full(n_lines, -1, dtype=np.int64)
        kept = numeric[keep]
        row_of_line[kept] = np.arange(len(kept))
        row = row_of_line[v_line]
        sel = row >= 0
        out = np.zeros((len(kept), n_fields))
        out[row[sel], v_field[sel]] = values[sel]
        return out

    return take


def check_time(time: np.ndarray, lines: np.ndarray, src: str) -> None:
    dt = np.diff(time)
    bad = np.flatnonzero(~(dt > 0))
    if len(bad):
        j = int(bad[0])
        raise InputError(
            f"{src}: time does not increase at line {int(lines[j + 1])} ({time[j + 1]:.9g} s "
            f"after {time[j]:.9g} s at line {int(lines[j])}); {len(bad)} such step(s)"
        )
