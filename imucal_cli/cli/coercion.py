"""Command-line values turned into ``str``, ``int``, ``float`` and ``Path`` without pydantic.

typer (0.29) coerces every parameter of a command through a pydantic ``TypeAdapter``, built
when the command runs: importing pydantic and building the adapters costs 0.06-0.1 s of CPU on
every ``imucal`` command, more than many commands' own work (issue 14).  Every imucal option
is a plain ``str``, ``bool``, ``int``, ``float``, ``Path`` (or a list, or None), so :func:`install`
gives typer a direct conversion for exactly the values whose meaning is not in doubt:

- ``str``: a ``str`` as it is; ``bool``: a ``bool`` (a flag) as it is;
- ``int``: ASCII digits with an optional sign (``int(text)``); ``float``: a plain decimal
  number (``1``, ``-2.5``, ``.5``, ``1e-3``; ``float(text)``), both parsed exactly as
  pydantic parses them (the correctly rounded double); a default of the command as it is;
- ``Path``: ``Path(text)`` (or a ``Path`` default), then typer's own path checks
  (``coerce_cli_path``);
- a ``list`` of these, item by item.

Anything else (``inf``, ``1_000``, bytes, an invalid number, a non-plain annotation) goes to
typer's own pydantic coercion, imported only then, so results and error messages are typer's.
``tests/test_cli_coercion.py`` checks that both give the same values.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args, get_origin

from imucal_cli.formats.number import NUMBER

_INT = re.compile(r"[+-]?[0-9]+")


class _Undecided(Exception):
    """The value is left to typer's own coercion."""


def _to_str(value: Any) -> str:
    if isinstance(value, str):
        return value
    raise _Undecided


def _to_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return value
    raise _Undecided


def _to_int(value: Any) -> int:
    if type(value) is int:  # a default
        return value
    if isinstance(value, str) and _INT.fullmatch(value):
        return int(value)
    raise _Undecided


def _to_float(value: Any) -> float:
    if type(value) in (float, int):  # a default
        return float(value)
    if isinstance(value, str) and NUMBER.match(value):
        return float(value)
    raise _Undecided


_LEAVES = {str: _to_str, bool: _to_bool, int: _to_int, float: _to_float}


def install() -> bool:
    """Give typer the direct conversions above; False (typer unchanged) when this typer
    has no pydantic coercion to replace (older typer converts with click's own types)."""
    try:
        from typer import _coercion, _param_types, core
    except ImportError:
        return False
    original = getattr(core, "build_runtime_param", None)
    runtime_param = getattr(_coercion, "RuntimeParam", None)
    path_check = getattr(_param_types, "coerce_cli_path", None)
    routes_to_path = getattr(_param_types, "routes_to_path", None)
    if None in (original, runtime_param, path_check, routes_to_path):
        return False
    if getattr(original, "imucal_plain", False):
        return True

    @dataclass(frozen=True)
    class PlainParam(runtime_param):
        """A parameter of a plain annotation: direct conversion, typer's when undecided."""

        descriptor: Any = None
        is_list: bool = False
        path_type: Any = None

        def _leaf(self, value: Any, param: Any, ctx: Any) -> Any:
            if self.path_type is None:
                return _LEAVES[self.leaf_type](value)
            if isinstance(value, str):
                value = Path(value)
            elif not isinstance(value, Path):
                raise _Undecided
            return path_check(value, self.parameter_info, path_type=Path,
                              param=param, ctx=ctx)  # fmt: skip

        @property
        def leaf_type(self) -> Any:
            return get_args(self.annotation)[0] if self.is_list else self.annotation

        def _coerce_value(self, value: Any, param: Any, ctx: Any) -> Any:
            try:
                if self.is_list:
                    items = value if isinstance(value, (list, tuple)) else [value]
                    return [self._leaf(item, param, ctx) for item in items]
                return self._leaf(value, param, ctx)
            except _Undecided:
                typer_own = original(self.descriptor)
                return typer_own._coerce_value(value, param=param, ctx=ctx)

    def build(descriptor: Any) -> Any:
        annotation, info = descriptor.annotation, descriptor.parameter_info
        is_list = get_origin(annotation) is list
        leaf = get_args(annotation)[0] if is_list else annotation
        plain = (
            descriptor.file_annotation is None
            and info.parser is None
            and info.min is None
            and info.max is None
            and (not is_list or len(get_args(annotation)) == 1)
        )
        if plain and leaf is Path and routes_to_path(leaf, info) and info.path_type is None:
            return PlainParam(info, annotation, descriptor, is_list, Path)
        if plain and leaf in _LEAVES:
            return PlainParam(info, annotation, descriptor, is_list)
        return original(descriptor)

    build.imucal_plain = True
    core.build_runtime_param = build
    return True
