"""The one result type every method returns: time series, summary, energy bookkeeping; print, plot, tabulate.

>>> import vpsim
>>> r = vpsim.simulate("nedc", method="backward")
>>> r.summary()["fuel_l_per_100km"] > 0
True
>>> df = r.to_dataframe()          # one row per time sample
>>> fig = r.plot()                 # speed, gear, engine torque/speed, intake pressure, fuel flow
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from .model.record import memo

# name -> unit; the order is the DataFrame's column order
SERIES = {
    "time_s": "s",
    "reference_speed_mps": "m/s",
    "speed_mps": "m/s",
    "accel_mps2": "m/s^2",
    "gear": "-",
    "gearbox_ratio": "-",
    "engine_speed_radps": "rad/s",
    "crank_torque_nm": "N m",
    "engine_torque_nm": "N m",
    "intake_pressure_pa": "Pa",
    "throttle_area_m2": "m^2",
    "fuel_flow_kgps": "kg/s",
    "fuel_flow_used_kgps": "kg/s",
    "brake_force_n": "N",
}


def _one_update_init(cls):
    """Give the frozen dataclass ``cls`` an ``__init__`` that fills the instance's ``__dict__`` in one update.

    The generated one calls ``object.__setattr__`` once per field (a frozen class's only way past its own
    ``__setattr__``): for :class:`Result`'s 18 fields about 3 of the 20 us of Python around a backward run,
    which every run pays (``vpsim bench``'s linearity: a call's fixed cost). The same parameters, defaults
    and default factories (a fresh object per call), then ``__post_init__`` as before; a field the
    generated ``__init__`` would treat otherwise (``init=False``, keyword-only) is refused here.
    """
    fields = dataclasses.fields(cls)
    if any(not f.init or f.kw_only for f in fields):
        raise TypeError(f"{cls.__name__}: init=False and keyword-only fields are not supported")
    ns = {"_MISSING": dataclasses.MISSING}
    params, items = [], []
    for f in fields:
        value = f.name
        if f.default is not dataclasses.MISSING:
            ns[f"_default_{f.name}"] = f.default
            params.append(f"{f.name}=_default_{f.name}")
        elif f.default_factory is not dataclasses.MISSING:
            ns[f"_factory_{f.name}"] = f.default_factory
            params.append(f"{f.name}=_MISSING")
            value = f"_factory_{f.name}() if {f.name} is _MISSING else {f.name}"
        else:
            params.append(f.name)
        items.append(f"{f.name!r}: {value}")
    src = f"def __init__(self, {', '.join(params)}):\n    self.__dict__.update({{{', '.join(items)}}})\n"
    if hasattr(cls, "__post_init__"):
        src += "    self.__post_init__()\n"
    exec(src, ns)  # noqa: S102 - source built above from the class's own field names
    init = ns["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__module__ = cls.__module__
    cls.__init__ = init
    return cls


@_one_update_init
@dataclass(frozen=True)
class EnergyBalance:
    """Energy bookkeeping over a run (J), from the model's own quantities.

    indicated = friction + pumping + engine_kinetic + driveline_loss + vehicle_kinetic + aero + rolling
                + brake - trace_miss + idle_control  (+ residual)

    ``indicated`` is the work of the model's own fuel flow before the idle floor (q_hv eta_th int mdot_f dt);
    ``driveline_loss`` is (1 - eta_tm) int T_e w_e dt, negative while the engine brakes (the paper's constant
    efficiency applies both ways); ``trace_miss`` is the work the cycle asked for that the engine could not
    give (backward method at the max-torque line); ``idle_control`` is the work of the idealised idle
    governor that holds a declutched engine at idle speed when its crank torque is negative (forward method,
    extended mode).
    """

    indicated: float
    friction: float
    pumping: float
    engine_kinetic: float
    driveline_loss: float
    vehicle_kinetic: float
    aero: float
    rolling: float
    brake: float = 0.0
    trace_miss: float = 0.0
    idle_control: float = 0.0
    accessories: float = 0.0

    @property
    def consumers(self) -> float:
        return (
            self.friction
            + self.pumping
            + self.engine_kinetic
            + self.driveline_loss
            + self.vehicle_kinetic
            + self.aero
            + self.rolling
            + self.brake
            - self.trace_miss
            + self.idle_control
            + self.accessories
        )

    @property
    def residual(self) -> float:
        return self.indicated - self.consumers

    @property
    def relative_residual(self) -> float:
        return abs(self.residual) / abs(self.indicated) if self.indicated else float("nan")

    def as_dict(self) -> dict[str, float]:
        d = asdict(self)
        d["residual"] = self.residual
        d["relative_residual"] = self.relative_residual
        return d

    def __str__(self) -> str:
        rows = [f"  {k:<16} {v / 1e3:12.2f} kJ" for k, v in asdict(self).items()]
        rows.append(
            f"  {'residual':<16} {self.residual / 1e3:12.2f} kJ ({self.relative_residual:.2e} of indicated)"
        )
        return "EnergyBalance\n" + "\n".join(rows)


@dataclass(frozen=True)
class ElectricBalance:
    """Energy bookkeeping of an electric powertrain over a run (J), by name
    (:data:`vpsim.methods.bev.ELECTRIC_TERMS`):

    chemical (+ indicated) = battery_loss + accessories + machine_loss + rotor_kinetic + driveline_loss
                             + vehicle_kinetic + aero + rolling + brake - trace_miss - unserved
                             (+ friction + pumping + engine_kinetic)  (+ residual)

    ``chemical`` is the energy the pack's stored charge gave (U_oc I; negative when the run charged it); a
    hybrid's engine adds its ``indicated`` work as a source and its friction, pumping and kinetic terms;
    ``unserved`` the electric power asked beyond the pack's limits (an empty pack's accessories).
    """

    terms: dict

    SOURCES = ("chemical", "indicated")  # a hybrid's engine is a source beside the battery
    NEGATIVE = ("trace_miss", "unserved")

    @property
    def consumers(self) -> float:
        t = self.terms
        rest = sum(v for k, v in t.items() if k not in self.SOURCES + self.NEGATIVE)
        return rest - sum(t.get(k, 0.0) for k in self.NEGATIVE)

    @property
    def residual(self) -> float:
        return sum(self.terms.get(k, 0.0) for k in self.SOURCES) - self.consumers

    @property
    def relative_residual(self) -> float:
        scale = sum(abs(v) for v in self.terms.values())
        return self.residual / scale if scale > 0 else float("nan")

    def as_dict(self) -> dict[str, float]:
        return {**self.terms, "residual": self.residual}

    def __str__(self) -> str:
        parts = ", ".join(f"{k} {v / 3.6e3:.2f}" for k, v in self.terms.items())
        return f"{parts} Wh (relative residual {self.relative_residual:.1e})"


# summary keys of an electric powertrain; NaN (null in JSON, with the reason) for a car without one
ELECTRIC_KEYS = ("electric_wh_per_km", "wall_wh_per_km", "mpge", "soc_start", "soc_end", "regen_wh")
# a hybrid's further figures (NaN for other cars, but the charge-sustaining fuel of an engine car: its fuel)
HYBRID_KEYS = ("fuel_l_per_100km_cs", "engine_starts")


@_one_update_init
@dataclass(frozen=True)
class TraceMiss:
    """Where the powertrain could not do what the cycle (or driver) asked.

    ``seconds``: time the demand was not met; ``max_torque_shortfall_nm``: largest crank-torque deficit at
    the max-torque line; ``max_speed_error_mps``: largest |v - v_ref| for methods that do not track exactly;
    ``infeasible_throttle_s``: time the inverse method's throttle left [A_min, A_max].
    """

    seconds: float = 0.0
    max_torque_shortfall_nm: float = 0.0
    max_speed_error_mps: float = 0.0
    infeasible_throttle_s: float = 0.0
    details: dict = field(default_factory=dict)

    def __str__(self) -> str:
        if self.seconds == 0 and self.infeasible_throttle_s == 0:
            return "none"
        parts = [f"{self.seconds:g} s"]
        if self.max_torque_shortfall_nm:
            parts.append(f"max torque shortfall {self.max_torque_shortfall_nm:.1f} N m")
        if self.max_speed_error_mps:
            parts.append(f"max speed error {self.max_speed_error_mps:.3f} m/s")
        if self.infeasible_throttle_s:
            parts.append(f"throttle outside [A_min, A_max] {self.infeasible_throttle_s:g} s")
        return ", ".join(parts)


BAND_KMH = 2.0  # the regulations' speed tolerance (UN ECE R83 / EPA: +-2 km/h resp. +-2 mph)
# the core columns every method's time series has (at the cycle's samples); methods add their own extras
MAX_STEPPED_GEARS = 20  # gears of a stepped gearbox at most (the parameter check's limit)
CORE_COLUMNS = tuple(SERIES) + ("torque_shortfall_nm", "clutch_engaged")


@dataclass(frozen=True)
class Deviations:
    """Where a run left what the cycle asked or what physics allows, in seconds of the cycle.

    * speed not followed: ``speed_not_followed_s`` (|v - v_cycle| beyond the +-2 km/h band) and
      ``max_speed_error_mps``;
    * demand not deliverable, per cause: ``torque_beyond_full_load_s`` (with ``max_torque_shortfall_nm``),
      ``throttle_below_minimum_s`` (deceleration beyond engine braking without brakes),
      ``engine_speed_out_of_range_s`` (above the engine's top speed); ``demand_not_deliverable_s`` is the time
      any of them holds;
    * states outside physics: ``negative_intake_pressure_s``, ``negative_fuel_flow_s`` (the model's flow
      below zero: an air charge below zero), plus overspeed and speed error above.

    The same names are the keys of ``Result.summary()`` (the CLI's ``--json``) and the flag columns of
    ``Result.to_dataframe()``. ``None`` where a run kept no time series to assess.
    """

    speed_not_followed_s: float | None = 0.0
    max_speed_error_mps: float = 0.0
    demand_not_deliverable_s: float | None = 0.0
    torque_beyond_full_load_s: float | None = 0.0
    max_torque_shortfall_nm: float = 0.0
    throttle_below_minimum_s: float | None = 0.0
    engine_speed_out_of_range_s: float | None = 0.0
    max_engine_speed_radps: float | None = 0.0
    negative_intake_pressure_s: float | None = 0.0
    negative_fuel_flow_s: float | None = 0.0
    # an electric powertrain's limits (NaN: the powertrain has no machine or battery)
    machine_at_limit_s: float = float("nan")
    battery_at_limit_s: float = float("nan")
    band_kmh: float = BAND_KMH

    @property
    def outside_physics_s(self) -> float | None:
        """Seconds with any state outside physics (the largest of its parts; they may overlap)."""
        parts = (
            self.negative_intake_pressure_s,
            self.negative_fuel_flow_s,
            self.engine_speed_out_of_range_s,
            self.speed_not_followed_s,
        )
        return None if any(p is None for p in parts) else max(parts)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["outside_physics_s"] = self.outside_physics_s
        return d

    def __str__(self) -> str:
        def s(x):
            return "not assessed" if x is None else f"{x:g} s"

        parts = [
            f"speed not followed {s(self.speed_not_followed_s)} "
            f"(max error {self.max_speed_error_mps:.2f} m/s)"
        ]
        dn = self.demand_not_deliverable_s
        if dn:
            causes = [
                f"torque beyond full load {self.torque_beyond_full_load_s:g} s"
                + (f" (max {self.max_torque_shortfall_nm:.1f} N m)" if self.max_torque_shortfall_nm else "")
                if self.torque_beyond_full_load_s
                else "",
                f"throttle below minimum {self.throttle_below_minimum_s:g} s"
                if self.throttle_below_minimum_s
                else "",
                f"engine speed out of range {self.engine_speed_out_of_range_s:g} s "
                f"(max {self.max_engine_speed_radps:.0f} rad/s)"
                if self.engine_speed_out_of_range_s
                else "",
            ]
            parts.append(f"demand not deliverable {dn:g} s: " + ", ".join(c for c in causes if c))
        else:
            parts.append(f"demand not deliverable {s(dn)}")
        neg = [
            f"negative intake pressure {self.negative_intake_pressure_s:g} s"
            if self.negative_intake_pressure_s
            else "",
            f"negative fuel flow {self.negative_fuel_flow_s:g} s" if self.negative_fuel_flow_s else "",
        ]
        if any(neg):
            parts.append("outside physics: " + ", ".join(n for n in neg if n))
        return "; ".join(parts)


def sample_weights(t) -> np.ndarray:
    """The time each sample stands for (trapezoid weights): half of each adjacent interval."""
    t = np.asarray(t, float)
    w = np.zeros(t.size)
    if t.size > 1:
        d = np.diff(t)
        w[:-1] += 0.5 * d
        w[1:] += 0.5 * d
    return w


def flags(series: dict, limits: dict) -> dict[str, np.ndarray]:
    """Per-sample flags of the deviations (boolean arrays, the keys of :class:`Deviations` without ``_s``)."""
    n = len(series["time_s"])
    zero = np.zeros(n, bool)

    def col(k):
        return np.asarray(series[k], float) if k in series else None

    v, ref = col("speed_mps"), col("reference_speed_mps")
    band = BAND_KMH / 3.6
    err = np.abs(v - ref) if v is not None and ref is not None else np.zeros(n)
    out = {"speed_not_followed": err > band * (1 + 1e-9)}
    short = col("torque_shortfall_nm")
    beyond = zero.copy() if short is None else short > 1e-9
    below = zero.copy()
    demand, thr = col("throttle_demand_m2"), col("throttle_area_m2")
    brake = col("brake_force_n")
    braked = zero if brake is None else brake > 0.0
    a_min, a_max = limits.get("min_throttle_area_m2"), limits.get("max_throttle_area_m2")
    u_max = limits.get("max_throttle_command_m2", a_max)  # a boosted engine's command goes on to full boost
    moving = (v > 1e-9) if v is not None else zero
    if demand is not None and a_min is not None:  # the inverse method's throttle demand
        below |= moving & ~braked & ~(demand >= a_min)
        beyond |= moving & (demand > u_max)
    elif short is not None and thr is not None and a_min is not None:  # backward: the steady throttle asked
        below |= moving & ~braked & (thr < a_min * (1 - 1e-6))
    elif thr is not None and a_max is not None and ref is not None:  # a driver at its limits, still behind
        cmd = col("driver_command_m2")
        at_top = thr >= a_max * (1 - 1e-9) if cmd is None else cmd >= u_max * (1 - 1e-9)
        beyond |= at_top & (v < ref - band)
        below |= (thr <= a_min * (1 + 1e-9)) & ~braked & (v > ref + band)
    out["torque_beyond_full_load"] = beyond
    out["throttle_below_minimum"] = below
    w_e = col("engine_speed_radps")
    w_max = limits.get("max_engine_speed_radps")
    over = zero.copy() if w_e is None or w_max is None else w_e > w_max * (1 + 1e-9)
    out["engine_speed_out_of_range"] = over
    out["demand_not_deliverable"] = beyond | below | over
    p = col("intake_pressure_pa")
    out["negative_intake_pressure"] = zero.copy() if p is None else p < 0.0
    f = col("fuel_flow_kgps")
    out["negative_fuel_flow"] = zero.copy() if f is None else f < 0.0
    return out


def assess(series: dict, limits: dict, trace) -> Deviations:
    """:class:`Deviations` of a run from its time series (at the cycle's samples) and its trace figures."""
    if not series:
        return Deviations(
            speed_not_followed_s=None,
            max_speed_error_mps=float(trace.max_speed_error_mps),
            demand_not_deliverable_s=None,
            torque_beyond_full_load_s=float(trace.seconds) if trace.max_torque_shortfall_nm else None,
            max_torque_shortfall_nm=float(trace.max_torque_shortfall_nm),
            throttle_below_minimum_s=None,
            engine_speed_out_of_range_s=None,
            max_engine_speed_radps=None,
            negative_intake_pressure_s=None,
            negative_fuel_flow_s=None,
            **_electric_limits(trace.details if isinstance(trace.details, dict) else {}),
        )
    w = sample_weights(series["time_s"])
    f = flags(series, limits)
    exact = trace.details if isinstance(trace.details, dict) else {}

    def sec(k):
        if f"{k}_s" in exact:  # counted by the method over its own intervals
            return round(float(exact[f"{k}_s"]), 6)
        return round(float(np.sum(w[f[k]])), 6)

    v = np.asarray(series["speed_mps"], float)
    ref = np.asarray(series.get("reference_speed_mps", v), float)
    w_e = np.asarray(series.get("engine_speed_radps", np.zeros(v.size)), float)
    short = np.asarray(series.get("torque_shortfall_nm", np.zeros(v.size)), float)
    return Deviations(
        speed_not_followed_s=sec("speed_not_followed"),
        max_speed_error_mps=max(
            float(np.max(np.abs(v - ref), initial=0.0)), float(trace.max_speed_error_mps)
        ),
        demand_not_deliverable_s=_union_s(w, f, exact),
        torque_beyond_full_load_s=sec("torque_beyond_full_load"),
        max_torque_shortfall_nm=max(float(np.max(short, initial=0.0)), float(trace.max_torque_shortfall_nm)),
        throttle_below_minimum_s=sec("throttle_below_minimum"),
        engine_speed_out_of_range_s=sec("engine_speed_out_of_range"),
        max_engine_speed_radps=float(np.nanmax(w_e, initial=0.0)),
        negative_intake_pressure_s=sec("negative_intake_pressure"),
        negative_fuel_flow_s=sec("negative_fuel_flow"),
        **_electric_limits(exact),
    )


def _electric_limits(exact: dict) -> dict:
    return {k: float(exact[k]) for k in ("machine_at_limit_s", "battery_at_limit_s") if k in exact}


def _union_s(w, f, exact) -> float:
    """Seconds with any cause of demand not deliverable; a cause the method counted exactly over its own
    intervals counts so, the others at the samples where it does not hold."""
    if "torque_beyond_full_load_s" not in exact:
        return round(float(np.sum(w[f["demand_not_deliverable"]])), 6)
    rest = (f["throttle_below_minimum"] | f["engine_speed_out_of_range"]) & ~f["torque_beyond_full_load"]
    return round(float(exact["torque_beyond_full_load_s"]) + float(np.sum(w[rest])), 6)


def limits_of(params) -> dict:
    """The physical limits a run is assessed against (:func:`flags`)."""
    return dict(memo(params, "limits", _limits))  # (once per parameter set: every run's result carries it)


def _limits(params) -> dict:
    from .model import engine as en
    from .model.record import record

    e = params.engine
    return {
        "max_engine_speed_radps": float(e.map_speed_range[1]),
        "min_throttle_area_m2": float(e.min_throttle_area),
        "max_throttle_area_m2": float(e.max_throttle_area),
        "max_throttle_command_m2": float(en.max_command(record(params))),
    }


def _refuse_non_finite(r) -> None:
    """Raise :class:`~vpsim.errors.NonFiniteRunError` when a run's totals (fuel, distance, energy terms, the
    final state of charge) are NaN or infinite: a parameter set the model cannot compute (a machine rated
    at 1e-320 W, say) must not come out as 0 L/100 km. Names the first sample where the state of charge
    stopped being finite, where there is one."""
    # (every simulate builds a Result: plain attribute reads and math.isfinite, not asdict's deep copy, which
    # cost a third of a backward UDDS run)
    terms = {}
    if r.energy is not None:
        terms = r.energy.terms if isinstance(r.energy, ElectricBalance) else vars(r.energy)
    soc_end = r.electric.get("soc_end")
    # a NaN or an infinity in any of them makes the sum one (finite values that overflow only send the
    # check below, which finds nothing): one test for the usual case
    if math.isfinite(r.fuel_kg + r.distance_m + sum(terms.values()) + (0.0 if soc_end is None else soc_end)):
        return
    bad = [k for k, v in (("fuel_kg", r.fuel_kg), ("distance_m", r.distance_m)) if not math.isfinite(v)]
    bad += [f"energy term {k}" for k, v in terms.items() if not math.isfinite(v)]
    if soc_end is not None and not math.isfinite(soc_end):
        bad.append("final state of charge")
    if not bad:
        return
    from .errors import NonFiniteRunError

    where = ""
    soc = r.series.get("soc") if isinstance(r.series, dict) else None
    ts = r.series.get("time_s") if isinstance(r.series, dict) else None
    if soc is not None and ts is not None and len(soc) == len(ts):
        nonfinite = np.flatnonzero(~np.isfinite(np.asarray(soc, float)))
        if nonfinite.size:
            where = f" (the state of charge from t = {float(ts[nonfinite[0]]):g} s)"
    raise NonFiniteRunError(
        f"the {r.method} run of {r.vehicle or 'the vehicle'} on {r.cycle} became non-finite: "
        f"{', '.join(bad[:4])}{' ...' if len(bad) > 4 else ''}{where}; "
        "expected parameters the model can compute (check machine ratings, speeds and ratios)"
    )


@_one_update_init
@dataclass(frozen=True)
class Result:
    """Outcome of one simulation: time series (``series``), summary figures, energy balance."""

    method: str
    cycle: str
    driver: str | None
    mode: str
    series: dict[str, np.ndarray]
    fuel_kg: float
    distance_m: float
    fuel_density_kg_per_l: float
    cpu_time_s: float
    steps: int
    trace_miss: TraceMiss = field(default_factory=TraceMiss)
    energy: EnergyBalance | None = None
    vehicle: str = ""
    notes: tuple[str, ...] = ()
    solver: dict = field(default_factory=dict)  # integrator statistics (steps, rejections, evaluations)
    limits: dict = field(default_factory=dict, repr=False)  # physical limits the run is assessed against
    electric: dict = field(default_factory=dict)  # an electric powertrain's figures (ELECTRIC_KEYS and more)

    def __post_init__(self) -> None:
        _refuse_non_finite(self)

    @property
    def deviations(self) -> Deviations:
        """Speed not followed, demand not deliverable (per cause), states outside physics (seconds)."""
        hit = self.__dict__.get("_deviations")
        if hit is None:
            hit = assess(self.series, self.limits, self.trace_miss)
            object.__setattr__(self, "_deviations", hit)
        return hit

    @property
    def fuel_l_per_100km(self) -> float:
        if self.distance_m <= 0:
            return float("nan")
        return self.fuel_kg / self.fuel_density_kg_per_l / (self.distance_m / 1e5)

    @property
    def fuel_economy_mpg(self) -> float:
        """Fuel economy in US miles per gallon (what a U.S. certification list reports); NaN where the
        consumption is undefined."""
        from .units import mpg_from_l_per_100km

        lp100 = self.fuel_l_per_100km
        return mpg_from_l_per_100km(lp100) if lp100 > 0 else float("nan")

    @property
    def distance_km(self) -> float:
        return self.distance_m / 1e3

    def __getattr__(self, name):
        series = self.__dict__.get("series")
        if series is not None and name in series:
            return series[name]
        raise AttributeError(name)

    def summary(self) -> dict:
        """The figures a user compares (the CLI's ``--json`` keys)."""
        return {
            "method": self.method,
            "cycle": self.cycle,
            "driver": None
            if self.driver is None
            else int(self.driver)
            if str(self.driver).isdigit()
            else self.driver,
            "mode": self.mode,
            "vehicle": self.vehicle,
            "fuel_l_per_100km": float(self.fuel_l_per_100km),
            "fuel_economy_mpg": float(self.fuel_economy_mpg),
            "fuel_kg": float(self.fuel_kg),
            "distance_km": float(self.distance_km),
            "cpu_time_s": float(self.cpu_time_s),
            "steps": int(self.steps),
            "trace_miss_s": float(self.trace_miss.seconds),
            "trace_miss_max_torque_shortfall_nm": float(self.trace_miss.max_torque_shortfall_nm),
            "max_speed_error_mps": float(self.trace_miss.max_speed_error_mps),
            "infeasible_throttle_s": float(self.trace_miss.infeasible_throttle_s),
            "energy_relative_residual": None if self.energy is None else float(self.energy.relative_residual),
            **{k: float(self.electric.get(k, float("nan"))) for k in ELECTRIC_KEYS},
            "fuel_l_per_100km_cs": float(
                self.electric.get(
                    "fuel_l_per_100km_cs", float("nan") if self.electric else self.fuel_l_per_100km
                )
            ),
            "engine_starts": self.electric.get("engine_starts", self.solver.get("engine_starts")),
            "ems": self.electric.get("ems"),
            **self.deviations.as_dict(),
        }

    def to_json(self, **kw) -> str:
        """The summary as valid JSON: an undefined figure is null with a ``<key>_undefined`` reason."""
        from .jsonsafe import dumps

        return dumps(self.summary(), **kw)

    def to_dataframe(self, *, raw: bool = False):
        """Time series as a pandas DataFrame, one row per cycle sample, SI units in the column names.

        The core columns (:data:`CORE_COLUMNS`) come first, then the method's own; then one boolean column per
        deviation (``speed_not_followed``, ``demand_not_deliverable``, ``torque_beyond_full_load``,
        ``throttle_below_minimum``, ``engine_speed_out_of_range``, ``negative_intake_pressure``,
        ``negative_fuel_flow``). A state outside physics is not shown as a plain number: a negative
        intake pressure or fuel flow is NaN there (flagged in its column); ``raw=True`` keeps the values.
        """
        import pandas as pd

        cols = {k: self.series[k] for k in CORE_COLUMNS if k in self.series}
        cols.update({k: v for k, v in self.series.items() if k not in cols})
        df = pd.DataFrame(cols)
        if not self.series:
            return df
        fl = flags(self.series, self.limits)
        if not raw:
            for key, flag in (
                ("intake_pressure_pa", "negative_intake_pressure"),
                ("fuel_flow_kgps", "negative_fuel_flow"),
            ):
                if key in df:
                    df.loc[fl[flag], key] = np.nan
            if "throttle_area_m2" in df:  # a negative area (an air flow out of the cylinders) is no throttle
                df.loc[df["throttle_area_m2"] < 0.0, "throttle_area_m2"] = np.nan
        for k, v in fl.items():
            df[k] = v
        return df

    def compare(self, *others):
        """The core columns of this run and ``others`` side by side on the cycle's samples (one DataFrame,
        columns ``(label, column)`` with label method[/driver])."""
        import pandas as pd

        frames = {}
        for r in (self, *others):
            label = r.method if r.driver is None else f"{r.method}/{r.driver}"
            while label in frames:
                label += "'"
            df = r.to_dataframe()
            frames[label] = df[[c for c in CORE_COLUMNS if c in df]].set_index("time_s")
        return pd.concat(frames, axis=1)

    def __repr__(self) -> str:
        from .jsonsafe import number

        if self.electric and self.fuel_kg > 0.0:  # a hybrid
            cs = number(self.electric.get("fuel_l_per_100km_cs", float("nan")), ".3f", "fuel_l_per_100km_cs")
            return (
                f"Result({self.method}, {self.cycle}, {self.electric.get('ems', '')}: "
                f"{number(self.fuel_l_per_100km, '.3f', 'fuel_l_per_100km')} L/100 km "
                f"({cs} charge-sustaining), "
                f"SOC {self.electric['soc_start']:.3f} -> {self.electric['soc_end']:.3f}, "
                f"{self.electric.get('engine_starts', 0)} engine starts, {self.distance_km:.3f} km, "
                f"{self.steps} steps, {self.cpu_time_s * 1e3:.2f} ms; {self.deviations})"
            )
        if self.electric:
            return (
                f"Result({self.method}{'' if self.driver is None else ' driver ' + str(self.driver)}, "
                f"{self.cycle}: {number(self.electric['electric_wh_per_km'], '.1f', 'electric_wh_per_km')} "
                f"Wh/km battery, {number(self.electric['mpge'], '.1f', 'mpge')} MPGe, SOC "
                f"{self.electric['soc_start']:.3f} -> {self.electric['soc_end']:.3f} over "
                f"{self.distance_km:.3f} km, {self.steps} steps, {self.cpu_time_s * 1e3:.2f} ms; "
                f"{self.deviations})"
            )
        lp100 = number(self.fuel_l_per_100km, ".3f", "fuel_l_per_100km")
        return (
            f"Result({self.method}{'' if self.driver is None else ' driver ' + str(self.driver)}, "
            f"{self.cycle}, {self.mode}: {lp100} L/100 km, "
            f"{self.fuel_kg * 1e3:.1f} g over {self.distance_km:.3f} km, "
            f"{self.steps} steps, {self.cpu_time_s * 1e3:.2f} ms; {self.deviations})"
        )

    def plot(self, *, t_range: tuple[float, float] | None = None, fig=None):
        """Speed, gear, engine speed and torque, intake pressure, throttle and fuel flow against time.

        The cycle is drawn dashed over the method's line; seconds with a deviation (speed not followed,
        demand not deliverable, a state outside physics) are shaded, and values outside physics (negative
        intake pressure or fuel flow) are not drawn.
        """
        import matplotlib.pyplot as plt

        from .jsonsafe import number

        df = self.to_dataframe()
        t = df["time_s"].to_numpy()
        sel = np.ones(t.size, bool) if t_range is None else (t >= t_range[0]) & (t <= t_range[1])
        panels = [
            ("speed (km/h)", [("speed_mps", 3.6, self.method), ("reference_speed_mps", 3.6, "cycle")]),
            # a CVT (more ratios than a stepped gearbox has gears): its ratio, not the grid point's number
            ("gearbox ratio", [("gearbox_ratio", 1, None)])
            if "gearbox_ratio" in df and "gear" in df and df["gear"].nunique() > MAX_STEPPED_GEARS
            else ("gear", [("gear", 1, None)]),
            ("engine speed (rad/s)", [("engine_speed_radps", 1, None)]),
            ("machine speed (rad/s)", [("machine_speed_radps", 1, None)]),
            ("machine torque (N m)", [("machine_torque_nm", 1, None)]),
            ("state of charge (%)", [("soc", 100, None)]),
            ("battery current (A)", [("battery_current_a", 1, None)]),
            (
                "battery voltage (V)",
                [("battery_voltage_v", 1, "terminal"), ("open_circuit_voltage_v", 1, "open circuit")],
            ),
            ("crank torque (N m)", [("crank_torque_nm", 1, None)]),
            ("intake pressure (kPa)", [("intake_pressure_pa", 1e-3, None)]),
            ("throttle area (mm²)", [("throttle_area_m2", 1e6, None)]),
            (
                "fuel flow (g/s)",
                [("fuel_flow_kgps", 1e3, "model"), ("fuel_flow_used_kgps", 1e3, "with idle floor")],
            ),
        ]
        # a single reduction, or a power split (no gearbox): no gear to show
        if self.electric and ("gear" not in df or df["gear"].nunique() == 1):
            panels = [p for p in panels if p[0] not in ("gear", "gearbox ratio")]
        panels = [
            (lab, [c for c in cs if c[0] in df and np.any(np.isfinite(df[c[0]].to_numpy(float)))])
            for lab, cs in panels
        ]
        panels = [p for p in panels if p[1]]
        if fig is None:
            fig, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(9, 1.6 * len(panels) + 1))
        else:
            axes = fig.subplots(len(panels), 1, sharex=True)
        axes = np.atleast_1d(axes)
        bad = {
            "speed not followed": df["speed_not_followed"].to_numpy(bool),
            "demand not deliverable": df["demand_not_deliverable"].to_numpy(bool),
            "outside physics": (df["negative_intake_pressure"] | df["negative_fuel_flow"]).to_numpy(bool),
        }
        colours = {
            "speed not followed": "tab:orange",
            "demand not deliverable": "tab:red",
            "outside physics": "k",
        }
        for ax, (label, curves) in zip(axes, panels, strict=True):
            for key, scale, name in curves:
                y = df[key].to_numpy(float)[sel] * scale
                if key in ("gear", "gearbox_ratio"):
                    ax.plot(t[sel], y, lw=1, drawstyle="steps-post")
                elif key == "reference_speed_mps":
                    ax.plot(t[sel], y, "k--", lw=0.8, label=name)
                else:
                    ax.plot(t[sel], y, lw=1, label=name)
            for what, mask in bad.items():
                m = mask & sel
                if m.any():
                    ax.fill_between(
                        t,
                        0,
                        1,
                        where=m,
                        transform=ax.get_xaxis_transform(),
                        color=colours[what],
                        alpha=0.15,
                        lw=0,
                        label=what if ax is axes[0] else None,
                    )
            ax.set_ylabel(label, fontsize=8)
            if any(c[2] for c in curves) and len(curves) > 1 or ax is axes[0]:
                ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
        axes[-1].set_xlabel("time (s)")
        if self.electric and self.fuel_kg > 0.0:  # a hybrid
            cs = self.electric.get("fuel_l_per_100km_cs", float("nan"))
            figure = (
                f"{number(self.fuel_l_per_100km, '.2f', 'fuel_l_per_100km')} L/100 km, "
                f"{number(cs, '.2f', 'fuel_l_per_100km_cs')} charge-sustaining ({self.electric.get('ems')})"
            )
        elif self.electric:
            figure = (
                f"{number(self.electric['electric_wh_per_km'], '.1f', 'electric_wh_per_km')} Wh/km "
                f"(battery), {number(self.electric['mpge'], '.1f', 'mpge')} MPGe"
            )
        else:
            figure = f"{number(self.fuel_l_per_100km, '.2f', 'fuel_l_per_100km')} L/100 km"
        axes[0].set_title(
            f"{self.method}{'' if self.driver is None else ' driver ' + str(self.driver)} on {self.cycle} "
            f"({self.mode}): {figure}",
            fontsize=9,
        )
        fig.tight_layout()
        return fig
