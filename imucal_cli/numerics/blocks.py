"""What the block-by-block accumulators share (:class:`~.allan.AllanAccumulator`,
:class:`imucal_cli.design.static_stream.StaticStream`): a recording is announced by its
length, then given a block at a time, and its result exists only once every sample announced
was given."""

from __future__ import annotations

from imucal_cli.errors import InputError

__all__ = ["check_all_given", "check_not_more"]


def check_not_more(seen: int, k: int, announced: int) -> None:
    """Refuse a block of ``k`` samples after ``seen`` that goes past the ``announced`` ones."""
    if seen + k > announced:
        raise InputError(f"more than the {announced} samples announced")


def check_all_given(seen: int, announced: int) -> None:
    """Refuse a result before every sample announced was given (``seen`` of them were)."""
    if seen != announced:
        raise InputError(f"{seen} of the {announced} samples announced were given")
