"""SAE J1711's charge-balance regression for a charge-sustaining hybrid: the fuel at zero net energy change.

One run of a hybrid rarely ends at its starting charge. J1711 accepts a run whose battery changed by at most
1 % of its fuel's energy as it is (the run's ``fuel_l_per_100km_cs``), and otherwise corrects the fuel by
the slope of fuel against the battery's net energy change measured over several tests. A single run cannot
measure that slope; :func:`vpsim.model.hybrid.battery_corrected_fuel` stands for it with the engine's
average efficiency over the run (and the run's ``fuel_l_per_100km_corrected`` with it), which credits the
charge at what the run's *average* fuel cost, not at what a little more or less charge costs it.

:func:`regression` does what the standard does: it runs the same car, cycle, method and management from
several starting charges (the management then charges or spends), fits the fuel consumption linearly on the
battery's net energy per distance, and reads the fuel at zero change (the intercept). The slope, made a fuel
energy per unit of battery energy (J/J), is the management's own marginal price of charge on that cycle:
the figure to set an ECMS's equivalence factor against, and the one the single-run correction guesses.

    from vpsim.charge_balance import regression
    cb = regression("udds", "hev_p2", ems="ecms")
    print(cb)              # the intercept, the slope, the points
    cb.to_dataframe()      # one row per run
    cb.plot()              # fuel against the battery's net energy, with the line

Each run is an ordinary :func:`vpsim.simulate` call (a backward ECMS run on UDDS is about a millisecond).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import VpsimError

# starting charges about the parameter set's own, as J1711's tests start from charges a little apart
SOC_OFFSETS = (-0.06, -0.03, 0.0, 0.03, 0.06)
WH_PER_KM = 3.6  # J/m in one Wh/km
KINDS = {"bev": "a battery-electric", "conventional": "an engine"}
MAX_EXTRA_RUNS = 6  # runs added to reach zero change
WINDOW_MARGIN = 1e-3  # a run whose charge came this close to soc_min or soc_max met the window
MIN_NEC_SPAN = 0.002  # the runs' changes must span this share of the fuel's energy for a slope


@dataclass(frozen=True)
class ChargeBalance:
    """The regression's outcome. ``fuel_l_per_100km``: the fuel at zero net energy change (the intercept);
    ``price``: fuel energy per unit of battery energy along the line (J/J: how much fuel a joule of charge
    stored costs, or a joule spent saves); ``r2``: the fit's coefficient of determination; ``extrapolated``:
    zero change lies outside the runs' changes (the intercept then extends the line); ``points``: per run,
    the starting charge, its net energy change (Wh/km, positive: the battery gave), its ratio to the fuel's
    energy (J1711's NEC), and its fuel (L/100 km), of the runs the line goes through."""

    cycle: str
    vehicle: str
    method: str
    ems: str
    fuel_l_per_100km: float
    price: float
    r2: float
    extrapolated: bool
    points: tuple[tuple[float, float, float, float], ...]
    runs: int = 0  # runs made (those beyond the offsets stepped the start toward zero change)

    def to_dataframe(self):
        import pandas as pd

        return pd.DataFrame(
            self.points,
            columns=["soc_initial", "battery_wh_per_km", "net_energy_change_ratio", "fuel_l_per_100km"],
        )

    def as_dict(self) -> dict:
        return {
            "cycle": self.cycle,
            "vehicle": self.vehicle,
            "method": self.method,
            "ems": self.ems,
            "fuel_l_per_100km_at_zero_net_energy": self.fuel_l_per_100km,
            "price_of_charge_j_per_j": self.price,
            "r2": self.r2,
            "extrapolated": self.extrapolated,
            "points": self.to_dataframe().to_dict(orient="records"),
        }

    def __str__(self) -> str:
        lines = [
            f"J1711 charge-balance regression, {self.vehicle} on {self.cycle} ({self.method}, {self.ems}), "
            f"{len(self.points)} runs" + (f" of {self.runs}" if self.runs > len(self.points) else ""),
            f"  fuel at zero net energy change  {self.fuel_l_per_100km:.3f} L/100 km"
            + ("  (extrapolated: no run crossed zero)" if self.extrapolated else ""),
            f"  price of charge                 {self.price:.2f} J of fuel per J of battery energy "
            f"(R^2 {self.r2:.3f})",
            "  soc_initial  battery Wh/km  NEC of fuel energy  L/100 km",
        ]
        for soc, wh, nec, fuel in self.points:
            lines.append(f"  {soc:11.3f}  {wh:13.2f}  {100 * nec:17.2f} %  {fuel:8.3f}")
        return "\n".join(lines)

    def plot(self, *, ax=None):
        """Fuel against the battery's net energy per km, the runs and the fitted line to zero change."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(5.5, 4))
        df = self.to_dataframe()
        x = df["battery_wh_per_km"].to_numpy()
        lo, hi = min(x.min(), 0.0), max(x.max(), 0.0)
        grid = np.linspace(lo, hi, 50)
        if np.ptp(x) > 0.0:
            slope, intercept = np.polyfit(x, df["fuel_l_per_100km"].to_numpy(), 1)
            ax.plot(grid, intercept + slope * grid, color="0.5", lw=1, label="fit")
        ax.plot(x, df["fuel_l_per_100km"], "o", label="runs")
        ax.plot([0.0], [self.fuel_l_per_100km], "s", color="C3", label="at zero change")
        ax.axvline(0.0, color="0.8", lw=0.8)
        ax.set_xlabel("battery net energy (Wh/km, + drawn)")
        ax.set_ylabel("fuel (L/100 km)")
        ax.set_title(f"{self.vehicle}, {self.cycle}, {self.method}, {self.ems}")
        ax.legend()
        return ax


def regression(
    cycle, params="hev_p2", *, method: str = "backward", ems: str | None = None, soc_offsets=None, **options
) -> ChargeBalance:
    """J1711's regression for ``params`` (a hybrid's preset, file or Parameters) on ``cycle`` by ``method``
    and management ``ems`` (default the set's ``hybrid.ems``): one run from each starting charge
    ``battery.soc_initial + offset`` (``soc_offsets``, default :data:`SOC_OFFSETS`), each inside the
    battery's window. Where no run crosses zero change, up to :data:`MAX_EXTRA_RUNS` more step the start
    toward it; the line goes through the runs nearest zero change, as many as the offsets, leaving out any
    whose charge met the window's edge (its change then the window's, not the management's). Further
    ``options`` go to :func:`vpsim.simulate`."""
    from .cycles import Cycle, load_cycle
    from .params import HYBRIDS, Parameters, load_parameters
    from .simulation import simulate

    if not isinstance(params, Parameters):
        params = load_parameters(params)
    if params.powertrain.type not in HYBRIDS:
        raise VpsimError(
            f"the charge-balance regression is for hybrids; {params.name} is "
            f"{KINDS.get(params.powertrain.type, 'a ' + params.powertrain.type)} car"
        )
    if not isinstance(cycle, Cycle):
        cycle = load_cycle(cycle)
    ems = params.hybrid.ems if ems is None else ems
    if ems == "dp":
        raise VpsimError(
            "the dynamic programme ends at its starting charge from any start: its run's own "
            "fuel_l_per_100km_cs is charge-sustaining; the regression is for managements that charge or spend"
        )
    offsets = SOC_OFFSETS if soc_offsets is None else tuple(float(x) for x in soc_offsets)
    if not all(math.isfinite(x) for x in offsets):
        raise VpsimError(f"soc_offsets {offsets}: every offset must be a finite number")
    b = params.battery
    socs = sorted({round(b.soc_initial + x, 12) for x in offsets})
    if len(socs) < 3:
        raise VpsimError(
            f"soc_offsets: {len(socs)} distinct starting charges; the regression needs 3 or more"
        )
    outside = [s for s in socs if not b.soc_min <= s <= b.soc_max]
    if outside:
        raise VpsimError(
            f"soc_offsets: starting charge {outside[0]:g} is outside the battery's window "
            f"[soc_min, soc_max] = [{b.soc_min:g}, {b.soc_max:g}]"
        )
    q_hv, density = params.engine.fuel_heating_value, params.simulation.fuel_density

    def point(soc):
        r = simulate(cycle, method, params.with_changes(battery={"soc_initial": soc}), ems=ems, **options)
        km = r.distance_m / 1e3
        if not km > 1e-3:
            raise VpsimError(
                f"cycle {cycle.name!r}: the car drove {r.distance_m:.3g} m, no fuel per distance"
            )
        chem = r.energy.terms["chemical"]
        fuel_energy = r.fuel_kg * q_hv
        soc_path = r.series["soc"]
        clipped = soc_path.max() >= b.soc_max - WINDOW_MARGIN or soc_path.min() <= b.soc_min + WINDOW_MARGIN
        if clipped:
            edge.add(soc)
        return (
            soc,
            chem / 3.6e3 / km,
            chem / fuel_energy if fuel_energy > 0 else math.nan,
            r.fuel_l_per_100km,
        )

    edge: set[float] = set()  # starts whose run reached the window's edge
    points = [point(soc) for soc in socs]
    # J1711's tests straddle zero change; where every run spent (or every run stored), further runs step the
    # start down (up) by the offsets' spacing, within the window, until one crosses
    step = float(np.median(np.diff(socs)))
    for _ in range(MAX_EXTRA_RUNS):
        changes = [p[1] for p in points]
        if min(changes) <= 0.0 <= max(changes):
            break
        soc = points[0][0] - step if min(changes) > 0.0 else points[-1][0] + step
        if not b.soc_min <= soc <= b.soc_max:
            break
        soc = round(soc, 12)
        points = sorted([*points, point(soc)])
        if soc in edge:
            break
    # the line through the runs nearest zero change, as many as the offsets asked for; a run whose charge
    # reached the window's edge is left out (the window, not the management, set its change)
    usable = [p for p in points if p[0] not in edge]
    if len(usable) < 3:
        raise VpsimError(
            f"{len(points) - len(usable)} of {len(points)} runs reached the battery's window "
            f"[{b.soc_min:g}, {b.soc_max:g}]: fewer than 3 left to fit (narrower soc_offsets)"
        )
    used = sorted(sorted(usable, key=lambda p: abs(p[2]))[: len(socs)])
    x = np.array([p[1] for p in used])
    y = np.array([p[3] for p in used])
    nec = np.array([p[2] for p in used])
    if not np.ptp(nec) >= MIN_NEC_SPAN:
        raise VpsimError(
            f"the runs' net energy changes span {100 * np.ptp(nec):.2f} % of the fuel's energy, under "
            f"{100 * MIN_NEC_SPAN:g} %: too little to fit J1711's slope (wider soc_offsets, or a management "
            "whose charge follows its start)"
        )
    slope, intercept = np.polyfit(x, y, 1)
    fit = intercept + slope * x
    ss = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum((y - fit) ** 2)) / ss if ss > 0 else 1.0
    l100_j_per_m = density / 1e5 * q_hv  # J of fuel per m in one L/100 km
    return ChargeBalance(
        cycle=cycle.name,
        vehicle=params.name,
        method=method,
        ems=ems,
        fuel_l_per_100km=float(intercept),
        price=float(-slope * l100_j_per_m / WH_PER_KM),
        r2=float(r2),
        extrapolated=not (x.min() <= 0.0 <= x.max()),
        points=tuple(used),
        runs=len(points),
    )
