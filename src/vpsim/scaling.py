"""Engine scaling (paper section 5.3): the physical engine scaled to measured engines, Figure 7 and Table 4.

The paper scales the bore B, stroke S and inertia J_e of its engine model to two engines measured for NREL's
ADVISOR (FC_SI41_emis, a 1991 Geo Metro 1.0 L, and FC_SI63_emis, a 1996 Saturn 1.9 L), generates their fuel
maps with the BQM at the measured (torque, speed) points, and compares (a) the maps side by side (its
Figure 7) and (b) the backward-method fuel consumption on NEDC and FTP-75 with the measured and the
generated map, in vehicles adjusted to each engine (its Table 4: error up to 4.6 %).

    >>> from vpsim.params import load_parameters
    >>> from vpsim.scaling import scale_engine
    >>> base = load_parameters("hofman2011").engine
    >>> geo = scale_engine(base, bore=0.074, stroke=0.077, cylinders=3, inertia=0.1)
    >>> round(geo.displacement * 1e3, 3), round(geo.max_throttle_area / base.max_throttle_area, 3)
    (0.993, 0.507)

Scaling rule (:func:`scale_engine`): the cylinder count z, B, S and J_e are set; then

* the throttle areas A_max, A_min scale with z B^2, the total piston area. The air the cylinders draw at a
  given mean piston speed c_m = S w_e / pi is proportional to z B^2 c_m (eqs. (8),(9)); the throttle flow
  is proportional to A (10). With A / (z B^2) fixed, the manifold pressure, and so the full-load BMEP, is
  the same function of c_m for every engine: valve and throttle area per cylinder grow with B^2. (A_max
  proportional to V_d instead would give a long-stroke engine a relatively larger throttle.)
* the map's speed range scales with 1/S: the same mean piston speeds, the limit that sets rated speed.
* the intake manifold volume scales with V_d (the paper's is about V_d); it sets only a time constant.
* J_e, when not given, scales with V_d (a rough rule; the measured files give J_e themselves).
Everything else (thermodynamics, friction law, which already scales with B through (0.075/B)^0.5) stays.

The comparison and bookkeeping rules (the measured map outside its grid, idle and zero torque) are those of
:class:`vpsim.engines.measured.MeasuredEngineMap`; :class:`TractionOnlyMap` applies the same zero-torque
rule to the generated map. docs/scaling.md gives the choices and the Table 4 this produces.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .errors import VpsimError

TABLE4_COLUMNS = (
    "engine",
    "cycle",
    "measured_l_per_100km",
    "generated_l_per_100km",
    "error_pct",
    "calibrated_l_per_100km",
    "calibrated_error_pct",
)
COVERAGE_KEYS = ("no_traction", "outside", "below_speed", "below_torque", "above_torque", "above_speed")
TABLE4_CYCLES = ("nedc", "ftp75")


@dataclass(frozen=True)
class EngineCase:
    """One measured engine of the paper's section 5.3 and the preset of the vehicle built around it."""

    file_stem: str
    preset: str
    label: str
    bore: float
    stroke: float
    cylinders: int


PAPER_ENGINES = (
    EngineCase("FC_SI41_emis", "geo_metro_1l", "Geo 1.0 L", 0.074, 0.077, 3),
    EngineCase("FC_SI63_emis", "saturn_1_9l", "Saturn 1.9 L", 0.082, 0.090, 4),
)


# --------------------------------------------------------------------------------------- scaling


def scale_engine(base, *, bore: float, stroke: float, cylinders: int, inertia: float | None = None):
    """``base`` (a :class:`vpsim.params.Engine`) with B, S, z (and J_e) changed by the module's rule."""
    for name, v in (("bore", bore), ("stroke", stroke), ("cylinders", cylinders)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise VpsimError(f"{name} must be a positive number, got {v!r}")
    if int(cylinders) != cylinders:
        raise VpsimError(f"cylinders must be a whole number, got {cylinders!r}")
    area = cylinders * bore**2 / (base.cylinders * base.bore**2)
    vd = cylinders * math.pi / 4.0 * bore**2 * stroke
    vd_ratio = vd / base.displacement
    speed = base.stroke / stroke
    return replace(
        base,
        bore=float(bore),
        stroke=float(stroke),
        cylinders=int(cylinders),
        inertia=float(base.inertia * vd_ratio if inertia is None else inertia),
        max_throttle_area=base.max_throttle_area * area,
        min_throttle_area=base.min_throttle_area * area,
        map_speed_range=(base.map_speed_range[0] * speed, base.map_speed_range[1] * speed),
        intake_manifold_volume=base.intake_manifold_volume * vd_ratio,
    )


def scaled_machine(machine, rated_power: float) -> dict[str, float]:
    """A machine section scaled to ``rated_power`` at the same base and top speeds: its rotor's length (so
    its torque and its inertia) in proportion to the power; ``rated_power`` and ``inertia`` of the result."""
    k = rated_power / machine.rated_power
    return {"rated_power": float(rated_power), "inertia": machine.inertia * k}


def mass_ratio(mass_kg: float, vehicle, bounds: tuple[float, float]) -> float:
    """A car's test mass over a reference vehicle section's mass, held within ``bounds``: the factor a
    component sized by the car's weight is scaled by."""
    return min(max(mass_kg / vehicle.mass, bounds[0]), bounds[1])


def scaled_parameters(params, *, bore: float, stroke: float, cylinders: int, inertia: float | None = None):
    """``params`` with its engine scaled (:func:`scale_engine`), validated like any parameter set."""
    from dataclasses import asdict

    eng = scale_engine(params.engine, bore=bore, stroke=stroke, cylinders=cylinders, inertia=inertia)
    changes = {k: v for k, v in asdict(eng).items() if k in ("bore", "stroke", "cylinders", "inertia")}
    # validate the user's numbers first (unit hints such as "did you mean 0.074?"), then set the rest
    checked = params.with_changes(engine=changes)
    return replace(checked, engine=eng)


# --------------------------------------------------------------------------------------- maps


@dataclass(frozen=True, eq=False)
class TractionOnlyMap:
    """A fuel map with the zero-torque rule of the measured maps: no fuel of its own where T_cr <= 0.

    The backward method then books the idle flow there (its floor), for the generated map as for the
    measured one; the measurements say nothing about a motoring engine. Everything else is ``inner``'s.
    """

    inner: Any
    label: str = "generated"

    @property
    def inertia(self) -> float:
        return self.inner.inertia

    @property
    def name(self) -> str:
        return self.label

    @property
    def engine(self):
        return self.inner.engine

    def fuel_flow(self, t_cr, w_e):
        t = np.asarray(t_cr, dtype=float)
        return np.where(t > 0, self.inner.fuel_flow(t_cr, w_e), 0.0)

    def max_torque(self, w_e):
        return self.inner.max_torque(w_e)

    def min_torque(self, w_e):
        return self.inner.min_torque(w_e)


def generated_map(engine) -> TractionOnlyMap:
    """The BQM map of ``engine`` (:func:`vpsim.model.maps.generate_engine_map`) with the zero-torque rule."""
    from .model.maps import generate_engine_map

    return TractionOnlyMap(generate_engine_map(engine))


@dataclass(frozen=True)
class MapComparison:
    """Measured and generated fuel flow at the measured nodes (Figure 7); ``[i, j]`` at speed i, torque j.

    ``usable`` marks the nodes compared: positive torque, on or below the measured full-load curve (a
    rectangular table's nodes above it are fill-in, not measurements). ``relative_error`` is
    generated / measured - 1 there and NaN elsewhere.
    """

    name: str
    speed: np.ndarray
    torque: np.ndarray
    measured: np.ndarray
    generated: np.ndarray
    usable: np.ndarray
    relative_error: np.ndarray
    full_load_speed: np.ndarray = field(repr=False)
    full_load_torque: np.ndarray = field(repr=False)
    generated_full_load: np.ndarray = field(repr=False)

    def stats(self) -> dict[str, float]:
        """Median and 90th percentile of |relative error|, and the median signed error, usable nodes, %."""
        return error_stats(self.relative_error[self.usable])

    def __str__(self) -> str:
        st = self.stats()
        head = f"{self.name}: generated against measured fuel flow at {st['n']} nodes"
        if not st["n"]:
            return f"{head}: no measured node has positive torque within the measured full load"
        return (
            f"{head} (positive torque, within the measured full load): median |error| "
            f"{st['median_abs_pct']:.1f} %, 90th percentile {st['p90_abs_pct']:.1f} %, median error "
            f"{st['median_pct']:+.1f} %"
        )

    def to_dataframe(self):
        """One row per measured node (:meth:`rows`): speed, torque, both fuel flows, the error, usable."""
        import pandas as pd

        return pd.DataFrame(self.rows())

    def plot(self):
        """The paper's Figure 7 for this engine (:func:`plot_figure7`): measured and generated BSFC, and
        their relative difference. Returns the Figure."""
        return plot_figure7([self])

    def rows(self) -> list[dict[str, Any]]:
        out = []
        for i, w in enumerate(self.speed):
            for j, t in enumerate(self.torque):
                out.append(
                    {
                        "speed_radps": float(w),
                        "torque_nm": float(t),
                        "measured_gps": float(self.measured[i, j] * 1e3),
                        "generated_gps": float(self.generated[i, j] * 1e3),
                        "relative_error_pct": float(self.relative_error[i, j] * 100)
                        if self.usable[i, j]
                        else "",
                        "usable": bool(self.usable[i, j]),
                    }
                )
        return out


def compare_maps(measured, engine, name: str | None = None) -> MapComparison:
    """The BQM of ``engine`` at the nodes of ``measured`` (a :class:`vpsim.engines.MeasuredEngine`)."""
    from .model.maps import bqm_fuel_flow, max_torque

    t_node, w_node = np.meshgrid(measured.torque_grid, measured.speed_grid)
    gen = bqm_fuel_flow(t_node, w_node, engine)
    usable = (t_node > 0) & (t_node <= measured.max_torque_at(w_node) + 1e-9) & (measured.fuel_flow > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(usable, gen / measured.fuel_flow - 1.0, np.nan)
    return MapComparison(
        name=name or measured.name,
        speed=measured.speed_grid,
        torque=measured.torque_grid,
        measured=measured.fuel_flow,
        generated=gen,
        usable=usable,
        relative_error=rel,
        full_load_speed=measured.max_torque_speed,
        full_load_torque=measured.max_torque,
        generated_full_load=max_torque(measured.max_torque_speed, engine),
    )


def weighted_quantile(values, weights, q: float) -> float:
    """The smallest value whose cumulative weight reaches ``q`` of the total (q in [0, 1])."""
    v = np.asarray(values, dtype=float).ravel()
    w = np.asarray(weights, dtype=float).ravel()
    if v.size == 0 or not np.any(w > 0):
        return float("nan")
    order = np.argsort(v)
    cw = np.cumsum(w[order])
    k = int(np.searchsorted(cw, q * cw[-1] * (1 - 1e-12)))
    return float(v[order][min(k, v.size - 1)])


def error_stats(rel, weights=None) -> dict[str, float]:
    """Median and 90th percentile of |rel| and the median of rel, in %, optionally weighted."""
    rel = np.asarray(rel, dtype=float)
    w = np.ones_like(rel) if weights is None else np.asarray(weights, dtype=float)
    ok = np.isfinite(rel)
    rel, w = rel[ok], w[ok]
    return {
        "median_abs_pct": 100 * weighted_quantile(np.abs(rel), w, 0.5),
        "p90_abs_pct": 100 * weighted_quantile(np.abs(rel), w, 0.9),
        "median_pct": 100 * weighted_quantile(rel, w, 0.5),
        "n": int(rel.size),
    }


# --------------------------------------------------------------------------------------- cycles


@dataclass(frozen=True)
class CycleCell:
    """One Table 4 cell (engine x cycle): fuel with each map, errors, and how the measured map was read."""

    engine: str
    cycle: str
    measured_l_per_100km: float
    generated_l_per_100km: float
    calibrated_l_per_100km: float
    coverage: dict[str, float]  # share of cycle time (0..1) per COVERAGE_KEYS
    trace_miss_s: dict[str, float]
    point_stats: dict[str, dict[str, float]]  # time-weighted error stats at the cycle's traction points
    torque_bands: dict[str, float] = field(default_factory=dict)  # error contribution (% points) by load
    sensitivity: dict[str, float] = field(default_factory=dict)  # error_pct under alternative rules

    @property
    def error_pct(self) -> float:
        return 100.0 * (self.generated_l_per_100km / self.measured_l_per_100km - 1.0)

    @property
    def calibrated_error_pct(self) -> float:
        return 100.0 * (self.calibrated_l_per_100km / self.measured_l_per_100km - 1.0)

    def table4_row(self) -> dict[str, Any]:
        return {
            "engine": self.engine,
            "cycle": self.cycle,
            "measured_l_per_100km": round(self.measured_l_per_100km, 4),
            "generated_l_per_100km": round(self.generated_l_per_100km, 4),
            "error_pct": round(self.error_pct, 3),
            "calibrated_l_per_100km": round(self.calibrated_l_per_100km, 4)
            if math.isfinite(self.calibrated_l_per_100km)
            else "",
            "calibrated_error_pct": round(self.calibrated_error_pct, 3)
            if math.isfinite(self.calibrated_l_per_100km)
            else "",
        }


def compare_on_cycle(
    measured_map, params, cycle, *, label: str, calibrated_engine=None, sensitivity: bool = False
) -> CycleCell:
    """Backward method on ``cycle`` with the measured, the generated and (optionally) a calibrated map.

    All runs share one gear schedule, the documented default rule with the measured full-load curve, so
    the difference is the fuel map alone. Each map keeps its own full-load line (trace misses reported).
    """
    from .cycles import load_cycle
    from .gears import default_schedule
    from .methods import backward
    from .model.maps import bqm_fuel_flow

    cyc = load_cycle(cycle) if isinstance(cycle, str) else cycle
    schedule = default_schedule(cyc, params, measured_map)

    def run(engine_map, p=params):
        return backward.run(cyc, p, engine_map=engine_map, schedule=schedule)

    r_meas = run(measured_map)
    r_gen = run(generated_map(params.engine))
    trace = {"measured": r_meas.trace_miss.seconds, "generated": r_gen.trace_miss.seconds}
    cal_l = float("nan")
    engines = {"generated": params.engine}
    if calibrated_engine is not None:
        p_cal = replace(params, engine=calibrated_engine)
        r_cal = run(generated_map(calibrated_engine), p_cal)
        cal_l = r_cal.fuel_l_per_100km
        trace["calibrated"] = r_cal.trace_miss.seconds
        engines["calibrated"] = calibrated_engine

    op = backward.intervals(cyc, params, engine_map=measured_map, schedule=schedule, mode="paper")
    t_cr = op["crank_torque_nm"]
    w_e = op["engine_speed_radps"]
    dt = op["dt_s"]
    masks = measured_map.coverage(t_cr, w_e)
    coverage = {k: float(np.sum(dt[masks[k]]) / np.sum(dt)) for k in COVERAGE_KEYS}

    idle = params.simulation.idle_fuel_flow
    trac = t_cr > 0
    f_meas = np.maximum(measured_map.fuel_flow(t_cr, w_e), idle)
    point_stats = {}
    for key, eng in engines.items():
        f_gen = np.maximum(bqm_fuel_flow(t_cr, w_e, eng), idle)
        point_stats[key] = error_stats((f_gen / f_meas - 1.0)[trac], dt[trac])

    # where the fuel difference comes from: contribution (% of measured cycle fuel) by load band
    op_gen = backward.intervals(
        cyc, params, engine_map=generated_map(params.engine), schedule=schedule, mode="paper"
    )
    f_gen_run = np.maximum(op_gen["fuel_flow_kgps"], idle)
    f_meas_run = np.maximum(op["fuel_flow_kgps"], idle)
    total = float(np.sum(f_meas_run * dt))
    peak = float(np.max(measured_map.engine.max_torque))
    bands = {
        "no traction": ~trac,
        f"0-25 % of peak torque ({0.25 * peak:.0f} N m)": trac & (t_cr <= 0.25 * peak),
        "25-60 %": trac & (t_cr > 0.25 * peak) & (t_cr <= 0.6 * peak),
        "above 60 %": trac & (t_cr > 0.6 * peak),
    }
    contrib = {k: float(100 * np.sum(((f_gen_run - f_meas_run) * dt)[m]) / total) for k, m in bands.items()}
    contrib_time = {f"time share {k}": float(np.sum(dt[m]) / np.sum(dt)) for k, m in bands.items()}

    sens: dict[str, float] = {}
    if sensitivity:
        from .engines.measured import MeasuredEngineMap

        def err(r_m, r_g=r_gen):
            return 100.0 * (r_g.fuel_l_per_100km / r_m.fuel_l_per_100km - 1.0)

        sens["low_speed=clamp"] = err(
            run(
                MeasuredEngineMap(
                    measured_map.engine, low_speed="clamp", zero_torque_column=measured_map.zero_torque_column
                )
            )
        )
        if measured_map.engine.torque_grid[0] <= 0:
            sens["zero_torque_column=use"] = err(
                run(
                    MeasuredEngineMap(
                        measured_map.engine, low_speed=measured_map.low_speed, zero_torque_column="use"
                    )
                )
            )
        from .model.maps import generate_engine_map

        sens["generated burns its own fuel at T_cr<=0"] = err(r_meas, run(generate_engine_map(params.engine)))
    return CycleCell(
        engine=label,
        cycle=cyc.name,
        measured_l_per_100km=r_meas.fuel_l_per_100km,
        generated_l_per_100km=r_gen.fuel_l_per_100km,
        calibrated_l_per_100km=cal_l,
        coverage=coverage,
        trace_miss_s=trace,
        point_stats=point_stats,
        torque_bands={**contrib, **contrib_time},
        sensitivity=sens,
    )


def cycle_points(measured_map, params, cycles=TABLE4_CYCLES) -> tuple[np.ndarray, np.ndarray]:
    """(T_cr, w_e) of the traction points of ``cycles`` (for plotting where the cycles run)."""
    from .calibration import cycle_operating_points

    t, w, _ = cycle_operating_points(measured_map, params, cycles)
    return t, w


# --------------------------------------------------------------------------------------- Figure 7


def _speed_axes(ax) -> None:
    """Engine speed in rad/s below (vpsim's unit, as in Figures 2 and 3), in rpm on a secondary axis above."""
    ax.set_xlabel("engine speed ω_e (rad/s)")
    top = ax.secondary_xaxis("top", functions=(lambda w: w * 30.0 / np.pi, lambda n: n * np.pi / 30.0))
    top.set_xlabel("engine speed (rpm)", fontsize=8)
    top.tick_params(labelsize=7)


def _legend_below(ax) -> None:
    """The legend under the axes, clear of the maps (the panels are filled to their edges)."""
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)


def plot_figure7(comparisons, path=None, points=None, labels=None, points_label="NEDC + FTP-75 points"):
    """Paper Figure 7: per engine, measured and generated BSFC contours and the relative difference map.

    ``comparisons`` is a list of :class:`MapComparison`; ``points`` an optional list of (T_cr, w_e) arrays of
    cycle operating points, drawn on the difference panels. Returns the figure (saved to ``path`` if given).
    """
    import matplotlib.pyplot as plt
    from matplotlib import colors

    n = len(comparisons)
    fig, axes = plt.subplots(n, 3, figsize=(14, 4.2 * n), squeeze=False, constrained_layout=True)
    bsfc_levels = [230, 250, 270, 290, 320, 350, 400, 450, 500, 600, 800]
    norm = colors.BoundaryNorm(bsfc_levels, 256, extend="both")
    for row, cmp in enumerate(comparisons):
        w_rad = cmp.speed  # rad/s as everywhere in vpsim; rpm on the top axis
        w_fl = cmp.full_load_speed
        t_top = 1.05 * max(float(np.max(cmp.full_load_torque)), float(np.max(cmp.generated_full_load)))
        t_node, w_node = np.meshgrid(cmp.torque, cmp.speed)
        power_kw = t_node * w_node / 1e3
        shown = cmp.usable
        label = labels[row] if labels else cmp.name
        panels = ((cmp.measured, "measured"), (cmp.generated, "generated (scaled model)"))
        for col, (flow, title) in enumerate(panels):
            ax = axes[row, col]
            with np.errstate(divide="ignore", invalid="ignore"):
                bsfc = np.where(shown, flow * 1e3 / power_kw * 3600, np.nan)
            cs = ax.contourf(
                w_rad,
                cmp.torque,
                np.ma.masked_invalid(bsfc).T,
                levels=bsfc_levels,
                norm=norm,
                cmap="viridis_r",
                extend="both",
            )
            ax.contour(
                w_rad,
                cmp.torque,
                np.ma.masked_invalid(bsfc).T,
                levels=bsfc_levels,
                colors="k",
                linewidths=0.4,
            )
            ax.plot(w_fl, cmp.full_load_torque, "k-", lw=1.8, label="full load")
            if col == 1:
                ax.plot(w_fl, cmp.generated_full_load, "k--", lw=1.2, label="model full load (A_max)")
            ax.set_ylim(0, t_top)
            ax.set_title(f"{label}: {title}", fontsize=9)
            _speed_axes(ax)
            ax.set_ylabel("torque (N m)")
            _legend_below(ax)
            if col == 1:
                fig.colorbar(cs, ax=axes[row, :2], label="BSFC (g/kWh)", shrink=0.9)
        ax = axes[row, 2]
        rel = np.ma.masked_invalid(cmp.relative_error * 100).T
        lim = 30.0
        cs = ax.pcolormesh(w_rad, cmp.torque, rel, cmap="RdBu_r", vmin=-lim, vmax=lim, shading="nearest")
        ax.plot(w_fl, cmp.full_load_torque, "k-", lw=1.8)
        ax.set_ylim(0, t_top)
        if points is not None and points[row] is not None:
            t_p, w_p = points[row]
            ax.plot(
                w_p,
                t_p,
                ".",
                ms=1.5,
                color="0.25",
                alpha=0.35,
                label=points_label,
            )
            _legend_below(ax)
        s = cmp.stats()
        ax.set_title(
            f"{label}: generated / measured - 1 (median |e| {s['median_abs_pct']:.1f} %, "
            f"p90 {s['p90_abs_pct']:.1f} %)",
            fontsize=9,
        )
        _speed_axes(ax)
        ax.set_ylabel("torque (N m)")
        fig.colorbar(cs, ax=ax, label="relative difference of fuel flow (%)", extend="both")
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


# --------------------------------------------------------------------------------------- Table 4


@dataclass(frozen=True)
class Table4:
    """Everything :func:`table4` computed: cells, map comparisons, calibrations (per engine label)."""

    cells: list[CycleCell]
    maps: dict[str, MapComparison]
    calibrations: dict[str, Any]
    points: dict[str, tuple[np.ndarray, np.ndarray]]

    def rows(self) -> list[dict[str, Any]]:
        return [c.table4_row() for c in self.cells]


def table4(
    cases,
    *,
    cycles=TABLE4_CYCLES,
    calibrate: bool = True,
    calibration_kw: dict | None = None,
    sensitivity: bool = True,
) -> Table4:
    """Table 4 for ``cases``: a list of (label, measured engine, parameters) triples.

    ``parameters`` holds the vehicle and the scaled engine (e.g. the ``geo_metro_1l`` preset). With
    ``calibrate``, :func:`vpsim.calibration.calibrate` fits the engine first (``calibration_kw`` passed on).
    """
    from .calibration import calibrate as fit

    cells, cmps, cals, pts = [], {}, {}, {}
    for label, measured, params in cases:
        mmap = measured.engine_map()
        cmps[label] = compare_maps(measured, params.engine, name=label)
        cal = fit(mmap, params, **(calibration_kw or {})) if calibrate else None
        cals[label] = cal
        pts[label] = cycle_points(mmap, params, cycles)
        for c in cycles:
            cal_engine = cal.engine if cal else None
            cell = compare_on_cycle(
                mmap, params, c, label=label, calibrated_engine=cal_engine, sensitivity=sensitivity
            )
            cells.append(cell)
    return Table4(cells, cmps, cals, pts)


def write_csv(path, rows, columns=None) -> Path:
    path = Path(path)
    columns = list(columns or (rows[0].keys() if rows else []))
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    return path


def coverage_rows(cells) -> list[dict[str, Any]]:
    rows = []
    for c in cells:
        row = {"engine": c.engine, "cycle": c.cycle}
        row.update({f"{k}_pct": round(100 * v, 2) for k, v in c.coverage.items()})
        row.update({f"trace_miss_{k}_s": v for k, v in c.trace_miss_s.items()})
        rows.append(row)
    return rows


def stats_rows(result: Table4) -> list[dict[str, Any]]:
    """Figure 7 statistics: per engine and map (generated/calibrated), nodes and cycle-time weighted."""
    from .model.maps import bqm_fuel_flow

    rows = []
    for label, cmp in result.maps.items():
        variants = {"generated": None}
        if result.calibrations.get(label) is not None:
            variants["calibrated"] = result.calibrations[label].engine
        for key, eng in variants.items():
            if eng is None:
                s = cmp.stats()
            else:
                with np.errstate(divide="ignore", invalid="ignore"):
                    t_node, w_node = np.meshgrid(cmp.torque, cmp.speed)
                    rel = bqm_fuel_flow(t_node, w_node, eng) / cmp.measured - 1.0
                s = error_stats(rel[cmp.usable])
            rows.append({"engine": label, "model": key, "weighting": "measured nodes", **_round(s)})
            for cell in result.cells:
                if cell.engine == label and key in cell.point_stats:
                    rows.append(
                        {
                            "engine": label,
                            "model": key,
                            "weighting": f"time on {cell.cycle}",
                            **_round(cell.point_stats[key]),
                        }
                    )
    return rows


def _round(s: dict[str, float]) -> dict[str, Any]:
    return {k: (round(v, 2) if isinstance(v, float) else v) for k, v in s.items()}


def _find_engine_file(folder: Path, stem: str) -> Path:
    for suffix in (".m", ".json"):
        p = folder / f"{stem}{suffix}"
        if p.is_file():
            return p
    raise VpsimError(f"{folder}: neither {stem}.m nor {stem}.json found (ADVISOR fuel-converter files)")


def paper_engine_cases(advisor_dir) -> list[tuple[str, Any, Any]]:
    """(label, measured engine, preset parameters) for the paper's two engines, read from ``advisor_dir``."""
    from .engines import load_engine
    from .params import load_parameters

    folder = Path(advisor_dir)
    if not folder.is_dir():
        raise VpsimError(f"{folder}: not a folder (expected ADVISOR's FC_SI41_emis.m and FC_SI63_emis.m)")
    return [
        (c.label, load_engine(_find_engine_file(folder, c.file_stem)), load_parameters(c.preset))
        for c in PAPER_ENGINES
    ]


def _fmt(x: float, nd: int = 2) -> str:
    return f"{x:.{nd}f}" if isinstance(x, float) and math.isfinite(x) else "n/a"


def paper_section(advisor_dir, out_dir) -> str:
    """Figure 7 and Table 4 of the paper for the ADVISOR engines in ``advisor_dir``; a markdown section.

    Writes into ``out_dir``: ``table4.csv`` (columns :data:`TABLE4_COLUMNS`), ``table4_coverage.csv`` (share
    of each cycle outside the measured map, trace misses), ``figure7.png``, ``figure7_stats.csv`` (median
    and 90th percentile of the fuel-flow error, over the map's nodes and weighted by cycle time),
    ``table4_sensitivity.csv`` and ``calibration.json``.
    """
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cases = paper_engine_cases(advisor_dir)
    res = table4(cases)
    write_csv(out / "table4.csv", res.rows(), TABLE4_COLUMNS)
    write_csv(out / "table4_coverage.csv", coverage_rows(res.cells))
    stats = stats_rows(res)
    write_csv(out / "figure7_stats.csv", stats)
    sens_rows = [
        {
            "engine": c.engine,
            "cycle": c.cycle,
            "baseline_error_pct": round(c.error_pct, 3),
            **{k: round(v, 3) for k, v in c.sensitivity.items()},
        }
        for c in res.cells
    ]
    cols = ["engine", "cycle", "baseline_error_pct"] + sorted({k for c in res.cells for k in c.sensitivity})
    write_csv(out / "table4_sensitivity.csv", sens_rows, cols)
    cal_json = {label: cal.as_dict() for label, cal in res.calibrations.items() if cal is not None}
    (out / "calibration.json").write_text(json.dumps(cal_json, indent=2) + "\n")
    fig = plot_figure7(list(res.maps.values()), out / "figure7.png", points=[res.points[k] for k in res.maps])
    plt.close(fig)
    return _markdown(res, stats, cases)


def _markdown(res: Table4, stats, cases) -> str:
    cyc_name = {"nedc": "NEDC", "ftp75": "FTP-75"}
    lines = [
        "## Engine scaling (paper section 5.3): Figure 7 and Table 4",
        "",
        "The physical engine model is scaled to the two ADVISOR engines by bore, stroke, cylinder count and "
        "inertia; throttle areas scale with z B² (total piston area: the same full-load manifold pressure at "
        "the same mean piston speed), the map speed range with 1/S (same mean piston speeds). Each engine "
        "drives a vehicle adjusted to it (presets `geo_metro_1l`, `saturn_1_9l`: mass, gear ratios and, for "
        "the 1.0 L car, frontal area, as the paper did). One gear schedule per cycle (default rule, measured "
        "full-load curve) serves all maps. While T_cr ≤ 0 every map books the preset's idle flow.",
        "",
        "![Figure 7](figure7.png)",
        "",
        "**Table 4.** Backward-method fuel consumption (L/100 km) with the measured and the generated map.",
        "",
        "| engine | cycle | measured | generated | error | calibrated | error | cycle time outside the map "
        "(traction) | no traction (idle flow) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in res.cells:
        cov = c.coverage
        parts = ("below_speed", "below_torque", "above_torque", "above_speed")
        detail = ", ".join(f"{k.replace('_', ' ')} {100 * cov[k]:.1f} %" for k in parts if cov[k] > 0)
        lines.append(
            f"| {c.engine} | {cyc_name.get(c.cycle, c.cycle)} | {c.measured_l_per_100km:.3f} | "
            f"{c.generated_l_per_100km:.3f} | {c.error_pct:+.1f} % | {_fmt(c.calibrated_l_per_100km, 3)} | "
            f"{_fmt(c.calibrated_error_pct, 1)} % | {100 * cov['outside']:.1f} %"
            f"{' (' + detail + ')' if detail else ''} | {100 * cov['no_traction']:.1f} % |"
        )
    worst = max(abs(c.error_pct) for c in res.cells)
    band_names = [k for k in res.cells[0].torque_bands if not k.startswith("time")]
    worst_cal = max(
        (abs(c.calibrated_error_pct) for c in res.cells if math.isfinite(c.calibrated_error_pct)),
        default=float("nan"),
    )
    lines += [
        "",
        f"Largest error: {worst:.1f} % uncalibrated (the paper: up to 4.6 %), "
        f"{_fmt(worst_cal, 1)} % calibrated.",
        "Outside the measured map the measured fuel flow is read as follows: below the lowest map speed at "
        "constant fuel per cycle (flow ∝ speed), below the lowest loaded torque column along the Willans "
        "line of the two lowest loaded columns, above the top column linearly; a zero-torque column "
        "(Saturn: 0.1935 g/s at every speed, an idle flow) is not interpolated to.",
        "",
        "Where the differences come from (contribution to the error, % of the measured cycle fuel, by load):",
        "",
        "| engine | cycle | " + " | ".join(band_names) + " |",
        "|---|---|" + "---|" * len(band_names),
    ]
    for c in res.cells:
        vals = [
            f"{v:+.2f} ({100 * c.torque_bands['time share ' + k]:.0f} % of time)"
            for k, v in c.torque_bands.items()
            if not k.startswith("time")
        ]
        lines.append(f"| {c.engine} | {cyc_name.get(c.cycle, c.cycle)} | " + " | ".join(vals) + " |")
    lines += [
        "",
        "**Figure 7 statistics** (|generated / measured − 1| of the fuel flow, %; nodes: measured nodes with "
        "positive torque up to full load; time on a cycle: the cycle's traction points, weighted by time):",
        "",
        "| engine | model | weighting | median | 90th percentile | median (signed) | n |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in stats:
        lines.append(
            f"| {r['engine']} | {r['model']} | {r['weighting']} | {r['median_abs_pct']:.1f} | "
            f"{r['p90_abs_pct']:.1f} | {r['median_pct']:+.1f} | {r['n']} |"
        )
    cal_lines = []
    for label, cal in res.calibrations.items():
        if cal is None:
            continue
        parts = []
        for k, n in enumerate(cal.names):
            se = cal.std_errors[k]
            se_txt = f" ± {se:.3g}" if math.isfinite(se) else (" (at bound)" if cal.at_bound[k] else "")
            parts.append(f"{n} = {cal.values[k]:.4g}{se_txt}")
        cal_lines.append(f"* {label}: " + ", ".join(parts) + (f" ({cal.message})" if cal.message else ""))
    if cal_lines:
        first = next(c for c in res.calibrations.values() if c is not None)
        lines += [
            "",
            f"**Calibration** (bounded least squares on the measured map at the traction points of "
            f"{', '.join(first.cycles) or 'the map nodes'}, weighted by time; standard errors from "
            "s²(JᵀJ)⁻¹, a lower bound as neighbouring seconds are correlated). The calibration cycle is "
            "not a Table 4 cycle, so the calibrated column is an out-of-sample check:",
            "",
            *cal_lines,
        ]
    return "\n".join(lines) + "\n"
