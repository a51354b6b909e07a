"""Subdividing a trace's long intervals, the speed interpolated linearly (the piecewise-linear trace itself is
unchanged): how the inverse method's step cap and the gear rule see coarse or gappy traces."""

from __future__ import annotations

import numpy as np

from ..errors import CycleError

MAX_POINTS = 10_000_000  # a subdivision beyond this is refused (the trace or the step is implausible)


def subdivide(time_s, speed, max_step: float):
    """(times, speeds, indices of the original samples) with no interval longer than ``max_step``;
    the indices are ``None`` when nothing needed subdividing (the arrays are then the inputs)."""
    time_s = np.asarray(time_s, dtype=float)
    dt = np.diff(time_s)
    if dt.size == 0 or not np.any(dt > max_step * (1.0 + 1e-9)):
        return time_s, np.asarray(speed, dtype=float), None
    pieces = np.maximum(np.ceil(dt / max_step - 1e-9), 1.0).astype(np.int64)
    total = int(pieces.sum()) + 1
    if total > MAX_POINTS:
        raise CycleError(
            f"subdividing the trace to steps of {max_step:g} s gives {total} points, more than {MAX_POINTS}"
        )
    starts = np.concatenate([[0], np.cumsum(pieces)])
    frac = np.concatenate([np.arange(k) / k for k in pieces])
    k_of = np.repeat(np.arange(dt.size), pieces)
    t_new = np.concatenate([time_s[k_of] + frac * dt[k_of], time_s[-1:]])
    v_new = np.interp(t_new, time_s, speed)
    t_new[starts] = time_s  # the original samples exactly
    return t_new, v_new, starts
