"""Technology calibration across the fleet by k-fold cross-validation (folds by vehicle).

A few *global* technology parameters (:data:`TECH_PARAMS`: ``engine.thermal_efficiency``,
``engine.friction_coefficient`` and ``engine.accessory_power``) are fitted per engine class (:data:`CLASSES`:
naturally aspirated, boosted, or high-output, from the record: :func:`vehicle_class`); nothing is tuned per
vehicle.

How (fast and exact where it matters):

1. every vehicle is simulated on each of its cycles at every node of a grid of the first two parameters
   (:data:`GRID`; one compiled batch call per vehicle and cycle), with the accessories at
   :data:`~vpsim.fleet.vehicle.ACCESSORY_POWER_W`;
2. for fold k and class c, the parameters minimise the mean |ln(predicted / measured)| over the vehicles of
   class c that are *not* in fold k, all their cycles together (an L1 loss: its minimiser is a median, so a
   few vehicles the model cannot represent do not pull the technology of the rest). The prediction between
   grid nodes is the bilinear interpolation of ln(fuel) in (ln eta_th, xi), searched on a fine grid
   (:data:`FINE`); another accessory power P adds its work at the indicated efficiency,
   (P - P_grid) x the cycle's duration / (eta_th x LHV) of fuel (the accessories' torque is on the crank
   while the engine runs, idling included; this overstates the change a little where fuel is cut in
   overrun), searched on :data:`ACCESSORY_AXIS`. Both are used only to *choose* the parameters;
3. each vehicle is then simulated once more at its own fold's parameters: every error reported comes from
   that real simulation, and the vehicle's measurements never entered the fit that produced it.

Why the accessories: with the two engine parameters alone the model's town fuel was low against its
highway fuel (measured HWY / FTP bag 2 mpg 1.54 on the 2022 list, predicted 1.48), most of all for small
engines, where a load that does not scale with the engine weighs most; a constant power on the crank is
such a load. On the 2022 list the fit takes 0.7-1.6 kW, more than an alternator's base load alone: the
parameter stands for whatever costs fuel per second rather than per unit of work (a direct-injection fuel
pump, the oil and water pumps, a gearbox's spin loss), booked as accessories in the energy balance.

Folds are deterministic and hold out whole groups (:func:`vehicle_groups`): by default a vehicle family
(the same test vehicle, the same manufacturer, model and engine, or the same inputs to the model), so no
car is predicted from its sibling configuration or its twin; ``manufacturer`` leaves each manufacturer out
in turn; ``record`` (earlier versions) deals single records. Groups are shuffled with a fixed seed and dealt
to the emptiest fold, or (``deal="hash"``) each sent to the fold a hash of the seed and its label names, which
no other group's presence changes (:func:`assign_folds`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

TECH_PARAMS = ("engine.thermal_efficiency", "engine.friction_coefficient", "engine.accessory_power")
SIMULATED = TECH_PARAMS[:2]  # the grid's axes; the accessories' power is fitted on its linear effect
CLASSES = ("na", "boosted", "high_output")
# a boosted engine above this specific power (rated power per litre) is its own technology class: the
# record's high-output engines (sports and performance cars) run the cycles at very low load with more
# friction, valve overlap and enrichment than the boosted class's typical 1.5-2.0 L turbocharged engine
HIGH_OUTPUT_KW_PER_L = 100.0


def vehicle_class(rec) -> str:
    """The technology class of a certification record: ``na``, ``boosted`` or ``high_output``."""
    if not rec.boosted:
        return "na"
    return "high_output" if rec.specific_power_kw_per_l > HIGH_OUTPUT_KW_PER_L else "boosted"


EFFICIENCY_AXIS = np.array([0.30, 0.36, 0.42, 0.48, 0.54])  # the thermal efficiency's grid nodes
FRICTION_AXIS = np.array([0.1, 0.8, 1.5, 2.2, 2.9])  # the friction coefficient's grid nodes
GRID = (EFFICIENCY_AXIS, FRICTION_AXIS)
FINE = 41  # points per axis of the search between the grid nodes
# W, the accessory powers searched: up to 3 kW (the high-output class sat on an earlier 2 kW bound; a load
# that costs fuel per second, pumps and spin losses included, has no physical ceiling near it)
ACCESSORY_MAX_W = 3000.0
ACCESSORY_STEP_W = 25.0
ACCESSORY_AXIS = np.arange(0.0, ACCESSORY_MAX_W + 0.1, ACCESSORY_STEP_W)
ACCESSORY_COARSE = 4  # the first pass takes every 4th of them, on every 4th point of the fine grid
FUEL_FLOOR = 1e-3  # L/100 km: a cycle's fuel the linear accessory term may not take below (a lower bound)
SEED = 20220
# how groups are dealt into folds (:func:`assign_folds`); the fleet's headline is the first
DEALS = ("shuffle", "hash", "blocks")
DEFAULT_DEAL = "shuffle"


# why a fitted value may sit on a bound of its search, and the bound stays (reported with the fit)
BOUND_REASONS = {
    ("engine.friction_coefficient", "low"): "0.1 x Soltic's friction law is already below any running "
    "engine's friction (a warm engine's FMEP is about 1-1.5 bar at mid speed, 0.1 x the law 0.1 bar); a fit "
    "that wants less asks the friction term to stand in for something else (cylinder deactivation, an "
    "Atkinson cycle)",
    ("engine.thermal_efficiency", "high"): "0.54 indicated efficiency is beyond the best production engines "
    "(about 0.45-0.50 indicated)",
    ("engine.thermal_efficiency", "low"): "0.30 indicated efficiency is below any current gasoline engine",
    ("engine.accessory_power", "low"): "no accessory load is the physical lower end",
    ("engine.accessory_power", "high"): "3 kW of continuous mechanical load is beyond a car's accessories "
    "and spin losses together",
}


def search_bounds() -> dict[str, tuple[float, float]]:
    """The range each technology parameter is searched in."""
    return {
        TECH_PARAMS[0]: (float(GRID[0][0]), float(GRID[0][-1])),
        TECH_PARAMS[1]: (float(GRID[1][0]), float(GRID[1][-1])),
        TECH_PARAMS[2]: (float(ACCESSORY_AXIS[0]), float(ACCESSORY_AXIS[-1])),
    }


def on_bounds(params: dict) -> dict[str, str]:
    """{parameter: "low" | "high"} for each fitted value of ``params`` that sits on its search bound."""
    from .techgrid import bounds_hit

    return bounds_hit(search_bounds(), params)


def grid_variants() -> dict[str, np.ndarray]:
    """The grid as batch variants (one row per node, eta varying slowest)."""
    e, f = np.meshgrid(GRID[0], GRID[1], indexing="ij")
    return {SIMULATED[0]: e.ravel(), SIMULATED[1]: f.ravel()}


GROUPINGS = ("family", "manufacturer", "record")
DEFAULT_GROUPING = "family"


def vehicle_groups(vehicles, by: str = DEFAULT_GROUPING, labels=None) -> dict[str, str]:
    """The group of each record (key -> label) that cross-validation holds out together.

    * ``record``: every record on its own (the folds of earlier versions);
    * ``family``: records of the same test vehicle (its configurations), records that share manufacturer,
      model name and engine (displacement, cylinders), and records equal in every field the model reads
      (:func:`vpsim.fleet.vehicle.model_inputs`), joined transitively: a vehicle is never predicted from
      its own twin, sibling configuration or the same car with another transmission;
    * ``manufacturer``: every record of a manufacturer (leave-one-manufacturer-out).

    ``labels`` (record -> labels): the family labels of another kind of record (the battery-electric
    records': :func:`vpsim.fleet.ev.family_labels`); default the conventional ones above.
    """
    if by not in GROUPINGS:
        raise ValueError(f"unknown grouping {by!r}; expected one of {', '.join(GROUPINGS)}")
    vehicles = list(vehicles)
    if by == "record":
        return {v.key: v.key for v in vehicles}
    if by == "manufacturer":
        return {v.key: (v.manufacturer.strip().upper() or "unknown manufacturer") for v in vehicles}
    from .vehicle import model_inputs

    parent = {v.key: v.key for v in vehicles}

    def root(k):
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    def join(a, b):
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)

    def conventional(v):
        return (
            ("vehicle", v.vehicle_id),
            (
                "family",
                v.manufacturer.strip().upper(),
                v.model.strip().upper(),
                v.displacement_l,
                v.cylinders,
            ),
            ("inputs", model_inputs(v)),
        )

    first: dict[tuple, str] = {}
    for v in vehicles:
        for label in (labels or conventional)(v):
            if label in first:
                join(first[label], v.key)
            else:
                first[label] = v.key
    return {v.key: root(v.key) for v in vehicles}


def assign_folds(
    keys: list[str],
    k: int,
    seed: int = SEED,
    groups: dict[str, str] | None = None,
    deal: str = DEFAULT_DEAL,
) -> dict[str, int]:
    """Fold (0..k-1) of each vehicle key; deterministic, independent of the input order.

    ``groups`` (key -> label, :func:`vehicle_groups`): records of one group share a fold. ``deal``
    (:data:`DEALS`):

    * ``shuffle`` (the fleet's headline): groups are taken in an order shuffled with ``seed``, each to the
      fold with the fewest records so far (the lowest such fold); with one record per group this is a
      round-robin deal. The folds are balanced, but one group more or less reshuffles nearly every group,
      so a list the reader learns to read one more family of is dealt anew.
    * ``hash``: a group's fold is the SHA-256 of the seed and its label, modulo ``k``, so a group keeps its
      fold whatever other groups the list holds: a new family moves only its own records. The folds are
      balanced only on average (their sizes vary as a binomial draw's); a deal that leaves a fold empty is
      refused.
    * ``blocks``: the groups in the order of the same hash (:func:`hash_key`), cut into ``k`` blocks of about
      equal records (a group to the block its middle record falls in). The folds are balanced to within a
      group's records, and a group the list gains or loses (``s`` records) shifts every other group's place
      in the order by at most ``s`` records, so at most ``s + 1`` groups at each of the ``k - 1`` block
      edges change fold; no other group moves. A deal that leaves a fold empty (a group larger than a
      fold's share) is refused.
    """
    if k < 2:
        raise ValueError(f"cross-validation needs at least 2 folds, got {k}")
    if deal not in DEALS:
        raise ValueError(f"deal {deal!r}: expected one of {', '.join(DEALS)}")
    ordered = sorted(set(keys))
    label = {key: key for key in ordered} if groups is None else {key: groups[key] for key in ordered}
    members: dict[str, list[str]] = {}
    for key in ordered:
        members.setdefault(label[key], []).append(key)
    names = sorted(members)
    if len(names) < k:
        raise ValueError(f"{len(names)} group(s) cannot fill {k} folds; use fewer folds")
    out: dict[str, int] = {}
    if deal != "shuffle":  # the hash and blocks deals: a fold per group, then the same check and expansion
        if deal == "hash":
            fold_of_group = {name: hash_fold(name, k, seed) for name in names}
            why, other = f"{len(names)} groups", "fewer folds, another seed"
        else:
            fold_of_group = _block_folds(names, members, k, seed)
            why = f"{len(names)} groups, {len(ordered)} records: a group holds more than a fold's share"
            other = "fewer folds"
        empty = sorted(set(range(k)) - set(fold_of_group.values()))
        if empty:
            raise ValueError(
                f"the {deal} deal with seed {seed} leaves fold(s) {', '.join(map(str, empty))} of {k} empty "
                f"({why}); use {other} or the shuffle deal"
            )
        return {key: fold_of_group[label[key]] for key in ordered}
    perm = np.random.default_rng(seed).permutation(len(names))
    size = [0] * k
    for j in perm:
        f = min(range(k), key=lambda i: (size[i], i))
        for key in members[names[j]]:
            out[key] = f
        size[f] += len(members[names[j]])
    return out


def _block_folds(names: list[str], members: dict[str, list[str]], k: int, seed: int) -> dict[str, int]:
    """The ``blocks`` deal's fold of each group (:func:`assign_folds`): the groups in the order of
    :func:`hash_key`, each to the block of ``k`` equal shares of the records its middle record falls in."""
    total = sum(len(members[name]) for name in names)
    before = 0  # records of the groups before this one in the order
    out = {}
    for name in sorted(names, key=lambda name: (hash_key(name, seed), name)):
        size = len(members[name])
        # the block of the group's middle record, k (before + size / 2) / total, in integers
        out[name] = min(k - 1, (k * (2 * before + size)) // (2 * total))
        before += size
    return out


@dataclass(frozen=True)
class FoldSpec:
    """How a fleet run holds out: ``folds`` folds of the groups :func:`vehicle_groups` forms by
    ``group_by``, dealt with ``seed`` by ``deal`` (:func:`assign_folds`); every part of the fleet deals its
    own records by the same spec."""

    folds: int = 5
    group_by: str = DEFAULT_GROUPING
    seed: int = SEED
    deal: str = DEFAULT_DEAL

    def n_folds(self, n_groups: int) -> int:
        """The folds for ``n_groups`` groups: one per manufacturer when held out by manufacturer."""
        return n_groups if self.group_by == "manufacturer" else self.folds

    def assign(self, keys: list[str], groups: dict[str, str]) -> dict[str, int]:
        """:func:`assign_folds` of ``keys`` in their ``groups`` by this spec (a ValueError says why not)."""
        k = self.n_folds(len(set(groups[key] for key in keys)))
        return assign_folds(keys, k, seed=self.seed, groups=groups, deal=self.deal)


def hash_key(label: str, seed: int = SEED) -> int:
    """A group's place in the ``hash`` and ``blocks`` deals: SHA-256 of ``"<seed>:<label>"`` (UTF-8), its
    first 8 bytes as an unsigned big-endian integer. Depends on nothing but these two, on every platform and
    Python version (unlike :func:`hash`, which is salted per process)."""
    digest = hashlib.sha256(f"{int(seed)}:{label}".encode()).digest()
    return int.from_bytes(digest[:8], "big")


def hash_fold(label: str, k: int, seed: int = SEED) -> int:
    """The ``hash`` deal's fold of a group: :func:`hash_key` modulo ``k``."""
    return hash_key(label, seed) % k


def _fine_axes():
    return tuple(np.linspace(g[0], g[-1], FINE) for g in GRID)


def _axes_for_interpolation():
    """Interpolation coordinates: ln(eta) (fuel goes nearly as 1/eta, so ln fuel is nearly linear in it),
    and the friction coefficient itself (FMEP is linear in it)."""
    fe, ff = _fine_axes()
    return (np.log(GRID[0]), np.log(fe)), (GRID[1], ff)


def _interp_weights(grid: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    j = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, len(grid) - 2)
    w = (x - grid[j]) / (grid[j + 1] - grid[j])
    return j, w


def surrogate(log_fuel_grid: np.ndarray) -> np.ndarray:
    """ln(fuel) of each row on the fine grid (rows, FINE, FINE) by bilinear interpolation of the nodes.

    ``log_fuel_grid``: (rows, len(GRID[0]), len(GRID[1])).
    """
    (ge, fe), (gf, ff) = _axes_for_interpolation()
    je, we = _interp_weights(ge, fe)
    jf, wf = _interp_weights(gf, ff)
    g = log_fuel_grid
    a = g[:, je][:, :, jf] * (1 - wf) + g[:, je][:, :, jf + 1] * wf
    b = g[:, je + 1][:, :, jf] * (1 - wf) + g[:, je + 1][:, :, jf + 1] * wf
    return a * (1 - we)[None, :, None] + b * we[None, :, None]


def fuel_per_watt(duration_s: float, distance_m: float) -> float:
    """L/100 km of fuel per watt of accessory power at an indicated efficiency of 1 over a cycle of this
    duration and distance (certification gasoline's density and heating value)."""
    from .vehicle import FUEL_DENSITY_KG_PER_L, FUEL_LHV_J_PER_KG

    return duration_s / (FUEL_LHV_J_PER_KG * FUEL_DENSITY_KG_PER_L) / (distance_m / 1e5)


def fit(
    log_fuel_grid: np.ndarray, log_measured_fuel: np.ndarray, per_watt: np.ndarray | None = None
) -> tuple[dict[str, float], float]:
    """The technology minimising mean |ln(pred/meas)| over the rows given; (params, loss).

    ``per_watt``: each row's :func:`fuel_per_watt`; None keeps the accessories at the grid's power.
    """
    from .vehicle import ACCESSORY_POWER_W

    if log_fuel_grid.shape[0] == 0:
        raise ValueError("no vehicle to fit the technology on")
    s = surrogate(log_fuel_grid)
    m = log_measured_fuel[:, None, None]
    fe, ff = _fine_axes()
    if per_watt is None:
        loss = np.mean(np.abs(s - m), axis=0)
        i, j = np.unravel_index(int(np.argmin(loss)), loss.shape)
        return (
            {TECH_PARAMS[0]: float(fe[i]), TECH_PARAMS[1]: float(ff[j]), TECH_PARAMS[2]: ACCESSORY_POWER_W},
            float(loss[i, j]),
        )
    fuel = np.exp(s)
    slope = np.asarray(per_watt, float)[:, None, None] / fe[None, :, None]  # L/100 km per W

    def best(power, sub):
        f = fuel[:, sub, sub] + (power - ACCESSORY_POWER_W) * slope[:, sub]
        loss = np.mean(np.abs(np.log(np.maximum(f, FUEL_FLOOR)) - m), axis=0)
        k = int(np.argmin(loss))
        return float(loss.flat[k]), np.unravel_index(k, loss.shape)

    c = ACCESSORY_COARSE
    coarse = slice(None, None, c)
    k0 = min(range(0, ACCESSORY_AXIS.size, c), key=lambda k: best(ACCESSORY_AXIS[k], coarse)[0])
    near = range(max(k0 - c, 0), min(k0 + c + 1, ACCESSORY_AXIS.size))
    results = {k: best(ACCESSORY_AXIS[k], slice(None)) for k in near}
    k = min(results, key=lambda k: results[k][0])
    loss, (i, j) = results[k]
    return {
        TECH_PARAMS[0]: float(fe[i]),
        TECH_PARAMS[1]: float(ff[j]),
        TECH_PARAMS[2]: float(ACCESSORY_AXIS[k]),
    }, loss


def cross_validate(
    log_fuel_grid: np.ndarray,
    log_measured_fuel: np.ndarray,
    vehicle_fold: np.ndarray,
    vehicle_class: np.ndarray,
    k: int,
    per_watt: np.ndarray | None = None,
) -> dict[tuple[int, str], dict[str, float]]:
    """Technology per (fold, class), each fitted without that fold's rows. Rows are vehicle x cycle.

    ``vehicle_fold``, ``vehicle_class``, ``per_watt`` (:func:`fit`): per row. A class with no training row
    in some fold falls back to the fit over all classes' training rows of that fold (and says so in the
    returned dict).
    """

    def fit_rows(rows):
        pw = None if per_watt is None else per_watt[rows]
        return fit(log_fuel_grid[rows], log_measured_fuel[rows], pw)

    return per_fold_and_class(fit_rows, vehicle_fold, vehicle_class, k)


def per_fold_and_class(fit_rows, vehicle_fold, vehicle_class, k: int, classes=CLASSES) -> dict:
    """``fit_rows(mask) -> (params, loss)`` per (fold, class) on the training rows (the other folds' rows of
    the class): the one cross-validation procedure, for vpsim's technology and for the peer's
    (:func:`vpsim.fleet.peer.calibrate_peer`). A class with no training row in some fold falls back to all
    classes' training rows of that fold, and says so (``basis``)."""
    out: dict[tuple[int, str], dict] = {}
    for fold in range(k):
        train = vehicle_fold != fold
        for cls in classes:
            rows = train & (vehicle_class == cls)
            basis = "class"
            if not rows.any():
                rows, basis = train, "all classes (no training vehicle of this class)"
            if not rows.any():
                raise ValueError(f"fold {fold} leaves no vehicle to train on; use fewer folds")
            params, loss = fit_rows(rows)
            out[(fold, cls)] = {**params, "train_loss": loss, "n_train": int(rows.sum()), "basis": basis}
    return out


def fit_all(log_fuel_grid, log_measured_fuel, vehicle_class, per_watt=None) -> dict[str, dict[str, float]]:
    """Technology per class fitted on every vehicle (for new cars; never used for the reported errors)."""
    out = {}
    for cls in CLASSES:
        rows = vehicle_class == cls
        if rows.any():
            pw = None if per_watt is None else per_watt[rows]
            params, loss = fit(log_fuel_grid[rows], log_measured_fuel[rows], pw)
            out[cls] = {**params, "train_loss": loss, "n_train": int(rows.sum())}
    return out


__all__ = [
    "ACCESSORY_AXIS",
    "CLASSES",
    "GRID",
    "SIMULATED",
    "TECH_PARAMS",
    "GROUPINGS",
    "DEALS",
    "FoldSpec",
    "assign_folds",
    "hash_fold",
    "hash_key",
    "cross_validate",
    "per_fold_and_class",
    "fit",
    "fit_all",
    "fuel_per_watt",
    "grid_variants",
    "vehicle_groups",
]
