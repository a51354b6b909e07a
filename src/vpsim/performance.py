"""Acceleration performance: the 0-100 km/h time at full throttle, from the forward dynamic model.

The figure a designer trades against fuel consumption. The model is the forward dynamic model of the paper
(states v and p_i) with the throttle wide open, A_eff = A_max, integrating

* the intake manifold (9): dp_i/dt = (R T_i / V_i) [mdot_at(A_max, p_i) - w_e m_ac(p_i) / (2 pi n_r)],
* the vehicle (18) with the engine inertia (1),(14)-(17): m_eq dv/dt = i eta_tm T_cr(p_i, w_e) / r - F_road,

with the functions of :mod:`vpsim.model`. Gears and launch:

* **Launch** (``launch_speed``, default :data:`LAUNCH_SPEED` = 250 rad/s, about 2400 rpm). The paper's stiff
  driveline cannot start from standstill (w_e = 0 at v = 0, as in the ``paper`` mode of the backward method),
  so the start is a clutch-slip launch like the ``extended`` mode: the driver holds the engine at
  ``launch_speed`` with the throttle open, the manifold starts at its full-throttle steady state there (the
  FQM), and the slipping clutch passes the crank torque T_cr(p_i, w_launch) to gear 1 (the engine speed is
  constant, so the engine inertia takes nothing: m dv/dt = i_1 eta_tm T_cr / r - F_road). The clutch locks
  when the wheel side reaches the launch speed (i_1 v / r = w_launch); from then on the driveline is stiff.
* **Upshifts** at a stated engine speed ``shift_speed`` (rad/s). Default: ``shift_fraction`` (0.9) x the
  max-power speed, the speed of the largest power T_max(w) w on the max-torque line (the FQM at A_max)
  within the engine's ``map_speed_range``. The mean-value model has no rev limit and its power still rises at
  the top of that range for the reference engine, so the upper end of ``map_speed_range`` is taken as the rev
  limit: the max-power speed is searched below it, and the engine is not run above it. A shift is
  instantaneous with no torque interruption (stiff driveline, no clutch model during shifts); the engine
  speed drops to the next gear's w_e = i v / r, v and p_i are continuous. A ``shift_speed`` above the rev
  limit is lowered to it.
* No wheel slip and no traction limit (the paper's rigid tyre): a design with much torque in gear 1 launches
  as hard as its engine allows.
* **Not reached**: the time is ``inf`` with a reason when the car cannot launch (road load above the launch
  force), when it stops accelerating below the target speed (``min_acceleration``), when the engine meets
  the rev limit in the top gear, or after ``t_max`` seconds.

The manifold is stiff at full throttle (dPsi/dp_r -> -inf as p_i -> p_a, time constant of some 10 ms against
the vehicle's seconds), so the integrator is the L-stable linearly implicit Rosenbrock method ROS2 (Verwer,
Spee, Blom & Hundsdorfer 1999) with a fixed step ``dt`` (default 50 ms), run on many designs at once (the
model's equations broadcast over an array of parameter records). Every event is a speed threshold (clutch
lock-up,
upshift, rev limit, target), so a step that would pass one is shortened to land on it. The time agrees
with an adaptive implicit solver with event location (scipy Radau, rtol 1e-8) to about 1 ms (see the tests).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import VpsimError
from .model import electric as el
from .model import engine as en
from .model import hybrid as hy
from .model import vehicle as vh
from .model._compile import kernel
from .model.record import fields, record_array

LAUNCH_SPEED = 250.0  # rad/s, engine speed held while the clutch slips at launch
SHIFT_FRACTION = 0.9  # default upshift speed as a fraction of the max-power speed
TARGET_KMH = 100.0
_G = 1.0 + 1.0 / np.sqrt(2.0)  # gamma of ROS2
BOOST_STEP = 2.0  # rad/s: the spacing of a P2 hybrid's boost-torque table


@dataclass(frozen=True)
class Acceleration:
    """Outcome of a full-throttle run from standstill.

    ``time_s`` is the time to ``target_kmh`` (``inf`` if not reached, with ``reason`` saying why; ``reason``
    is empty when reached). ``series`` (only with ``keep_series=True``) holds time, speed, gear, engine
    speed and intake pressure at every step.
    """

    time_s: float
    reason: str
    target_kmh: float
    launch_speed: float  # rad/s
    shift_speed: float  # rad/s
    shift_times_s: tuple[float, ...] = ()
    series: dict = field(default_factory=dict, repr=False)

    @property
    def reached(self) -> bool:
        return bool(np.isfinite(self.time_s))


def max_power_speed(eng, *, n: int = 301) -> float:
    """Engine speed (rad/s) of the largest power on the max-torque line within ``eng.map_speed_range``."""
    lo, hi = eng.map_speed_range
    w = np.linspace(lo, hi, n)
    from .model.maps import max_torque

    return float(w[np.argmax(max_torque(w, eng) * w)])


def acceleration_time(
    params,
    *,
    target_kmh: float = TARGET_KMH,
    shift_speed: float | None = None,
    shift_fraction: float = SHIFT_FRACTION,
    launch_speed: float = LAUNCH_SPEED,
    dt: float = 0.05,
    t_max: float = 60.0,
    min_acceleration: float = 0.01,
    keep_series: bool = False,
) -> Acceleration:
    """Time from standstill to ``target_kmh`` at full throttle for one parameter set (module docstring)."""
    return acceleration_times(
        [params],
        target_kmh=target_kmh,
        shift_speed=shift_speed,
        shift_fraction=shift_fraction,
        launch_speed=launch_speed,
        dt=dt,
        t_max=t_max,
        min_acceleration=min_acceleration,
        keep_series=keep_series,
    )[0]


def acceleration_times(
    params_list,
    *,
    target_kmh: float = TARGET_KMH,
    shift_speed=None,
    shift_fraction: float = SHIFT_FRACTION,
    launch_speed=LAUNCH_SPEED,
    dt: float = 0.05,
    t_max: float = 60.0,
    min_acceleration: float = 0.01,
    keep_series: bool = False,
) -> list[Acceleration]:
    """:func:`acceleration_time` for many parameter sets at once, integrated side by side.

    Designs that are done drop out of the arrays (whenever half of them are), so a slow design does not make
    the others pay for its steps."""
    n = len(params_list)
    if n == 0:
        return []
    if not target_kmh > 0:
        raise ValueError(f"target_kmh must be positive, got {target_kmh!r}")
    if not 0 < shift_fraction <= 1.0:
        raise ValueError(f"shift_fraction must be in (0, 1], got {shift_fraction!r}")
    if not dt > 0:
        raise ValueError(f"dt must be positive, got {dt!r}")
    w_launch = np.broadcast_to(np.asarray(launch_speed, float), (n,)).copy()
    if np.any(w_launch <= 0):
        raise ValueError(f"launch_speed must be positive, got {launch_speed!r}")
    rev_limit = np.array([p.engine.map_speed_range[1] for p in params_list])
    if shift_speed is None:
        w_shift = np.array([shift_fraction * max_power_speed(p.engine) for p in params_list])
    else:
        w_shift = np.broadcast_to(np.asarray(shift_speed, float), (n,)).copy()
    w_shift = np.minimum(w_shift, rev_limit)  # never above the rev limit
    n_g = np.array([p.transmission.n_gears for p in params_list])
    ratios = np.full((n, int(n_g.max())), np.nan)
    for k, p in enumerate(params_list):
        ratios[k, : n_g[k]] = p.transmission.ratios
    boost, rotor_inertia = _boost_tables(params_list)
    full = _Designs(
        rec=np.concatenate([record_array(p) for p in params_list]).view(np.recarray),
        ratios=ratios,
        n_g=n_g,
        rev_limit=rev_limit,
        w_shift=w_shift,
        w_launch=w_launch,
        boost=boost,
        rotor_inertia=rotor_inertia,
    )
    state = _State.start(full)
    reason = np.array([""] * n, dtype=object)
    dv0, _ = full.deriv(state.v, state.p, ratios[:, 0], state.slip)
    stuck = dv0 <= 0
    reason[stuck] = "cannot launch: the clutch-slip force at the launch speed is below the road load"
    low = ~stuck & (w_shift <= w_launch)
    reason[low] = [f"shift speed {ws:.0f} rad/s is not above the launch speed" for ws in w_shift[low]]
    state.done |= stuck | low
    shifts: list[list[float]] = [[] for _ in range(n)]
    rows: list = []
    settings = (target_kmh / 3.6, float(dt), t_max, min_acceleration)
    while not state.done.all():
        sel = np.flatnonzero(~state.done)
        sub = full if sel.size == n else full.subset(sel)
        st = state if sel.size == n else state.subset(sel)
        _integrate(
            sub,
            st,
            settings,
            reason_out=(reason, sel),
            shifts=(shifts, sel),
            rows=rows if keep_series else None,
            compact=not keep_series,
        )
        if st is not state:
            state.put(sel, st)
    out = []
    for k in range(n):
        series = {}
        if keep_series and rows:
            series = {
                "time_s": np.array([r[0][k] for r in rows]),
                "speed_mps": np.array([r[1][k] for r in rows]),
                "gear": np.array([r[2][k] for r in rows]),
                "engine_speed_radps": np.array([r[3][k] for r in rows]),
                "intake_pressure_pa": np.array([r[4][k] for r in rows]),
            }
        out.append(
            Acceleration(
                time_s=float(state.t_hit[k]),
                reason="" if np.isfinite(state.t_hit[k]) else str(reason[k]),
                target_kmh=float(target_kmh),
                launch_speed=float(w_launch[k]),
                shift_speed=float(w_shift[k]),
                shift_times_s=tuple(shifts[k]),
                series=series,
            )
        )
    return out


@dataclass
class _Designs:
    """Per-design parameter records and settings (one entry per design) and the model's right-hand side."""

    rec: np.ndarray  # vpsim.model.record records, one per design
    ratios: np.ndarray  # (designs, gears) total ratios, NaN beyond a design's gears
    n_g: np.ndarray
    rev_limit: np.ndarray
    w_shift: np.ndarray
    w_launch: np.ndarray
    boost: np.ndarray  # (designs, BOOST_POINTS): a P2 machine's boost torque on BOOST_STEP speeds; 0 without
    rotor_inertia: np.ndarray  # the P2 machine's rotor, kg m^2 (0 without)

    def __post_init__(self):
        # the equations below read the records' fields as plain attributes (vpsim.model.record.fields: the
        # same column arrays; a recarray's attribute look-up took most of a sweep's time); the compiled
        # manifold rate takes the records themselves
        self.c = fields(self.rec)

    def subset(self, sel) -> _Designs:
        return _Designs(
            self.rec[sel],
            self.ratios[sel],
            self.n_g[sel],
            self.rev_limit[sel],
            self.w_shift[sel],
            self.w_launch[sel],
            self.boost[sel],
            self.rotor_inertia[sel],
        )

    def _boost(self, w_m):
        """The P2 machine's boost torque at input speed w_m, linear in the table (0 beyond it)."""
        x = np.clip(w_m / BOOST_STEP, 0.0, self.boost.shape[1] - 1.0)
        j = np.minimum(x.astype(int), self.boost.shape[1] - 2)
        f = x - j
        rows = np.arange(w_m.size)
        return self.boost[rows, j] * (1.0 - f) + self.boost[rows, j + 1] * f

    def _engine_speed(self, v, i, slip):
        return np.where(slip, self.w_launch, vh.engine_speed(v, i, self.c))  # (14),(17); launch: clutch slips

    def deriv(self, v, p, i, slip):
        """(dv/dt, dp_i/dt) at full throttle: (18) with (1),(14)-(17), and (9)."""
        c = self.c
        w_e = self._engine_speed(v, i, slip)
        t_cr = en.crank_torque(p, w_e, c)  # (2)-(8)
        # a P2 hybrid's machine turns with the gearbox input (behind the slipping clutch at launch) and adds
        # its boost torque there; its rotor's inertia is seen at the wheels (E1). Both 0 without a machine
        w_m = vh.engine_speed(v, i, c)
        t_in = t_cr + self._boost(w_m)
        rotor = el.rotor_mass(i, True, c, _Rotor(self.rotor_inertia))
        m_eff = np.where(slip, c.mass, vh.equivalent_mass(i, c)) + rotor
        # launching forward: rolling resistance acts from the start (as static friction it holds a car whose
        # drive force is smaller: see the ``stuck`` check)
        road = vh.aero_force(v, c) + vh.rolling_force_in_motion(v, c)
        dv = (vh.engine_to_wheel_force(t_in, i, c) - road) / m_eff
        dp, _ = en.manifold_pressure_rate_array(p, c.max_throttle_area, w_e, self.rec)
        return dv, dp

    def step(self, v, p, i, slip, h, f1):
        """One step of the L-stable linearly implicit Rosenbrock method ROS2 (Verwer et al. 1999);
        ``f1`` is the right-hand side at (v, p)."""
        f1v, f1p = f1
        dv_ = 1e-6 * np.maximum(v, 1.0)
        fvv, fvp = self.deriv(v + dv_, p, i, slip)
        fpv, _ = self.deriv(v, p + 1.0, i, slip)  # dv/dt is affine in p_i
        j11, j21, j12 = (fvv - f1v) / dv_, (fvp - f1p) / dv_, fpv - f1v
        # d(dp_i/dt)/dp_i, analytic: the throttle term is singular as p_i -> p_a (9),(10),(13)
        w_e = self._engine_speed(v, i, slip)
        _, j22 = en.manifold_pressure_rate_array(p, self.c.max_throttle_area, w_e, self.rec)
        m11, m12, m21, m22 = 1.0 - _G * h * j11, -_G * h * j12, -_G * h * j21, 1.0 - _G * h * j22
        det = m11 * m22 - m12 * m21
        k1v, k1p = (m22 * f1v - m12 * f1p) / det, (m11 * f1p - m21 * f1v) / det
        f2v, f2p = self.deriv(v + h * k1v, p + h * k1p, i, slip)
        b1, b2 = f2v - 2.0 * k1v, f2p - 2.0 * k1p
        k2v, k2p = (m22 * b1 - m12 * b2) / det, (m11 * b2 - m21 * b1) / det
        return v + h * (1.5 * k1v + 0.5 * k2v), p + h * (1.5 * k1p + 0.5 * k2p)


@dataclass(frozen=True)
class _Rotor:
    """The field of the electric record :func:`vpsim.model.electric.rotor_mass` reads, as an array."""

    machine_inertia: np.ndarray


def _boost_tables(params_list):
    """(boost torque table, rotor inertia) of every design: a P2 hybrid's machine at its envelope limit cut to
    the pack's discharge limit at ``battery.soc_initial`` (:func:`vpsim.model.hybrid.boost_torque`), on speeds
    0, BOOST_STEP, ... up to its top speed; zeros for a car without one. A power split is refused."""
    n = len(params_list)
    top = [p.machine.max_speed for p in params_list if p.powertrain.type == "hev_p2"]
    n_w = int(np.ceil(max(top, default=0.0) / BOOST_STEP)) + 2
    table = np.zeros((n, n_w))
    inertia = np.zeros(n)
    speeds = np.arange(n_w) * BOOST_STEP
    for k, p in enumerate(params_list):
        kind = p.powertrain.type
        if kind == "hev_split":
            raise VpsimError(
                "0-100 km/h of the power-split hybrid is not modelled (the conventional car and the P2 "
                "hybrid are); switch the acceleration objective off"
            )
        if kind == "bev":
            raise VpsimError("0-100 km/h of the battery-electric car is not modelled (the engine cars are)")
        if kind != "hev_p2":
            continue
        e, m, tabs = el.electric_records(p)
        _boost_kernel(speeds, p.battery.soc_initial, e, m, tabs.astuple(), table[k])
        inertia[k] = p.machine.inertia
    return table, inertia


@kernel(_nrt=False)
def _boost_kernel(speeds, soc, e, m, tabs, out):
    """out[j] = the P2 machine's boost torque at speeds[j] (:func:`vpsim.model.hybrid.boost_torque`)."""
    for j in range(speeds.size):
        out[j] = hy.boost_torque(speeds[j], soc, e, m, tabs)


@dataclass
class _State:
    v: np.ndarray
    p: np.ndarray
    t: np.ndarray
    gear: np.ndarray
    slip: np.ndarray
    done: np.ndarray
    t_hit: np.ndarray

    @classmethod
    def start(cls, d: _Designs) -> _State:
        n = d.rec.size
        p0, _ = en.steady_pressure_array(d.c.max_throttle_area, d.w_launch, d.rec)
        return cls(
            np.zeros(n),
            p0,
            np.zeros(n),
            np.ones(n, dtype=int),
            np.ones(n, bool),
            np.zeros(n, bool),
            np.full(n, np.inf),
        )

    def subset(self, sel) -> _State:
        return _State(
            *(getattr(self, f)[sel].copy() for f in ("v", "p", "t", "gear", "slip", "done", "t_hit"))
        )

    def put(self, sel, other: _State) -> None:
        for f in ("v", "p", "t", "gear", "slip", "done", "t_hit"):
            getattr(self, f)[sel] = getattr(other, f)


def _integrate(d: _Designs, st: _State, settings, *, reason_out, shifts, rows, compact: bool) -> None:
    """Step the designs of ``st`` until all are done, or (``compact``) until half of them are."""
    v_target, h, t_max, min_acceleration = settings
    reason, sel_r = reason_out
    shift_lists, sel_s = shifts
    n = st.v.size
    idx = np.arange(n)
    r_w = d.c.wheel_radius
    i = d.ratios[idx, st.gear - 1]
    f = d.deriv(st.v, st.p, i, st.slip)
    while not st.done.all():
        if compact and st.done.sum() * 2 >= n and n > 8:
            return
        if rows is not None:
            rows.append(
                (
                    st.t.copy(),
                    st.v.copy(),
                    st.gear.copy(),
                    d._engine_speed(st.v, i, st.slip),
                    st.p.copy(),
                )
            )
        # the next event is a speed threshold: clutch lock-up, upshift, rev limit in top gear, or the target
        top = st.gear == d.n_g
        v_event = np.where(st.slip, d.w_launch * r_w / i, np.where(top, d.rev_limit, d.w_shift) * r_w / i)
        v_event = np.minimum(v_event, v_target)
        acc = f[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_event = np.where(acc > 0, (v_event - st.v) / acc, np.inf)
        # land on the event (a hair past it) instead of stepping over it
        h_k = np.where(t_event < h, t_event * (1.0 + 1e-6) + 1e-9, h)
        v_new, p_new = d.step(st.v, st.p, i, st.slip, h_k, f)
        keep = ~st.done
        st.v = np.where(keep, v_new, st.v)
        st.p = np.where(keep, p_new, st.p)
        st.t = np.where(keep, st.t + h_k, st.t)
        crossed = keep & (st.v >= v_event - 1e-9)
        hit = crossed & (v_event >= v_target)
        st.t_hit[hit] = st.t[hit]
        st.done |= hit
        act = ~st.done
        lock = act & crossed & st.slip
        st.slip &= ~lock
        up = act & crossed & ~lock & ~top
        for k in np.flatnonzero(up):
            shift_lists[sel_s[k]].append(float(st.t[k]))
        st.gear = np.where(up, st.gear + 1, st.gear)
        over = act & crossed & ~lock & top
        reason[sel_r[over]] = [f"rev limit in top gear at {vk * 3.6:.0f} km/h" for vk in st.v[over]]
        st.done |= over
        act = ~st.done
        i = d.ratios[idx, st.gear - 1]
        f = d.deriv(st.v, st.p, i, st.slip)  # also the next step's first stage
        flat = act & (f[0] < min_acceleration)
        reason[sel_r[flat]] = [
            f"stops accelerating at {vk * 3.6:.0f} km/h in gear {g}"
            + (" with the clutch slipping" if sl else "")
            for vk, g, sl in zip(st.v[flat], st.gear[flat], st.slip[flat], strict=True)
        ]
        st.done |= flat
        late = ~st.done & (st.t >= t_max)
        reason[sel_r[late]] = f"not reached within {t_max:g} s"
        st.done |= late
