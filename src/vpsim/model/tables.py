"""Table look-ups used by the maps and the kernels, written once (compiled; Python gets array views).

* :func:`interp_at`: ``numpy.interp`` for one point (end values held outside the grid),
* :func:`bilinear_at`: bilinear interpolation on a rectilinear grid, linear extrapolation outside.

Grids are increasing; a uniform grid is found in one multiplication (by the grid's inverse mean spacing,
:func:`inverse_spacing`, computed once by the caller), any other by a short walk from there.
"""

from __future__ import annotations

import numpy as np

from ._compile import kernel
from .engine import equation, inline


@equation
def inverse_spacing(xg):
    """(len(xg) - 1) / (xg[-1] - xg[0]): intervals per unit of x, for the first guess of a look-up."""
    return (xg.size - 1) / (xg[xg.size - 1] - xg[0])


@equation
def _guess(xg, x, inv):
    """Interval index a uniform grid would give for x, clipped to 0..len(xg) - 2 (a start for the walks)."""
    n = xg.size
    g = (x - xg[0]) * inv
    if not g > 0.0:  # also NaN
        return 0
    return min(int(g), n - 2)


@equation
def interval_at(x, xp, inv):
    """The nodes numpy.interp(x, xp, fp) reads for one x: (j, exact), the value fp[j] if ``exact`` (at or
    beyond an end, or on a node), else between fp[j] and fp[j + 1] (xp[j] < x < xp[j + 1])."""
    n = xp.size
    if x <= xp[0]:
        return 0, True
    if x >= xp[n - 1]:
        return n - 1, True
    j = _guess(xp, x, inv)
    while j > 0 and xp[j] > x:
        j -= 1
    while xp[j + 1] <= x:
        j += 1
    return j, xp[j] == x


@equation
def interp_at(x, xp, fp, inv):
    """numpy.interp(x, xp, fp) for one x: end values held outside, exact at the nodes."""
    j, exact = interval_at(x, xp, inv)
    if exact:
        return fp[j]
    return _on_interval(x, xp, fp, j, (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]))


@equation
def _on_interval(x, xp, fp, j, slope):
    """The line through (xp[j], fp[j]) with ``slope``, at x."""
    return slope * (x - xp[j]) + fp[j]


def interval_slopes(xp, fp) -> np.ndarray:
    """(fp[j+1] - fp[j]) / (xp[j+1] - xp[j]) of every interval: :func:`interp_at`'s slopes, for a caller
    that reads one table at many points (:func:`interp_sloped_at`). An interval of zero width (a repeated
    node, which a look-up never reads inside) gets a non-finite slope, without a warning."""
    xp, fp = np.asarray(xp, dtype=float), np.asarray(fp, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (fp[1:] - fp[:-1]) / (xp[1:] - xp[:-1])


@equation
def interp_sloped_at(x, xp, fp, slope, inv):
    """:func:`interp_at` with the intervals' slopes at hand (:func:`interval_slopes`): the same value to the
    bit, without a division on the way from x to it."""
    j, exact = interval_at(x, xp, inv)
    if exact:
        return fp[j]
    return _on_interval(x, xp, fp, j, slope[j])


@equation
def _cell(xg, x, inv):
    """Cell of x: the j in 0..len(xg) - 2 with xg[j] < x <= xg[j+1] (the end cells extend outward)."""
    last = xg.size - 2
    j = _guess(xg, x, inv)
    while j > 0 and xg[j] >= x:
        j -= 1
    while j < last and xg[j + 1] < x:
        j += 1
    return j


@inline
def bilinear_at(xg, yg, table, x, y, inv_x, inv_y):
    """Bilinear interpolation of ``table[i, j]`` at (xg[i], yg[j]) for one point; linear outside."""
    i = _cell(xg, x, inv_x)
    j = _cell(yg, y, inv_y)
    tx = (x - xg[i]) / (xg[i + 1] - xg[i])
    ty = (y - yg[j]) / (yg[j + 1] - yg[j])
    f00 = table[i, j]
    f01 = table[i, j + 1]
    f10 = table[i + 1, j]
    f11 = table[i + 1, j + 1]
    return (1 - tx) * ((1 - ty) * f00 + ty * f01) + tx * ((1 - ty) * f10 + ty * f11)


@kernel
def _interp_loop(x, xp, fp, out):
    inv = inverse_spacing(xp)
    for k in range(x.size):
        out[k] = interp_at(x[k], xp, fp, inv)


@kernel
def _bilinear_loop(xg, yg, table, x, y, out):
    inv_x, inv_y = inverse_spacing(xg), inverse_spacing(yg)
    for k in range(x.size):
        out[k] = bilinear_at(xg, yg, table, x[k], y[k], inv_x, inv_y)


def interp(x, xp, fp):
    """:func:`interp_at` over an array ``x``."""
    x = np.asarray(x, dtype=float)
    flat = np.array(x).ravel()  # writable copies: a read-only input would be another signature to compile
    out = np.empty(flat.size)
    _interp_loop(flat, np.array(xp, float), np.array(fp, float), out)
    return out.reshape(x.shape) if x.ndim else float(out[0])


def bilinear(xg, yg, table, x, y):
    """:func:`bilinear_at` over arrays ``x``, ``y`` (broadcast)."""
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    xs, ys = np.array(x).ravel(), np.array(y).ravel()  # writable copies: one signature (see interp)
    out = np.empty(xs.size)
    _bilinear_loop(np.array(xg, float), np.array(yg, float), np.array(table, dtype=float), xs, ys, out)
    return out.reshape(x.shape) if x.ndim else float(out[0])


@inline
def gear_index(time_s, k, sched_t, sched_gear, j):
    """Index (0-based) of the gear engaged on interval k (the schedule held right-continuously), and the
    schedule position to start the next search from."""
    m = sched_t.size
    while j < m and sched_t[j] <= time_s[k]:
        j += 1
    idx = min(max(j - 1, 0), m - 1)
    return sched_gear[idx] - 1, j
