"""The fleet's figures over several deals of families into folds (``vpsim fleet-deals``).

A ``vpsim fleet`` run holds out whole families, dealt into folds in an order its ``--seed`` fixes. Every
seed is an equally valid deal, and in the small parts of the list (the electrified cars) a deal moves a
median |error| by up to a point, so a headline from one deal can be a coin toss. This module reads the
output folders of runs on several deals (``vpsim fleet FILE --out DIR --seed N``, one folder per seed) and
gives, per powertrain and test:

* vpsim's and the calibrated FASTSim's median |error|: their mean over the deals and their range (and
  vpsim's 90th percentile |error|, ``vpsim_p90_abs_error_pct``, the other figure the targets name);
* vpsim minus FASTSim (points) on each deal, with that deal's 95 % interval from the paired family
  bootstrap of :func:`vpsim.fleet.report.paired_difference`, and how many deals put the interval below
  zero (vpsim ahead), above it (behind) or across it (not told apart);
* a pooled 95 % interval: the percentiles of every deal's bootstrap draws taken together (the same family
  draws on every deal), so that it holds both what the families drawn and what the deal move. Its verdict
  is "ahead" below zero, "behind" above it, "not told apart" across it. Beside it (``mean_ci95_pts``) the
  interval of the deal-averaged difference, each family draw's difference averaged over the deals: the
  usual reading of repeated cross-validation, narrower; the verdict is the more cautious pooled one's.

The figures are recomputed from each folder's per-row tables (``vehicles.csv``, ``vehicles_ev.csv``,
``vehicles_hev.csv``, ``vehicles_mhev.csv``), the same rows on every deal; ``summary.json`` gives the deal
(its seed, grouping and folds). Folders of different lists, versions, groupings or fold counts, or two
folders of one deal, are refused in one line.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import VpsimError
from ..textio import printable, read_json, read_text
from .calibrate import DEALS, DEFAULT_DEAL
from .report import (
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    EV_CYCLES,
    HEV_CYCLES,
    MHEV_CYCLES,
    check_complete,
    family_bootstrap,
)

# powertrain -> (the folder's per-row table, the tests it holds; None: the conventional run's --cycles)
PARTS = {
    "conventional": ("vehicles.csv", None),
    "bev": ("vehicles_ev.csv", EV_CYCLES),
    "hev": ("vehicles_hev.csv", HEV_CYCLES),
    "mhev": ("vehicles_mhev.csv", MHEV_CYCLES),
}
ROW_KEY = ("vehicle_id", "configuration", "cycle")
PEER_COLUMN = "fastsim_calibrated_error_pct"
NEEDED = (*ROW_KEY, "error_pct", "family")
MAX_TABLE_BYTES = 256 * 1024**2  # a per-row table larger than this is refused (the 2022 list's: about 1 MB)


@dataclass(frozen=True)
class Deal:
    """One output folder of ``vpsim fleet``: its seed and validation, and its per-row tables."""

    folder: Path
    seed: int
    grouping: str
    folds: int
    n_vehicles: int | None  # as its summary.json says
    tables: dict  # powertrain -> DataFrame of the rows with a test of that part
    deal: str = DEFAULT_DEAL  # validation.deal (calibrate.DEALS; folders written before it: the shuffle)

    @property
    def label(self) -> str:
        """``seed N``, or ``<deal> seed N`` for a deal other than the headline's shuffle."""
        return f"seed {self.seed}" if self.deal == DEFAULT_DEAL else f"{self.deal} seed {self.seed}"


def read_deal(folder) -> Deal:
    """A ``vpsim fleet --out`` folder; one clear line when it is not one (or predates ``--seed``)."""
    folder = Path(folder)
    path = folder / "summary.json"
    if not path.is_file():
        raise VpsimError(f"{folder}: no summary.json; expected a folder written by `vpsim fleet --out`")
    check_complete(folder, "summary.json")  # a run killed while writing: its files are of two runs
    s = read_json(path, VpsimError, what="fleet summary")
    v = s.get("validation") if isinstance(s, dict) else None
    if not isinstance(v, dict) or not all(k in v for k in ("grouping", "folds", "seed")):
        raise VpsimError(
            f"{path}: no validation.seed, .grouping and .folds (written before `vpsim fleet --seed`; "
            "run it again)"
        )
    seed, folds = v["seed"], v["folds"]
    if (
        isinstance(seed, bool)
        or not isinstance(seed, int)
        or isinstance(folds, bool)
        or not isinstance(folds, int)
    ):
        raise VpsimError(f"{path}: validation.seed {seed!r} and .folds {folds!r}: expected whole numbers")
    deal = v.get("deal", DEFAULT_DEAL)
    if not isinstance(deal, str) or deal not in DEALS:
        raise VpsimError(f"{path}: validation.deal {str(deal)[:40]!r}: expected {' or '.join(DEALS)}")
    tables = {}
    for pt, (name, _) in PARTS.items():
        f = folder / name
        if not f.is_file():
            if pt == "conventional":
                raise VpsimError(f"{f}: missing; expected the table `vpsim fleet --out` writes")
            continue
        text = read_text(f, VpsimError, limit=MAX_TABLE_BYTES, what="fleet table")
        try:
            df = pd.read_csv(io.StringIO(text))
        except (pd.errors.ParserError, pd.errors.EmptyDataError) as e:
            raise VpsimError(f"{f}: not a table ({printable(str(e).splitlines()[0])[:200]})") from None
        missing = [c for c in NEEDED if c not in df.columns]
        if missing and len(df):
            raise VpsimError(f"{f}: no column {', '.join(missing)} (written by an older vpsim; run it again)")
        for col in ("error_pct", PEER_COLUMN):
            if col in df.columns:
                values = pd.to_numeric(df[col], errors="coerce")
                bad = values.isna() & df[col].notna()
                if bad.any():
                    i = int(np.flatnonzero(bad.to_numpy())[0])
                    raise VpsimError(
                        f"{f}: {col} {str(df[col].iloc[i])[:40]!r} on data row {i + 1}: expected a number "
                        "(or empty: no prediction)"
                    )
                df[col] = values.astype(float)
        if len(df) and df["family"].isna().any():
            i = int(np.flatnonzero(df["family"].isna().to_numpy())[0])
            raise VpsimError(f"{f}: family empty on data row {i + 1}: every row names its family")
        tables[pt] = df
    n = s.get("n_vehicles")
    n = n if isinstance(n, int) and not isinstance(n, bool) else None
    return Deal(folder, seed, str(v["grouping"]), folds, n, tables, deal)


def _part_tests(deal: Deal, pt: str) -> tuple[str, ...]:
    tests = PARTS[pt][1]
    if tests is None:  # the conventional run's --cycles, in the order the fleet knows them
        df = deal.tables[pt]
        return tuple(dict.fromkeys(df["cycle"])) if len(df) else ()
    return tests


def _check_same_validation(deals: Sequence[Deal]) -> None:
    first = deals[0]
    seen = {}
    for d in deals:
        if (d.grouping, d.folds) != (first.grouping, first.folds):
            raise VpsimError(
                f"{d.folder} holds out by {d.grouping} in {d.folds} folds, {first.folder} by "
                f"{first.grouping} in {first.folds}: compare deals of one validation"
            )
        if (d.deal, d.seed) in seen:
            raise VpsimError(
                f"{seen[d.deal, d.seed]} and {d.folder} are the same deal ({d.label}): give each deal once"
            )
        seen[d.deal, d.seed] = d.folder


def _rows(deal: Deal, pt: str, test: str, reference: pd.DataFrame | None) -> pd.DataFrame:
    df = deal.tables[pt]
    rows = df[df["cycle"] == test].sort_values(list(ROW_KEY), kind="stable").reset_index(drop=True)
    if reference is not None:
        same = len(rows) == len(reference) and all(
            (rows[k].astype(str).to_numpy() == reference[k].astype(str).to_numpy()).all() for k in ROW_KEY
        )
        if not same:
            raise VpsimError(
                f"{deal.folder / PARTS[pt][0]}: its {test} rows ({len(rows)}) are not those of the first "
                f"folder ({len(reference)}): the deals must be runs of one list with one version of vpsim"
            )
    return rows


def _range(values: list) -> dict:
    x = np.asarray([np.nan if v is None else v for v in values], float)
    if not np.isfinite(x).all():
        return {"mean": None, "min": None, "max": None, "by_deal": [None if v is None else v for v in values]}
    return {
        "mean": round(float(x.mean()), 3),
        "min": round(float(x.min()), 3),
        "max": round(float(x.max()), 3),
        "by_deal": [round(float(v), 3) for v in x],
    }


def _test_figures(deals, pt, test, resamples, seed) -> dict | None:
    reference = None
    vp, vp90, peer, diff, ci, pools, n_fam = [], [], [], [], [], [], None
    for d in deals:
        rows = _rows(d, pt, test, reference)
        reference = rows if reference is None else reference
        e = rows["error_pct"].to_numpy(float)
        ok = np.isfinite(e)
        vp.append(float(np.median(np.abs(e[ok]))) if ok.any() else None)
        vp90.append(float(np.percentile(np.abs(e[ok]), 90)) if ok.any() else None)
        q = rows[PEER_COLUMN].to_numpy(float) if PEER_COLUMN in rows else np.full(len(rows), np.nan)
        drawn = family_bootstrap(e, q, rows["family"], resamples, seed)
        if drawn is None:
            peer.append(None)
            diff.append(None)
            ci.append(None)
            continue
        ee, qq, n_fam, draws = drawn
        peer.append(float(np.median(qq)))
        diff.append(float(np.median(ee) - np.median(qq)))
        ci.append([round(float(x), 3) for x in np.percentile(draws, [2.5, 97.5])])
        pools.append(draws)
    if reference is None or not len(reference):
        return None
    predicted = np.isfinite(reference["error_pct"].to_numpy(float))
    out = {
        "n": int(predicted.sum()),  # rows vpsim predicts; the differences: those both tools predict
        "families": n_fam if n_fam is not None else int(reference["family"][predicted].nunique()),
        "vpsim_median_abs_error_pct": _range(vp),
        "vpsim_p90_abs_error_pct": _range(vp90),
        "peer_median_abs_error_pct": _range(peer),
        "difference_pts": _range(diff),
        "ci95_pts_by_deal": ci,
    }
    if len(pools) < len(deals):
        out["verdict"] = "no peer"
        out["verdict_reason"] = (
            "the calibrated FASTSim was not run on every deal (--no-peer, or not installed)"
        )
        return out
    pooled = np.concatenate(pools)
    lo, hi = np.percentile(pooled, [2.5, 97.5])
    out.update(
        deals_vpsim_ahead=sum(c[1] < 0.0 for c in ci),
        deals_not_told_apart=sum(c[0] <= 0.0 <= c[1] for c in ci),
        deals_vpsim_behind=sum(c[0] > 0.0 for c in ci),
        pooled_ci95_pts=[round(float(lo), 3), round(float(hi), 3)],
        pooled_share_vpsim_lower=round(float(np.mean(pooled < 0.0)), 3),
        # the interval of the deal-averaged difference (each family draw's difference averaged over the
        # deals, the usual reading of repeated cross-validation): narrower; the verdict is the pooled one's
        mean_ci95_pts=[round(float(x), 3) for x in np.percentile(np.mean(pools, axis=0), [2.5, 97.5])],
        verdict="ahead" if hi < 0.0 else "behind" if lo > 0.0 else "not told apart",
    )
    return out


@dataclass(frozen=True)
class DealComparison:
    """vpsim against the calibrated FASTSim over several deals (:func:`compare_deals`). ``print`` it,
    ``.as_dict()`` (what ``vpsim fleet-deals --json`` prints), ``.to_frame()`` (a row per powertrain, test
    and deal) and ``.plot()`` (each deal's difference and interval, and the pooled interval)."""

    deals: tuple[Deal, ...]
    tests: dict  # powertrain -> test -> figures
    resamples: int

    def as_dict(self) -> dict:
        d0 = self.deals[0]
        return {
            "deals": [
                {"folder": str(d.folder), "seed": d.seed, "deal": d.deal, "n_vehicles": d.n_vehicles}
                for d in self.deals
            ],
            "grouping": d0.grouping,
            "folds": d0.folds,
            "resamples_per_deal": self.resamples,
            "tests": self.tests,
        }

    def to_frame(self) -> pd.DataFrame:
        rows = []
        for pt, tests in self.tests.items():
            for test, f in tests.items():
                for i, d in enumerate(self.deals):
                    c = f["ci95_pts_by_deal"][i]
                    rows.append(
                        {
                            "powertrain": pt,
                            "test": test,
                            "seed": d.seed,
                            "deal": d.deal,
                            "folder": str(d.folder),
                            "n": f["n"],
                            "vpsim_median_abs_error_pct": f["vpsim_median_abs_error_pct"]["by_deal"][i],
                            "vpsim_p90_abs_error_pct": f["vpsim_p90_abs_error_pct"]["by_deal"][i],
                            "peer_median_abs_error_pct": f["peer_median_abs_error_pct"]["by_deal"][i],
                            "difference_pts": f["difference_pts"]["by_deal"][i],
                            "ci95_low_pts": None if c is None else c[0],
                            "ci95_high_pts": None if c is None else c[1],
                        }
                    )
        return pd.DataFrame(rows)

    def __str__(self) -> str:
        d0 = self.deals[0]
        seeds = ", ".join(d.label.removeprefix("seed ") for d in self.deals)
        L = [
            f"{len(self.deals)} deals of {d0.grouping} folds ({d0.folds} folds), seeds {seeds}",
            "median |error| %: mean over the deals [lowest-highest]; vpsim minus the calibrated FASTSim, "
            "points: mean [range]; deals with vpsim's 95 % interval below / across / above zero; pooled "
            "interval (every deal's bootstrap draws)",
            f"{'powertrain':12s} {'test':9s} {'n':>4s}  {'vpsim':>19s}  {'FASTSim cal.':>19s}  "
            f"{'difference':>20s}  {'ahead/tie/behind':>16s}  {'pooled interval':>16s}  verdict",
        ]

        def trio(r):
            if r["mean"] is None:
                return f"{'–':>19s}"
            return f"{r['mean']:5.2f} [{r['min']:.2f}-{r['max']:.2f}]".rjust(19)

        for pt, tests in self.tests.items():
            for test, f in tests.items():
                line = f"{pt:12s} {test:9s} {f['n']:4d}  {trio(f['vpsim_median_abs_error_pct'])}  "
                line += f"{trio(f['peer_median_abs_error_pct'])}  "
                dr = f["difference_pts"]
                if f["verdict"] == "no peer":
                    L.append(line + f"{'–':>20s}  {'–':>16s}  {'–':>16s}  no peer")
                    continue
                line += f"{dr['mean']:+6.2f} [{dr['min']:+.2f}, {dr['max']:+.2f}]".rjust(20) + "  "
                counts = f"{f['deals_vpsim_ahead']}/{f['deals_not_told_apart']}/{f['deals_vpsim_behind']}"
                lo, hi = f["pooled_ci95_pts"]
                L.append(line + f"{counts:>16s}  {f'{lo:+.2f} to {hi:+.2f}':>16s}  {f['verdict']}")
        return "\n".join(L)

    def plot(self, ax=None):
        """Each deal's vpsim-minus-FASTSim difference with its 95 % interval, and below them the pooled
        interval (a dark bar) with the mean over the deals (a diamond), per powertrain and test; zero is the
        line where the two tools are level."""
        import matplotlib.pyplot as plt

        items = [
            (pt, test, f)
            for pt, tests in self.tests.items()
            for test, f in tests.items()
            if f["verdict"] != "no peer"
        ]
        if ax is None:
            _, ax = plt.subplots(figsize=(7.5, 0.42 * max(len(items), 3) + 1.2))
        n = len(self.deals)
        for y, (_, _, f) in enumerate(items):
            for i, d in enumerate(self.deals):  # the deals fanned out above the pooled bar
                yy = y - 0.38 + 0.5 * i / max(n - 1, 1)
                c = f["ci95_pts_by_deal"][i]
                x = f["difference_pts"]["by_deal"][i]
                ax.errorbar(
                    x,
                    yy,
                    xerr=[[x - c[0]], [c[1] - x]],
                    fmt="o",
                    ms=2.5,
                    lw=0.7,
                    alpha=0.8,
                    color=f"C{i % 10}",
                    label=d.label if y == 0 else None,
                )
            lo, hi = f["pooled_ci95_pts"]
            ax.plot(
                [lo, hi],
                [y + 0.28, y + 0.28],
                color="0.3",
                lw=4,
                solid_capstyle="butt",
                label="pooled 95 % interval" if y == 0 else None,
            )
            ax.plot(
                f["difference_pts"]["mean"],
                y + 0.28,
                "D",
                color="k",
                ms=4,
                label="mean over the deals" if y == 0 else None,
            )
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_yticks(range(len(items)), [f"{pt} {test}" for pt, test, _ in items])
        ax.invert_yaxis()
        ax.set_xlabel("vpsim minus calibrated FASTSim, median |error| (points; < 0: vpsim closer)")
        ax.set_title(f"{n} deals of families into folds, each with its 95 % interval", fontsize=10)
        if items:
            ax.legend(fontsize=7, loc="best")
        return ax


def compare_deals(
    folders: Sequence, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> DealComparison:
    """The figures of ``vpsim fleet`` output ``folders`` (two or more deals of one list) side by side."""
    folders = list(folders)
    if len(folders) < 2:
        raise VpsimError(
            f"{len(folders)} folder given: give two or more `vpsim fleet --out` folders, each run with "
            "its own --seed"
        )
    deals = tuple(read_deal(f) for f in folders)
    _check_same_validation(deals)
    tests = {}
    for pt in PARTS:
        have = [pt in d.tables for d in deals]
        if not any(have):
            continue
        if not all(have):
            lacking = deals[have.index(False)].folder
            raise VpsimError(f"{lacking}: no {PARTS[pt][0]}, which {deals[have.index(True)].folder} has")
        cycles = [set(d.tables[pt]["cycle"]) if len(d.tables[pt]) else set() for d in deals]
        for d, c in zip(deals[1:], cycles[1:], strict=True):
            if c != cycles[0]:
                raise VpsimError(
                    f"{d.folder / PARTS[pt][0]}: tests {', '.join(sorted(c)) or 'none'}, against "
                    f"{', '.join(sorted(cycles[0])) or 'none'} in {deals[0].folder}: run every deal on the "
                    "same tests"
                )
        part = {}
        for test in _part_tests(deals[0], pt):
            f = _test_figures(deals, pt, test, resamples, seed)
            if f is not None:
                part[test] = f
        if part:
            tests[pt] = part
    return DealComparison(deals, tests, resamples)
