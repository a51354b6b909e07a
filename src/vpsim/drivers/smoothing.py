"""The smoothing driver of the inverse dynamic method, eqs (34)-(35) of Hofman et al. (2011).

The drive cycle v_c(t) (samples joined piecewise linearly) is smoothed by convolution with a bump kernel of
half-width ``a``:

    v_d(t) = (1/C) ∫ g(t - τ) v_c(τ) dτ,    g(s) = exp(a² / (s² - a²)) for |s| < a, else 0,    C = ∫ g.

The inverse method needs v_d and its first two derivatives; because g is C-infinity with compact support, so
is v_d, and the derivatives follow exactly by integrating by parts against the piecewise-linear v_c:

    dv_d/dt   = (1/C) ∫ g(t - τ) v_c'(τ) dτ              (v_c' piecewise constant)
    d²v_d/dt² = (1/C) Σ_k Δm_k g(t - τ_k)                (Δm_k: slope change at breakpoint τ_k)

Outside its time range the cycle is held at its end values (so it stays continuous; for the usual cycles,
which start and end at rest, this is the same as holding it at zero). Note that
:meth:`vpsim.cycles.Cycle.speed_at` uses zero instead; the two differ only for traces that do not start and
end at rest.

Method. Write v_c(τ) = v_0 + Σ_k Δm_k (τ - τ_k)_+. The kernel normalised to unit mass, k_a = g/C, has
antiderivative G_a(s) = ∫_{-a}^{s} k_a and first moment M_a(s) = ∫_{-a}^{s} u k_a(u) du; the response to one
ramp (τ - τ_k)_+ is R_a(x) = x G_a(x) - M_a(x) with x = t - τ_k (0 for x <= -a, x for x >= a). Breakpoints
with τ_k <= t - a sum to a straight line L(τ) whose convolution is L(t) itself (the kernel is symmetric), so
only the breakpoints inside the window (t - a, t + a) need to be visited (found with ``np.searchsorted``):

    v_d(t) = L(t) + Σ_window Δm_k R_a(t - τ_k),    dv_d/dt = L' + Σ_window Δm_k G_a(t - τ_k),
    d²v_d/dt² = Σ_window Δm_k k_a(t - τ_k).

This is exact; the only approximation is in G and M, tabulated once for a = 1 (the normalised kernel is
scale invariant: k_a(s) = k_1(s/a)/a, G_a(s) = G_1(s/a), M_a(s) = a M_1(s/a)) by 12-point Gauss-Legendre on
1024 sub-intervals of [-1, 0] and interpolated by quintic Hermite polynomials built from the analytic kernel
and its derivative; the symmetry G_1(-s) = 1 - G_1(s), M_1(-s) = M_1(s) covers [0, 1]. The error of G and M
is about 1e-15 absolute.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ..errors import VpsimError

__all__ = [
    "SmoothingDriver",
    "inverse_grid",
    "bump_kernel",
    "bump_kernel_cdf",
    "bump_kernel_moment",
    "bump_normalisation",
    "smooth_reference",
]

# exp(-1/x) < exp(-700) ~ 1e-304 is taken as zero; this also keeps 1/x**3 in g'' finite.
_X_MIN = 1.0 / 700.0
_TABLE_INTERVALS = 1024  # sub-intervals of [-1, 0]
_GAUSS_POINTS = 12
_CHUNK = 1 << 18  # window terms evaluated per vectorised pass (bounds the temporary arrays)
_REFERENCE_SPLITS = np.array([-0.95, -0.9, -0.8, -0.6, -0.3, 0.0, 0.3, 0.6, 0.8, 0.9, 0.95])


# --- the unit bump g_1(s) = exp(1 / (s² - 1)) and its derivatives (not normalised) ----------------------


def _bump1(s: np.ndarray, derivative: int = 0) -> np.ndarray:
    """g_1 (or its first or second derivative) at ``s``; zero for |s| >= 1."""
    s = np.asarray(s, dtype=float)
    x = (1.0 - s) * (1.0 + s)  # 1 - s², accurate near |s| = 1
    out = np.zeros(np.shape(s))
    inside = x > _X_MIN
    xi, si = x[inside], s[inside]
    gi = np.exp(-1.0 / xi)
    if derivative == 0:
        out[inside] = gi
    elif derivative == 1:
        out[inside] = gi * (-2.0 * si / xi**2)
    else:
        h = -2.0 * si / xi**2  # g' = g h
        out[inside] = gi * (h * h - (6.0 * si * si + 2.0) / xi**3)  # g'' = g (h² + h')
    return out


def _quintic_hermite_coefficients(f, d1, d2, h):
    """Coefficients c_0..c_5 (in θ = (s - s_i)/h) of the quintic Hermite interpolant on each interval.

    ``f``, ``d1``, ``d2`` are the values and the first and second derivatives at the nodes (length n + 1).
    """
    f0, f1 = f[:-1], f[1:]
    p0, p1 = h * d1[:-1], h * d1[1:]
    q0, q1 = h * h * d2[:-1], h * h * d2[1:]
    df = f1 - f0
    c3 = 10.0 * df - 6.0 * p0 - 4.0 * p1 - 1.5 * q0 + 0.5 * q1
    c4 = -15.0 * df + 8.0 * p0 + 7.0 * p1 + 1.5 * q0 - q1
    c5 = 6.0 * df - 3.0 * p0 - 3.0 * p1 - 0.5 * q0 + 0.5 * q1
    return np.stack([f0, p0, 0.5 * q0, c3, c4, c5], axis=1)


@dataclass(frozen=True)
class _UnitKernelTables:
    norm: float  # C_1 = ∫ g_1
    coef_g: np.ndarray  # (n, 6) quintic pieces of G_1 on [-1, 0]
    coef_m: np.ndarray  # (n, 6) quintic pieces of M_1 on [-1, 0]
    rows: list  # per interval, the 12 coefficients of G_1 then M_1 as floats (scalar path)


@lru_cache(maxsize=1)
def _tables() -> _UnitKernelTables:
    n = _TABLE_INTERVALS
    h = 1.0 / n
    nodes = np.linspace(-1.0, 0.0, n + 1)
    xg, wg = np.polynomial.legendre.leggauss(_GAUSS_POINTS)
    u = nodes[:-1, None] + 0.5 * (xg + 1.0) * h
    w = 0.5 * h * wg
    gu = _bump1(u)
    piece_g = (gu * w).sum(axis=1)
    piece_m = (u * gu * w).sum(axis=1)
    norm = 2.0 * math.fsum(piece_g)
    big_g = np.concatenate([[0.0], np.cumsum(piece_g)]) / norm
    big_m = np.concatenate([[0.0], np.cumsum(piece_m)]) / norm
    big_g[-1] = 0.5  # exact by symmetry
    k = _bump1(nodes) / norm
    dk = _bump1(nodes, 1) / norm
    coef_g = _quintic_hermite_coefficients(big_g, k, dk, h)
    coef_m = _quintic_hermite_coefficients(big_m, nodes * k, k + nodes * dk, h)
    for arr in (coef_g, coef_m):
        arr.flags.writeable = False
    rows = np.concatenate([coef_g, coef_m], axis=1).tolist()
    return _UnitKernelTables(norm, coef_g, coef_m, rows)


def _unit_cdf_moment(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """G_1(x) and M_1(x) for any real x (G_1 = 0, M_1 = 0 below -1; G_1 = 1, M_1 = 0 above 1)."""
    tab = _tables()
    n = _TABLE_INTERVALS
    neg = -np.minimum(np.abs(x), 1.0)  # in [-1, 0]
    pos = (neg + 1.0) * n
    i = np.minimum(pos.astype(np.intp), n - 1)
    th = pos - i
    cg, cm = tab.coef_g[i], tab.coef_m[i]
    g = cg[:, 5]
    m = cm[:, 5]
    for j in range(4, -1, -1):
        g = g * th + cg[:, j]
        m = m * th + cm[:, j]
    g = np.where(x > 0.0, 1.0 - g, g)
    return g, m


def _unit_cdf_moment_scalar(x: float) -> tuple[float, float]:
    """Scalar :func:`_unit_cdf_moment` (same table, same arithmetic)."""
    n = _TABLE_INTERVALS
    neg = -min(abs(x), 1.0)
    pos = (neg + 1.0) * n
    i = min(int(pos), n - 1)
    th = pos - i
    g0, g1, g2, g3, g4, g5, m0, m1, m2, m3, m4, m5 = _tables().rows[i]
    g = ((((g5 * th + g4) * th + g3) * th + g2) * th + g1) * th + g0
    m = ((((m5 * th + m4) * th + m3) * th + m2) * th + m1) * th + m0
    return (1.0 - g if x > 0.0 else g), m


def _check_a(a) -> float:
    try:
        a = float(a)
    except (TypeError, ValueError):
        raise VpsimError(f"smoothing half-width a must be a number, got {a!r}") from None
    if not (math.isfinite(a) and a > 0.0):
        raise VpsimError(f"smoothing half-width a must be finite and > 0 s, got {a:g}")
    return a


def _as_float_array(x, what: str) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise VpsimError(f"{what} must be numeric") from None
    bad = np.flatnonzero(~np.isfinite(arr.ravel()))
    if bad.size:
        raise VpsimError(f"{what} has a non-finite value at index {bad[0]}: {arr.ravel()[bad[0]]}")
    return arr


# --- public kernel functions ---------------------------------------------------------------------------


def bump_normalisation(a: float = 1.0) -> float:
    """C = ∫ g for half-width ``a`` (= a × 0.443993816168...)."""
    return _check_a(a) * _tables().norm


def bump_kernel(s, a: float = 1.0, derivative: int = 0):
    """The normalised kernel g(s)/C (``derivative`` 0) or its first or second derivative in s (1, 2)."""
    a = _check_a(a)
    if derivative not in (0, 1, 2):
        raise VpsimError(f"kernel derivative order must be 0, 1 or 2, got {derivative!r}")
    s = np.asarray(s, dtype=float)
    out = _bump1(s / a, derivative) / (_tables().norm * a ** (derivative + 1))
    return out if out.ndim else float(out)


def bump_kernel_cdf(s, a: float = 1.0):
    """G(s) = (1/C) ∫_{-a}^{s} g: 0 for s <= -a, 1/2 at 0, 1 for s >= a."""
    a = _check_a(a)
    s = np.asarray(s, dtype=float)
    g, _ = _unit_cdf_moment(np.atleast_1d(s / a).ravel())
    return g.reshape(s.shape) if s.ndim else float(g[0])


def bump_kernel_moment(s, a: float = 1.0):
    """M(s) = (1/C) ∫_{-a}^{s} u g(u) du: even in s, <= 0, zero for |s| >= a."""
    a = _check_a(a)
    s = np.asarray(s, dtype=float)
    _, m = _unit_cdf_moment(np.atleast_1d(s / a).ravel())
    m = a * m
    return m.reshape(s.shape) if s.ndim else float(m[0])


# --- the driver ----------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SmoothingDriver:
    """Smoothed drive cycle v_d(t) with its first and second time derivatives, eqs (34)-(35).

    ``time_s`` strictly increasing, ``speed_mps`` finite (at least two samples), half-width ``a`` > 0 s.
    The cycle is held at its end values outside ``time_s``. Evaluate with :meth:`evaluate` (all three at
    once) or :meth:`v_d`, :meth:`dv_d`, :meth:`ddv_d`; each accepts a scalar (returns floats) or an array of
    any shape (returns arrays of that shape). The cost is O(len(t) × breakpoints within ±a of t).
    """

    time_s: np.ndarray
    speed_mps: np.ndarray
    a: float
    # breakpoints where the slope changes (collinear samples are dropped), and the slope changes there
    _tau: np.ndarray = field(init=False, repr=False)
    _dm: np.ndarray = field(init=False, repr=False)
    # line L_j(t) = _base_v[j] + _base_m[j] (t - _base_t[j]) carried by all breakpoints before window j
    _base_t: np.ndarray = field(init=False, repr=False)
    _base_v: np.ndarray = field(init=False, repr=False)
    _base_m: np.ndarray = field(init=False, repr=False)
    _lists: tuple = field(init=False, repr=False)  # the five arrays above as lists, for scalar calls

    def __post_init__(self):
        a = _check_a(self.a)
        t = _as_float_array(self.time_s, "time_s")
        v = _as_float_array(self.speed_mps, "speed_mps")
        if t.ndim != 1 or v.ndim != 1 or t.shape != v.shape:
            raise VpsimError(
                f"time_s and speed_mps must be 1-D arrays of equal length, got shapes {t.shape} and {v.shape}"
            )
        if t.size < 2:
            raise VpsimError(f"a drive cycle needs at least two samples, got {t.size}")
        bad = np.flatnonzero(np.diff(t) <= 0.0)
        if bad.size:
            k = bad[0] + 1
            raise VpsimError(f"time_s must increase strictly; sample {k} has t = {t[k]:g} after {t[k - 1]:g}")
        t = t.copy()
        v = v.copy()
        t.flags.writeable = False
        v.flags.writeable = False
        # slope before sample k is m[k], after it m[k + 1]; held ends have slope 0
        m = np.concatenate([[0.0], np.diff(v) / np.diff(t), [0.0]])
        dm = np.diff(m)
        keep = dm != 0.0
        keep[0] = True  # anchor of the line before the first window (dm may be 0 there: a constant cycle)
        tau, vk, m_after = t[keep], v[keep], m[1:][keep]
        base_t = np.concatenate([[tau[0]], tau])
        base_v = np.concatenate([[vk[0]], vk])
        base_m = np.concatenate([[0.0], m_after])
        arrays = {
            "time_s": t,
            "speed_mps": v,
            "a": a,
            "_tau": tau,
            "_dm": dm[keep],
            "_base_t": base_t,
            "_base_v": base_v,
            "_base_m": base_m,
        }
        for name, value in arrays.items():
            if isinstance(value, np.ndarray):
                value.flags.writeable = False
            object.__setattr__(self, name, value)
        lists = tuple(x.tolist() for x in (tau, dm[keep], base_t, base_v, base_m))
        object.__setattr__(self, "_lists", lists)

    @classmethod
    def from_cycle(cls, cycle, a: float) -> SmoothingDriver:
        """Driver for a :class:`vpsim.cycles.Cycle` (anything with ``time_s`` and ``speed_mps``)."""
        return cls(cycle.time_s, cycle.speed_mps, a)

    def speed_trace(self, t):
        """The unsmoothed piecewise-linear cycle v_c(t), held at its end values outside the cycle."""
        return np.interp(t, self.time_s, self.speed_mps)

    def evaluate(self, t):
        """(v_d, dv_d/dt, d²v_d/dt²) at times ``t`` (scalar or array; m/s, m/s², m/s³).

        A Python or NumPy float takes a pure-Python path (a few microseconds, for ODE right-hand sides);
        arrays are evaluated in vectorised passes over the breakpoints inside each time's window.
        """
        if isinstance(t, float | int) and not isinstance(t, bool):
            return self._evaluate_scalar(float(t))  # the ODE solver's case: skip the array machinery
        tt = _as_float_array(t, "evaluation time t")
        shape = tt.shape
        tt = tt.ravel()
        v, dv, ddv = self._evaluate_flat(tt)
        if not shape:
            return float(v[0]), float(dv[0]), float(ddv[0])
        return v.reshape(shape), dv.reshape(shape), ddv.reshape(shape)

    def v_d(self, t):
        """Smoothed speed v_d(t), m/s."""
        return self.evaluate(t)[0]

    def dv_d(self, t):
        """Smoothed acceleration dv_d/dt, m/s²."""
        return self.evaluate(t)[1]

    def ddv_d(self, t):
        """Smoothed jerk d²v_d/dt², m/s³."""
        return self.evaluate(t)[2]

    def __call__(self, t):
        return self.evaluate(t)

    def __repr__(self) -> str:
        return (
            f"SmoothingDriver(a={self.a:g} s, {self.time_s.size} samples over "
            f"[{self.time_s[0]:g}, {self.time_s[-1]:g}] s, {self._tau.size} slope changes)"
        )

    def _evaluate_scalar(self, t: float) -> tuple[float, float, float]:
        if not math.isfinite(t):
            raise VpsimError(f"evaluation time t must be finite, got {t}")
        a = self.a
        tau, dm, base_t, base_v, base_m = self._lists
        lo = bisect_right(tau, t - a)
        hi = bisect_left(tau, t + a, lo)
        mj = base_m[lo]
        v = base_v[lo] + mj * (t - base_t[lo])
        dv = mj
        ddv = 0.0
        for k in range(lo, hi):
            x = (t - tau[k]) / a
            big_g, big_m = _unit_cdf_moment_scalar(x)
            v += dm[k] * (a * (x * big_g - big_m))
            dv += dm[k] * big_g
            ddv += dm[k] * _bump1_scalar(x, 0)
        return v, dv, ddv / (a * _tables().norm)

    def _evaluate_flat(self, tt: np.ndarray):
        a, tau = self.a, self._tau
        lo = np.searchsorted(tau, tt - a, side="right")  # first breakpoint with τ > t - a
        hi = np.searchsorted(tau, tt + a, side="left")  # first breakpoint with τ >= t + a
        v = self._base_v[lo] + self._base_m[lo] * (tt - self._base_t[lo])
        dv = self._base_m[lo].copy()
        ddv = np.zeros_like(tt)
        count = hi - lo
        # process the times in chunks so that the flattened window terms stay bounded in memory
        ends = np.cumsum(count)
        start = 0
        while start < tt.size:
            stop = int(np.searchsorted(ends, (ends[start - 1] if start else 0) + _CHUNK, side="right"))
            stop = max(stop, start + 1)
            self._add_window_terms(tt[start:stop], lo[start:stop], count[start:stop], v, dv, ddv, start)
            start = stop
        return v, dv, ddv

    def _add_window_terms(self, tt, lo, count, v, dv, ddv, offset):
        total = int(count.sum())
        if total == 0:
            return
        a = self.a
        rows = np.repeat(np.arange(tt.size), count)
        first = np.cumsum(count) - count
        idx = np.arange(total) - np.repeat(first, count) + np.repeat(lo, count)
        x = (tt[rows] - self._tau[idx]) / a
        big_g, big_m = _unit_cdf_moment(x)
        w = self._dm[idx]
        n = tt.size
        sl = slice(offset, offset + n)
        v[sl] += np.bincount(rows, weights=w * (a * (x * big_g - big_m)), minlength=n)
        dv[sl] += np.bincount(rows, weights=w * big_g, minlength=n)
        ddv[sl] += np.bincount(rows, weights=w * _bump1(x), minlength=n) / (a * _tables().norm)


# --- brute-force reference (for tests) -----------------------------------------------------------------


def smooth_reference(time_s, speed_mps, a: float, t, *, epsrel: float = 1e-12):
    """(v_d, dv_d/dt, d²v_d/dt²) at ``t`` by adaptive quadrature of the literal convolutions.

    v_d = (1/C) ∫ g(t-τ) v_c(τ) dτ,   dv_d/dt = (1/C) ∫ g'(t-τ) v_c(τ) dτ,
    d²v_d/dt² = (1/C) ∫ g''(t-τ) v_c(τ) dτ,

    over τ in (t - a, t + a) with the analytic kernel derivatives, by ``scipy.integrate.quad`` between
    consecutive breakpoints of v_c (so every piece has a smooth integrand), and C itself from ``quad``.
    The cycle is held at its end values, as in :class:`SmoothingDriver`. Slow; meant for tests.
    """
    from scipy.integrate import quad

    a = _check_a(a)
    ts = _as_float_array(time_s, "time_s")
    vs = _as_float_array(speed_mps, "speed_mps")
    if ts.ndim != 1 or ts.shape != vs.shape or ts.size < 2 or np.any(np.diff(ts) <= 0.0):
        raise VpsimError("time_s must be strictly increasing and match speed_mps (at least two samples)")
    tq = _as_float_array(t, "evaluation time t")
    scale = max(float(np.max(np.abs(vs))), 1e-300)
    norm = quad(lambda u: _bump1_scalar(u, 0), -1.0, 1.0, epsabs=0.0, epsrel=1e-13)[0]

    def conv(t0: float, derivative: int) -> float:
        lo, hi = t0 - a, t0 + a
        # pieces: between breakpoints of v_c, and split further where the kernel changes shape (quad's error
        # estimate is unreliable on a whole bump flank, whose derivatives vanish to all orders at |s| = a)
        inner = np.concatenate([ts[(ts > lo) & (ts < hi)], t0 + a * _REFERENCE_SPLITS])
        edges = np.concatenate([[lo], np.unique(inner), [hi]])
        total = 0.0
        for e0, e1 in zip(edges[:-1], edges[1:], strict=True):
            # v_c is linear on [e0, e1]: its values at the ends fix it there
            v0, v1 = np.interp([e0, e1], ts, vs)
            slope = (v1 - v0) / (e1 - e0)

            def f(tau, v0=v0, e0=e0, slope=slope):
                return _bump1_scalar((t0 - tau) / a, derivative) * (v0 + slope * (tau - e0))

            total += quad(f, e0, e1, epsabs=1e-13 * scale * a, epsrel=epsrel, limit=200)[0]
        return total / (norm * a ** (derivative + 1))

    out = np.empty((3,) + tq.shape)
    for i, t0 in np.ndenumerate(tq):
        for d in range(3):
            out[(d,) + i] = conv(float(t0), d)
    if not tq.shape:
        return float(out[0]), float(out[1]), float(out[2])
    return out[0], out[1], out[2]


def _bump1_scalar(s: float, derivative: int) -> float:
    """Scalar :func:`_bump1` for the reference integrands."""
    x = (1.0 - s) * (1.0 + s)
    if x <= _X_MIN:
        return 0.0
    g = math.exp(-1.0 / x)
    if derivative == 0:
        return g
    h = -2.0 * s / (x * x)
    if derivative == 1:
        return g * h
    return g * (h * h - (6.0 * s * s + 2.0) / x**3)


def inverse_grid(time_s, max_step: float) -> np.ndarray:
    """The points an inverse method evaluates the smoothed cycle at: the cycle's samples, each interval split
    into equal parts at most ``max_step`` long (the electric and hybrid cars' inverse methods)."""
    time_s = np.asarray(time_s, float)
    dt = np.diff(time_s)
    parts = np.maximum(1, np.ceil(dt / max_step - 1e-12).astype(np.int64))
    # interval k's points start + i (dt / parts), i = 0 .. parts - 1, in one pass: what np.linspace(start,
    # stop, parts + 1)[:-1] gives, to the bit (i * step + start), without a call per interval
    k_of = np.repeat(np.arange(dt.size), parts)
    first = np.cumsum(parts) - parts  # each interval's first point's index
    i = np.arange(k_of.size) - first[k_of]
    return np.concatenate([i * (dt / parts)[k_of] + time_s[k_of], time_s[-1:]])
