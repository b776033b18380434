"""JSON objects to typed records and back: the one mapping between the calibration model's
dataclasses and the calibration JSON (``shared/spec/session-format.md``).

A :class:`Record` is a dataclass whose fields are the members of a JSON object, named as the
JSON names them (``rms_loo``, ``n_distinct``; :func:`item` gives another key where the name
cannot be the key). The field's annotation says what it holds: ``float``, ``int``, ``bool``,
``str``, ``list[...]``, ``dict[str, ...]``, ``numpy.ndarray`` (a numeric JSON array), another
record, a ``StrEnum``, ``Any`` (a JSON value kept as it is), or unions of these with None.
:func:`item(flat=True) <item>` merges a record's members into its parent's object (the
fit statistics are members of the section, not an object of their own).

Reading (:func:`decode`) is forgiving: a member this version does not know, or one whose value
does not fit its annotation, is kept in the record's :attr:`Record.unknown` and written back
unchanged (the spec: readers ignore fields they do not know); its field stays None. Presence
is kept too: a member written as ``null`` is None in the record and listed in
:attr:`Record.nulls`, so that it is written as ``null`` again; a producer lists the members it
writes as ``null`` there (:func:`nulls`), or an :func:`item(always=True) <item>` member is
written whether it has a value or not (the columns of a table). Writing (:func:`encode`)
gives the members in the order of the fields, then the unknown ones; NaN and infinity
become ``null`` as the calibration JSON writes them (:func:`jsonable`).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from enum import Enum
from functools import cache
from typing import Any, Union

import numpy as np

__all__ = ["Mismatch", "Record", "build", "decode", "encode", "item", "jsonable", "nulls"]


class Mismatch(ValueError):
    """A JSON value that does not fit a field's annotation."""


@dataclasses.dataclass
class Record:
    """Base of every record of the calibration model.

    Attributes
    ----------
    unknown : dict
        Members of the JSON object this version does not model, or whose value did not fit:
        written back unchanged after the known ones.
    nulls : set of str
        Keys written as ``null`` when their field is None (a value the solver could not
        determine: "present, not known"); without it a None field is left out.
    """

    unknown: dict = dataclasses.field(default_factory=dict, kw_only=True, repr=False)
    nulls: set = dataclasses.field(default_factory=set, kw_only=True, repr=False)


def item(default: Any = None, *, key: str | None = None, flat: bool = False,
         always: bool = False, factory: Any = None, own: bool = False,
         transient: bool = False) -> Any:  # fmt: skip
    """A record field: its JSON ``key`` (default: the field's name); ``flat``: a record whose
    members are its parent's; ``always``: written as ``null`` when None; ``own``: read and
    written by the record's own methods, not here (the sections of a calibration, whose class
    depends on their solver); ``transient``: no member of the JSON at all, neither read nor
    written (what a later step of the same run uses: a section's covariance given its poses'
    placement, for a set's rotations)."""
    meta = {"key": key, "flat": flat, "always": always, "own": own, "transient": transient}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def build(cls: type, **members: Any) -> Any:
    """A record of ``cls`` from its members as its JSON object names them: each goes to its
    field, or to the flat record that holds it (``iterations`` to the section's
    :class:`~.parts.FitStatistics`); a member given as None is written as ``null`` (present,
    not determined), one not given is left out. Values are the fields' types (records, not
    dicts).

    Raises
    ------
    TypeError
        A member ``cls`` does not have.
    """
    direct, flat = {}, {}
    by_key = {f.key: f for f in _fields(cls)}
    owners = {key: f for f in _fields(cls) if f.flat for key in _keys(_record_type(f.kind))}
    own = {f.name for f in dataclasses.fields(cls)
           if f.metadata.get("own") or f.metadata.get("transient")}  # fmt: skip
    null = set()
    for key, value in members.items():
        if key in by_key and not by_key[key].flat:
            direct[by_key[key].name] = value
            if value is None:
                null.add(key)
        elif key in owners:
            flat.setdefault(owners[key].name, {})[key] = value
        elif key in own:
            direct[key] = value
        else:
            raise TypeError(f"{cls.__name__} has no member {key!r}")
    for f in _fields(cls):
        if f.flat and f.name in flat:
            direct[f.name] = build(_record_type(f.kind), **flat[f.name])
    record = cls(**direct)
    record.nulls.update(null)
    return record


def nulls(record: Record, *keys: str) -> Record:
    """``record`` with ``keys`` written as ``null`` while their fields are None; returned."""
    record.nulls.update(keys)
    return record


@dataclasses.dataclass(frozen=True)
class _Field:
    name: str
    key: str
    kind: Any
    flat: bool
    always: bool


@cache
def _fields(cls: type) -> tuple[_Field, ...]:
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if f.name in ("unknown", "nulls") or f.metadata.get("own") or f.metadata.get("transient"):
            continue
        meta = f.metadata
        out.append(_Field(f.name, meta.get("key") or f.name, hints[f.name],
                          bool(meta.get("flat")), bool(meta.get("always"))))  # fmt: skip
    return tuple(out)


@cache
def _keys(cls: type) -> frozenset[str]:
    """Every JSON key a record of ``cls`` reads (its flat members' and its own ones too)."""
    keys = {f.metadata.get("key") or f.name for f in dataclasses.fields(cls)
            if f.metadata.get("own")}  # fmt: skip
    for f in _fields(cls):
        keys |= _keys(_record_type(f.kind)) if f.flat else {f.key}
    return frozenset(keys)


def _record_type(kind: Any) -> type:
    """The record class of a (possibly optional) record annotation."""
    for k in _alternatives(kind):
        if isinstance(k, type) and dataclasses.is_dataclass(k):
            return k
    raise TypeError(f"not a record annotation: {kind!r}")


def _alternatives(kind: Any) -> tuple:
    if typing.get_origin(kind) in (Union, types.UnionType):
        return typing.get_args(kind)
    return (kind,)


# ------------------------------------------------------------------------------------ encode


def jsonable(value: Any) -> Any:
    """JSON types of numpy arrays and scalars, tuples, enums and records; NaN and infinity
    become None (``null``)."""
    if isinstance(value, Record):
        return encode(value)
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [jsonable(v) for v in value]
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def encode(record: Record) -> dict:
    """The JSON object of a record (module notes)."""
    out: dict = {}
    _encode_into(record, out)
    for key, value in record.unknown.items():
        if key not in out:
            out[key] = jsonable(value)
    return out


def _encode_into(record: Record, out: dict) -> None:
    for f in _fields(type(record)):
        value = getattr(record, f.name)
        if f.flat:
            if value is not None:
                _encode_into(value, out)
                for key, raw in value.unknown.items():
                    out.setdefault(key, jsonable(raw))
            continue
        if value is None:
            if f.always or f.key in record.nulls:
                out[f.key] = None
            continue
        out[f.key] = jsonable(value)


# ------------------------------------------------------------------------------------ decode


def decode(cls: type, obj: Any) -> Any:
    """The record of class ``cls`` a JSON object describes (module notes).

    Raises
    ------
    Mismatch
        ``obj`` is not a JSON object.
    """
    if not isinstance(obj, dict):
        raise Mismatch(f"expected an object, got {type(obj).__name__}")
    record = _decode_fields(cls, obj)
    known = _keys(cls)
    record.unknown.update({k: v for k, v in obj.items() if k not in known})
    return record


def _decode_fields(cls: type, obj: dict) -> Any:
    values: dict = {}
    unknown: dict = {}
    null: set = set()
    for f in _fields(cls):
        if f.flat:
            sub = _record_type(f.kind)
            if any(k in obj for k in _keys(sub)):
                values[f.name] = _decode_fields(sub, obj)
            continue
        if f.key not in obj:
            continue
        raw = obj[f.key]
        if raw is None:
            null.add(f.key)
            continue
        try:
            values[f.name] = _value(f.kind, raw)
        except Mismatch:
            unknown[f.key] = raw
    record = cls(**values)
    record.unknown.update(unknown)
    record.nulls.update(null)
    return record


def _value(kind: Any, raw: Any) -> Any:
    """``raw`` (not None) as ``kind`` describes it, or :class:`Mismatch`."""
    alternatives = [k for k in _alternatives(kind) if k is not type(None)]
    if len(alternatives) > 1:
        for k in alternatives:
            try:
                return _value(k, raw)
            except Mismatch:
                continue
        raise Mismatch(f"{raw!r} is none of {alternatives}")
    kind = alternatives[0]
    if kind is Any:
        return raw
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin is list:
        if not isinstance(raw, list):
            raise Mismatch(f"expected a list, got {type(raw).__name__}")
        return [None if v is None else _value(args[0], v) for v in raw]
    if origin is dict:
        if not isinstance(raw, dict):
            raise Mismatch(f"expected an object, got {type(raw).__name__}")
        return {k: None if v is None else _value(args[1], v) for k, v in raw.items()}
    if origin is tuple:
        if not isinstance(raw, list):
            raise Mismatch(f"expected a list, got {type(raw).__name__}")
        return tuple(raw)
    if kind is np.ndarray:
        return _array(raw)
    if isinstance(kind, type) and dataclasses.is_dataclass(kind):
        return decode(kind, raw)
    if isinstance(kind, type) and issubclass(kind, Enum):
        try:
            return kind(raw)
        except ValueError:
            raise Mismatch(f"{raw!r} is not a {kind.__name__}") from None
    return _scalar(kind, raw)


def _scalar(kind: type, raw: Any) -> Any:
    if kind is bool:
        if isinstance(raw, bool):
            return raw
    elif kind is float:  # an integer stays as written (a float field may hold 48 or 48.0)
        if isinstance(raw, int | float) and not isinstance(raw, bool):
            return raw
    elif kind is int:
        if isinstance(raw, int) and not isinstance(raw, bool):
            return raw
    elif kind is str:
        if isinstance(raw, str):
            return raw
    else:
        raise TypeError(f"unsupported annotation {kind!r}")
    raise Mismatch(f"{raw!r} is not a {kind.__name__}")


def _array(raw: Any) -> np.ndarray:
    """A numeric JSON array (nested lists of numbers; null is NaN) as a float array."""

    def numeric(v) -> bool:
        if isinstance(v, list):
            return all(numeric(x) for x in v)
        return v is None or (isinstance(v, int | float) and not isinstance(v, bool))

    if not isinstance(raw, list) or not numeric(raw):
        raise Mismatch("expected an array of numbers")
    try:
        return np.array(raw, dtype=np.float64)
    except ValueError:  # ragged
        raise Mismatch("expected a rectangular array of numbers") from None
