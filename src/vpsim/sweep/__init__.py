"""Design-space sweeps: many design points x cycles x methods, on local cores or a Dask cluster, resumable.

    >>> from vpsim.sweep import make_spec, run_sweep
    >>> spec = make_spec(parameters={"engine.bore": {"range": [0.08, 0.095], "n": 4}}, cycles=["nedc"])
    >>> run = run_sweep(spec, out="sweep_out", workers=1)        # doctest: +SKIP
    >>> run.results[["engine.bore", "fuel_l_per_100km", "accel_0_100_s"]]   # doctest: +SKIP

* :mod:`~vpsim.sweep.spec`: the specification (TOML or keywords), sampling, validation;
* :mod:`~vpsim.sweep.runner`: planning, chunking and execution (in process, local processes, Dask);
* :mod:`~vpsim.sweep.store`: the append-only output folder, point identities, resume;
* :mod:`~vpsim.sweep.plots`: fuel against displacement, and the Pareto front of fuel against 0-100 km/h.

See ``docs/sweeps.md``.
"""

from .runner import SweepRun, compute_chunk, plan, result_schema, run_sweep
from .spec import (
    AccelerationSettings,
    Axis,
    Design,
    SpecError,
    SweepSpec,
    apply_changes,
    load_spec,
    make_spec,
)
from .store import ResultStore, load_results

__all__ = [
    "AccelerationSettings",
    "Axis",
    "Design",
    "ResultStore",
    "SpecError",
    "SweepRun",
    "SweepSpec",
    "apply_changes",
    "compute_chunk",
    "load_results",
    "load_spec",
    "make_spec",
    "plan",
    "result_schema",
    "run_sweep",
]
