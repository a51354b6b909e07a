"""Looking at a sweep: fuel against displacement per cycle, and the Pareto front of fuel against 0-100 km/h.

Both take the result DataFrame (:func:`vpsim.sweep.load_results` or ``run_sweep(...).results``); failed rows
(``error`` set) and designs that never reach 100 km/h are left out of the front, and the baseline (the base
parameter set unchanged, ``is_baseline``) is marked with a star.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

FUEL = "fuel_l_per_100km"
FUEL_CS = "fuel_l_per_100km_cs"  # a hybrid's charge-sustaining fuel (vpsim.sweep.hybrid)
ACCEL = "accel_0_100_s"


def _fuel_column(df: pd.DataFrame) -> str:
    """The fuel a figure shows: a hybrid sweep's charge-sustaining fuel, otherwise the cycle's fuel."""
    return FUEL_CS if FUEL_CS in df else FUEL


def _feasible(df: pd.DataFrame) -> pd.DataFrame:
    """A hybrid sweep's feasible rows (``feasible``); every row of another sweep."""
    return df[df["feasible"].astype(bool)] if "feasible" in df else df


def _ok(df: pd.DataFrame) -> pd.DataFrame:
    return df[df["error"].isna() & np.isfinite(df[FUEL].astype(float))] if "error" in df else df


def _pick(df: pd.DataFrame, cycle: str | None, method: str | None, driver: str | None = None):
    """Rows of one cycle x method (x driver): the first of each in the table unless named."""
    if df.empty:
        return df, cycle, method
    cycle = cycle or df["cycle"].iloc[0]
    method = method or ("backward" if "backward" in set(df["method"]) else df["method"].iloc[0])
    sel = (df["cycle"] == cycle) & (df["method"] == method)
    if driver is not None:
        sel &= df["driver"] == str(driver)
    elif method != "backward" and sel.any():
        sel &= df["driver"] == df.loc[sel, "driver"].iloc[0]
    return df[sel], cycle, method


def pareto_front(df: pd.DataFrame, x: str = ACCEL, y: str = FUEL) -> pd.DataFrame:
    """The rows not dominated in (x, y), both to be minimised, sorted by x. Non-finite values are left out."""
    d = df[np.isfinite(df[x].astype(float)) & np.isfinite(df[y].astype(float))].sort_values(
        [x, y], kind="stable"
    )
    keep = []
    best = np.inf
    for idx, yy in zip(d.index, d[y].to_numpy(float), strict=True):
        if yy < best:
            keep.append(idx)
            best = yy
    return d.loc[keep]


def plot_fuel_vs_displacement(df: pd.DataFrame, *, method: str | None = None, ax=None):
    """Fuel consumption against engine displacement, one colour per cycle; the baseline starred."""
    import matplotlib.pyplot as plt

    d = _ok(df)
    if method is None and not d.empty:
        method = "backward" if "backward" in set(d["method"]) else d["method"].iloc[0]
    if method is not None:
        d = d[d["method"] == method]
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 4.5))
    for cyc, g in d.groupby("cycle", sort=False):
        pts = ax.scatter(g["displacement_l"], g[FUEL], s=14, alpha=0.7, label=str(cyc))
        base = g[g["is_baseline"].astype(bool)]
        if not base.empty:
            ax.scatter(
                base["displacement_l"],
                base[FUEL],
                marker="*",
                s=180,
                color=pts.get_facecolor()[0],
                edgecolor="k",
                zorder=5,
            )
    if (d["is_baseline"].astype(bool)).any():
        ax.scatter([], [], marker="*", s=120, color="w", edgecolor="k", label="baseline")
    ax.set_xlabel("engine displacement (L)")
    ax.set_ylabel("fuel consumption (L/100 km)")
    ax.set_title(f"fuel against displacement ({method}, {len(d)} rows)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return ax


def plot_pareto(
    df: pd.DataFrame,
    *,
    cycle: str | None = None,
    method: str | None = None,
    driver: str | None = None,
    ax=None,
    label_front=None,
):
    """Fuel on one cycle against the 0-100 km/h time: every design, the Pareto front, the baseline.

    A hybrid sweep's table shows its charge-sustaining fuel and leaves its infeasible rows out (counted in the
    legend). ``label_front``: a function of a front row giving its label (e.g. the design's values).
    Returns ``(ax, front)`` with the front as a DataFrame (fastest first).
    """
    import matplotlib.pyplot as plt

    fuel = _fuel_column(df)
    picked, cycle, method = _pick(_ok(df), cycle, method, driver)
    d = _feasible(picked)
    n_infeasible = len(picked) - len(d)
    d = d[np.isfinite(d[ACCEL].astype(float))] if not d.empty else d
    front = pareto_front(d, y=fuel) if not d.empty else d
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 4.5))
    ax.scatter(d[ACCEL], d[fuel], s=12, color="0.6", alpha=0.7, label=f"designs ({len(d)})")
    if n_infeasible:  # no fuel figure to place: counted in the legend
        ax.scatter([], [], marker="x", color="0.6", label=f"infeasible, not shown ({n_infeasible})")
    ax.plot(
        front[ACCEL],
        front[fuel],
        "-o",
        color="C3",
        ms=4,
        lw=1.5,
        drawstyle="steps-post",
        label=f"Pareto front ({len(front)})",
    )
    base = d[d["is_baseline"].astype(bool)] if not d.empty else d
    if not base.empty:
        ax.scatter(
            base[ACCEL],
            base[fuel],
            marker="*",
            s=220,
            color="gold",
            edgecolor="k",
            zorder=5,
            label="baseline",
        )
    if label_front and not front.empty:
        for k, (_, row) in enumerate(front.iterrows()):  # above and below the front in turn
            ax.annotate(
                label_front(row),
                (row[ACCEL], row[fuel]),
                xytext=(4, 6 if k % 2 == 0 else -12),
                textcoords="offset points",
                fontsize=7,
            )
    ax.set_xlabel("0-100 km/h at full throttle (s)")
    what = "charge-sustaining fuel" if fuel == FUEL_CS else "fuel consumption"
    ax.set_ylabel(f"{what} on {cycle} (L/100 km)")
    ax.set_title(f"fuel against acceleration ({method} on {cycle})", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return ax, front


def write_sweep_figures(df: pd.DataFrame, out: str | Path) -> list[Path]:
    """Write ``fuel_vs_displacement.png`` and ``pareto_<cycle>.png`` (one per cycle) into ``out``.

    Draws with pyplot under whatever backend is in use (the command line picks a non-interactive one).
    """
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    ax = plot_fuel_vs_displacement(df)
    p = out / "fuel_vs_displacement.png"
    ax.figure.tight_layout()
    ax.figure.savefig(p, dpi=120)
    plt.close(ax.figure)
    written.append(p)
    d = _ok(df)
    if ACCEL in d and np.isfinite(d[ACCEL].astype(float)).any():
        label = _hybrid_label if FUEL_CS in df else None
        for cyc in dict.fromkeys(d["cycle"]):
            ax, _ = plot_pareto(df, cycle=cyc, label_front=label)
            p = out / f"pareto_{cyc}.png"
            ax.figure.tight_layout()
            ax.figure.savefig(p, dpi=120)
            plt.close(ax.figure)
            written.append(p)
    return written


def _hybrid_label(row) -> str:
    """A hybrid design's sizing in short: engine displacement, machine power, cells."""
    parts = [f"{row['displacement_l']:.2f} L"]
    if "machine.rated_power" in row:
        parts.append(f"{row['machine.rated_power'] / 1e3:g} kW")
    if "battery.cells_in_series" in row:
        parts.append(f"{int(row['battery.cells_in_series'])} cells")
    return ", ".join(parts)
