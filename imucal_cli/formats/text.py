"""Strings from files made safe for a terminal and for an export (issue 11.5).

A session's ``sensor`` or a segment's ``label`` is whatever the file says: an ANSI escape
(``\\x1b[2J``) would clear the user's terminal or forge output, a bidirectional override
(U+202E) would show text reversed, a newline would split a one-line message or a YAML key.
:func:`clean_text` writes every such character as a visible escape (``\\x1b``, ``\\u202e``),
so nothing is lost from view and nothing is interpreted.  The readers of sessions and
calibrations apply it to every string they return; exporters and messages may rely on it.
"""

from __future__ import annotations

import re
from typing import Any

__all__ = ["clean_text", "clean_tree", "has_control", "is_clean"]

# C0 controls but tab, DEL and C1 controls, zero-width and bidirectional formatting, line and
# paragraph separators, lone surrogates (bytes that were not UTF-8), the byte-order mark and
# interlinear annotations.
_UNSAFE = re.compile(
    "[\x00-\x08\x0a-\x1f\x7f-\x9f\u00ad\u061c\u180e\u200b-\u200f\u2028-\u202e"
    "\u2060-\u206f\ud800-\udfff\ufeff\ufff9-\ufffb]"
)


def _escape(match: re.Match[str]) -> str:
    code = ord(match.group())
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def clean_text(text: str) -> str:
    """``text`` with control and invisible formatting characters written as escapes, and tabs
    as spaces: one printable line."""
    return _UNSAFE.sub(_escape, text).replace("\t", " ")


def is_clean(text: str) -> bool:
    """Whether :func:`clean_text` would leave ``text`` as it is."""
    return _UNSAFE.search(text) is None and "\t" not in text


def has_control(text: str) -> bool:
    """Whether ``text`` holds a character :func:`clean_text` would escape (tabs and newlines
    are fine: a file's layout)."""
    return _UNSAFE.search(text.replace("\n", " ")) is not None


def clean_tree(value: Any) -> Any:
    """:func:`clean_text` applied to every string (keys too) of a parsed JSON value."""
    if isinstance(value, str):
        return clean_text(value)
    if isinstance(value, dict):
        return {clean_tree(k): clean_tree(v) for k, v in value.items()}
    if isinstance(value, list):
        return [clean_tree(v) for v in value]
    return value
