"""Column specs that name several IMUs in one line (issue 28): ``capture --columns`` and
``import --columns`` (or a CSV header) with the other IMUs' fields suffixed ``.N``::

    t,ax,ay,az,gx,gy,gz,temp,ax.1,ay.1,az.1,gx.1,gy.1,gz.1,t.1

The fields without a suffix are the reference IMU's; ``name.N`` (N = 1, 2, ...) are IMU N's,
named ``imuN``.  An IMU without its own ``t.N`` takes the line's ``t`` (one device sampled
them together); one with ``t.N`` has its own stamps.  :func:`split_columns` gives one spec per
IMU, the others' fields skipped (``_``), so that each IMU is read by the one-IMU readers as it
is.
"""

from __future__ import annotations

import re

from imucal_cli.errors import InputError

__all__ = ["imu_number_name", "split_columns", "split_header"]

_SUFFIX = re.compile(r"^(.+)\.(\d+)$")
_SEPARATORS = re.compile(r"[,\s;]+")
MAX_SUFFIX = 255


def imu_number_name(number: int) -> str:
    """``reference`` for 0, ``imu<N>`` for IMU N."""
    return "reference" if number == 0 else f"imu{number}"


def _split(names: list[str], where: str) -> dict[int, list[str]] | None:
    numbers: dict[int, None] = {}
    parsed = []
    for name in names:
        m = _SUFFIX.match(name)
        if m and m.group(2).isdigit():
            number = int(m.group(2))
            if not 1 <= number <= MAX_SUFFIX:
                raise InputError(f"{where}: field {name!r}: IMUs are numbered 1 to {MAX_SUFFIX}")
            parsed.append((m.group(1), number))
            numbers[number] = None
        else:
            parsed.append((name, 0))
    if not numbers:
        return None
    out = {}
    for imu in [0, *sorted(numbers)]:
        own_time = any(stem == "t" and n == imu for stem, n in parsed)
        fields = []
        for stem, n in parsed:
            if n == imu:
                fields.append(stem)
            elif n == 0 and stem == "t" and not own_time:
                fields.append("t")  # the line's time, shared
            else:
                fields.append("_")
        out[imu] = fields
    return out


def split_columns(text: str) -> dict[int, str] | None:
    """One column spec per IMU of a spec naming several (module notes), ``{0: reference's,
    N: IMU N's}``; None when it names one IMU.

    Raises
    ------
    InputError
        A suffix outside 1..:data:`MAX_SUFFIX`.
    """
    names = [n for n in _SEPARATORS.split(str(text).strip().lower()) if n]
    split = _split(names, f"--columns {text!r}")
    return None if split is None else {k: ",".join(v) for k, v in split.items()}


def split_header(fields: list[str]) -> dict[int, list[str]] | None:
    """A header line's fields split the same way (each IMU's stems, the others' fields empty,
    for :func:`~imucal_cli.formats.importers.text.infer_columns`); None for one IMU."""
    names = [str(f).strip() for f in fields]
    split = _split([n.lower() for n in names], "header")
    if split is None:
        return None
    return {k: ["" if s == "_" else s for s in v] for k, v in split.items()}
