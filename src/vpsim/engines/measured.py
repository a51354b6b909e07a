"""Measured engines: a fuel-flow map on a speed x torque grid plus a full-load torque curve.

    >>> from vpsim.engines.measured import MeasuredEngine
    >>> import numpy as np
    >>> e = MeasuredEngine(
    ...     name="toy", speed_grid=np.array([100.0, 200.0]), torque_grid=np.array([10.0, 20.0]),
    ...     fuel_flow=np.array([[1.0, 2.0], [3.0, 4.0]]) * 1e-3, max_torque_speed=np.array([100.0, 200.0]),
    ...     max_torque=np.array([20.0, 20.0]), inertia=0.1, displacement=1e-3, fuel_density=0.749,
    ...     fuel_lhv=42.6e6, source="example")
    >>> round(e.fuel_flow_at(15.0, 150.0) * 1e3, 6)
    2.5

Units are SI throughout: rad/s, N*m, kg/s, kg*m^2, m^3, J/kg; the fuel density is in kg/L.

ADVISOR maps are oriented with rows = speed and columns = torque (``fuel_flow[i, j]`` is at
``speed_grid[i]``, ``torque_grid[j]``), as ADVISOR's ``meshgrid(fc_map_trq, fc_map_spd)``.

Outside the measured grid, :meth:`MeasuredEngine.fuel_flow_at` does this:

* speed below or above the grid is clamped to the first or last grid speed;
* torque below the first or above the last grid column is extrapolated linearly from the two nearest
  columns (fuel flow is close to linear in torque at fixed speed, the Willans line), and the result is
  never less than zero;
* the optional ``outside`` mask marks every point that was clamped or extrapolated, so callers can say how
  much of a cycle relied on it.

Caveat: the Geo Metro map (``FC_SI41_emis``) starts at 6.8 N*m and has no zero-torque column. Its two lowest
columns have equal g/kWh at several speeds, so extrapolating to zero torque gives (close to) zero fuel flow,
while a real engine at zero torque still burns idle fuel. Points at low torque are flagged in ``outside``;
use an idle or motoring fuel model there. The Saturn map (``FC_SI63_emis``) has a zero-torque column, but its
full-load curve (up to 145 N*m) rises above its highest map column (135.8 N*m) at mid speeds, so full-load
points are extrapolated and flagged too.

:class:`MeasuredEngineMap` (``engine.engine_map()``) is the view the backward method consumes, with the same
``fuel_flow(T, w)``, ``max_torque(w)``, ``min_torque(w)``, ``inertia`` and ``name`` as the generated map
(:class:`vpsim.model.maps.GeneratedEngineMap`). It adds the rules for the part of a drive cycle the
measurements do
not cover (zero and negative torque, speeds below the map); see its docstring and docs/scaling.md.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EngineFileError
from ..textio import check_path, read_text
from ._matlab_base import MAX_FILE_BYTES
from .matlab import read_m_file

__all__ = ["MeasuredEngine", "MeasuredEngineMap", "load_engine"]

# Units the JSON conversions in shared/data/engines state in their "units" table (ADVISOR's own units).
_JSON_UNITS = {
    "fc_map_spd": "rad/s",
    "fc_map_trq": "N*m",
    "fc_fuel_map": "g/s",
    "fc_max_trq": "N*m",
    "fc_disp": "L",
    "fc_inertia": "kg*m^2",
    "fc_fuel_den": "g/L",
    "fc_fuel_lhv": "J/g",
    "fc_max_trq_spd": "rad/s",
    "fc_ct_trq": "N*m",
}
JSON_FORMAT = "vpsim-engine/1"  # the "format" tag of the JSON that MeasuredEngine.write_json writes


# Plausibility of a measured engine's metadata (SI; fuel density in kg/L). Hard limits (an error): values no
# fuel or engine has, which signal wrong units. Per-fuel ranges and the BSFC range give warnings.
FUEL_DENSITY_RANGE = (0.0005, 1.5)  # kg/L: compressed natural gas at 1 bar (0.0007) to heavy oils
FUEL_LHV_RANGE = (5.0e6, 1.5e8)  # J/kg: methanol-water blends to hydrogen (120 MJ/kg)
DISPLACEMENT_RANGE = (0.01e-3, 30.0e-3)  # m^3
PLAUSIBLE_MIN_BSFC = (150.0, 1000.0)  # g/kWh: best brake efficiency about 55 % (large Diesel) to 8 %
REFUSED_MIN_BSFC = 10 * PLAUSIBLE_MIN_BSFC[1]  # g/kWh (0.8 %): a unit slip (mg/s for g/s), not an engine
FUELS: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    # fuel: ((density kg/L), (lower heating value J/kg))
    "gasoline": ((0.69, 0.79), (40.0e6, 44.5e6)),
    "diesel": ((0.80, 0.89), (41.5e6, 43.5e6)),
    "cng": ((0.0006, 0.3), (44.0e6, 50.5e6)),
    "lpg": ((0.49, 0.58), (45.0e6, 47.0e6)),
    "e85": ((0.76, 0.80), (28.0e6, 30.5e6)),
    "hydrogen": ((0.00007, 0.08), (118.0e6, 121.0e6)),
}
_FUEL_ALIASES = {
    "gas": "gasoline",
    "gasoline": "gasoline",
    "petrol": "gasoline",
    "si": "gasoline",
    "diesel": "diesel",
    "ci": "diesel",
    "natural gas": "cng",
    "cng": "cng",
    "lng": "cng",
    "lpg": "lpg",
    "propane": "lpg",
    "e85": "e85",
    "ethanol": "e85",
    "hydrogen": "hydrogen",
    "h2": "hydrogen",
}


def _fuel_type(value: Any, p: Path) -> str | None:
    if value is None:
        return None
    if not isinstance(value, str) or len(value) > 100:
        raise EngineFileError(f"{p}: fc_fuel_type must be a short text such as 'Gasoline'")
    return value


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def checked_arrays(obj, numeric, axes, bad) -> dict[str, np.ndarray]:
    """The fields ``numeric`` of a measured map ``obj`` as float arrays, each finite, and each of ``axes`` a
    strictly increasing 1-D grid of at least two points; ``bad(message)`` makes the one-line error raised."""
    arrays: dict[str, np.ndarray] = {}
    for field_name in numeric:
        try:
            a = np.array(getattr(obj, field_name), dtype=float)
        except (TypeError, ValueError):
            raise bad(f"{field_name} is not numeric") from None
        if not np.all(np.isfinite(a)):
            raise bad(f"{field_name} holds non-finite values (NaN or infinity)")
        arrays[field_name] = a
    for field_name in axes:
        a = arrays[field_name]
        if a.ndim != 1 or a.size < 2:
            raise bad(f"{field_name} must be a 1-D array of at least 2 points, got shape {a.shape}")
        if not np.all(np.diff(a) > 0):
            raise bad(f"{field_name} must be strictly increasing")
    return arrays


@dataclass(frozen=True, eq=False)
class MeasuredEngine:
    """An engine described by measured data (for example an ADVISOR fuel-converter file).

    Attributes are SI: ``speed_grid`` rad/s (strictly increasing), ``torque_grid`` N*m (strictly
    increasing), ``fuel_flow`` kg/s with shape ``(n_speed, n_torque)``, ``max_torque_speed`` rad/s and
    ``max_torque`` N*m (full-load curve), ``inertia`` kg*m^2, ``displacement`` m^3, ``fuel_density`` kg/L,
    ``fuel_lhv`` J/kg. ``source`` says where the data came from. ``closed_throttle_torque`` (N*m, <= 0, over
    ``speed_grid``) is ADVISOR's ``fc_ct_trq``, the torque of the closed-throttle (motoring) engine, where the
    file gives it; ``None`` otherwise. Arrays are stored read-only.
    Instances compare by identity (``eq=False``) because their fields are arrays.
    """

    name: str
    speed_grid: np.ndarray
    torque_grid: np.ndarray
    fuel_flow: np.ndarray
    max_torque_speed: np.ndarray
    max_torque: np.ndarray
    inertia: float
    displacement: float
    fuel_density: float
    fuel_lhv: float
    source: str
    closed_throttle_torque: np.ndarray | None = None
    fuel_type: str | None = None  # ADVISOR's fc_fuel_type ("Gasoline", "Diesel", "CNG", ...) where given

    def __post_init__(self) -> None:
        where = self.source or self.name

        def bad(msg: str) -> EngineFileError:
            return EngineFileError(f"{where}: {msg}")

        arrays = checked_arrays(
            self,
            ("speed_grid", "torque_grid", "fuel_flow", "max_torque_speed", "max_torque"),
            ("speed_grid", "torque_grid", "max_torque_speed"),
            bad,
        )
        if arrays["speed_grid"][0] < 0 or arrays["max_torque_speed"][0] < 0:
            raise bad("speeds must not be negative")
        shape = (arrays["speed_grid"].size, arrays["torque_grid"].size)
        if arrays["fuel_flow"].shape != shape:
            got = arrays["fuel_flow"].shape
            raise bad(f"fuel_flow has shape {got}, expected (n_speed, n_torque) = {shape}")
        if np.any(arrays["fuel_flow"] < 0):
            raise bad("fuel_flow holds negative values")
        if arrays["max_torque"].shape != arrays["max_torque_speed"].shape:
            raise bad("max_torque and max_torque_speed differ in length")
        if not np.all(arrays["max_torque"] > 0):
            raise bad("max_torque must be positive everywhere")
        if self.closed_throttle_torque is not None:
            try:
                ct = np.array(self.closed_throttle_torque, dtype=float)
            except (TypeError, ValueError):
                raise bad("closed_throttle_torque is not numeric") from None
            if ct.ndim == 0:
                ct = np.full(shape[0], float(ct))
            if ct.shape != (shape[0],):
                raise bad(f"closed_throttle_torque has shape {ct.shape}, expected ({shape[0]},)")
            if not np.all(np.isfinite(ct)) or np.any(ct > 0):
                raise bad("closed_throttle_torque must be finite and not positive (a motoring torque)")
            arrays["closed_throttle_torque"] = ct
        for field_name, a in arrays.items():
            object.__setattr__(self, field_name, _frozen(a))
        for field_name, positive in (
            ("inertia", False),
            ("displacement", True),
            ("fuel_density", True),
            ("fuel_lhv", True),
        ):
            try:
                x = float(getattr(self, field_name))
            except (TypeError, ValueError):
                raise bad(f"{field_name} is not a number") from None
            if not math.isfinite(x) or x < 0 or (positive and x == 0):
                kind = "positive" if positive else "non-negative"
                raise bad(f"{field_name} must be a finite {kind} number")
            object.__setattr__(self, field_name, x)
        if self.fuel_type is not None and not isinstance(self.fuel_type, str):
            raise bad(f"fuel_type = {self.fuel_type!r} must be a text such as 'Gasoline'")
        for field_name, (lo, hi), unit, scale in (
            ("fuel_density", FUEL_DENSITY_RANGE, "kg/L", 1.0),
            ("fuel_lhv", FUEL_LHV_RANGE, "MJ/kg", 1e-6),
            ("displacement", DISPLACEMENT_RANGE, "L", 1e3),
        ):
            x = getattr(self, field_name)
            if not lo <= x <= hi:
                raise bad(
                    f"{field_name} = {x * scale:g} {unit} is outside the plausible range "
                    f"[{lo * scale:g}, {hi * scale:g}] {unit} (fc_fuel_den g/L, fc_fuel_lhv J/g, fc_disp L)"
                )
        eff = self.peak_efficiency()
        if eff is not None and eff > 1.0:
            raise bad(
                f"the map gives a brake efficiency of {eff * 100:.4g} % (fuel power below shaft power) at a "
                "node; fc_fuel_map must be fuel flow in g/s and fc_fuel_lhv in J/g"
            )

    # ------------------------------------------------------------------ sanity against the metadata

    def _bsfc_nodes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(BSFC g/kWh, torque, speed) at the measured nodes with positive torque and speed on or below the
        full-load curve and positive fuel flow (nodes above it are fill-in, not operating points)."""
        t_node, w_node = np.meshgrid(self.torque_grid, self.speed_grid)
        usable = (t_node > 0) & (w_node > 0) & (t_node <= self.max_torque_at(w_node) + 1e-9)
        usable &= self.fuel_flow > 0
        with np.errstate(all="ignore"):  # extreme grids: a non-finite BSFC is left out below
            bsfc = self.fuel_flow[usable] * 1e3 / (t_node[usable] * w_node[usable] / 1e3) * 3600.0
        ok = np.isfinite(bsfc) & (bsfc > 0)
        return bsfc[ok], t_node[usable][ok], w_node[usable][ok]

    def peak_efficiency(self) -> float | None:
        """Largest brake efficiency T w / (mdot_f LHV) over the measured operating nodes (None if none)."""
        bsfc, _, _ = self._bsfc_nodes()
        if bsfc.size == 0:
            return None
        return float(3.6e9 / (float(np.min(bsfc)) * self.fuel_lhv))  # g/kWh -> efficiency

    def fuel(self) -> str | None:
        """The fuel as a key of :data:`FUELS` ("gasoline", "diesel", ...), None when the file names none,
        "unknown" when it names one vpsim does not know."""
        if self.fuel_type is None:
            return None
        key = self.fuel_type.strip().lower()
        return _FUEL_ALIASES.get(key, key if key in FUELS else "unknown")

    def sanity_warnings(self) -> list[str]:
        """What looks wrong against the file's own metadata: fuel density and heating value for its fuel
        type, and a BSFC range plausible for a piston engine. One line each; empty when all is plausible."""
        out = []
        fuel = self.fuel()
        if fuel == "unknown":
            out.append(f"fuel type {self.fuel_type!r} is not one vpsim knows ({', '.join(FUELS)})")
        elif fuel is not None:
            (d_lo, d_hi), (l_lo, l_hi) = FUELS[fuel]
            if not d_lo <= self.fuel_density <= d_hi:
                out.append(
                    f"fuel density {self.fuel_density:g} kg/L is not that of {fuel} ({d_lo:g}-{d_hi:g} kg/L)"
                )
            if not l_lo <= self.fuel_lhv <= l_hi:
                out.append(
                    f"fuel heating value {self.fuel_lhv / 1e6:g} MJ/kg is not that of {fuel} "
                    f"({l_lo / 1e6:g}-{l_hi / 1e6:g} MJ/kg)"
                )
        bsfc, _, _ = self._bsfc_nodes()
        if bsfc.size:
            lo, hi = PLAUSIBLE_MIN_BSFC
            b = float(np.min(bsfc))
            if not lo <= b <= hi:
                out.append(
                    f"minimum BSFC {b:.4g} g/kWh is outside the {lo:g}-{hi:g} g/kWh of piston engines "
                    "(fc_fuel_map not in g/s, or fc_map_trq / fc_map_spd not in N*m and rad/s?)"
                )
        return out

    def check_gasoline(self, fuel_density_kg_per_l: float | None = None) -> None:
        """Refuse (EngineFileError) to stand for a gasoline engine: vpsim's model is a gasoline SI engine and
        its fuel is counted in litres of gasoline, so a Diesel, CNG, ... map, or one whose fuel density
        differs by more than 3 % from ``fuel_density_kg_per_l``, cannot be compared with it in litres. Nor can
        a map whose best BSFC is ten times any piston engine's (:data:`REFUSED_MIN_BSFC`; between that and
        :data:`PLAUSIBLE_MIN_BSFC` it is a warning): its fuel is in other units or nonsense, and a fit or a
        cycle's fuel from it would be a number of hundreds of digits. (Too low a BSFC, a brake efficiency
        above any engine's, is refused when the map is read.)"""
        where = self.source or self.name
        fuel = self.fuel()
        if fuel is not None and fuel != "gasoline":
            raise EngineFileError(
                f"{where}: fuel type {self.fuel_type!r}: vpsim compares measured maps with its gasoline SI "
                "engine in litres of gasoline; a map of another fuel cannot be compared"
            )
        bsfc, _, _ = self._bsfc_nodes()
        hi = REFUSED_MIN_BSFC
        if bsfc.size == 0:  # (none finite: a map of 1e306 g/s overflows)
            raise EngineFileError(f"{where}: no measured node below full load gives a finite, positive BSFC")
        if not float(np.min(bsfc)) <= hi:
            raise EngineFileError(
                f"{where}: minimum BSFC {float(np.min(bsfc)):.4g} g/kWh is more than {hi:g} g/kWh, ten times "
                "any piston engine's (fc_fuel_map not in g/s?); such a map cannot be compared or fitted"
            )
        d = fuel_density_kg_per_l
        if d is not None and abs(self.fuel_density / d - 1.0) > 0.03:
            raise EngineFileError(
                f"{where}: fuel density {self.fuel_density:g} kg/L (fc_fuel_den) differs from the "
                f"vehicle's simulation.fuel_density {d:g} kg/L by more than 3 %; litres would not compare"
            )

    # ------------------------------------------------------------------ interpolation

    def fuel_flow_at(self, torque: Any, speed: Any, return_outside: bool = False) -> Any:
        """Fuel mass flow (kg/s) at engine torque (N*m) and speed (rad/s), bilinear on the map.

        ``torque`` and ``speed`` broadcast against each other. Exact at grid nodes. Outside the grid,
        speed is clamped to the grid ends and torque is extrapolated linearly from the two nearest columns,
        never below zero flow (see the module docstring). NaN inputs give NaN flow, flagged as outside.
        With ``return_outside=True`` the result is ``(flow, outside)``, where ``outside`` is a boolean
        array (or bool for scalar inputs) that is True where the point was outside the measured grid.
        Scalar inputs give a float.
        """
        t, w = np.broadcast_arrays(np.asarray(torque, dtype=float), np.asarray(speed, dtype=float))
        sg, tg, f = self.speed_grid, self.torque_grid, self.fuel_flow
        with np.errstate(invalid="ignore"):
            outside = ~((w >= sg[0]) & (w <= sg[-1]) & (t >= tg[0]) & (t <= tg[-1]))
        ws_clamped = np.clip(w, sg[0], sg[-1])
        i = np.clip(np.searchsorted(sg, ws_clamped, side="right") - 1, 0, sg.size - 2)
        a = (ws_clamped - sg[i]) / (sg[i + 1] - sg[i])
        j = np.clip(np.searchsorted(tg, t, side="right") - 1, 0, tg.size - 2)  # t outside: j is an end cell
        b = (t - tg[j]) / (tg[j + 1] - tg[j])  # < 0 or > 1 outside: linear extrapolation in torque
        low = (1.0 - b) * f[i, j] + b * f[i, j + 1]
        high = (1.0 - b) * f[i + 1, j] + b * f[i + 1, j + 1]
        flow = (1.0 - a) * low + a * high
        flow = np.maximum(flow, 0.0)  # NaN stays NaN
        if flow.ndim == 0:
            result: Any = float(flow)
            mask: Any = bool(outside)
        else:
            result, mask = flow, outside
        return (result, mask) if return_outside else result

    def max_torque_at(self, speed: Any) -> Any:
        """Full-load torque (N*m) at ``speed`` (rad/s): linear in the curve, clamped to its end values."""
        out = np.interp(np.asarray(speed, dtype=float), self.max_torque_speed, self.max_torque)
        return float(out) if np.ndim(out) == 0 else out

    def engine_map(
        self, *, low_speed: str = "proportional", zero_torque_column: str = "ignore"
    ) -> MeasuredEngineMap:
        """This engine as the backward method sees it (:class:`MeasuredEngineMap`, same options)."""
        return MeasuredEngineMap(self, low_speed=low_speed, zero_torque_column=zero_torque_column)

    def summary(self) -> dict[str, Any]:
        """Grids, peak torque and power, minimum BSFC: what ``vpsim engine import`` prints (SI units).

        The minimum BSFC (g/kWh) is taken over the measured nodes with positive torque that lie on or below
        the full-load curve; nodes above it are fill-in of a rectangular table, not operating points.
        """
        sg, tg = self.speed_grid, self.torque_grid
        power = self.max_torque * self.max_torque_speed
        k_t, k_p = int(np.argmax(self.max_torque)), int(np.argmax(power))
        t_node, w_node = np.meshgrid(tg, sg)
        usable = (t_node > 0) & (t_node <= self.max_torque_at(w_node) + 1e-9)
        bsfc = np.full(t_node.shape, np.inf)
        bsfc[usable] = self.fuel_flow[usable] * 1e3 / (t_node[usable] * w_node[usable] / 1e3) * 3600.0
        k_b = np.unravel_index(int(np.argmin(bsfc)), bsfc.shape)
        ok = bool(np.isfinite(bsfc[k_b]))
        return {
            "name": self.name,
            "source": self.source,
            "displacement_l": self.displacement * 1e3,
            "inertia_kgm2": self.inertia,
            "speed_grid_radps": [float(sg[0]), float(sg[-1]), int(sg.size)],
            "torque_grid_nm": [float(tg[0]), float(tg[-1]), int(tg.size)],
            "zero_torque_column": bool(tg[0] <= 0),
            "peak_torque_nm": float(self.max_torque[k_t]),
            "peak_torque_speed_radps": float(self.max_torque_speed[k_t]),
            "peak_power_kw": float(power[k_p] / 1e3),
            "peak_power_speed_radps": float(self.max_torque_speed[k_p]),
            "min_bsfc_g_per_kwh": float(bsfc[k_b]) if ok else None,
            "min_bsfc_torque_nm": float(t_node[k_b]) if ok else None,
            "min_bsfc_speed_radps": float(w_node[k_b]) if ok else None,
            "full_load_above_grid": bool(np.any(self.max_torque > tg[-1])),
            "closed_throttle_torque": self.closed_throttle_torque is not None,
            "fuel_density_kg_per_l": self.fuel_density,
            "fuel_lhv_j_per_kg": self.fuel_lhv,
            "fuel_type": self.fuel_type,
            "warnings": self.sanity_warnings(),
        }

    def to_json_dict(self) -> dict[str, Any]:
        """vpsim's JSON form: ADVISOR's variable names and units, which :meth:`from_json` reads back."""
        d: dict[str, Any] = {
            "format": JSON_FORMAT,
            "name": self.name,
            "fc_description": self.source,
            "units": dict(_JSON_UNITS),
            "fc_map_spd": self.speed_grid.tolist(),
            "fc_map_trq": self.torque_grid.tolist(),
            "fc_fuel_map": (self.fuel_flow * 1000.0).tolist(),
            "fc_max_trq_spd": self.max_torque_speed.tolist(),
            "fc_max_trq": self.max_torque.tolist(),
            "fc_inertia": self.inertia,
            "fc_disp": self.displacement * 1000.0,
            "fc_fuel_den": self.fuel_density * 1000.0,
            "fc_fuel_lhv": self.fuel_lhv / 1000.0,
        }
        if self.closed_throttle_torque is not None:
            d["fc_ct_trq"] = self.closed_throttle_torque.tolist()
        if self.fuel_type is not None:
            d["fc_fuel_type"] = self.fuel_type
        return d

    def write_json(self, path: str | Path) -> Path:
        """Write :meth:`to_json_dict` to ``path`` (``.json``); :func:`load_engine` reads it back."""
        p = Path(path)
        if p.suffix.lower() != ".json":
            raise EngineFileError(f"{p}: the output must be a .json file (load_engine reads by suffix)")
        p.write_text(json.dumps(self.to_json_dict(), indent=1) + "\n", encoding="utf-8")
        return p

    # ------------------------------------------------------------------ constructors

    @classmethod
    def from_advisor_m(cls, path: str | Path) -> MeasuredEngine:
        """Read an ADVISOR fuel-converter ``.m`` file (safely, see :mod:`vpsim.engines.matlab`).

        Uses what the file computes with its default scales: ``fc_map_spd`` (rad/s), ``fc_map_trq`` (N*m),
        ``fc_fuel_map`` (g/s -> kg/s; for FC_SI41 the file itself converts its g/kWh map), ``fc_max_trq``
        (N*m, over ``fc_max_trq_spd`` if the file has it, else over ``fc_map_spd``), ``fc_inertia``,
        ``fc_disp`` (L -> m^3), ``fc_fuel_den`` (g/L -> kg/L), ``fc_fuel_lhv`` (J/g -> J/kg). Files that set
        ``fc_spd_scale`` or ``fc_trq_scale`` to anything but 1 are refused: ADVISOR applies those scales in
        its model, not in the data.
        """
        p = Path(path)
        v = read_m_file(p)

        def get(name: str, kind: str = "array") -> Any:
            if name not in v:
                raise EngineFileError(f"{p}: variable '{name}' is not assigned")
            x = v[name]
            if kind == "scalar":
                if not isinstance(x, float):
                    raise EngineFileError(f"{p}: '{name}' must be a number")
                return x
            if not isinstance(x, np.ndarray | float):
                raise EngineFileError(f"{p}: '{name}' must be numeric")
            return np.asarray(x, dtype=float)

        for scale in ("fc_spd_scale", "fc_trq_scale"):
            if scale in v and get(scale, "scalar") != 1.0:
                raise EngineFileError(f"{p}: {scale} = {v[scale]:g}; only unscaled engines (1) are supported")
        speed = get("fc_map_spd")
        description = v.get("fc_description")
        source = f"ADVISOR {p.name}" + (f": {description}" if isinstance(description, str) else "")
        return cls(
            name=p.stem,
            speed_grid=speed,
            torque_grid=get("fc_map_trq"),
            fuel_flow=get("fc_fuel_map") / 1000.0,
            max_torque_speed=get("fc_max_trq_spd") if "fc_max_trq_spd" in v else speed,
            max_torque=get("fc_max_trq"),
            inertia=get("fc_inertia", "scalar"),
            displacement=get("fc_disp", "scalar") / 1000.0,
            fuel_density=get("fc_fuel_den", "scalar") / 1000.0,
            fuel_lhv=get("fc_fuel_lhv", "scalar") * 1000.0,
            source=source,
            closed_throttle_torque=get("fc_ct_trq") if "fc_ct_trq" in v else None,
            fuel_type=_fuel_type(v.get("fc_fuel_type"), p),
        )

    @classmethod
    def from_json(cls, path: str | Path) -> MeasuredEngine:
        """Read the JSON form of an ADVISOR fuel converter (as in ``shared/data/engines``).

        The JSON keeps ADVISOR's names and units (``fc_fuel_map`` in g/s, ``fc_disp`` in L, ``fc_fuel_den``
        in g/L, ``fc_fuel_lhv`` in J/g); if it has a ``units`` table, it must state those units.
        """
        p = Path(path)
        text = read_text(p, EngineFileError, limit=MAX_FILE_BYTES, what="engine JSON file")

        def no_constants(token: str) -> Any:
            raise EngineFileError(f"{p}: {token} is not allowed in engine data")

        try:
            data = json.loads(text, parse_constant=no_constants)
        except json.JSONDecodeError as e:
            raise EngineFileError(f"{p}:{e.lineno}: invalid JSON ({e.msg})") from None
        except RecursionError:
            raise EngineFileError(f"{p}: JSON nested too deeply") from None
        except ValueError as e:  # e.g. an integer literal of more than 4300 digits
            raise EngineFileError(f"{p}: invalid JSON ({e})") from None
        if not isinstance(data, dict):
            raise EngineFileError(f"{p}: expected a JSON object")
        units = data.get("units", {})
        if not isinstance(units, dict):
            raise EngineFileError(f"{p}: 'units' must be an object")
        for key, unit in _JSON_UNITS.items():
            if key in units and units[key] != unit:
                raise EngineFileError(f"{p}: {key} is in {units[key]!r}; expected {unit!r}")

        def get(name: str, scalar: bool = False) -> Any:
            if name not in data:
                raise EngineFileError(f"{p}: key '{name}' is missing")
            x = data[name]
            stack = [x]
            while stack:  # true/false are not numbers (numpy reads them as 1 and 0)
                y = stack.pop()
                if isinstance(y, bool):
                    raise EngineFileError(f"{p}: '{name}' holds {json.dumps(y)}, expected numbers")
                if isinstance(y, list):
                    stack.extend(y)
            try:
                a = np.array(x, dtype=float)
            except (TypeError, ValueError, OverflowError):
                raise EngineFileError(f"{p}: '{name}' must be numeric (finite numbers)") from None
            if np.any(np.isnan(a)):
                raise EngineFileError(f"{p}: '{name}' holds null or non-numeric entries")
            if scalar:
                if a.ndim != 0:
                    raise EngineFileError(f"{p}: '{name}' must be a single number")
                return float(a)
            return a

        speed = get("fc_map_spd")
        name = data.get("name") if isinstance(data.get("name"), str) else p.stem
        description = data.get("fc_description")
        source = f"{p.name}" + (f": {description}" if isinstance(description, str) else "")
        return cls(
            name=name,
            speed_grid=speed,
            torque_grid=get("fc_map_trq"),
            fuel_flow=get("fc_fuel_map") / 1000.0,
            max_torque_speed=get("fc_max_trq_spd") if "fc_max_trq_spd" in data else speed,
            max_torque=get("fc_max_trq"),
            inertia=get("fc_inertia", scalar=True),
            displacement=get("fc_disp", scalar=True) / 1000.0,
            fuel_density=get("fc_fuel_den", scalar=True) / 1000.0,
            fuel_lhv=get("fc_fuel_lhv", scalar=True) * 1000.0,
            source=source,
            closed_throttle_torque=get("fc_ct_trq") if "fc_ct_trq" in data else None,
            fuel_type=_fuel_type(data.get("fc_fuel_type"), p),
        )


LOW_SPEED_RULES = ("proportional", "clamp")
ZERO_TORQUE_RULES = ("ignore", "use")


@dataclass(frozen=True, eq=False)
class MeasuredEngineMap:
    """A measured engine as the backward method consumes it, an
    :class:`~vpsim.model.maps.EngineMap` like :class:`~vpsim.model.maps.GeneratedEngineMap`.

    ``fuel_flow(t_cr, w_e)`` (kg/s), ``max_torque(w_e)``, ``min_torque(w_e)`` (N*m), ``inertia``, ``name``.
    The measured map is steady-state data at positive brake torque, read as the crank torque T_cr of the
    model. Where a drive cycle leaves it, these rules apply (docs/scaling.md quantifies them):

    * ``T_cr <= 0`` (coasting, braking, standstill): fuel flow 0, so the backward method's idle floor
      ``params.simulation.idle_fuel_flow`` applies. The measurements hold nothing about a motoring engine.
    * ``zero_torque_column="ignore"`` (default): a zero-torque column in the file is not used; for
      ``0 < T_cr`` below the lowest loaded column the flow follows the straight (Willans) line through the two
      lowest loaded columns, never below 0. ADVISOR's FC_SI63_emis holds the same 0.1935 g/s at every speed
      from 73 to 576 rad/s in that column, an idle flow rather than a zero-load measurement, and interpolating
      towards it would let a 2500 rpm engine at 5 N*m burn little more than idle. ``"use"`` interpolates to
      it, as ADVISOR does.
    * ``low_speed="proportional"`` (default): below the lowest map speed w_0, the flow at (T, w_0) is scaled
      by w / w_0, i.e. the fuel per engine cycle (and the BSFC) at that torque is held. ``"clamp"`` holds the
      flow itself, as :meth:`MeasuredEngine.fuel_flow_at` does. Above the highest map speed the speed is
      clamped.
    * Above the highest torque column the flow is extrapolated linearly in torque (Willans line).
    * ``min_torque`` is the closed-throttle line ADVISOR gives as ``fc_ct_trq`` where the file has it, else 0
      (no engine braking known); only the backward method's extended mode uses it.

    :meth:`coverage` says which of these rules a set of operating points relied on.
    """

    engine: MeasuredEngine
    low_speed: str = "proportional"
    zero_torque_column: str = "ignore"

    def __post_init__(self) -> None:
        if self.low_speed not in LOW_SPEED_RULES:
            raise ValueError(f"low_speed must be one of {LOW_SPEED_RULES}, got {self.low_speed!r}")
        if self.zero_torque_column not in ZERO_TORQUE_RULES:
            raise ValueError(
                f"zero_torque_column must be one of {ZERO_TORQUE_RULES}, got {self.zero_torque_column!r}"
            )
        e = self.engine
        keep = e.torque_grid > 0 if self.zero_torque_column == "ignore" else np.ones(e.torque_grid.size, bool)
        if np.count_nonzero(keep) < 2:
            raise EngineFileError(f"{e.source or e.name}: fewer than two map columns with positive torque")
        table = e
        if not keep.all():
            from dataclasses import replace

            table = replace(e, torque_grid=e.torque_grid[keep], fuel_flow=e.fuel_flow[:, keep])
        object.__setattr__(self, "_table", table)

    @property
    def inertia(self) -> float:
        return self.engine.inertia

    @property
    def name(self) -> str:
        return self.engine.name

    @property
    def loaded_torque_grid(self) -> np.ndarray:
        """The torque columns the map is read from (positive torques unless ``zero_torque_column="use"``)."""
        return self._table.torque_grid

    def fuel_flow(self, t_cr: Any, w_e: Any) -> np.ndarray:
        """Fuel mass flow (kg/s) at crank torque ``t_cr`` (N*m) and speed ``w_e`` (rad/s), as above."""
        t, w = np.broadcast_arrays(np.asarray(t_cr, dtype=float), np.asarray(w_e, dtype=float))
        w0 = float(self.engine.speed_grid[0])
        flow = np.asarray(self._table.fuel_flow_at(t, np.maximum(w, w0)), dtype=float)
        if self.low_speed == "proportional":
            flow = np.where(w < w0, flow * np.clip(w, 0.0, None) / w0, flow)
        return np.where(t > 0, flow, 0.0)

    def max_torque(self, w_e: Any) -> Any:
        """Full-load torque (N*m), the measured curve (clamped to its end values outside it)."""
        return self.engine.max_torque_at(w_e)

    def min_torque(self, w_e: Any) -> np.ndarray:
        """Closed-throttle torque (N*m): ADVISOR's ``fc_ct_trq`` over the map speeds where given, else 0."""
        w = np.asarray(w_e, dtype=float)
        ct = self.engine.closed_throttle_torque
        if ct is None:
            return np.zeros_like(w)
        return np.interp(w, self.engine.speed_grid, ct)

    def coverage(self, t_cr: Any, w_e: Any) -> dict[str, np.ndarray]:
        """Boolean masks of the operating points by how the map was read.

        ``no_traction`` (T_cr <= 0: idle floor), and among the points with traction: ``below_speed``,
        ``above_speed``, ``below_torque`` (under the lowest loaded column), ``above_torque``; ``outside`` is
        any of these four.
        """
        t, w = np.broadcast_arrays(np.asarray(t_cr, dtype=float), np.asarray(w_e, dtype=float))
        sg, tg = self.engine.speed_grid, self.loaded_torque_grid
        trac = t > 0
        masks = {
            "no_traction": ~trac,
            "below_speed": trac & (w < sg[0]),
            "above_speed": trac & (w > sg[-1]),
            "below_torque": trac & (t < tg[0]),
            "above_torque": trac & (t > tg[-1]),
        }
        masks["outside"] = (
            masks["below_speed"] | masks["above_speed"] | masks["below_torque"] | masks["above_torque"]
        )
        return masks


def load_engine(path: str | Path) -> MeasuredEngine:
    """Load a measured engine from an ADVISOR ``.m`` file or its ``.json`` form (chosen by suffix)."""
    p = check_path(path, EngineFileError, "engine file")
    suffix = p.suffix.lower()
    if suffix == ".m":
        return MeasuredEngine.from_advisor_m(p)
    if suffix == ".json":
        return MeasuredEngine.from_json(p)
    raise EngineFileError(f"{p}: unsupported engine file type {p.suffix!r}; expected .m or .json")
