"""The one result type every method returns: time series, summary, energy bookkeeping; print, plot, tabulate.

>>> import vpsim
>>> r = vpsim.simulate("nedc", method="backward")
>>> r.summary()["fuel_l_per_100km"] > 0
True
>>> df = r.to_dataframe()          # one row per time sample
>>> fig = r.plot()                 # speed, gear, engine torque/speed, intake pressure, fuel flow
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

import numpy as np

# name -> unit; the order is the DataFrame's column order
SERIES = {
    "time_s": "s",
    "reference_speed_mps": "m/s",
    "speed_mps": "m/s",
    "accel_mps2": "m/s^2",
    "gear": "-",
    "engine_speed_radps": "rad/s",
    "crank_torque_nm": "N m",
    "engine_torque_nm": "N m",
    "intake_pressure_pa": "Pa",
    "throttle_area_m2": "m^2",
    "fuel_flow_kgps": "kg/s",
    "fuel_flow_used_kgps": "kg/s",
    "brake_force_n": "N",
}


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

    @property
    def fuel_l_per_100km(self) -> float:
        if self.distance_m <= 0:
            return float("nan")
        return self.fuel_kg / self.fuel_density_kg_per_l / (self.distance_m / 1e5)

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
            "driver": self.driver,
            "mode": self.mode,
            "vehicle": self.vehicle,
            "fuel_l_per_100km": float(self.fuel_l_per_100km),
            "fuel_kg": float(self.fuel_kg),
            "distance_km": float(self.distance_km),
            "cpu_time_s": float(self.cpu_time_s),
            "steps": int(self.steps),
            "trace_miss_s": float(self.trace_miss.seconds),
            "trace_miss_max_torque_shortfall_nm": float(self.trace_miss.max_torque_shortfall_nm),
            "max_speed_error_mps": float(self.trace_miss.max_speed_error_mps),
            "infeasible_throttle_s": float(self.trace_miss.infeasible_throttle_s),
            "energy_relative_residual": None if self.energy is None else float(self.energy.relative_residual),
        }

    def to_json(self, **kw) -> str:
        return json.dumps(self.summary(), **kw)

    def to_dataframe(self):
        """Time series as a pandas DataFrame, one row per sample, SI units in the column names."""
        import pandas as pd

        cols = {k: self.series[k] for k in SERIES if k in self.series}
        cols.update({k: v for k, v in self.series.items() if k not in cols})
        return pd.DataFrame(cols)

    def __repr__(self) -> str:
        return (
            f"Result({self.method}{'' if self.driver is None else ' driver ' + self.driver}, "
            f"{self.cycle}, {self.mode}: {self.fuel_l_per_100km:.3f} L/100 km, "
            f"{self.fuel_kg * 1e3:.1f} g over {self.distance_km:.3f} km, "
            f"{self.steps} steps, {self.cpu_time_s * 1e3:.2f} ms, trace miss {self.trace_miss})"
        )

    def plot(self, *, t_range: tuple[float, float] | None = None, fig=None):
        """Speed, gear, engine speed and torque, intake pressure, throttle and fuel flow against time."""
        import matplotlib.pyplot as plt

        s = self.series
        t = s["time_s"]
        sel = slice(None) if t_range is None else (t >= t_range[0]) & (t <= t_range[1])
        panels = [
            ("speed (km/h)", [("reference_speed_mps", 3.6, "cycle"), ("speed_mps", 3.6, self.method)]),
            ("gear", [("gear", 1, None)]),
            ("engine speed (rad/s)", [("engine_speed_radps", 1, None)]),
            ("crank torque (N m)", [("crank_torque_nm", 1, None)]),
            ("intake pressure (kPa)", [("intake_pressure_pa", 1e-3, None)]),
            ("throttle area (mm^2)", [("throttle_area_m2", 1e6, None)]),
            (
                "fuel flow (g/s)",
                [("fuel_flow_kgps", 1e3, "model"), ("fuel_flow_used_kgps", 1e3, "with idle floor")],
            ),
        ]
        panels = [(lab, [c for c in cs if c[0] in s and np.any(np.isfinite(s[c[0]]))]) for lab, cs in panels]
        panels = [p for p in panels if p[1]]
        if fig is None:
            fig, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(9, 1.6 * len(panels) + 1))
        else:
            axes = fig.subplots(len(panels), 1, sharex=True)
        axes = np.atleast_1d(axes)
        for ax, (label, curves) in zip(axes, panels, strict=True):
            for key, scale, name in curves:
                kw = {"drawstyle": "steps-post"} if key == "gear" else {}
                ax.plot(t[sel], np.asarray(s[key])[sel] * scale, label=name, lw=1, **kw)
            ax.set_ylabel(label, fontsize=8)
            if any(c[2] for c in curves) and len(curves) > 1:
                ax.legend(fontsize=7, loc="upper right")
        axes[-1].set_xlabel("time (s)")
        axes[0].set_title(
            f"{self.method}{'' if self.driver is None else ' driver ' + self.driver} on {self.cycle}: "
            f"{self.fuel_l_per_100km:.2f} L/100 km",
            fontsize=9,
        )
        fig.tight_layout()
        return fig
