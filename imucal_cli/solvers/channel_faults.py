"""Faults of a sensor's channel that no calibration can mend (issue 24.6): a dead, stuck,
saturated or disconnected axis.

Each channel's finite readings over a whole recording are judged on their own:

* **disconnected**: no finite reading at all (the reader had nothing), or every reading -1
  in raw counts (an I2C or SPI read of an absent device returns all ones, 0xFFFF);
* **dead**: every reading exactly 0;
* **saturated**: every reading at one end of the channel's range, or more than
  :data:`SATURATED_SHARE` of them at either end (a channel pinned at its rail: an axis whose
  sensing element is broken, or a range far too small);
* **stuck**: every reading one value (a frozen register, a sensor that stopped converting).

A working MEMS channel over :data:`MIN_SAMPLES` or more samples always varies by its noise
(at least one code of a 16-bit converter), so a constant channel is a fault; shorter
recordings are not judged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Fewest readings of a channel judged (a constant stretch shorter than this may be quiet).
MIN_SAMPLES = 50
#: A channel at an end of its range in more than this share of its readings is saturated.
SATURATED_SHARE = 0.5


@dataclass(frozen=True)
class ChannelFault:
    """One faulty channel: its index, the kind of fault and what it reads."""

    channel: int
    kind: str  # "disconnected", "dead", "saturated", "stuck"
    detail: str


def channel_faults(x: np.ndarray, *, counts: bool = False,
                   limits: tuple[float, float] | None = None) -> list[ChannelFault]:
    """The faulty channels of one sensor's readings (see the module notes).

    Parameters
    ----------
    x : ndarray (N, c)
        Raw readings, NaN where a channel has no value.
    counts : bool
        The readings are ADC counts (-1 then means all ones).
    limits : (low, high), optional
        The channels' range in raw units (readings at or beyond either end are saturated).
    """
    out = []
    for c in range(x.shape[1]):
        col = np.asarray(x[:, c], float)
        v = col[np.isfinite(col)]
        if not len(v):
            if len(col) >= MIN_SAMPLES:
                out.append(ChannelFault(c, "disconnected", "no value in any sample"))
            continue
        if len(v) < MIN_SAMPLES:
            continue
        lo, hi = float(v.min()), float(v.max())
        if lo == hi:
            out.append(_constant(c, lo, counts, limits))
            continue
        if limits is not None:
            at_rail = float(np.mean((v <= limits[0]) | (v >= limits[1])))
            if at_rail > SATURATED_SHARE:
                out.append(ChannelFault(c, "saturated", f"at an end of its range ({limits[0]:g} "
                                        f"or {limits[1]:g}) in {100 * at_rail:.0f} % of the "
                                        "samples"))  # fmt: skip
    return out


def _constant(c: int, value: float, counts: bool, limits) -> ChannelFault:
    if value == 0:
        return ChannelFault(c, "dead", "reads 0 in every sample")
    if counts and value == -1:
        return ChannelFault(c, "disconnected", "reads -1 (0xFFFF, all ones) in every sample")
    if limits is not None and (value <= limits[0] or value >= limits[1]):
        return ChannelFault(c, "saturated", f"reads {value:g}, the end of its range, in every "
                            "sample")  # fmt: skip
    return ChannelFault(c, "stuck", f"reads {value:g} in every sample")
