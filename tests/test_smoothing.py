"""The smoothing driver of the inverse method, eqs (34)-(35): bump-kernel convolution of the drive cycle."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from vpsim.drivers import (
    SmoothingDriver,
    bump_kernel,
    bump_kernel_cdf,
    bump_kernel_moment,
    bump_normalisation,
    smooth_reference,
)
from vpsim.drivers import smoothing as smoothing_module
from vpsim.errors import VpsimError

C1 = 0.443993816168079  # ∫ exp(1/(s² - 1)) ds over (-1, 1)
_S = np.linspace(-1.0, 1.0, 20001)
K1_MAX = 1.01 * float(np.max(np.abs(bump_kernel(_S, 1.0, 1))))  # max |d/ds (g/C)| for a = 1
K2_MAX = 1.01 * float(np.max(np.abs(bump_kernel(_S, 1.0, 2))))  # max |d²/ds² (g/C)| for a = 1


def nedc_like(rng: np.random.Generator, n_phases: int = 8, dt: float | None = 1.0):
    """A random speed trace shaped like a legislative cycle: idle, accelerate, cruise, decelerate.

    Sampled at ``dt`` (or at random steps in [0.2, 2] s when ``dt`` is None), with a little noise while
    moving; starts and ends at rest.
    """
    t, v = [0.0], [0.0]
    for _ in range(n_phases):
        for kind in ("idle", "accelerate", "cruise", "decelerate"):
            steps = int(rng.integers(3, 18))
            target = {
                "idle": 0.0,
                "accelerate": rng.uniform(4.0, 33.0),
                "cruise": v[-1],
                "decelerate": 0.0 if rng.random() < 0.6 else v[-1] * rng.uniform(0.3, 0.8),
            }[kind]
            for k in range(1, steps + 1):
                t.append(t[-1] + (dt if dt is not None else rng.uniform(0.2, 2.0)))
                v.append(v[-1] + (target - v[-1]) / (steps - k + 1))
    t, v = np.array(t), np.array(v)
    v = np.maximum(v + np.where(v > 0.0, rng.normal(0.0, 0.05, v.size), 0.0), 0.0)
    v[-3:] = 0.0
    return t, v


def slope_changes(t, v):
    m = np.concatenate([[0.0], np.diff(v) / np.diff(t), [0.0]])
    return np.diff(m)


def gauss_legendre(f, lo: float, hi: float, h: float, n: int = 16) -> float:
    """∫ f over [lo, hi] by n-point Gauss-Legendre on sub-intervals no longer than h (f vectorised)."""
    m = max(1, int(np.ceil((hi - lo) / h)))
    edges = np.linspace(lo, hi, m + 1)
    x, w = np.polynomial.legendre.leggauss(n)
    mid, half = 0.5 * (edges[:-1] + edges[1:]), 0.5 * np.diff(edges)
    pts = mid[:, None] + half[:, None] * x
    return float(np.sum(f(pts.ravel()).reshape(pts.shape) * w * half[:, None]))


# --- agreement with the brute-force quadrature of the literal convolution ------------------------------


@pytest.mark.parametrize("sampling", ["1 Hz", "irregular"])
@pytest.mark.parametrize("a", [1.0, 5.0, 0.4])
def test_matches_quad_reference(a, sampling):
    rng = np.random.default_rng(20110834 + int(10 * a) + (sampling == "irregular"))
    t, v = nedc_like(rng, n_phases=6, dt=1.0 if sampling == "1 Hz" else None)
    tq = rng.uniform(t[0] - 2 * a, t[-1] + 2 * a, 80)
    tq = np.concatenate([tq, t[rng.integers(0, t.size, 10)] + rng.uniform(-1e-3, 1e-3, 10)])
    assert np.min(np.abs(tq[:, None] - t[None, :])) > 0.0  # non-grid times

    drv = SmoothingDriver(t, v, a)
    got = drv.evaluate(tq)
    ref = smooth_reference(t, v, a, tq)
    scales = (
        np.max(np.abs(v)),  # speed
        np.max(np.abs(np.diff(v) / np.diff(t))),  # acceleration: the steepest slope of the cycle
        np.max(np.abs(slope_changes(t, v))) / (a * C1),  # jerk: the largest single-breakpoint term
    )
    for name, g, r, scale in zip(("v", "dv", "ddv"), got, ref, scales, strict=True):
        err = np.max(np.abs(g - r)) / scale
        assert err <= 1e-8, f"{name}: relative error {err:.2e}"


def test_scalar_calls_match_array_calls():
    rng = np.random.default_rng(3)
    t, v = nedc_like(rng, n_phases=4)
    for a in (0.3, 1.0, 5.0):
        drv = SmoothingDriver(t, v, a)
        tq = rng.uniform(t[0] - 2 * a, t[-1] + 2 * a, 200)
        vec = drv.evaluate(tq)
        for i, x in enumerate(tq):
            scal = drv.evaluate(float(x))
            assert all(isinstance(q, float) for q in scal)
            np.testing.assert_allclose(scal, [vec[0][i], vec[1][i], vec[2][i]], rtol=0, atol=1e-12)


def test_shapes_and_convenience_methods():
    t = np.arange(0.0, 30.0)
    v = np.clip(np.sin(t / 5.0) * 10.0, 0.0, None)
    drv = SmoothingDriver(t, v, 2.0)
    tq = np.linspace(-5.0, 35.0, 24).reshape(4, 6)
    v_d, dv, ddv = drv.evaluate(tq)
    assert v_d.shape == dv.shape == ddv.shape == (4, 6)
    np.testing.assert_array_equal(drv.v_d(tq), v_d)
    np.testing.assert_array_equal(drv.dv_d(tq), dv)
    np.testing.assert_array_equal(drv.ddv_d(tq), ddv)
    np.testing.assert_allclose(drv.evaluate(tq.ravel())[0], v_d.ravel(), rtol=0, atol=0)
    assert isinstance(drv.v_d(3.5), float)
    assert isinstance(drv.v_d(np.float64(3.5)), float)
    assert isinstance(drv.v_d(np.int64(3)), float)
    assert drv.evaluate(np.array([]))[0].shape == (0,)


def test_chunked_evaluation_matches(monkeypatch):
    rng = np.random.default_rng(11)
    t, v = nedc_like(rng, n_phases=3, dt=None)
    drv = SmoothingDriver(t, v, 3.0)
    tq = rng.uniform(t[0] - 5, t[-1] + 5, 500)
    whole = drv.evaluate(tq)
    monkeypatch.setattr(smoothing_module, "_CHUNK", 7)
    chunked = drv.evaluate(tq)
    for x, y in zip(whole, chunked, strict=True):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-13)


def test_held_at_end_values_outside_the_cycle():
    t = np.array([0.0, 10.0, 20.0])
    v = np.array([2.0, 12.0, 7.0])  # does not start or end at rest
    a = 1.5
    drv = SmoothingDriver(t, v, a)
    before = drv.evaluate(np.array([-100.0, -a - 1e-9]))
    after = drv.evaluate(np.array([20.0 + a + 1e-9, 1e4]))
    np.testing.assert_allclose(before[0], 2.0, rtol=0, atol=1e-13)
    np.testing.assert_allclose(after[0], 7.0, rtol=0, atol=1e-13)
    for d in (before[1], before[2], after[1], after[2]):
        np.testing.assert_allclose(d, 0.0, rtol=0, atol=1e-13)
    np.testing.assert_allclose(drv.speed_trace([-5.0, 25.0]), [2.0, 7.0])


# --- properties -------------------------------------------------------------------------------------------

steps = st.lists(st.floats(0.2, 3.0), min_size=1, max_size=30)
half_widths = st.floats(0.05, 12.0)
unit = st.floats(0.0, 1.0)


@settings(max_examples=60, deadline=None)
@given(steps=steps, c=st.floats(-40.0, 60.0), a=half_widths, where=st.lists(unit, min_size=1, max_size=8))
def test_constant_speed_stays_constant(steps, c, a, where):
    t = np.concatenate([[0.0], np.cumsum(steps)])
    drv = SmoothingDriver(t, np.full(t.size, c), a)
    tq = t[0] - 2 * a + np.array(where) * (t[-1] - t[0] + 4 * a)
    v_d, dv, ddv = drv.evaluate(tq)
    np.testing.assert_allclose(v_d, c, rtol=1e-14, atol=1e-14)
    np.testing.assert_array_equal(dv, 0.0)
    np.testing.assert_array_equal(ddv, 0.0)


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(st.floats(0.2, 3.0), min_size=4, max_size=40),
    v0=st.floats(-30.0, 30.0),
    slope=st.floats(-4.0, 4.0),
    frac=st.floats(0.02, 0.9),
    where=st.lists(unit, min_size=1, max_size=8),
)
def test_linear_ramp_is_reproduced_away_from_its_ends(steps, v0, slope, frac, where):
    t = np.concatenate([[0.0], np.cumsum(steps)])
    a = max(frac * 0.5 * t[-1], 0.05)
    v = v0 + slope * t
    drv = SmoothingDriver(t, v, a)
    tq = np.clip(a + np.array(where) * (t[-1] - 2 * a), a, t[-1] - a)
    v_d, dv, ddv = drv.evaluate(tq)
    vscale = max(np.max(np.abs(v)), 1.0)
    dt_min = min(steps)
    # exact up to the rounding of the sampled ramp (slopes from differences of values ~ eps |v| / dt)
    np.testing.assert_allclose(v_d, v0 + slope * tq, rtol=0, atol=1e-12 * vscale)
    np.testing.assert_allclose(dv, slope, rtol=0, atol=1e-12 * vscale / dt_min)
    np.testing.assert_allclose(ddv, 0.0, rtol=0, atol=1e-12 * vscale / (dt_min * a))


@st.composite
def cycles_at_rest(draw, margin_over_a: float = 1.0):
    """(t, v, a): a random trace starting and ending at rest, standing still for > a at both ends."""
    a = draw(half_widths)
    inner = draw(st.lists(st.floats(0.0, 40.0), min_size=1, max_size=20))
    gaps = draw(st.lists(st.floats(0.2, 3.0), min_size=len(inner) + 1, max_size=len(inner) + 1))
    lead = margin_over_a * a + draw(st.floats(0.01, 3.0))
    tail = margin_over_a * a + draw(st.floats(0.01, 3.0))
    t_motion = lead + np.concatenate([[0.0], np.cumsum(gaps)])
    t = np.concatenate([[0.0], t_motion, [t_motion[-1] + tail]])
    v = np.concatenate([[0.0, 0.0], inner, [0.0, 0.0]])
    return t, v, a


@settings(max_examples=40, deadline=None)
@given(cyc=cycles_at_rest())
def test_smoothing_preserves_distance(cyc):
    t, v, a = cyc
    drv = SmoothingDriver(t, v, a)
    distance = float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t)))
    smoothed = gauss_legendre(drv.v_d, t[0], t[-1], h=a / 8)
    assert abs(smoothed - distance) <= 1e-9 * max(distance, 1e-300)


@settings(max_examples=40, deadline=None)
@given(cyc=cycles_at_rest(margin_over_a=0.0), where=st.lists(unit, min_size=2, max_size=6))
def test_derivatives_are_consistent(cyc, where):
    t, v, a = cyc
    drv = SmoothingDriver(t, v, a)
    tq = t[0] - a + np.array(where) * (t[-1] - t[0] + 2 * a)
    v_d, dv, ddv = drv.evaluate(tq)
    total_kink = np.sum(np.abs(slope_changes(t, v)))
    v_scale = max(np.max(v), 1.0)
    slope_scale = max(np.max(np.abs(np.diff(v) / np.diff(t))), 1e-3)
    # central differences: truncation <= h² max|f⁽³⁾| / 6, where |v_d⁽³⁾| <= Σ|Δm| max|k'_a| and
    # |dv_d⁽³⁾| <= Σ|Δm| max|k''_a|; plus the rounding of the difference quotient
    h = 1e-3 * a
    fd_v = (drv.v_d(tq + h) - drv.v_d(tq - h)) / (2 * h)
    fd_dv = (drv.dv_d(tq + h) - drv.dv_d(tq - h)) / (2 * h)
    tol_v = h**2 / 6 * total_kink * K1_MAX / a**2 + 1e-14 * v_scale / h
    tol_dv = h**2 / 6 * total_kink * K2_MAX / a**3 + 1e-14 * slope_scale / h
    np.testing.assert_allclose(fd_v, dv, rtol=0, atol=2 * tol_v)
    np.testing.assert_allclose(fd_dv, ddv, rtol=0, atol=2 * tol_dv)
    # and integrating the derivative back: v(t2) - v(t1) = ∫ dv, dv(t2) - dv(t1) = ∫ ddv
    t1, t2 = np.min(tq), np.max(tq)
    v1, dv1, _ = drv.evaluate(t1)
    v2, dv2, _ = drv.evaluate(t2)
    np.testing.assert_allclose(
        gauss_legendre(drv.dv_d, t1, t2, a / 16), v2 - v1, rtol=0, atol=1e-10 * v_scale
    )
    np.testing.assert_allclose(
        gauss_legendre(drv.ddv_d, t1, t2, a / 16), dv2 - dv1, rtol=0, atol=1e-10 * slope_scale
    )


@settings(max_examples=25, deadline=None)
@given(a=st.floats(0.01, 100.0), s=st.lists(st.floats(-1.2, 1.2), min_size=1, max_size=5))
def test_kernel_normalisation_antiderivative_and_moment(a, s):
    total = quad(lambda u: bump_kernel(u, a), -a, a, epsabs=0.0, epsrel=1e-13)[0]
    assert abs(total - 1.0) <= 1e-12
    assert bump_normalisation(a) == pytest.approx(a * C1, rel=1e-14)
    assert bump_kernel_cdf(-a, a) == 0.0
    assert bump_kernel_cdf(0.0, a) == pytest.approx(0.5, abs=1e-15)
    assert bump_kernel_cdf(a, a) == 1.0
    assert bump_kernel_moment(-a, a) == 0.0
    assert bump_kernel_moment(a, a) == 0.0
    for x in np.array(s) * a:
        # quad over the lower flank up to -|x| (G(x) = 1 - G(-x), M(x) = M(-x) by symmetry)
        y = min(abs(x), a)
        flank, m_ref = 0.0, 0.0
        if y < a:
            flank = quad(lambda u: bump_kernel(u, a), -a, -y, epsabs=1e-14, epsrel=1e-13)[0]
            m_ref = quad(lambda u: u * bump_kernel(u, a), -a, -y, epsabs=1e-14 * a, epsrel=1e-13)[0]
        g_ref = flank if x < 0 else 1.0 - flank
        assert abs(bump_kernel_cdf(x, a) - g_ref) <= 1e-13
        assert abs(bump_kernel_moment(x, a) - m_ref) <= 1e-13 * a
    # the analytic kernel derivatives
    x = np.array(s) * a * 0.8
    for d in (1, 2):
        h = 1e-5 * a
        fd = (bump_kernel(x + h, a, d - 1) - bump_kernel(x - h, a, d - 1)) / (2 * h)
        np.testing.assert_allclose(bump_kernel(x, a, d), fd, rtol=0, atol=1e-6 / a ** (d + 1))


def test_kernel_is_scale_invariant_and_vectorised():
    r = np.linspace(0.0, 1.3, 51)
    s = np.concatenate([-r[::-1], r[1:]])  # exactly symmetric
    for a in (0.1, 2.0, 7.5):
        np.testing.assert_allclose(bump_kernel_cdf(s * a, a), bump_kernel_cdf(s), rtol=0, atol=1e-15)
        np.testing.assert_allclose(
            bump_kernel_moment(s * a, a), a * bump_kernel_moment(s), rtol=1e-13, atol=1e-16 * a
        )
        np.testing.assert_allclose(bump_kernel(s * a, a), bump_kernel(s) / a, rtol=1e-12, atol=0)
    g = bump_kernel_cdf(s)
    assert np.all(np.diff(g) >= 0.0)
    np.testing.assert_allclose(g + g[::-1], 1.0, rtol=0, atol=1e-15)
    m = bump_kernel_moment(s)
    np.testing.assert_array_equal(m, m[::-1])
    assert np.all(m <= 0.0)


# --- limits ---------------------------------------------------------------------------------------------


def test_small_half_width_approaches_the_cycle():
    rng = np.random.default_rng(7)
    t, v = nedc_like(rng, n_phases=5)
    tq = np.concatenate([rng.uniform(t[0], t[-1], 400), t])  # v_d - v_c is largest at the samples
    vc = np.interp(tq, t, v)
    dm_max = np.max(np.abs(slope_changes(t, v)))
    errors = []
    for a in (0.3, 1e-1, 1e-2, 1e-3, 1e-5):
        drv = SmoothingDriver(t, v, a)
        v_d, dv, _ = drv.evaluate(tq)
        err = np.max(np.abs(v_d - vc))
        # for a < 0.5 s at most one kink lies within ±a of t, and |v_d - v_c| <= |Δm| a |M_1(0)|, with
        # equality at the kink itself: the error is exactly proportional to a
        assert err == pytest.approx(dm_max * a * abs(bump_kernel_moment(0.0)), rel=1e-6)
        far = np.min(np.abs(tq[:, None] - t[None, :]), axis=1) > a
        slope = np.diff(v)[np.searchsorted(t, tq[far]) - 1] / np.diff(t)[np.searchsorted(t, tq[far]) - 1]
        np.testing.assert_allclose(dv[far], slope, rtol=0, atol=1e-12)
        errors.append(err)
    assert errors[-1] < 1e-5 * np.max(v)


# --- bad input ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "time_s, speed_mps, a",
    [
        ([0, 1, 2], [0, 1, 0], 0.0),
        ([0, 1, 2], [0, 1, 0], -1.0),
        ([0, 1, 2], [0, 1, 0], float("nan")),
        ([0, 1, 2], [0, 1, 0], float("inf")),
        ([0, 1, 2], [0, 1, 0], "wide"),
        ([0, 1, 1], [0, 1, 0], 1.0),
        ([0, 2, 1], [0, 1, 0], 1.0),
        ([0, 1, 2], [0, 1], 1.0),
        ([0.0], [0.0], 1.0),
        ([0, 1, 2], [0, float("nan"), 0], 1.0),
        ([0, float("inf"), 2], [0, 1, 0], 1.0),
        ([[0, 1], [2, 3]], [[0, 1], [1, 0]], 1.0),
        (["a", "b"], [0, 1], 1.0),
    ],
)
def test_bad_inputs_raise_one_line_errors(time_s, speed_mps, a):
    with pytest.raises(VpsimError) as info:
        SmoothingDriver(time_s, speed_mps, a)
    assert "\n" not in str(info.value) and str(info.value)


def test_bad_evaluation_times_and_kernel_arguments():
    drv = SmoothingDriver([0.0, 1.0, 2.0], [0.0, 1.0, 0.0], 0.5)
    for bad in (float("nan"), float("inf"), np.array([0.5, np.nan]), "soon"):
        with pytest.raises(VpsimError):
            drv.evaluate(bad)
    with pytest.raises(VpsimError):
        bump_kernel(0.0, 1.0, derivative=3)
    with pytest.raises(VpsimError):
        bump_kernel_cdf(0.0, a=0.0)
    with pytest.raises(VpsimError):
        smooth_reference([0.0, 1.0], [0.0, 1.0], -1.0, 0.5)


def test_inputs_are_copied_and_read_only():
    t = np.array([0.0, 1.0, 2.0])
    v = np.array([0.0, 3.0, 0.0])
    drv = SmoothingDriver(t, v, 0.5)
    v[1] = 100.0
    assert drv.v_d(1.0) < 3.0
    with pytest.raises(ValueError):
        drv.speed_mps[1] = 5.0
    with pytest.raises(AttributeError):
        drv.a = 2.0


@settings(max_examples=200, deadline=None)
@given(
    t0=st.floats(-100.0, 100.0),
    steps=st.lists(st.floats(1e-3, 10.0), min_size=0, max_size=40),
    max_step=st.floats(0.01, 3.0),
)
def test_inverse_grid_is_each_interval_split_as_linspace_does(t0, steps, max_step):
    """The electric and hybrid inverse methods' grid, built in one pass, is np.linspace's split of each
    interval into the fewest equal parts no longer than max_step, to the bit, and ends at the last sample."""
    time_s = t0 + np.concatenate([[0.0], np.cumsum(steps)])
    time_s = time_s[np.concatenate([[True], np.diff(time_s) > 0.0])]  # strictly increasing after rounding
    grid = smoothing_module.inverse_grid(time_s, max_step)
    dt = np.diff(time_s)
    parts = np.maximum(1, np.ceil(dt / max_step - 1e-12).astype(np.int64))
    expected = [np.linspace(time_s[k], time_s[k + 1], parts[k] + 1)[:-1] for k in range(dt.size)]
    assert np.array_equal(grid, np.concatenate([*expected, time_s[-1:]]))
    assert np.all(np.diff(grid) <= max_step * (1.0 + 1e-9))
