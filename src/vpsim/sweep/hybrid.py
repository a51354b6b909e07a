"""A sweep over a hybrid base (hev_p2, hev_split): its rows, their charge-sustaining columns and feasibility.

A hybrid row is one :func:`vpsim.simulate` call with the spec's energy management (``ems``; DP on the
backward method is the optimal charge-sustaining fuel, the sizing study's objective) on the hybrid's own gear
rule. Beside the engine car's objectives it has

* ``fuel_l_per_100km_cs``: the fuel corrected for the battery's net energy change (SAE J1711, docs/model.md);
* ``soc_start``, ``soc_end``, ``net_energy_change_ratio`` (battery energy over fuel energy),
  ``engine_starts``, ``speed_not_followed_s``, ``demand_not_deliverable_s``;
* ``feasible`` and ``infeasible_reason``. A design is infeasible when its row failed (``error``), when the car
  cannot follow the cycle (any time outside the speed band or with a demand its engine, machine and battery
  cannot deliver), or when the run ends below its starting charge by more than J1711's 1 % of the fuel's
  energy (the DP's state-of-charge grid had no charge-sustaining path, or a causal management ran the
  battery down). An infeasible row keeps what the run gave in ``fuel_l_per_100km`` (with the reason beside
  it) but its ``fuel_l_per_100km_cs`` is NaN: there is no charge-sustaining figure of a design that does not
  sustain its charge or does not drive the cycle.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

HYBRID_COLUMNS = {
    "fuel_l_per_100km_cs": "float",
    "soc_start": "float",
    "soc_end": "float",
    "net_energy_change_ratio": "float",
    "engine_starts": "float",
    "speed_not_followed_s": "float",
    "demand_not_deliverable_s": "float",
    "feasible": "bool",
    "infeasible_reason": "str",
}
CHARGE_TOLERANCE = 0.01  # SAE J1711: a net energy change within 1 % of the fuel's energy is charge-sustaining
# chunk sizing, in the runner's units of about 1 ms: a backward row by management (FTP-75-sized, 2 cores)
ROW_COST = {"dp": 1500.0, "ecms": 150.0, "rule": 60.0}


def simulate_row(cycle, method: str, driver: str, params, mode: str, ems: str | None, objectives) -> dict:
    """One hybrid row's objectives (the runner's and :data:`HYBRID_COLUMNS` but the flag)."""
    from ..simulation import simulate

    kw = {"ems": ems} if ems is not None else {}
    if method == "inverse":  # (the hybrid's forward run drives with the electric car's PI gains, no --driver)
        kw["driver"] = driver
    r = simulate(cycle, method, params, mode=mode, **kw)
    s = r.summary()
    out = {k: s[k] for k in objectives if k in s}
    for k in HYBRID_COLUMNS:
        if k in s:
            out[k] = s[k]
    out["net_energy_change_ratio"] = r.electric.get("net_energy_change_ratio", math.nan)
    return out


def flag_feasibility(df: pd.DataFrame) -> pd.DataFrame:
    """Fill ``feasible`` and ``infeasible_reason`` (module docstring); NaN the charge-sustaining fuel of an
    infeasible row."""
    reasons = []
    for row in df.itertuples(index=False):
        reasons.append(_reason(row._asdict()))
    df["infeasible_reason"] = [r or None for r in reasons]
    df["feasible"] = [not r for r in reasons]
    df.loc[~df["feasible"].astype(bool), "fuel_l_per_100km_cs"] = np.nan
    return df


def _reason(row: dict) -> str:
    err = row.get("error")
    if isinstance(err, str) and err:
        return "the run failed (error)"

    def num(k):
        v = row.get(k)
        return float(v) if v is not None else math.nan

    miss = max(num("speed_not_followed_s"), num("trace_miss_s"))
    undeliverable = num("demand_not_deliverable_s")
    if miss > 0.0 or undeliverable > 0.0:
        return (
            f"cannot follow the cycle: {miss:g} s outside the speed band, "
            f"{undeliverable:g} s of demand not deliverable"
        )
    nec, s0, s1 = num("net_energy_change_ratio"), num("soc_start"), num("soc_end")
    if not math.isfinite(num("fuel_l_per_100km")):
        return "no fuel figure"
    if s1 < s0 and not (abs(nec) <= CHARGE_TOLERANCE):
        return (
            f"not charge-sustaining: SOC {s0:.3f} -> {s1:.3f}, the battery gave {nec:.1%} of the fuel's "
            f"energy (tolerance {CHARGE_TOLERANCE:.0%})"
        )
    return ""
