"""The traction battery: an equivalent circuit scaled from one cell, written once.

The pack is ``cells_in_series`` x ``cells_in_parallel`` identical cells. A cell is an open-circuit voltage
U_oc(SOC) behind an internal resistance R(SOC) (discharge and charge values), both tabulated over the state of
charge; the pack's tables follow by scaling (series multiplies the voltage and the resistance, parallel
divides the resistance and multiplies the capacity):

    U_oc,pack = n_s U_oc,cell      R_pack = (n_s / n_p) R_cell      Q_pack = n_p Q_cell        (B1)

At terminal power P (> 0 discharging) the current solves P = (U_oc - R I) I; the root that goes to zero with P
is written in the form that cancels nothing (for P -> 0 and for P < 0 alike):

    I = 2 P / (U_oc + sqrt(U_oc^2 - 4 R P))                                                  (B2)

Where U_oc^2 < 4 R P there is no solution: the pack delivers at most U_oc^2 / (4 R), at I = U_oc / (2 R). The
current is further limited by the cells' current limits (C-rates), the terminal voltage's limits
U_min <= U_oc - R I <= U_max, and by the state of charge's window (no discharge at or below ``soc_min``, no
charge at or above ``soc_max``) (:func:`current_limits`). State of charge by coulomb counting, charge accepted
with the coulombic efficiency eta_c:

    dSOC/dt = -I / Q_pack  (I > 0),    -eta_c I / Q_pack  (I < 0)                             (B3)

Energy: the chemical power U_oc I = terminal power U I + loss R I^2 (B4) is what the energy balance books
as the battery's own; charge kept back by the coulombic efficiency is booked as a loss too (its U_oc share).

Cells (:data:`CELLS`): three presets with their sources, or an ADVISOR energy-storage file (``ESS_*.m``,
read by the safe reader of :mod:`vpsim.engines.matlab`, never executed; its module is the cell).
Each scalar function is an :func:`~vpsim.model.engine.equation`: compiled kernels inline it, Python calls it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from . import tables as tb
from .engine import equation

CHARGE_SECONDS_PER_AH = 3600.0


@dataclass(frozen=True)
class Cell:
    """One cell's tables (SI): ``soc`` ascending over [0, 1]; ``ocv_v``, ``r_discharge_ohm``,
    ``r_charge_ohm`` at those states of charge."""

    name: str
    chemistry: str
    capacity_ah: float
    soc: tuple[float, ...]
    ocv_v: tuple[float, ...]
    r_discharge_ohm: tuple[float, ...]
    r_charge_ohm: tuple[float, ...]
    v_min: float
    v_max: float
    max_discharge_c: float  # continuous discharge current per ampere-hour of capacity
    max_charge_c: float
    coulombic_efficiency: float = 1.0
    mass_kg: float = 0.0
    source: str = ""

    def __post_init__(self):
        check_cell(self)


def check_cell(cell: Cell) -> None:
    """One line naming the cell and the field when the tables cannot describe a cell."""
    where = f"cell {cell.name!r}" + (f" ({cell.source})" if cell.source else "")
    n = len(cell.soc)
    if n < 2:
        raise ParameterError(f"{where}: soc needs at least 2 points, got {n}")
    for key in ("ocv_v", "r_discharge_ohm", "r_charge_ohm"):
        if len(getattr(cell, key)) != n:
            raise ParameterError(f"{where}: {key} has {len(getattr(cell, key))} values, soc has {n}")
    for key in ("soc", "ocv_v", "r_discharge_ohm", "r_charge_ohm"):
        vals = getattr(cell, key)
        if not all(isinstance(x, int | float) and math.isfinite(x) for x in vals):
            raise ParameterError(f"{where}: {key} holds a value that is not a finite number")
    s = np.asarray(cell.soc, float)
    if s[0] < 0.0 or s[-1] > 1.0 or np.any(np.diff(s) <= 0.0):
        raise ParameterError(f"{where}: soc must rise strictly within [0, 1]")
    if min(cell.ocv_v) <= 0.0:
        raise ParameterError(f"{where}: ocv_v must be positive, got {min(cell.ocv_v):g} V")
    if min(cell.r_discharge_ohm) <= 0.0 or min(cell.r_charge_ohm) <= 0.0:
        raise ParameterError(f"{where}: resistances must be positive (an ideal cell has no current limit)")
    for key in ("capacity_ah", "v_min", "v_max", "max_discharge_c", "max_charge_c"):
        x = getattr(cell, key)
        if not (isinstance(x, int | float) and math.isfinite(x) and x > 0.0):
            raise ParameterError(f"{where}: {key} = {x!r}, expected a positive number")
    if not cell.v_min < cell.v_max:
        raise ParameterError(f"{where}: v_min = {cell.v_min:g} V must be below v_max = {cell.v_max:g} V")
    if not 0.5 <= cell.coulombic_efficiency <= 1.0:
        raise ParameterError(f"{where}: coulombic_efficiency = {cell.coulombic_efficiency!r}, expected 0.5-1")


_SOC11 = tuple(i / 10 for i in range(11))

# Cell presets. Values are read from the sources named, to the precision of a published curve; each is
# labelled "reconstructed" in the sense of vpsim's presets: a curve read off a figure, not a measurement of
# ours. The shape of U_oc(SOC) sets the voltage; the resistance sets the losses (a few per cent of the
# energy on a cycle), the capacity the state of charge's swing.
CELLS: dict[str, Cell] = {
    "nmc": Cell(
        name="nmc",
        chemistry="NMC811 / graphite-SiOx, 21700, 5 Ah",
        capacity_ah=5.0,
        soc=_SOC11,
        # full-cell open-circuit voltage of the LG M50 (Chen et al. 2020, J. Electrochem. Soc. 167 080534,
        # fig. 8, GITT at 25 degC), read at 10 % steps
        ocv_v=(3.00, 3.45, 3.55, 3.62, 3.68, 3.75, 3.85, 3.94, 4.03, 4.10, 4.19),
        # DC resistance (10 s pulse) of the same cell, about 25 mOhm mid-SOC, rising towards empty
        r_discharge_ohm=(0.045, 0.032, 0.028, 0.026, 0.025, 0.025, 0.025, 0.025, 0.025, 0.025, 0.026),
        r_charge_ohm=(0.045, 0.032, 0.028, 0.026, 0.025, 0.025, 0.025, 0.025, 0.025, 0.026, 0.028),
        v_min=2.5,
        v_max=4.2,
        # the M50's datasheet gives 1.45C continuous; EV packs of NMC cells give about 3C for 10 s, which
        # is what a drive cycle asks (the class's value, not this cell's)
        max_discharge_c=3.0,
        max_charge_c=1.5,  # regenerative pulses (the datasheet's 0.7C is a full charge's rate)
        coulombic_efficiency=0.999,
        mass_kg=0.0693,
        source="LG INR21700-M50 datasheet; OCV from Chen et al. (2020), reconstructed from their figure",
    ),
    "nmc_hev": Cell(
        name="nmc_hev",
        chemistry="high-power NMC/LMO pouch, 6.5 Ah (hybrid cell)",
        capacity_ah=6.5,
        soc=_SOC11,
        # the NMC full-cell curve above (a hybrid cell's own is within a few tens of mV of it)
        ocv_v=(3.00, 3.45, 3.55, 3.62, 3.68, 3.75, 3.85, 3.94, 4.03, 4.10, 4.19),
        # power cells: about 1.5 mOhm DC mid-SOC (hybrid pouch cells of 5-6.5 Ah publish 1-2 mOhm)
        r_discharge_ohm=(
            0.0030,
            0.0022,
            0.0018,
            0.0016,
            0.0015,
            0.0015,
            0.0015,
            0.0015,
            0.0015,
            0.0016,
            0.0017,
        ),
        r_charge_ohm=(0.0030, 0.0022, 0.0018, 0.0016, 0.0015, 0.0015, 0.0015, 0.0016, 0.0017, 0.0018, 0.0020),
        v_min=2.7,
        v_max=4.2,
        max_discharge_c=20.0,  # 10 s pulses of a hybrid cell
        max_charge_c=15.0,
        coulombic_efficiency=0.999,
        mass_kg=0.20,
        source="high-power lithium-ion pouch cells of hybrid packs (Hyundai Ioniq / Kia Niro: 1.56 kWh, "
        "240 V, "
        "6.5 Ah); reconstructed from their published pack figures",
    ),
    "lfp": Cell(
        name="lfp",
        chemistry="LiFePO4 / graphite, 26650, 2.5 Ah",
        capacity_ah=2.5,
        soc=_SOC11,
        # the flat LFP plateau (A123 ANR26650M1-B datasheet: 3.3 V nominal; the curve's shape from the
        # datasheet's discharge curve at C/5), read at 10 % steps
        ocv_v=(2.80, 3.20, 3.24, 3.27, 3.29, 3.30, 3.30, 3.31, 3.33, 3.34, 3.45),
        r_discharge_ohm=(0.020, 0.013, 0.011, 0.010, 0.010, 0.010, 0.010, 0.010, 0.010, 0.010, 0.011),
        r_charge_ohm=(0.020, 0.013, 0.011, 0.010, 0.010, 0.010, 0.010, 0.010, 0.010, 0.011, 0.013),
        v_min=2.0,
        v_max=3.6,
        max_discharge_c=20.0,  # 50 A continuous (datasheet)
        max_charge_c=4.0,  # 10 A fast charge (datasheet)
        coulombic_efficiency=0.999,
        mass_kg=0.076,
        source="A123 ANR26650M1-B datasheet (DC resistance about 10 mOhm, 1 kHz 6 mOhm); reconstructed",
    ),
    "nimh": Cell(
        name="nimh",
        chemistry="NiMH prismatic, 6.5 Ah (hybrid cell)",
        capacity_ah=6.5,
        soc=_SOC11,
        # a hybrid-vehicle NiMH cell, 1.2 V nominal (Panasonic EV Energy prismatic module of 6 cells,
        # 7.2 V and 6.5 Ah; Kelly, Zolot et al. 2002, NREL/CP-540-31796: Prius pack test), per cell
        ocv_v=(1.18, 1.25, 1.27, 1.28, 1.29, 1.30, 1.31, 1.32, 1.33, 1.35, 1.40),
        r_discharge_ohm=(
            0.0030,
            0.0025,
            0.0022,
            0.0021,
            0.0020,
            0.0020,
            0.0020,
            0.0020,
            0.0021,
            0.0022,
            0.0025,
        ),
        r_charge_ohm=(0.0030, 0.0025, 0.0022, 0.0021, 0.0020, 0.0020, 0.0021, 0.0022, 0.0024, 0.0027, 0.0032),
        v_min=1.0,
        v_max=1.6,
        max_discharge_c=15.0,  # about 100 A pulses of the 6.5 Ah module
        max_charge_c=10.0,
        coulombic_efficiency=0.95,
        mass_kg=0.175,
        source="Panasonic prismatic NiMH module (6 cells, 7.2 V, 6.5 Ah); Kelly et al. 2002; reconstructed",
    ),
}


def cell_from_ess_file(path: str | Path, temperature_c: float = 25.0) -> Cell:
    """A cell from an ADVISOR energy-storage file (``ESS_*.m``): its module is the cell, its tables taken
    at ``temperature_c`` (linear between the file's temperatures, held beyond them)."""
    from ..engines.matlab import read_m_file

    p = Path(path)
    v = read_m_file(p)
    where = p.name

    def need(key, ndim=None):
        if key not in v:
            raise ParameterError(f"{where}: {key} is missing (an ADVISOR ESS file defines it)")
        x = v[key]
        if isinstance(x, str | tuple) or x is None:
            raise ParameterError(f"{where}: {key} must be numeric")
        a = np.atleast_1d(np.asarray(x, float))
        if not np.all(np.isfinite(a)):
            raise ParameterError(f"{where}: {key} holds a value that is not a finite number")
        return a

    soc = need("ess_soc")
    temps = need("ess_tmp")

    def at_temperature(key):
        a = need(key)
        if a.ndim == 1:
            if a.size == soc.size:
                return a
            a = a.reshape(1, -1)
        if a.shape == (soc.size, temps.size):
            a = a.T
        if a.shape != (temps.size, soc.size):
            raise ParameterError(
                f"{where}: {key} is {a.shape[0]}x{a.shape[1]}, expected {temps.size} temperatures x "
                f"{soc.size} states of charge"
            )
        if temps.size == 1:
            return a[0]
        return np.array([np.interp(temperature_c, temps, a[:, j]) for j in range(soc.size)])

    def cap() -> float:
        c = need("ess_max_ah_cap")
        return float(np.interp(temperature_c, temps, c)) if c.size == temps.size else float(c[0])

    order = np.argsort(soc)
    s = soc[order]
    if s.size < 2 or s[0] < 0 or s[-1] > 1 or np.any(np.diff(s) <= 0):
        raise ParameterError(f"{where}: ess_soc must rise strictly within [0, 1]")
    ah = cap()
    coul = need("ess_coulombic_eff")
    eta = float(np.interp(temperature_c, temps, coul)) if coul.size == temps.size else float(coul[0])
    return Cell(
        name=p.stem,
        chemistry=str(v.get("ess_description", p.stem)),
        capacity_ah=ah,
        soc=tuple(float(x) for x in s),
        ocv_v=tuple(float(x) for x in at_temperature("ess_voc")[order]),
        r_discharge_ohm=tuple(float(x) for x in at_temperature("ess_r_dis")[order]),
        r_charge_ohm=tuple(float(x) for x in at_temperature("ess_r_chg")[order]),
        v_min=float(need("ess_min_volts")[0]),
        v_max=float(need("ess_max_volts")[0]),
        # ADVISOR limits the current through the voltage limits only; a generous C-rate leaves that to them
        max_discharge_c=50.0,
        max_charge_c=50.0,
        coulombic_efficiency=min(1.0, max(0.5, eta)),
        mass_kg=float(need("ess_module_mass")[0]) if "ess_module_mass" in v else 0.0,
        source=f"ADVISOR energy-storage file {p.name}",
    )


def resolve_cell(name: str, base_dir: Path | None = None) -> Cell:
    """A preset name (``nmc``, ``lfp``, ``nimh``) or the path of an ``ESS_*.m`` file."""
    if name in CELLS:
        return CELLS[name]
    p = Path(name)
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    if p.suffix.lower() == ".m":
        if not p.exists() and not p.is_symlink():  # (a FIFO, folder or link loop: named by the reader)
            raise ParameterError(f"battery.cell = {name!r}: no such file")
        return cell_from_ess_file(p)
    raise ParameterError(
        f"battery.cell = {name!r}: expected one of {', '.join(CELLS)} or an ADVISOR ESS_*.m file"
    )


@dataclass(frozen=True)
class Pack:
    """The pack's tables and limits (SI), scaled from a cell by (B1); what kernels read."""

    soc: np.ndarray
    ocv_v: np.ndarray
    r_discharge_ohm: np.ndarray
    r_charge_ohm: np.ndarray
    capacity_as: float  # A s
    v_min: float
    v_max: float
    i_max_discharge: float
    i_max_charge: float
    soc_min: float
    soc_max: float
    coulombic_efficiency: float
    mass_kg: float
    cell: Cell = field(repr=False)

    @property
    def energy_wh(self) -> float:
        """Stored energy between SOC 0 and 1, the integral of U_oc dQ (trapezoids of the table)."""
        return float(np.trapezoid(self.ocv_v, self.soc) * self.capacity_as / 3600.0)

    @property
    def inv_soc(self) -> float:
        return tb.inverse_spacing(self.soc)


def pack(cell: Cell, n_series: int, n_parallel: int, soc_min: float, soc_max: float) -> Pack:
    """Scale ``cell`` to a pack of ``n_series`` x ``n_parallel`` cells (B1)."""
    ns, npar = float(n_series), float(n_parallel)
    return Pack(
        soc=np.asarray(cell.soc, float),
        ocv_v=ns * np.asarray(cell.ocv_v, float),
        r_discharge_ohm=ns / npar * np.asarray(cell.r_discharge_ohm, float),
        r_charge_ohm=ns / npar * np.asarray(cell.r_charge_ohm, float),
        capacity_as=npar * cell.capacity_ah * CHARGE_SECONDS_PER_AH,
        v_min=ns * cell.v_min,
        v_max=ns * cell.v_max,
        i_max_discharge=npar * cell.max_discharge_c * cell.capacity_ah,
        i_max_charge=npar * cell.max_charge_c * cell.capacity_ah,
        soc_min=soc_min,
        soc_max=soc_max,
        coulombic_efficiency=cell.coulombic_efficiency,
        mass_kg=ns * npar * cell.mass_kg,
        cell=cell,
    )


# --- equations (scalars; kernels inline them) -------------------------------------------------------------


@equation
def open_circuit_voltage(soc, soc_grid, ocv, inv):
    """U_oc(SOC) of the pack, linear in the table, end values held (B1)."""
    return tb.interp_at(soc, soc_grid, ocv, inv)


@equation
def resistance(current_sign, soc, soc_grid, r_dis, r_chg, inv):
    """R(SOC): the discharge table for current_sign >= 0, the charge table below (B1)."""
    if current_sign >= 0.0:
        return tb.interp_at(soc, soc_grid, r_dis, inv)
    return tb.interp_at(soc, soc_grid, r_chg, inv)


@equation
def current_for_power(p, u_oc, r):
    """The current of terminal power p: the root of p = (U_oc - R I) I that vanishes with p (B2). Where no
    root exists (p > U_oc^2 / 4R) the current of the largest power, U_oc / 2R."""
    disc = u_oc * u_oc - 4.0 * r * p
    if disc <= 0.0:
        return u_oc / (2.0 * r)
    return 2.0 * p / (u_oc + math.sqrt(disc))


@equation
def terminal_voltage(u_oc, r, current):
    """U = U_oc - R I."""
    return u_oc - r * current


@equation
def current_limits(soc, u_oc, r_dis, r_chg, v_min, v_max, i_max_dis, i_max_chg, soc_min, soc_max):
    """(I_low <= 0, I_high >= 0): the currents the pack may carry now. Discharge: the cells' current limit,
    U >= U_min, the largest power (U_oc / 2R) and none at or below soc_min; charge: the cells' limit,
    U <= U_max and none at or above soc_max."""
    hi = min(i_max_dis, (u_oc - v_min) / r_dis, u_oc / (2.0 * r_dis))
    lo = max(-i_max_chg, (u_oc - v_max) / r_chg)
    if soc <= soc_min:
        hi = 0.0
    if soc >= soc_max:
        lo = 0.0
    return min(lo, 0.0), max(hi, 0.0)


@equation
def soc_rate(current, capacity_as, coulombic_efficiency):
    """dSOC/dt by coulomb counting (B3): charge in is counted at the coulombic efficiency."""
    if current >= 0.0:
        return -current / capacity_as
    return -coulombic_efficiency * current / capacity_as


@equation
def chemical_power(u_oc, current, coulombic_efficiency):
    """The pack's stored-energy rate drawn (W; negative while charging): U_oc I discharging, U_oc eta_c I
    charging (the charge not kept is lost), consistent with (B3)."""
    if current >= 0.0:
        return u_oc * current
    return coulombic_efficiency * u_oc * current


@equation
def battery_loss(u_oc, r, current, coulombic_efficiency):
    """Loss (W, >= 0): R I^2, and while charging (1 - eta_c) U_oc |I|, the charge not kept (B4)."""
    loss = r * current * current
    if current < 0.0:
        loss += (1.0 - coulombic_efficiency) * u_oc * (-current)
    return loss
