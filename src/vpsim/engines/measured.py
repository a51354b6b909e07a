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
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EngineFileError
from .matlab import MAX_FILE_BYTES, read_m_file

__all__ = ["MeasuredEngine", "load_engine"]

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
}


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class MeasuredEngine:
    """An engine described by measured data (for example an ADVISOR fuel-converter file).

    Attributes are SI: ``speed_grid`` rad/s (strictly increasing), ``torque_grid`` N*m (strictly
    increasing), ``fuel_flow`` kg/s with shape ``(n_speed, n_torque)``, ``max_torque_speed`` rad/s and
    ``max_torque`` N*m (full-load curve), ``inertia`` kg*m^2, ``displacement`` m^3, ``fuel_density`` kg/L,
    ``fuel_lhv`` J/kg. ``source`` says where the data came from. Arrays are stored read-only.
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

    def __post_init__(self) -> None:
        where = self.source or self.name

        def bad(msg: str) -> EngineFileError:
            return EngineFileError(f"{where}: {msg}")

        arrays = {}
        for field_name in ("speed_grid", "torque_grid", "fuel_flow", "max_torque_speed", "max_torque"):
            try:
                a = np.array(getattr(self, field_name), dtype=float)
            except (TypeError, ValueError):
                raise bad(f"{field_name} is not numeric") from None
            if not np.all(np.isfinite(a)):
                raise bad(f"{field_name} holds non-finite values (NaN or infinity)")
            arrays[field_name] = a
        for field_name in ("speed_grid", "torque_grid", "max_torque_speed"):
            a = arrays[field_name]
            if a.ndim != 1 or a.size < 2:
                raise bad(f"{field_name} must be a 1-D array of at least 2 points, got shape {a.shape}")
            if not np.all(np.diff(a) > 0):
                raise bad(f"{field_name} must be strictly increasing")
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
        )

    @classmethod
    def from_json(cls, path: str | Path) -> MeasuredEngine:
        """Read the JSON form of an ADVISOR fuel converter (as in ``shared/data/engines``).

        The JSON keeps ADVISOR's names and units (``fc_fuel_map`` in g/s, ``fc_disp`` in L, ``fc_fuel_den``
        in g/L, ``fc_fuel_lhv`` in J/g); if it has a ``units`` table, it must state those units.
        """
        p = Path(path)
        try:
            size = p.stat().st_size
            if size > MAX_FILE_BYTES:
                raise EngineFileError(f"{p}: file is {size} bytes, more than the {MAX_FILE_BYTES}-byte limit")
            text = p.read_text(encoding="utf-8")
        except OSError as e:
            raise EngineFileError(f"{p}: cannot read file ({e.strerror or e})") from None
        except UnicodeDecodeError:
            raise EngineFileError(f"{p}: not UTF-8 text") from None

        def no_constants(token: str) -> Any:
            raise EngineFileError(f"{p}: {token} is not allowed in engine data")

        try:
            data = json.loads(text, parse_constant=no_constants)
        except json.JSONDecodeError as e:
            raise EngineFileError(f"{p}:{e.lineno}: invalid JSON ({e.msg})") from None
        except RecursionError:
            raise EngineFileError(f"{p}: JSON nested too deeply") from None
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
            try:
                a = np.array(x, dtype=float)
            except (TypeError, ValueError):
                raise EngineFileError(f"{p}: '{name}' must be numeric") from None
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
        )


def load_engine(path: str | Path) -> MeasuredEngine:
    """Load a measured engine from an ADVISOR ``.m`` file or its ``.json`` form (chosen by suffix)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".m":
        return MeasuredEngine.from_advisor_m(p)
    if suffix == ".json":
        return MeasuredEngine.from_json(p)
    raise EngineFileError(f"{p}: unsupported engine file type {p.suffix!r}; expected .m or .json")
