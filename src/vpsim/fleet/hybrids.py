"""What the full hybrids (:mod:`vpsim.fleet.hev`) and the mild hybrids (:mod:`vpsim.fleet.mhev`) share: how
a hybrid's tests are read, and the runs their technology is fitted and predicted with (backward, ECMS, the
charge-sustaining figure). Each module keeps what differs: which FTP bags it compares, which fields it
checks, its vehicle mapping and the cycle each test runs on.
"""

from __future__ import annotations

from .epa import CERT_GASOLINE


def read_tests(
    tests: list[dict], cycles: tuple[str, ...], ftp, what: str, fields: tuple[str, ...], figures: str
):
    """(values, hows, first, test_rows, why) of one hybrid's parsed test rows: ``values`` {test: [mpg, ...]}
    over ``cycles``, ``hows`` how the FTPs were read, ``first`` the first test row read, ``test_rows`` the
    excluded ones; ``why`` the vehicle's exclusion reason, or "".

    Certification gasoline only, no cold-CO test; an FTP by ``ftp(row)``: ({test: mpg}, how) or why not; a HWY
    or US06 test its ``RND_ADJ_FE`` as ``hwy`` or ``us06``; any other test is passed over. Excluded: no test
    read (``figures`` names those looked for), or the first one's ``fields``, road load or power to mass
    (:func:`vpsim.fleet.epa.record_problem`). ``what`` names the vehicles in a reason (``hybrid``, ``mild
    hybrid``)."""
    from .epa import _excl, _plausible_mpg, record_problem

    test_rows: list[dict] = []
    values: dict[str, list[float]] = {c: [] for c in cycles}
    hows: set[str] = set()
    used: list[dict] = []
    for t in tests:
        cat = t["category"].upper()
        if t["fuel"] != CERT_GASOLINE or "cold co" in t["procedure"].lower():
            continue
        if cat == "FTP":
            got = ftp(t)
            if isinstance(got, str):
                test_rows.append(_excl(t, f"{what} FTP test: {got}", test=True))
                continue
            for c, x in got[0].items():
                values[c].append(x)
            hows.add(got[1])
        elif cat in ("HWY", "US06"):
            if not _plausible_mpg(t["fe"]):
                test_rows.append(_excl(t, f"{cat} test: RND_ADJ_FE missing or implausible", test=True))
                continue
            values["hwy" if cat == "HWY" else "us06"].append(t["fe"])
        else:
            continue
        used.append(t)
    if not used:
        return values, hows, None, test_rows, f"{what}, no usable test: {figures}"
    problem = record_problem(used[0], fields)
    return values, hows, used[0], test_rows, f"{what}, {problem}" if problem else ""


# --- technology fit ----------------------------------------------------------------------------------------


def cs_run(cycle, params) -> tuple[float, float]:
    """One backward ECMS run of ``params`` on ``cycle``: (charge-sustaining L/100 km, how long the trace's
    power was not deliverable, s)."""
    from ..simulation import simulate

    r = simulate(cycle, "backward", params, ems="ecms")
    s = r.summary()
    return float(s["fuel_l_per_100km_cs"]), float(r.deviations.demand_not_deliverable_s or 0.0)


def cs_fuel_of(cycle_of):
    """``fuel_of(rec, name)`` for :meth:`vpsim.fleet.techgrid.TechGrid.grid_chunk`: the charge-sustaining
    L/100 km of a params' run (:func:`cs_run`) on ``cycle_of(name)``."""

    def fuel_of(rec, name):
        return lambda p: cs_run(cycle_of(name), p)[0]

    return fuel_of


def predict_chunk(items: list[tuple], tech_params: tuple[str, ...], params_of, cycle_of) -> list[dict]:
    """One backward ECMS run per (record, test, technology) of ``params_of(rec, test, {tech_params})`` on
    ``cycle_of(test)``: ``l_per_100km_cs``, ``trace_miss_s``, ``machine_kw``, or ``error``."""
    from .run import _kernels_on_one_thread, _one_line

    out = []
    with _kernels_on_one_thread():
        for rec, name, tech in items:
            row = {"key": rec.key, "cycle": name, "error": ""}
            try:
                p = params_of(rec, name, {k: tech[k] for k in tech_params})
                row["l_per_100km_cs"], row["trace_miss_s"] = cs_run(cycle_of(name), p)
                row["machine_kw"] = p.machine.rated_power / 1e3
            except Exception as exc:
                row["error"] = _one_line(exc)
            out.append(row)
    return out
