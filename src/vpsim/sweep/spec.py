"""Sweep specification: which parameters vary and how, sampling, cycles x methods x drivers, validation.

A spec is a TOML file or the same keys as a Python call (:func:`make_spec`); both go through
:meth:`SweepSpec.from_dict`, so they validate alike and errors name the file and the field::

    name = "small"
    base = "hofman2011"             # preset name or a parameter TOML file (relative to the spec)
    sampling = "factorial"          # or "lhs" (Latin hypercube; needs samples)
    samples = 200                   # lhs only
    seed = 1                        # lhs only
    cycles = ["nedc", "ftp75"]      # standard names or CSV files (relative to the spec)
    methods = ["backward"]          # backward, forward, inverse
    drivers = [1]                   # forward/inverse only
    mode = "paper"                  # or "extended"
    gears = "baseline"              # every design on the base design's gear schedule; or "per_design"
    baseline = true                 # also run the unchanged base parameters (marked in plots)

    [parameters]
    "engine.bore" = { range = [0.080, 0.095], n = 4 }     # n levels (factorial); lhs samples the range
    "engine.cylinders" = [3, 4]                           # a list: exactly these values
    "transmission.gearbox_ratios[5]" = { range = [0.6, 0.8], n = 3 }   # one gear (1-based)
    "transmission.gearbox_ratios" = { values = [[3.4, 1.8, 1.1, 0.9, 0.7], [3.6, 2.0, 1.3, 1.0, 0.8]] }

    [acceleration]                  # 0-100 km/h objective (vpsim.performance); enabled by default
    enabled = true
    shift_fraction = 0.9            # or shift_speed = 560.0 (rad/s)
    launch_speed = 250.0            # rad/s

Parameter names are ``section.field`` of the parameter set (sections vehicle, transmission, engine,
simulation), the same names as a parameter TOML file; ``[parameters.engine]`` with ``bore = ...`` inside is
the same as ``"engine.bore" = ...``. Values are SI. A factorial spec runs every combination of the levels;
a Latin-hypercube spec draws ``samples`` points, one per stratum of every axis (continuous ranges are sampled
uniformly within the stratum; integer fields are rounded; lists are split into equal strata of their
values), reproducibly from ``seed``.

Gears (``gears``): the paper prescribes gear changes in time, identical for every method. ``"baseline"``
(default) derives the schedule once per cycle from the base design by the documented rule
(:func:`vpsim.gears.default_schedule`) and runs every design on it, so a design change shows its own effect
and not that of another shift pattern (and the compiled batch path, :func:`vpsim.batch.run_batch`, applies).
``"per_design"`` derives each design's own schedule by the same rule (what :func:`vpsim.simulate` does for
one design; a few ms per design). With ``"baseline"`` every design must keep the base's number of gears.

Every design point is applied to the base with :meth:`~vpsim.params.Parameters.with_changes`; a combination
that is not physical is recorded as a failed point, not rejected here. The extremes of every axis are checked
on their own when the spec is read, which catches a unit slip (a bore in millimetres) before anything runs.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import VpsimError
from ..params import Parameters, load_parameters, read_toml
from ..simulation import METHODS, MODES

SAMPLINGS = ("factorial", "lhs")
GEARS = ("baseline", "per_design")
SECTIONS = ("vehicle", "transmission", "engine", "simulation", "machine", "battery", "hybrid")
# sizing axes that are not fields but rules (apply_changes): the engine's displacement over the base's
SIZING_AXES = ("engine.scale",)
HYBRID_TYPES = ("hev_p2", "hev_split")
MAX_POINTS = 5_000_000
_TOP_KEYS = {
    "name",
    "base",
    "sampling",
    "samples",
    "seed",
    "cycles",
    "methods",
    "drivers",
    "mode",
    "gears",
    "baseline",
    "parameters",
    "acceleration",
    "ems",
}
_AXIS_KEYS = {"range", "n", "values"}
_ACCEL_KEYS = {"enabled", "shift_speed", "shift_fraction", "launch_speed"}
_GEAR_RE = re.compile(r"^transmission\.gearbox_ratios\[(\d+)\]$")
_SIG_DIGITS = 12  # sampled values are rounded to this many significant digits (stable point identity)


class SpecError(VpsimError):
    """A sweep specification is invalid: unknown key, bad range, unknown parameter, cycle or method."""


@dataclass(frozen=True)
class Axis:
    """One varied parameter: explicit ``values``, or a ``range`` (low, high) with ``n`` factorial levels."""

    name: str
    values: tuple | None = None
    low: float | None = None
    high: float | None = None
    n: int | None = None
    kind: str = "float"  # "float", "int" or "ratios" (a whole gearbox_ratios tuple)

    def levels(self) -> tuple:
        """The factorial levels."""
        if self.values is not None:
            return self.values
        if self.n == 1:
            return (self._cast(0.5 * (self.low + self.high)),)
        return tuple(self._cast(x) for x in np.linspace(self.low, self.high, self.n))

    def from_unit(self, u: np.ndarray) -> list:
        """Map points u in [0, 1) to values: uniform over the range, or the value whose stratum holds u."""
        if self.values is not None:
            k = np.minimum((u * len(self.values)).astype(int), len(self.values) - 1)
            return [self.values[j] for j in k]
        return [self._cast(self.low + x * (self.high - self.low)) for x in u]

    def _cast(self, x):
        if self.kind == "int":
            return int(round(float(x)))
        return _round_sig(float(x))


@dataclass(frozen=True)
class AccelerationSettings:
    """The 0-100 km/h objective: see :mod:`vpsim.performance` for the launch and shift rules."""

    enabled: bool = True
    shift_speed: float | None = None  # rad/s; None: shift_fraction x max-power speed
    shift_fraction: float = 0.9
    launch_speed: float = 250.0  # rad/s

    def as_dict(self) -> dict:
        return {
            "enabled": self.enabled,
            "shift_speed": self.shift_speed,
            "shift_fraction": self.shift_fraction,
            "launch_speed": self.launch_speed,
        }


@dataclass(frozen=True)
class Design:
    """One design point: its index, the changes to the base (``{"engine.bore": 0.085}``), baseline flag."""

    index: int
    changes: dict
    is_baseline: bool = False


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep: use :func:`load_spec` (TOML) or :func:`make_spec` (keywords) to build one."""

    axes: tuple[Axis, ...]
    base: str = "hofman2011"
    sampling: str = "factorial"
    samples: int | None = None
    seed: int = 0
    cycles: tuple[str, ...] = ("nedc",)
    methods: tuple[str, ...] = ("backward",)
    drivers: tuple[str, ...] = ("1",)
    mode: str = "paper"
    gears: str = "baseline"
    baseline: bool = True
    acceleration: AccelerationSettings = field(default_factory=AccelerationSettings)
    ems: str | None = None  # a hybrid base's energy management (None: the base's own)
    hybrid: bool = False  # the base is a hybrid: its charge-sustaining columns and feasibility flag
    name: str = "sweep"
    source: str = "spec"  # where it came from, for messages

    # --- construction -----------------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, where: str = "spec", root: Path | None = None) -> SweepSpec:
        """Validate a mapping with the TOML keys (module docstring). ``root`` resolves relative paths."""
        if not isinstance(data, dict):
            raise SpecError(f"{where}: a sweep spec is a table of keys, got {type(data).__name__}")
        unknown = set(data) - _TOP_KEYS
        if unknown:
            raise SpecError(
                f"{where}: unknown key {sorted(unknown)[0]!r}; "
                f"expected some of {', '.join(sorted(_TOP_KEYS))}"
            )
        root = Path(root) if root is not None else None
        base = _base(data.get("base", "hofman2011"), where, root)
        try:
            params = load_parameters(base)
        except VpsimError as exc:
            raise SpecError(f"{where}: base: {exc}") from None
        sampling = data.get("sampling", "factorial")
        if sampling not in SAMPLINGS:
            raise SpecError(f"{where}: sampling = {sampling!r}; expected one of {', '.join(SAMPLINGS)}")
        samples = data.get("samples")
        if sampling == "lhs":
            if samples is None:
                raise SpecError(f'{where}: sampling = "lhs" needs samples = N (the number of design points)')
            if isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= MAX_POINTS:
                raise SpecError(f"{where}: samples = {samples!r} must be a whole number in [1, {MAX_POINTS}]")
        elif samples is not None:
            raise SpecError(
                f'{where}: samples applies to sampling = "lhs"; a factorial sweep runs every level'
            )
        seed = data.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise SpecError(f"{where}: seed = {seed!r} must be a non-negative whole number")
        cycles = _str_list(data.get("cycles", ["nedc"]), "cycles", where)
        cycles = tuple(_cycle_ref(c, where, root) for c in cycles)
        methods = _str_list(data.get("methods", ["backward"]), "methods", where)
        for m in methods:
            if m not in METHODS:
                raise SpecError(
                    f"{where}: methods: unknown method {m!r}; expected some of {', '.join(METHODS)}"
                )
        drivers = tuple(str(d) for d in _list(data.get("drivers", [1]), "drivers", where))
        for d in drivers:
            if d not in params.drivers:
                raise SpecError(
                    f"{where}: drivers: driver {d!r} is not defined in {base!r}; "
                    f"available: {', '.join(sorted(params.drivers))}"
                )
        mode = data.get("mode", "paper")
        if mode not in MODES:
            raise SpecError(f"{where}: mode = {mode!r}; expected one of {', '.join(MODES)}")
        gears = data.get("gears", "baseline")
        if gears not in GEARS:
            raise SpecError(f"{where}: gears = {gears!r}; expected one of {', '.join(GEARS)}")
        baseline = data.get("baseline", True)
        if not isinstance(baseline, bool):
            raise SpecError(f"{where}: baseline = {baseline!r} must be true or false")
        raw_params = data.get("parameters", {})
        if not isinstance(raw_params, dict):
            raise SpecError(f"{where}: [parameters] must be a table of parameter = values")
        axes = tuple(_axis(name, entry, params, where) for name, entry in _flatten(raw_params, where))
        if sampling == "factorial":
            for a in axes:
                if a.values is None and a.n is None:
                    raise SpecError(
                        f"{where}: parameters.{a.name}: a factorial sweep needs n = N levels with range "
                        '(or sampling = "lhs")'
                    )
        names = [a.name for a in axes]
        _check_gear_axes(names, where)
        for a in axes:
            if a.kind == "ratios" and gears == "baseline":
                odd = [v for v in a.values if len(v) != params.transmission.n_gears]
                if odd:
                    raise SpecError(
                        f"{where}: parameters.{a.name}: {list(odd[0])} has {len(odd[0])} gears but the base "
                        f'has {params.transmission.n_gears}; with gears = "baseline" every design runs the '
                        "base's "
                        'gear schedule, so use gears = "per_design"'
                    )
        accel = _accel(data.get("acceleration", {}), where)
        ems = _ems(data.get("ems"), params, methods, accel, names, where)
        name = data.get("name", "sweep")
        if not isinstance(name, str):
            raise SpecError(f"{where}: name = {name!r} must be a string")
        spec = cls(
            axes=axes,
            base=base,
            sampling=sampling,
            samples=samples,
            seed=seed,
            cycles=cycles,
            methods=tuple(dict.fromkeys(methods)),
            drivers=tuple(dict.fromkeys(drivers)),
            mode=mode,
            gears=gears,
            baseline=baseline,
            acceleration=accel,
            ems=ems,
            hybrid=params.powertrain.type in HYBRID_TYPES,
            name=name,
            source=where,
        )
        n = spec.n_designs
        if n > MAX_POINTS:
            raise SpecError(
                f'{where}: {n} design points is more than the limit of {MAX_POINTS}; use sampling = "lhs"'
            )
        return spec

    # --- derived ------------------------------------------------------------------------------------------

    @property
    def n_designs(self) -> int:
        """Number of sampled design points (without the baseline)."""
        if self.sampling == "lhs":
            return int(self.samples)
        return math.prod(len(a.values) if a.values is not None else a.n for a in self.axes)

    @property
    def combos(self) -> tuple[tuple[str, str, str], ...]:
        """The (cycle, method, driver) combinations run for every design (driver "" for backward)."""
        out = []
        for c in self.cycles:
            for m in self.methods:
                for d in [""] if m == "backward" else self.drivers:
                    out.append((c, m, d))
        return tuple(out)

    def parameters(self) -> Parameters:
        return load_parameters(self.base)

    def designs(self) -> list[Design]:
        """The design points, baseline first (index 0) when ``baseline``; duplicates of it are merged."""
        names = [a.name for a in self.axes]
        if self.sampling == "factorial":
            rows = itertools.product(*(a.levels() for a in self.axes)) if self.axes else iter([()])
        else:
            rows = zip(*self._lhs_columns(), strict=True) if self.axes else iter([()] * self.samples)
        out: list[Design] = []
        k = 0
        if self.baseline:
            out.append(Design(0, {}, True))
            k = 1
        for row in rows:
            out.append(Design(k, dict(zip(names, row, strict=True))))
            k += 1
        return out

    def _lhs_columns(self) -> list[list]:
        rng = np.random.default_rng(self.seed)
        n = int(self.samples)
        cols = []
        for a in self.axes:
            u = (rng.permutation(n) + rng.random(n)) / n  # one point per stratum, strata shuffled per axis
            cols.append(a.from_unit(u))
        return cols

    def as_dict(self) -> dict:
        """The spec as plain data (the TOML keys), e.g. to record it beside the results."""
        params = {}
        for a in self.axes:
            if a.values is not None:
                params[a.name] = {"values": [list(v) if isinstance(v, tuple) else v for v in a.values]}
            else:
                params[a.name] = {"range": [a.low, a.high]} | ({"n": a.n} if a.n is not None else {})
        d = {
            "name": self.name,
            "base": self.base,
            "sampling": self.sampling,
            "seed": self.seed,
            "cycles": list(self.cycles),
            "methods": list(self.methods),
            "drivers": [int(x) if x.isdigit() else x for x in self.drivers],
            "mode": self.mode,
            "gears": self.gears,
            "baseline": self.baseline,
            "parameters": params,
            "acceleration": {k: v for k, v in self.acceleration.as_dict().items() if v is not None},
        }
        if self.ems is not None:
            d["ems"] = self.ems
        if self.samples is not None:
            d["samples"] = self.samples
        return d

    def fingerprint(self) -> str:
        """A short hash of the spec (recorded in the output folder to tell a resumed sweep what it was)."""
        return hashlib.sha256(json.dumps(self.as_dict(), sort_keys=True).encode()).hexdigest()[:16]


def load_spec(path: str | Path) -> SweepSpec:
    """Read and validate a sweep spec TOML file; relative paths inside it are relative to the file."""
    path = Path(path)
    data = read_toml(path, SpecError)
    data.setdefault("name", path.stem)
    return SweepSpec.from_dict(data, where=str(path), root=path.parent)


def make_spec(**keys) -> SweepSpec:
    """The Python form of a spec file: the same keys as keywords, e.g.
    ``make_spec(parameters={"engine.bore": {"range": [0.08, 0.095], "n": 4}}, cycles=["nedc"])``."""
    return SweepSpec.from_dict(keys, where="make_spec")


def apply_changes(params: Parameters, changes: dict) -> Parameters:
    """The base parameters with one design point's changes, validated (raises ParameterError).

    Sizing rules (:mod:`vpsim.scaling`): ``engine.scale`` is the displacement over the base's, reached by the
    bore (x sqrt(scale); stroke and cylinders kept, so the speed range and the full-load BMEP stay and the
    full-load torque scales with it), throttle areas, manifold and inertia following
    (:func:`vpsim.scaling.scale_engine`); a changed ``machine.rated_power`` takes the rotor's inertia with
    it (:func:`vpsim.scaling.scaled_machine`) unless ``machine.inertia`` is swept too."""
    sections: dict[str, dict] = {}
    gears: dict[int, float] = {}
    if "engine.scale" in changes:
        from ..scaling import scaled_parameters

        changes = dict(changes)
        k = changes.pop("engine.scale")
        if not (isinstance(k, int | float) and math.isfinite(k) and k > 0):
            raise SpecError(f"engine.scale = {k!r} must be a positive displacement ratio")
        e = params.engine
        params = scaled_parameters(params, bore=e.bore * math.sqrt(k), stroke=e.stroke, cylinders=e.cylinders)
    if "machine.rated_power" in changes and "machine.inertia" not in changes:
        from ..scaling import scaled_machine

        changes = dict(changes)
        sections["machine"] = scaled_machine(params.machine, changes.pop("machine.rated_power"))
    for name, value in changes.items():
        m = _GEAR_RE.match(name)
        if m:
            gears[int(m.group(1))] = value
            continue
        sec, fld = name.split(".", 1)
        sections.setdefault(sec, {})[fld] = list(value) if isinstance(value, tuple) else value
    if gears:
        ratios = list(
            sections.get("transmission", {}).get("gearbox_ratios", params.transmission.gearbox_ratios)
        )
        for g, value in gears.items():
            ratios[g - 1] = value
        sections.setdefault("transmission", {})["gearbox_ratios"] = ratios
    return params.with_changes(**sections) if sections else params


# --- helpers ---------------------------------------------------------------------------------------------


def _round_sig(x: float) -> float:
    if x == 0.0 or not math.isfinite(x):
        return x
    return float(f"{x:.{_SIG_DIGITS}g}")


def _base(value, where, root):
    if not isinstance(value, str) or not value:
        raise SpecError(f"{where}: base = {value!r} must be a preset name or a parameter TOML file")
    if value.endswith(".toml") and root is not None and not Path(value).is_absolute():
        return str(root / value)
    return value


def _list(value, key, where) -> list:
    if isinstance(value, str | int) and not isinstance(value, bool):
        value = [value]
    if not isinstance(value, list | tuple) or not value:
        raise SpecError(f"{where}: {key} must be a non-empty list")
    return list(value)


def _str_list(value, key, where) -> list[str]:
    vals = _list(value, key, where)
    for v in vals:
        if not isinstance(v, str):
            raise SpecError(f"{where}: {key}: {v!r} is not a name")
    return vals


def _cycle_ref(name: str, where: str, root: Path | None) -> str:
    from ..cycles import MIN_CONSUMPTION_DISTANCE_M, load_cycle

    ref = name
    if name.lower().endswith(".csv") and root is not None and not Path(name).is_absolute():
        ref = str(root / name)
    try:
        cyc = load_cycle(ref)
    except VpsimError as exc:
        raise SpecError(f"{where}: cycles: {exc}") from None
    if not cyc.distance_m >= MIN_CONSUMPTION_DISTANCE_M:
        raise SpecError(
            f"{where}: cycles: {name} drives no distance ({cyc.distance_m:.3g} m), so fuel per 100 km is "
            "undefined for every design"
        )
    return ref


def _flatten(table: dict, where: str, prefix: str = ""):
    for key, entry in table.items():
        name = f"{prefix}{key}"
        if isinstance(entry, dict) and not (set(entry) & _AXIS_KEYS):
            if name in SECTIONS:
                yield from _flatten(entry, where, f"{name}.")
                continue
            raise SpecError(
                f"{where}: parameters.{name}: expected a list of values, {{ values = [...] }} or "
                "{ range = [low, high], n = N }"
            )
        yield name, entry


def _axis(name: str, entry, params: Parameters, where: str) -> Axis:
    at = f"{where}: parameters.{name}"
    flat = params.flat()
    m = _GEAR_RE.match(name)
    if m:
        g = int(m.group(1))
        if not 1 <= g <= params.transmission.n_gears:
            raise SpecError(
                f"{at}: gear {g} does not exist; the base has gears 1..{params.transmission.n_gears}"
            )
        kind = "float"
    elif name in SIZING_AXES:  # a rule, not a field (apply_changes)
        kind = "float"
    else:
        sec = name.split(".", 1)[0]
        if name.startswith("drivers."):
            raise SpecError(f"{at}: driver tunings are chosen with drivers = [...], not varied as parameters")
        if sec not in SECTIONS or name not in flat:
            hint = ""
            close = [k for k in flat if k.split(".")[-1] == name.split(".")[-1]]
            if close:
                hint = f" (did you mean {close[0]!r}?)"
            raise SpecError(f"{at}: unknown parameter{hint}; names are section.field as in a parameter file")
        base_value = flat[name]
        if name == "transmission.gearbox_ratios":
            kind = "ratios"
        elif isinstance(base_value, tuple):
            raise SpecError(f"{at}: this field is a list and cannot be swept")
        elif isinstance(base_value, bool) or not isinstance(base_value, int | float):
            raise SpecError(f"{at}: only numeric fields can be swept")
        else:
            kind = "int" if isinstance(base_value, int) else "float"
    if isinstance(entry, list):
        entry = {"values": entry}
    if not isinstance(entry, dict):
        raise SpecError(
            f"{at}: expected a list of values, {{ values = [...] }} or {{ range = [low, high], n = N }}"
        )
    extra = set(entry) - _AXIS_KEYS
    if extra:
        raise SpecError(f"{at}: unknown key {sorted(extra)[0]!r}; expected values, or range and n")
    if "values" in entry:
        if set(entry) - {"values"}:
            raise SpecError(f"{at}: give either values or range (with n), not both")
        axis = Axis(name, values=_values(entry["values"], kind, at), kind=kind)
    else:
        if kind == "ratios":
            raise SpecError(
                f"{at}: a whole ratio set is swept with values = [[...], ...]; "
                'sweep one gear with "transmission.gearbox_ratios[k]"'
            )
        rng = entry.get("range")
        if (
            not isinstance(rng, list)
            or len(rng) != 2
            or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in rng)
        ):
            raise SpecError(f"{at}: range must be [low, high] (two numbers), got {rng!r}")
        lo, hi = float(rng[0]), float(rng[1])
        if not (math.isfinite(lo) and math.isfinite(hi)) or not lo < hi:
            raise SpecError(f"{at}: range = [{lo:g}, {hi:g}] must have low < high")
        n = entry.get("n")
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_POINTS):
            raise SpecError(f"{at}: n = {n!r} must be a whole number of levels in [1, {MAX_POINTS}]")
        axis = Axis(name, low=lo, high=hi, n=n, kind=kind)
    # each extreme on its own must be a valid parameter set: catches unit slips before anything runs
    ext = list(axis.values) if axis.values is not None else [axis._cast(axis.low), axis._cast(axis.high)]
    for v in ext:
        try:
            apply_changes(params, {name: v})
        except VpsimError as exc:
            raise SpecError(f"{at}: value {v!r} is not valid on its own: {exc}") from None
    return axis


def _values(vals, kind: str, at: str) -> tuple:
    if not isinstance(vals, list) or not vals:
        raise SpecError(f"{at}: values must be a non-empty list")
    out = []
    for v in vals:
        if kind == "ratios":
            if (
                not isinstance(v, list)
                or not v
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
            ):
                raise SpecError(f"{at}: each value must be a list of gear ratios, got {v!r}")
            out.append(tuple(float(x) for x in v))
            continue
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise SpecError(f"{at}: {v!r} is not a number")
        if kind == "int":
            if isinstance(v, float) and not v.is_integer():
                raise SpecError(f"{at}: {v!r} is not a whole number")
            out.append(int(v))
        else:
            out.append(float(v))
    if len(set(out)) != len(out):
        raise SpecError(f"{at}: values repeat ({', '.join(map(str, out))})")
    return tuple(out)


def _check_gear_axes(names: list[str], where: str) -> None:
    if "transmission.gearbox_ratios" in names and any(_GEAR_RE.match(n) for n in names):
        raise SpecError(
            f"{where}: parameters: sweep either transmission.gearbox_ratios or single gears, not both"
        )


def _ems(value, params: Parameters, methods, accel, names, where: str) -> str | None:
    """A hybrid base's energy management for every row (``ems``); checks what the hybrid cannot run."""
    kind = params.powertrain.type
    if kind not in HYBRID_TYPES:
        if value is not None:
            raise SpecError(f"{where}: ems applies to a hybrid base; {params.name!r} is {kind}")
        return None
    from ..model.hybrid import EMS_CODES

    if value is not None and value not in EMS_CODES:
        raise SpecError(f"{where}: ems = {value!r}; expected one of {', '.join(EMS_CODES)}")
    if (value or params.hybrid.ems) == "dp" and set(methods) != {"backward"}:
        raise SpecError(
            f'{where}: ems = "dp" runs on the backward method only (a known cycle): methods = ["backward"]'
        )
    if accel.enabled and kind == "hev_split":
        raise SpecError(
            f"{where}: acceleration: 0-100 km/h of the power-split hybrid is not modelled; "
            "set acceleration = false"
        )
    if "engine.scale" in names and any(
        n in names for n in ("engine.bore", "engine.stroke", "engine.cylinders")
    ):
        raise SpecError(
            f"{where}: parameters: sweep engine.scale or the engine's bore, stroke and cylinders, not both"
        )
    return value


def _accel(entry, where: str) -> AccelerationSettings:
    if isinstance(entry, bool):
        return AccelerationSettings(enabled=entry)
    if not isinstance(entry, dict):
        raise SpecError(f"{where}: [acceleration] must be a table (or acceleration = false)")
    extra = set(entry) - _ACCEL_KEYS
    if extra:
        raise SpecError(
            f"{where}: acceleration: unknown key {sorted(extra)[0]!r}; "
            f"expected some of {', '.join(sorted(_ACCEL_KEYS))}"
        )
    kw = {}
    for k, v in entry.items():
        if k == "enabled":
            if not isinstance(v, bool):
                raise SpecError(f"{where}: acceleration.enabled = {v!r} must be true or false")
            kw[k] = v
            continue
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
            raise SpecError(f"{where}: acceleration.{k} = {v!r} must be a positive number")
        kw[k] = float(v)
    if "shift_speed" in kw and "shift_fraction" in kw:
        raise SpecError(f"{where}: acceleration: give shift_speed (rad/s) or shift_fraction, not both")
    if kw.get("shift_fraction", 0.9) > 1.0:
        raise SpecError(f"{where}: acceleration.shift_fraction = {kw['shift_fraction']:g} must be at most 1")
    if "shift_speed" in kw and kw["shift_speed"] <= kw.get("launch_speed", 250.0):
        raise SpecError(f"{where}: acceleration.shift_speed must be above launch_speed")
    if "shift_speed" in kw and kw["shift_speed"] > 2000.0:
        raise SpecError(
            f"{where}: acceleration.shift_speed = {kw['shift_speed']:g} rad/s is implausible "
            "(rad/s, not rpm?)"
        )
    return AccelerationSettings(**kw)
