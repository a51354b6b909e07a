"""What the commands print: no number without meaning.

A figure that is undefined (fuel per distance on a cycle that drives no distance, a residual relative to
zero work) is not a number. In JSON it becomes ``null`` with a ``<key>_undefined`` entry giving the reason, so
the output stays valid JSON (``NaN`` and ``Infinity`` are not JSON); in text it is printed as
``undefined (reason)``, never ``nan``.
"""

from __future__ import annotations

import json
import math
from typing import Any

_REASONS = {
    "fuel_l_per_100km": "the cycle drives no distance (less than 1 m), so fuel per distance is undefined",
    "fuel_economy_mpg": "the cycle drives no distance (less than 1 m) or burns no fuel, so miles per gallon "
    "are undefined",
    "measured_error_pct": "no measurement of this vehicle on this cycle to compare with",
    "energy_relative_residual": "no indicated work, so a residual relative to it is undefined",
    "diff_vs_bqm_pct": "the backward method's figure it is compared with is undefined",
    "std_error": "the fit ended at a bound of this parameter, so it has no standard error",
    "electric_wh_per_km": "no traction battery in this powertrain, or no distance driven",
    "wall_wh_per_km": "no traction battery in this powertrain, or no distance driven",
    "mpge": "defined for a battery-electric car (from its wall energy), and only when the run drew energy "
    "from its battery",
    "fuel_l_per_100km_cs": "the charge-sustaining fuel is a hybrid's figure (a battery-electric car burns "
    "none), "
    "or the cycle drives no distance",
    "soc_start": "no traction battery in this powertrain",
    "soc_end": "no traction battery in this powertrain",
    "regen_wh": "no electric machine in this powertrain",
    "machine_at_limit_s": "no electric machine in this powertrain",
    "battery_at_limit_s": "no traction battery in this powertrain",
}
# figures some result objects hold as the text "nan" (vpsim.calibration's std_error): treated as numbers
_TEXT_NUMBER_KEYS = ("std_error",)
_NON_FINITE_TEXT = ("nan", "inf", "-inf", "infinity", "-infinity")


def reason(key: str, value: Any) -> str:
    """Why ``value`` of figure ``key`` has no meaning."""
    if key in _REASONS and isinstance(value, float) and math.isnan(value):
        return _REASONS[key]
    if isinstance(value, float) and math.isinf(value):
        return "not a finite number (it overflows)"
    return "not a number (undefined for this input)"


def _finite(value: Any) -> bool:
    return not (isinstance(value, float) and not math.isfinite(value))


def json_safe(obj: Any, *, reasons: dict | None = None, key: str = "") -> Any:
    """``obj`` with every non-finite float replaced by ``None``; the dicts gain ``<key>_undefined``."""
    if isinstance(obj, dict):
        out: dict = {}
        for k, v in obj.items():
            if k in _TEXT_NUMBER_KEYS and isinstance(v, str) and v.strip().lower() in _NON_FINITE_TEXT:
                v = float(v)
            if isinstance(v, float | int) and not isinstance(v, bool) and not _finite(float(v)):
                out[k] = None
                out[f"{k}_undefined"] = reason(str(k), float(v))
            else:
                out[k] = json_safe(v, key=str(k))
        return out
    if isinstance(obj, list | tuple):
        return [None if isinstance(v, float) and not _finite(v) else json_safe(v) for v in obj]
    if hasattr(obj, "item") and callable(obj.item) and getattr(obj, "ndim", None) == 0:  # numpy scalars
        v = obj.item()
        return None if isinstance(v, float) and not _finite(v) else v
    return obj


def dumps(obj: Any, **kw) -> str:
    """Valid JSON of ``obj`` (non-finite numbers as null with a reason); never ``NaN`` or ``Infinity``."""
    return json.dumps(json_safe(obj), allow_nan=False, **kw)


def number(value: Any, spec: str, key: str = "") -> str:
    """``value`` formatted with ``spec``, or ``undefined (reason)`` when it is not a finite number."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        return "undefined"
    if not math.isfinite(x):
        return f"undefined ({reason(key, x)})"
    return format(x, spec)


__all__ = ["dumps", "json_safe", "number", "reason"]
