"""Loss-form variants of the electric machine measured against the six ADVISOR maps (not shipped).

    python benchmarks/machine_loss_variants.py           # leave-one-out and own-fit floor per variant

Reproduces docs/model.md's "Measured again" paragraph. Each variant is the shipped form's seven terms
(:mod:`vpsim.model.machine`) plus candidate terms, written here in the same normalisation (``tau = T / T_r``,
``omega = |w| / w_b``, ``nu = |w| / w_max``, copper by ``T_r w_0``) so that the variants can differ from the
model; ``base`` is the shipped form, and its least-squares figures equal ``benchmarks/machine_fit.py``'s (a
check of this file's transcription). Fits: non-negative least squares on P_loss / P_r (``ls``, as shipped), or
an iteratively reweighted L1 fit of the efficiency error with each file weighted equally (``l1eff``).
Printed per file: leave-one-out median |efficiency error| (points), and with ``--floor`` the smallest median
|error| a Nelder-Mead search finds on the file alone (the form's floor on that map).

Two variants take a datasheet figure of each file beside its rating (read from the file with vpsim's safe
reader), the copper and field-weakening terms times (figure / reference)^0.5: ``copper by torque
density``, the rated torque over ``mc_mass`` (a machine light for its torque runs its copper at a higher
current density); ``copper by P_r / (I V)``, the rated power over ``mc_max_crrnt`` x ``mc_min_volts`` (a
machine that needs much current for its power at the lowest voltage loses more in its windings and
inverter). Several files mark these figures "estimated".
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize, nnls

sys.path.insert(0, str(Path(__file__).resolve().parent))
import machine_fit as mf  # noqa: E402

from vpsim.model.machine import REFERENCE_SPEED_RADPS as W0  # noqa: E402

BASE = ("k0", "k_sw", "k_cu", "k_fw", "k_fe_h", "k_fe_e", "k_mech")
VARIANTS = {
    "base": BASE,
    "+drag omega": BASE + ("omega",),
    "+drag omega, omega^2": BASE + ("omega", "omega2"),
    "+switching tau omega": BASE + ("tau_omega",),
    "copper by P_r": ("k0", "k_sw", "cu_pr", "fw_pr", "k_fe_h", "k_fe_e", "k_mech"),
    "copper by torque density": ("k0", "k_sw", "cu_td", "fw_td", "k_fe_h", "k_fe_e", "k_mech"),
    "copper by P_r / (I V)": ("k0", "k_sw", "cu_iv", "fw_iv", "k_fe_h", "k_fe_e", "k_mech"),
}
# the datasheet-figure variants' references (their spread's middle) and exponent
TORQUE_DENSITY_REF = 3.5  # N m / kg
POWER_PER_IV_REF = 1.5  # W / (A V)
FIGURE_EXPONENT = 0.5
# file name -> {"torque_density": ..., "power_per_iv": ...}, filled by main() from the files
FIGURES: dict[str, dict[str, float]] = {}


def columns(m, t, w) -> dict[str, np.ndarray]:
    tau = np.abs(t) / (m.rated_power_w / m.base_speed_radps)
    om = np.abs(w) / m.base_speed_radps
    nu = np.abs(w) / m.max_speed_radps
    fw = np.maximum(om, 1.0) ** 2 - 1.0
    cs = W0 / m.base_speed_radps
    fig = FIGURES.get(m.name, {"torque_density": TORQUE_DENSITY_REF, "power_per_iv": POWER_PER_IV_REF})
    td = (fig["torque_density"] / TORQUE_DENSITY_REF) ** FIGURE_EXPONENT
    iv = (fig["power_per_iv"] / POWER_PER_IV_REF) ** FIGURE_EXPONENT
    return {
        "k0": np.ones_like(tau),
        "k_sw": tau,
        "k_cu": cs * tau**2,
        "k_fw": cs * tau**2 * fw,
        "k_fe_h": nu,
        "k_fe_e": nu**2,
        "k_mech": nu**3,
        "omega": om,
        "omega2": om**2,
        "tau_omega": tau * om,
        "cu_pr": tau**2,
        "fw_pr": tau**2 * fw,
        "cu_td": td * cs * tau**2,
        "fw_td": td * cs * tau**2 * fw,
        "cu_iv": iv * cs * tau**2,
        "fw_iv": iv * cs * tau**2 * fw,
    }


def datasheet_figures(machines) -> dict[str, dict[str, float]]:
    """Each file's rated torque over ``mc_mass`` and rated power over ``mc_max_crrnt`` x ``mc_min_volts``."""
    from vpsim.engines.matlab import read_m_file

    out = {}
    for name, m in machines.items():
        v = read_m_file(mf.advisor_dir() / f"{name}.m")
        t_r = m.rated_power_w / m.base_speed_radps
        out[m.name] = {
            "torque_density": t_r / float(v["mc_mass"]),
            "power_per_iv": m.rated_power_w / (float(v["mc_max_crrnt"]) * float(v["mc_min_volts"])),
        }
    return out


def design(m, keys):
    t, w, eff = m.map_points()
    pm = t * w
    loss = np.where(pm > 0, pm / eff - pm, -pm * (1 - eff))
    c = columns(m, t, w)
    pin = np.where(pm > 0, pm + loss, np.abs(pm)) / m.rated_power_w
    return np.column_stack([c[k] for k in keys]), loss / m.rated_power_w, pin, t, w, eff


def errors_pts(m, keys, coef):
    x, _, _, t, w, eff = design(m, keys)
    loss = x @ coef
    pm = np.abs(t * w) / m.rated_power_w
    model = np.where(t * w > 0, pm / (pm + loss), (pm - loss) / pm)
    return 100.0 * (model - eff)


def fit(machines, keys, how):
    xs, ys, ws = [], [], []
    for m in machines:
        x, y, pin, *_ = design(m, keys)
        xs.append(x)
        ys.append(y)
        ws.append(np.ones_like(y) if how == "ls" else 1.0 / pin / len(y))
    x, y, wt = np.vstack(xs), np.concatenate(ys), np.concatenate(ws)
    c, _ = nnls(x * wt[:, None], y * wt)
    if how == "l1eff":
        for _ in range(10):
            r = np.abs(x @ c - y) * wt
            w2 = wt / np.sqrt(np.maximum(r, 1e-4 * np.median(r) + 1e-12))
            c, _ = nnls(x * w2[:, None], y * w2)
    return c


def floor(m, keys):
    start = fit([m], keys, "l1eff")

    def f(z):
        return float(np.median(np.abs(errors_pts(m, keys, np.abs(z)))))

    r = minimize(f, start, method="Nelder-Mead", options={"maxiter": 6000, "xatol": 1e-7, "fatol": 1e-5})
    return min(f(start), r.fun)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--floor", action="store_true", help="also the own-fit floor by direct search (slow)")
    args = ap.parse_args(argv)
    if not mf.advisor_dir().is_dir():
        print(f"machine_loss_variants: reference data not found at {mf.advisor_dir()}", file=sys.stderr)
        return 2
    ms = mf.load_all()
    names = list(mf.FILES)
    FIGURES.update(datasheet_figures(ms))
    print("| variant | fit | " + " | ".join(names) + " |")
    print("|---|---|" + "---:|" * len(names))
    for label, keys in VARIANTS.items():
        for how in ("ls", "l1eff"):
            loo = []
            for n in names:
                c = fit([ms[o] for o in names if o != n], keys, how)
                loo.append(np.median(np.abs(errors_pts(ms[n], keys, c))))
            print(f"| {label} | {how} | " + " | ".join(f"{x:.2f}" for x in loo) + " |")
        if args.floor:
            print(f"| {label} | floor | " + " | ".join(f"{floor(ms[n], keys):.2f}" for n in names) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
