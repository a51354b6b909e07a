"""Reading a ``vpsim fleet`` run's ``technology.json`` back (``vpsim vehicle from-epa --technology``).

The file is checked before any value is used: it must come from a run that finished writing its folder
(:func:`vpsim.fleet.report.check_complete`); its top-level keys, the battery-electric and hybrid parts'
keys, the classes under ``all_vehicles`` and the keys of each class's fit must be ones a fleet run writes
(a misspelt key read as absent would silently leave a default in its place: a wrong number); and each
fitted value must be a number in its field's range (:func:`vpsim.params.check_field`: ``true`` is not 1,
an efficiency of 1 is refused).
Every problem is one line naming the file, the key and the keys expected.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import VpsimError
from ..textio import printable, short_name

# what vpsim.fleet.report.write_outputs writes
TOP_KEYS = (
    "out_of_fold",
    "all_vehicles",
    "search_bounds",
    "on_search_bound",
    "peer_fastsim_calibrated_out_of_fold",
    "bev",
    "hev",
    "mhev",
)
BEV_KEYS = (
    "parameters",
    "out_of_fold",
    "all_vehicles",
    "search_bounds",
    "on_search_bound",
    "peer_fastsim_calibrated_out_of_fold",
)
HEV_KEYS = (
    "parameters",
    "out_of_fold",
    "all_vehicles",
    "search_bounds",
    "peer_fastsim_calibrated_out_of_fold",
)
FIT_INFO = ("train_loss", "n_train", "basis")  # how a class's fit was made: written beside its values
# a technology.json written before these were fitted (the conventional accessories, the mild hybrids'
# friction, the full hybrids' machine losses) has none: the vehicle file keeps its default
OPTIONAL = ("engine.accessory_power", "engine.friction_coefficient", "machine.loss_scale")


def _table(path, data, where: str, allowed) -> dict:
    """``data`` (the object at ``where``) as a dict whose keys are all in ``allowed``; one line if not."""
    if not isinstance(data, dict):
        raise VpsimError(f"{path}: {where or 'the file'} is not an object of {', '.join(allowed)}")
    for k in data:
        if k not in allowed:
            at = f"{where}.{k}" if where else k
            raise VpsimError(
                f"{path}: unknown key {printable(short_name(at))!r} (it would be ignored); a vpsim fleet "
                f"technology.json has at {where or 'its top level'} only: {', '.join(allowed)}"
            )
    return data


def read_technology(path, powertrain: str, cls: str) -> tuple[dict[str, float], str]:
    """The fit on all vehicles of class ``cls`` (``powertrain`` ``"conventional"``, ``"bev"``, ``"hev"`` or
    ``"mhev"``) in the technology.json ``path``, and the note a vehicle file gives for it; one-line
    :class:`VpsimError` if the file is from an unfinished run, not such a file, has keys no fleet run
    writes, or a value out of range."""
    from ..params import check_field
    from ..textio import check_path, read_json
    from . import ev, hev, mhev
    from .calibrate import CLASSES, TECH_PARAMS
    from .report import check_complete

    path = check_path(path, VpsimError, "technology.json")  # a name no file can have: one line first
    shown = printable(path)
    check_complete(path.parent, path.name)
    data = _table(shown, read_json(path, VpsimError, what="technology.json"), "", TOP_KEYS)
    # every fit's keys are checked, whichever is read: the file is one run's, valid or not as a whole
    parts = {"": (data, CLASSES, TECH_PARAMS)}
    if "bev" in data:
        parts["bev."] = (_table(shown, data["bev"], "bev", BEV_KEYS), ev.CLASSES, ev.TECH_PARAMS)
    if "hev" in data:
        parts["hev."] = (_table(shown, data["hev"], "hev", HEV_KEYS), hev.CLASSES, hev.TECH_PARAMS)
    if "mhev" in data:
        parts["mhev."] = (_table(shown, data["mhev"], "mhev", HEV_KEYS), mhev.CLASSES, mhev.TECH_PARAMS)
    for prefix, (part, classes, names) in parts.items():
        if "all_vehicles" in part:
            fits = _table(shown, part["all_vehicles"], f"{prefix}all_vehicles", classes)
            for c, fit in fits.items():
                _table(shown, fit, f"{prefix}all_vehicles.{c}", (*names, *FIT_INFO))
    prefix = {"bev": "bev.", "hev": "hev.", "mhev": "mhev."}.get(powertrain, "")
    if prefix not in parts:
        kind = {"bev": "a battery-electric", "mhev": "a mild-hybrid"}.get(powertrain, "a hybrid")
        raise VpsimError(
            f"{shown}: not a technology.json of vpsim fleet with {kind} fit (no {prefix}all_vehicles.{cls})"
        )
    part, classes, names = parts[prefix]
    if "all_vehicles" not in part:
        raise VpsimError(f"{shown}: not a technology.json of vpsim fleet (no {prefix}all_vehicles)")
    fits = part["all_vehicles"]
    where = f"{prefix}all_vehicles.{cls}"
    if cls not in fits:
        have = ", ".join(fits) or "none"
        raise VpsimError(
            f"{shown}: {prefix}all_vehicles has no fit for this car's class {cls} (the run fitted: {have}); "
            "run vpsim fleet on a list with vehicles of that class"
        )
    fit = fits[cls]
    values = {}
    for k in names:
        if k not in fit:
            if k in OPTIONAL:
                continue
            raise VpsimError(f"{shown}: {where} has no {k}; not a technology.json of vpsim fleet")
        values[k] = check_field(k, fit[k], f"{shown} ({where})")
    return values, f"fleet fit ({cls} class, all vehicles) from {printable(Path(path).name)}"
