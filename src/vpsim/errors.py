"""Errors a user can act on.

Every error raised for bad input derives from :class:`VpsimError`; the CLI prints its message as one line
and exits with status 2. Messages name the file, field or value and say what was expected.
"""


class VpsimError(ValueError):
    """Base class of all user-facing vpsim errors (bad input, infeasible request)."""


class ParameterError(VpsimError):
    """A parameter set is invalid: unknown field, wrong unit scale, non-physical value."""


class CycleError(VpsimError):
    """A drive cycle or gear schedule file is malformed."""


class EngineFileError(VpsimError):
    """An engine data file (ADVISOR .m or JSON) cannot be read safely."""


class MachineFileError(EngineFileError):
    """An electric-machine data file (ADVISOR MC_*.m or GC_*.m) cannot be read safely or makes no sense."""


class NonFiniteRunError(VpsimError):
    """A run's state or totals became NaN or infinite: the parameters are outside what the model can
    compute (a result is refused rather than shown with a wrong number)."""
