"""Figures of the paper that are not a single result's ``.plot()``: the map figures (2, 3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .model import maps


def plot_torque_lines(eng, ax=None):
    """Paper Figure 2: FQM crank torque against engine speed, one line per throttle area."""
    import matplotlib.pyplot as plt

    tm = maps.torque_map(eng)
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 4.5))
    # one colour per throttle area along a sequential map, so no colour repeats;
    # the order of the colours is the order of the areas; A_max, the max-torque line, black as in Figure 3
    shades = plt.get_cmap("viridis")(np.linspace(0.0, 0.9, len(tm.a_eff) - 1))
    for k, a in enumerate(tm.a_eff):
        top = k == len(tm.a_eff) - 1
        color = "k" if top else shades[k]
        ax.plot(tm.speed, tm.torque[k], lw=2.2 if top else 1.1, color=color, label=f"{a * 1e6:.0f} mm²")
    ax.axhline(0.0, color="0.4", lw=0.6)
    ax.set_xlabel("engine speed ω_e (rad/s)")
    ax.set_ylabel("crank torque T_cr (N m)")
    ax.set_title("FQM torque lines (bold black: A_max, the max-torque line)", fontsize=9)
    ax.legend(title="A_eff", fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    ax.grid(alpha=0.3)
    return ax, tm


def plot_fuel_map(eng, ax=None, engine_map=None):
    """Paper Figure 3: BQM fuel mass flow over (w_e, T_cr), with the max-torque line."""
    import matplotlib.pyplot as plt

    em = engine_map or maps.cached_engine_map(eng)
    lo, hi = eng.map_speed_range
    w = np.linspace(lo, hi, 121)
    # a grid that follows the max-torque line (torque from 0 to T_max(w) at every speed), so the filled map
    # reaches the line with no gap beneath it
    t = np.linspace(0.0, 1.0, 101)[None, :] * em.max_torque(w)[:, None]
    ww = np.broadcast_to(w[:, None], t.shape)
    fuel = maps.bqm_fuel_flow(t, ww, eng)
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 4.5))
    cs = ax.contourf(ww, t, fuel * 1e3, levels=20, cmap="viridis")
    ax.figure.colorbar(cs, ax=ax, label="fuel flow (g/s)")
    ax.plot(w, em.max_torque(w), "k", lw=2, label="max torque")
    ax.set_xlabel("engine speed ω_e (rad/s)")
    ax.set_ylabel("crank torque T_cr (N m)")
    ax.set_title("BQM fuel map", fontsize=9)
    ax.set_xlim(lo, hi)
    ax.set_ylim(0.0, 1.04 * float(t.max()))
    ax.legend(fontsize=8, loc="upper right")  # above the line at high speed: no data there
    return ax, (ww, t, fuel)


def write_map_figures(eng, out: Path) -> list[Path]:
    """Write figure2_torque_lines.{png,csv} and figure3_fuel_map.{png,csv} into ``out``.

    Draws with pyplot under whatever backend is in use (the command line picks a non-interactive one).
    """
    import matplotlib.pyplot as plt
    import pandas as pd

    out.mkdir(parents=True, exist_ok=True)
    written = []
    ax, tm = plot_torque_lines(eng)
    p = out / "figure2_torque_lines.png"
    ax.figure.savefig(p, dpi=120, bbox_inches="tight")
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
    df = pd.DataFrame({"speed_radps": w.ravel(), "torque_nm": t.ravel(), "fuel_flow_kgps": fuel.ravel()})
    p = out / "figure3_fuel_map.csv"
    df.to_csv(p, index=False, float_format="%.6g")
    written.append(p)
    return written


def plot_machine_efficiency(machine, ax=None, n: int = 120):
    """Efficiency contours of an electric machine (measured map or :class:`~vpsim.model.machine.MachineSpec`)
    over speed (rpm) and torque (N m), both quadrants, with its torque envelope. Returns the axes."""
    import matplotlib.pyplot as plt

    from .model.machine import MachineSpec, efficiency_table, machine_record, max_torque, min_torque

    if isinstance(machine, MachineSpec):
        m = machine_record(machine)
        w_hi = machine.max_speed_radps
        upper = lambda w: max_torque(w, m)  # noqa: E731
        lower = lambda w: min_torque(w, m)  # noqa: E731
        title = f"scaled model, {machine.kind}, {machine.rated_power_w / 1e3:.1f} kW"
    else:
        w_hi = machine.max_speed_radps
        upper, lower = machine.max_torque_at, machine.min_torque_at
        title = f"{machine.name}: {machine.description}" if machine.description else machine.name
    speeds = np.linspace(0.0, w_hi, n)
    t_hi = float(np.max(upper(speeds)))
    t_lo = float(np.min(lower(speeds)))
    torques = np.linspace(t_lo, t_hi, n)
    eff = efficiency_table(machine, speeds, torques)
    if ax is None:
        _, ax = plt.subplots(figsize=(7.5, 5.5))
    rpm = speeds * 60.0 / (2.0 * np.pi)
    levels = [0.5, 0.6, 0.7, 0.75, 0.8, 0.85, 0.88, 0.9, 0.92, 0.94, 0.96]
    filled = ax.contourf(rpm, torques, np.clip(eff.T, 0.4, 1.0), levels=[0.4, *levels, 1.0], cmap="viridis")
    lines = ax.contour(rpm, torques, eff.T, levels=levels, colors="k", linewidths=0.5)
    ax.clabel(lines, fmt="%.2f", fontsize=7)
    ax.plot(rpm, upper(speeds), "r-", lw=1.5, label="torque envelope")
    ax.plot(rpm, lower(speeds), "r-", lw=1.5)
    ax.axhline(0.0, color="0.3", lw=0.5)
    ax.figure.colorbar(filled, ax=ax, label="efficiency (machine and inverter)")
    ax.set_xlabel("speed (rpm)")
    ax.set_ylabel("torque (N m), > 0 motoring, < 0 generating")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    return ax
