"""vpsim: drive-cycle simulation of vehicle propulsion systems.

One physical powertrain model (mean-value SI engine with intake-manifold dynamics, stiff driveline, road
load) run by three simulation methods, after Hofman, van Leeuwen & Steinbuch (2011).
"""

from .cycles import Cycle, load_cycle
from .errors import CycleError, ParameterError, VpsimError
from .params import Parameters, load_parameters
from .result import Result
from .simulation import simulate

__version__ = "0.1.0"

__all__ = [
    "Cycle",
    "CycleError",
    "ParameterError",
    "Parameters",
    "Result",
    "VpsimError",
    "__version__",
    "load_cycle",
    "load_parameters",
    "simulate",
]
