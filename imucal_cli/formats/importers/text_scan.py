"""Text into numbers, for :mod:`.text`: a line split into fields (:func:`split_fields`), the
fields into numbers (:func:`parse_numbers`, :data:`NUMBER`), and a whole file scanned into its
numeric rows (:class:`Scan`), with array operations in pieces (:func:`scan_ascii`) or line by
line, the reference (:func:`scan_lines`).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imucal_cli.numerics.segmented import stacked_rows

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


def cut_line_start(raw) -> int | None:
    """Where the last line of a text recording starts when it was cut short, else None.

    A writer stopped mid-line (the logger killed, power lost, a full disk) leaves a last line
    without its line break, and the number it stops in still reads as a number (``-9.8`` of
    ``-9.81234``): nothing in the line itself can tell.  The rule is the file's own: where the
    lines before it end with a line break (``\\n``, or ``\\r`` in a file without ``\\n``), a
    last line without one is cut short, and dropped by every text reader (the importers'
    :func:`~.text.read_table` and :func:`~.serial_lines.read_serial_lines`, the DataFlash text
    log's, ``imucal apply``'s CSV input), with a warning naming it (:func:`cut_line_warning`).
    Kept whole: a file of one line (no line before it to say how lines end), a last line of
    blanks or a ``#`` comment (nothing of it is read), and one ending with ``\\r`` (a CR LF
    cut between the two: the line itself is whole).

    Parameters
    ----------
    raw : bytes or mmap.mmap
        The file's bytes (anything with ``rfind`` and slicing).

    Returns
    -------
    int or None
        The byte offset of the cut line (the file's complete lines are ``raw[:offset]``).
    """
    brk = raw.rfind(b"\n")
    if brk < 0:
        brk = raw.rfind(b"\r")  # classic Mac: lines end with CR alone
    if brk < 0:
        return None
    tail = raw[brk + 1 :]
    text = tail.strip(BLANK.encode())
    if not text or text.startswith(b"#") or tail.endswith(b"\r"):
        return None
    return brk + 1


def cut_line_number(raw, start: int) -> int:
    """The 1-based number of the line that starts at ``start`` (just after a line break)."""
    head = raw[:start]
    return (head.count(b"\n") or head.count(b"\r")) + 1


def cut_line_warning(where: str) -> str:
    """The one-line warning for a last line cut short (:func:`cut_line_start`) at ``where``
    (``file:line``)."""
    return (f"{where}: the last line has no line break (the writer stopped mid-line): dropped, "
            "its numbers may be cut short")  # fmt: skip


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


@dataclass
class Scan:
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


def scan_lines(
    lines: list[str], skip_rows: int, comma: bool | None, skip: frozenset[int]
) -> Scan:
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

    return Scan(
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


#: Bytes of a file scanned at once by :func:`scan_ascii` (each piece then cut just after a line
#: break): bounds the scanner's per-byte and per-token temporaries, several times the piece,
#: whatever the file's size (issue 14.1: 26 MiB of them for a 3.3 MB file scanned whole).
SCAN_PIECE = 512 << 10


def scan_ascii(
    raw: bytes, skip_rows: int, comma: bool | None, skip: frozenset[int], piece: int | None = None
) -> Scan | None:
    """The whole file with array operations (no Python loop per line), in pieces.

    Same result as :func:`scan_lines`; None (use that) when the file is not plain ASCII
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

    scan: Scan
    comma: bool | None
    content: bool


def _join_pieces(scans: list[Scan]) -> Scan:
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

    return Scan(
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
    """One piece of a file (whole lines, ``line0`` lines before it), as :func:`scan_ascii`.

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
    scan = Scan(
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
