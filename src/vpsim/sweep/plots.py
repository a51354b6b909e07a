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
ACCEL = "accel_0_100_s"


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
):
    """Fuel on one cycle against the 0-100 km/h time: every design, the Pareto front, the baseline.

    Returns ``(ax, front)`` with the front as a DataFrame (fastest first).
    """
    import matplotlib.pyplot as plt

    d, cycle, method = _pick(_ok(df), cycle, method, driver)
    d = d[np.isfinite(d[ACCEL].astype(float))] if not d.empty else d
    front = pareto_front(d) if not d.empty else d
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 4.5))
    ax.scatter(d[ACCEL], d[FUEL], s=12, color="0.6", alpha=0.7, label=f"designs ({len(d)})")
    ax.plot(
        front[ACCEL],
        front[FUEL],
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
            base[FUEL],
            marker="*",
            s=220,
            color="gold",
            edgecolor="k",
            zorder=5,
            label="baseline",
        )
    ax.set_xlabel("0-100 km/h at full throttle (s)")
    ax.set_ylabel(f"fuel consumption on {cycle} (L/100 km)")
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
        for cyc in dict.fromkeys(d["cycle"]):
            ax, _ = plot_pareto(df, cycle=cyc)
            p = out / f"pareto_{cyc}.png"
            ax.figure.tight_layout()
            ax.figure.savefig(p, dpi=120)
            plt.close(ax.figure)
            written.append(p)
    return written
