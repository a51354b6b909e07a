"""The figures of the fleet report (:func:`vpsim.fleet.report.write_outputs` saves them as PNG files).

Figures are drawn on :class:`matplotlib.figure.Figure` objects (no pyplot state, no backend choice);
matplotlib is imported only when a figure is drawn.
"""

from __future__ import annotations

import math

import numpy as np

from .report import EV_CYCLES, GROUPS, HEV_CYCLES, MHEV_CYCLES, _in_order


def _axes_grid(n, ncols=2, size=(5.2, 4.2)):
    from matplotlib.figure import Figure

    nrows = max(1, math.ceil(n / ncols))
    fig = Figure(figsize=(size[0] * ncols, size[1] * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes


def _diagonal(ax, lo, hi, title, measured_unit, predicted_unit):
    """A predicted-against-measured panel's frame: the diagonal, +-10 % lines, limits, labels, legend."""
    x = np.array([lo, hi])
    ax.plot(x, x, "k-", lw=0.8)
    ax.plot(x, 1.1 * x, "k:", lw=0.7)
    ax.plot(x, 0.9 * x, "k:", lw=0.7, label="±10 %")
    ax.set_xlim(lo, hi)
    ax.set_ylim(lo, hi)
    ax.set_title(title)
    ax.set_xlabel(f"measured {measured_unit}")
    ax.set_ylabel(f"predicted {predicted_unit} (out of fold)")
    ax.legend(fontsize=7, loc="upper left")


def _trace_misses(ax, sub, miss, size, label) -> None:
    """The rows ``miss`` of ``sub`` (runs that missed the trace) as red crosses, if any."""
    if miss.any():
        x, y = sub["measured_mpg"][miss], sub["predicted_mpg"][miss]
        ax.scatter(x, y, s=size, marker="x", c="tab:red", label=label)


def _hybrid_panel(ax, rows, c, peer: bool, what: str, peer_label: str) -> None:
    """One hybrid part's test ``c``: vpsim's charge-sustaining mpg (``what``: "full hybrid", "mild
    hybrid") against the measurement, trace misses as red crosses, and its peer (``peer_label``) calibrated
    on the same classes, or its defaults where it was not calibrated."""
    sub = rows[(rows["cycle"] == c) & np.isfinite(rows["predicted_mpg"].to_numpy(float))]
    vals = np.concatenate([sub["measured_mpg"], sub["predicted_mpg"]])
    lo, hi = (0.9 * vals.min(), 1.05 * vals.max()) if vals.size else (0, 1)
    for col, how in (("fastsim_calibrated_mpg", "calibrated"), ("fastsim_mpg", "defaults")):
        # the peer calibrated as vpsim's hybrids are (the fair comparison), else its defaults
        if peer and col in sub and np.isfinite(sub[col].to_numpy(float)).any():
            ax.scatter(
                sub["measured_mpg"],
                sub[col],
                s=14,
                marker="s",
                c="tab:orange",
                alpha=0.45,
                label=f"{peer_label}, {how}",
            )
            break
    miss = (sub["status"] == "trace_miss").to_numpy()
    ax.scatter(
        sub["measured_mpg"][~miss],
        sub["predicted_mpg"][~miss],
        s=24,
        marker="^" if what == "full hybrid" else "v",
        c="tab:purple" if what == "full hybrid" else "tab:brown",
        alpha=0.75,
        label=f"vpsim {what} (ECMS, charge-sustaining)",
    )
    _trace_misses(ax, sub, miss, 20, f"vpsim {what}, trace miss")
    _diagonal(ax, lo, hi, f"{what}, {c} (n = {len(sub)})", "mpg", "mpg")


def figure_predicted_vs_measured(df, cycles, peer: bool, ev=None, hev=None, mhev=None):
    """One panel per conventional cycle (mpg); with battery-electric rows ``ev``, one per EV test (MPGe:
    green diamonds); with full-hybrid rows ``hev``, one per hybrid test (charge-sustaining mpg: purple
    triangles, trace misses as red crosses; FASTSim's hybrid calibrated on the same classes beside them, or
    its defaults where it was not calibrated); with mild-hybrid rows ``mhev``, one per test the same way
    (brown triangles; beside them FASTSim's conventional car of the same record, its peer)."""
    ev_cycles = [c for c in EV_CYCLES if ev is not None and (ev["cycle"] == c).any()]
    hev_cycles = [c for c in HEV_CYCLES if hev is not None and (hev["cycle"] == c).any()]
    mhev_cycles = [c for c in MHEV_CYCLES if mhev is not None and (mhev["cycle"] == c).any()]
    fig, axes = _axes_grid(len(cycles) + len(ev_cycles) + len(hev_cycles) + len(mhev_cycles))
    first = len(cycles) + len(ev_cycles)
    for ax, c in zip(axes[first:], hev_cycles, strict=False):
        _hybrid_panel(ax, hev, c, peer, "full hybrid", "FASTSim 3.1 hybrid")
    for ax, c in zip(axes[first + len(hev_cycles) :], mhev_cycles, strict=False):
        _hybrid_panel(ax, mhev, c, peer, "mild hybrid", "FASTSim 3.1 conventional car")
    for ax, c in zip(axes[len(cycles) :], ev_cycles, strict=False):
        sub = ev[(ev["cycle"] == c) & np.isfinite(ev["predicted_mpge"].to_numpy(float))]
        vals = np.concatenate([sub["measured_mpge"], sub["predicted_mpge"]])
        lo, hi = (0.9 * vals.min(), 1.05 * vals.max()) if vals.size else (0, 1)
        if peer and np.isfinite(sub["fastsim_calibrated_mpge"].to_numpy(float)).any():
            ax.scatter(
                sub["measured_mpge"],
                sub["fastsim_calibrated_mpge"],
                s=14,
                marker="s",
                c="tab:orange",
                alpha=0.45,
                label="FASTSim 3.1 BEV, calibrated",
            )
        ax.scatter(
            sub["measured_mpge"],
            sub["predicted_mpge"],
            s=22,
            marker="D",
            c="tab:green",
            alpha=0.75,
            label="vpsim BEV",
        )
        _diagonal(ax, lo, hi, f"battery-electric, {c} (n = {len(sub)})", "MPGe (unadjusted)", "MPGe")
    for ax, c in zip(axes, cycles, strict=False):
        sub = df[(df["cycle"] == c) & np.isfinite(df["predicted_mpg"])]
        lo = 0.9 * min(sub["measured_mpg"].min(), sub["predicted_mpg"].min()) if len(sub) else 0
        hi = 1.05 * max(sub["measured_mpg"].max(), sub["predicted_mpg"].max()) if len(sub) else 1
        if peer and "fastsim_calibrated_mpg" in sub:  # the peer calibrated as vpsim is, the fair comparison
            ax.scatter(
                sub["measured_mpg"],
                sub["fastsim_calibrated_mpg"],
                s=7,
                c="tab:orange",
                alpha=0.45,
                label="FASTSim 3.1, calibrated",
            )
        elif peer and "fastsim_mpg" in sub:
            ax.scatter(
                sub["measured_mpg"], sub["fastsim_mpg"], s=7, c="tab:orange", alpha=0.45, label="FASTSim 3.1"
            )
        miss = sub["status"] == "trace_miss"
        ax.scatter(
            sub["measured_mpg"][~miss],
            sub["predicted_mpg"][~miss],
            s=7,
            c="tab:blue",
            alpha=0.6,
            label="vpsim",
        )
        _trace_misses(ax, sub, miss, 12, "vpsim, trace miss")
        _diagonal(ax, lo, hi, f"{c} (n = {len(sub)})", "mpg", "mpg")
    fig.suptitle(
        "Predicted against measured fuel economy (MPGe for the battery-electric cars), EPA test cars"
        if not (hev_cycles or mhev_cycles)
        else "Predicted against measured fuel economy (MPGe for the battery-electric cars; hybrids "
        "charge-sustaining), EPA test cars"
    )
    return fig


def figure_histograms(df, cycles, peer: bool):
    fig, axes = _axes_grid(len(cycles))
    bins = np.arange(-60, 61, 4)
    for ax, c in zip(axes, cycles, strict=False):
        sub = df[(df["cycle"] == c) & np.isfinite(df["error_pct"])]
        ax.hist(np.clip(sub["error_pct"], -59.9, 59.9), bins=bins, alpha=0.7, color="tab:blue", label="vpsim")
        peers = (
            ("fastsim_calibrated_error_pct", "FASTSim 3.1, calibrated", "-"),
            ("fastsim_error_pct", "FASTSim 3.1, defaults", ":"),
        )
        for col, label, style in peers if peer else ():
            if col in sub:
                ax.hist(
                    np.clip(sub[col].dropna(), -59.9, 59.9),
                    bins=bins,
                    histtype="step",
                    lw=1.5,
                    ls=style,
                    color="tab:orange",
                    label=label,
                )
        ax.axvline(0, color="k", lw=0.8)
        ax.set_title(f"{c}: median {np.median(sub['error_pct']):+.1f} %" if len(sub) else c)
        ax.set_xlabel("error of predicted mpg, % (clipped at ±60)")
        ax.set_ylabel("vehicles")
        ax.legend(fontsize=7)
    fig.suptitle("Error histograms (out of fold)")
    return fig


def figure_by_group(df, cycles):
    fig, axes = _axes_grid(len(GROUPS))
    ok = df[np.isfinite(df["error_pct"])].copy()
    colours = ["tab:blue", "tab:green", "tab:purple", "tab:red"]
    for ax, (kind, fn) in zip(axes, GROUPS.items(), strict=False):
        ok["group"] = fn(ok)
        groups = _in_order(ok["group"].unique())
        for j, c in enumerate(cycles):
            xs, med, q1, q3 = [], [], [], []
            for i, g in enumerate(groups):
                e = ok[(ok["group"] == g) & (ok["cycle"] == c)]["error_pct"]
                if len(e):
                    xs.append(i + (j - (len(cycles) - 1) / 2) * 0.18)
                    med.append(np.median(e))
                    q1.append(np.percentile(e, 25))
                    q3.append(np.percentile(e, 75))
            med, q1, q3 = map(np.asarray, (med, q1, q3))
            ax.errorbar(
                xs, med, yerr=[med - q1, q3 - med], fmt="o", ms=4, capsize=2, color=colours[j % 4], label=c
            )
        counts = ok.drop_duplicates(["vehicle_id", "configuration"]).groupby("group").size()
        ax.set_xticks(range(len(groups)), [f"{g}\n({counts.get(g, 0)})" for g in groups], fontsize=8)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_title(f"error by {kind} (median, quartiles; vehicles)")
        ax.set_ylabel("error of predicted mpg, %")
        ax.legend(fontsize=7)
    return fig


def figure_worst(w):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(16, 0.42 * max(len(w), 4) + 1.2), layout="constrained")
    ax = fig.subplots()
    if len(w):
        y = np.arange(len(w))[::-1]
        e = w["median_error_pct"].to_numpy()
        ax.barh(y, e, color=np.where(e > 0, "tab:blue", "tab:red"))
        labels = [f"{r.make} {r.model} ({r.vehicle_id}#{r.configuration})"[:48] for r in w.itertuples()]
        ax.set_yticks(y, labels, fontsize=7)
        lim = 1.05 * float(np.max(np.abs(e)))
        ax.set_xlim(-lim, lim)
        for yi, r in zip(y, w.itertuples(), strict=True):  # the mechanism on the empty side of the bar
            neg = r.median_error_pct < 0
            ax.text(
                0.01 * lim if neg else -0.01 * lim,
                yi,
                r.mechanism[:150],
                va="center",
                fontsize=5.5,
                ha="left" if neg else "right",
            )
        ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("median error over the vehicle's cycles, % (> 0: predicted mpg too high)")
    ax.set_title(f"The {len(w)} worst vehicles and the mechanism the record points at")
    return fig
