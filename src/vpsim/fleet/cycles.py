"""The cycles a certification test measures, built from vpsim's shipped cycles.

==========  ==========================================  ================================================
name        what                                        built as
==========  ==========================================  ================================================
ftp_bag2    FTP-75 bag 2, hot stabilised                UDDS 505-1369 s, time re-based to 0
ftp_bag3    FTP-75 bag 3, hot start                     UDDS 0-505 s (the same trace as bag 1)
hwy         Highway fuel economy test                   HWFET
us06        US06 (aggressive, high speed)               US06
==========  ==========================================  ================================================

The model has no engine temperature, so bag 3 (hot start after a 10-minute soak) is simulated hot, as is
bag 2. The cold-start bag 1 is not used.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from ..cycles import Cycle, load_cycle
from ..errors import CycleError

FLEET_CYCLES = ("ftp_bag2", "ftp_bag3", "hwy", "us06")
_PIECES = {
    "ftp_bag2": ("udds", 505.0, 1369.0),
    "ftp_bag3": ("udds", 0.0, 505.0),
    "hwy": ("hwfet", None, None),
    "us06": ("us06", None, None),
}


def time_window(cycle: Cycle, start_s: float, end_s: float, name: str | None = None) -> Cycle:
    """The part of ``cycle`` on [start_s, end_s], time re-based to 0 (the ends interpolated if off-grid)."""
    t, v = cycle.time_s, cycle.speed_mps
    if not (t[0] <= start_s < end_s <= t[-1]):
        raise CycleError(
            f"{cycle.name}: window [{start_s:g}, {end_s:g}] s is not inside the cycle [{t[0]:g}, {t[-1]:g}] s"
        )
    inner = (t > start_s) & (t < end_s)
    tt = np.concatenate(([start_s], t[inner], [end_s]))
    vv = np.concatenate(([np.interp(start_s, t, v)], v[inner], [np.interp(end_s, t, v)]))
    return Cycle(
        name or f"{cycle.name}[{start_s:g}:{end_s:g}]",
        tt - start_s,
        vv,
        source=f"{cycle.name} from {start_s:g} s to {end_s:g} s",
    )


@cache
def fleet_cycle(name: str) -> Cycle:
    """One of :data:`FLEET_CYCLES` as a :class:`~vpsim.cycles.Cycle`."""
    if name not in _PIECES:
        raise CycleError(f"unknown fleet cycle {name!r}; expected one of {', '.join(FLEET_CYCLES)}")
    base, start, end = _PIECES[name]
    cyc = load_cycle(base)
    if start is None:
        return Cycle(name, cyc.time_s, cyc.speed_mps, source=cyc.source)
    return time_window(cyc, start, end, name)


__all__ = ["FLEET_CYCLES", "fleet_cycle", "time_window"]
