"""vpsim: drive-cycle simulation of vehicle propulsion systems.

One physical powertrain model (mean-value SI engine with intake-manifold dynamics, stiff driveline, road
load) run by three simulation methods, after Hofman, van Leeuwen & Steinbuch (2011).
"""

from .errors import CycleError, ParameterError, VpsimError
from .params import Parameters, load_parameters

__version__ = "0.1.0"

__all__ = ["CycleError", "ParameterError", "Parameters", "VpsimError", "load_parameters", "__version__"]
