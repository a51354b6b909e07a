"""Figures of the paper that are not a single result's ``.plot()``: the map figures (2, 3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import maps


def plot_torque_lines(eng, ax=None):
    """Paper Figure 2: FQM crank torque against engine speed, one line per throttle area."""
    import matplotlib.pyplot as plt

    tm = maps.torque_map(eng)
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 4.5))
    for k, a in enumerate(tm.a_eff):
        lw = 2.0 if k == len(tm.a_eff) - 1 else 1.0
        ax.plot(tm.speed, tm.torque[k], lw=lw, label=f"{a * 1e6:.0f} mm²")
    ax.set_xlabel("engine speed ω_e (rad/s)")
    ax.set_ylabel("crank torque T_cr (N m)")
    ax.set_title("FQM torque lines (bold: A_max, the max-torque line)", fontsize=9)
    ax.legend(title="A_eff", fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    return ax, tm


def plot_fuel_map(eng, ax=None, engine_map=None):
    """Paper Figure 3: BQM fuel mass flow over (w_e, T_cr), with the max-torque line."""
    import matplotlib.pyplot as plt

    em = engine_map or maps.cached_engine_map(eng)
    lo, hi = eng.map_speed_range
    w = np.linspace(lo, hi, 121)
    t = np.linspace(0.0, float(em.max_torque(w).max()), 101)
    fuel = maps.bqm_fuel_flow(t[None, :], w[:, None], eng)
    fuel = np.where(t[None, :] <= em.max_torque(w)[:, None], fuel, np.nan)
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 4.5))
    cs = ax.contourf(w, t, fuel.T * 1e3, levels=20, cmap="viridis")
    ax.figure.colorbar(cs, ax=ax, label="fuel flow (g/s)")
    ax.plot(w, em.max_torque(w), "k", lw=2, label="max torque")
    ax.set_xlabel("engine speed ω_e (rad/s)")
    ax.set_ylabel("crank torque T_cr (N m)")
    ax.set_title("BQM fuel map", fontsize=9)
    ax.legend(fontsize=8)
    return ax, (w, t, fuel)


def write_map_figures(eng, out: Path) -> list[Path]:
    """Write figure2_torque_lines.{png,csv} and figure3_fuel_map.{png,csv} into ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    out.mkdir(parents=True, exist_ok=True)
    written = []
    ax, tm = plot_torque_lines(eng)
    p = out / "figure2_torque_lines.png"
    ax.figure.tight_layout()
    ax.figure.savefig(p, dpi=120)
    plt.close(ax.figure)
    written.append(p)
    a, w = np.meshgrid(tm.a_eff, tm.speed, indexing="ij")
    df = pd.DataFrame(
        {
            "a_eff_m2": a.ravel(),
            "speed_radps": w.ravel(),
            "torque_nm": tm.torque.ravel(),
            "intake_pressure_pa": tm.intake_pressure.ravel(),
            "fuel_flow_kgps": tm.fuel_flow.ravel(),
        }
    )
    p = out / "figure2_torque_lines.csv"
    df.to_csv(p, index=False, float_format="%.6g")
    written.append(p)
    ax, (w, t, fuel) = plot_fuel_map(eng)
    p = out / "figure3_fuel_map.png"
    ax.figure.tight_layout()
    ax.figure.savefig(p, dpi=120)
    plt.close(ax.figure)
    written.append(p)
    ww, tt = np.meshgrid(w, t, indexing="ij")
    df = pd.DataFrame({"speed_radps": ww.ravel(), "torque_nm": tt.ravel(), "fuel_flow_kgps": fuel.ravel()})
    df = df.dropna()
    p = out / "figure3_fuel_map.csv"
    df.to_csv(p, index=False)
    written.append(p)
    return written
