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

from ..cycles import PHASES, Cycle, load_cycle
from ..errors import CycleError

FLEET_CYCLES = ("ftp_bag2", "ftp_bag3", "hwy", "us06")
_WHOLE = {"hwy": "hwfet", "us06": "us06"}  # the tests that drive a whole standard cycle, and which one


def time_window(cycle: Cycle, start_s: float, end_s: float, name: str | None = None) -> Cycle:
    """The part of ``cycle`` on [start_s, end_s], time re-based to 0: :meth:`vpsim.cycles.Cycle.window`."""
    return cycle.window(start_s, end_s, name)


@cache
def fleet_cycle(name: str) -> Cycle:
    """One of :data:`FLEET_CYCLES` as a :class:`~vpsim.cycles.Cycle` (the bags: :data:`vpsim.cycles.PHASES`,
    which ``vpsim simulate --cycle`` knows by the same names)."""
    if name not in FLEET_CYCLES:
        raise CycleError(f"unknown fleet cycle {name!r}; expected one of {', '.join(FLEET_CYCLES)}")
    if name in PHASES:
        return load_cycle(name)
    cyc = load_cycle(_WHOLE[name])
    return Cycle(name, cyc.time_s, cyc.speed_mps, source=cyc.source)


__all__ = ["FLEET_CYCLES", "fleet_cycle", "time_window"]
