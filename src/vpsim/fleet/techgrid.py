"""A class's technology parameters fitted on a grid of real runs (the electric and hybrid fleets).

Each vehicle is run at the nodes of its first parameter (``axis``) and at two accessory powers
(``accessory_nodes_w``); the figure (wall energy, fuel) is then interpolated in its logarithm between the
first parameter's nodes onto ``fine``, and linearly in the accessory power (the figure is linear in a constant
load) onto ``accessory_axis``. The fit minimises the mean |ln(predicted / measured)| over a fold's training
rows; every reported figure then comes from one real run at the fitted values, not from this surrogate.
A third parameter (:class:`ThirdAxis`: the mild hybrids' engine friction, the full hybrids' machine losses)
stacks that grid at its own nodes and is searched on its own fine axis, interpolated linearly between them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def bounds_hit(bounds: dict[str, tuple[float, float]], params: dict) -> dict[str, str]:
    """{parameter: "low" | "high"} for each value of ``params`` that sits on its search bound."""
    out = {}
    for name, (lo, hi) in bounds.items():
        x = params.get(name)
        if x is None:
            continue
        tol = 1e-9 * max(abs(lo), abs(hi), 1.0)
        if x <= lo + tol:
            out[name] = "low"
        elif x >= hi - tol:
            out[name] = "high"
    return out


@dataclass(frozen=True, eq=False)
class TechGrid:
    names: tuple[str, str]  # (the first parameter, the accessory power)
    axis: np.ndarray  # the first parameter's run nodes
    fine: np.ndarray  # ... and the values the fit chooses among
    accessory_nodes_w: tuple[float, float]
    accessory_axis: np.ndarray
    what: str  # the vehicles, for the error when a fold has none ("hybrid")

    def surrogate(self, grid: np.ndarray) -> np.ndarray:
        """The figure of each row (grid: rows x len(axis) x 2 of its logarithm) on (fine, accessory_axis)."""
        n = grid.shape[0]
        lo = np.empty((n, self.fine.size))
        hi = np.empty_like(lo)
        for k in range(n):
            lo[k] = np.interp(self.fine, self.axis, grid[k, :, 0])
            hi[k] = np.interp(self.fine, self.axis, grid[k, :, 1])
        f0, f1 = np.exp(lo), np.exp(hi)
        a0, a1 = self.accessory_nodes_w
        slope = (f1 - f0) / (a1 - a0)
        return f0[:, :, None] + slope[:, :, None] * (self.accessory_axis[None, None, :] - a0)

    def fit(self, grid: np.ndarray, log_measured: np.ndarray) -> tuple[dict, float]:
        """The technology minimising mean |ln(predicted / measured)| over the rows; (params, loss)."""
        if grid.shape[0] == 0:
            raise ValueError(f"no {self.what} to fit the technology on")
        f = np.maximum(self.surrogate(grid), 1e-6)
        loss = np.mean(np.abs(np.log(f) - np.asarray(log_measured)[:, None, None]), axis=0)
        i, j = np.unravel_index(int(np.argmin(loss)), loss.shape)
        params = {self.names[0]: float(self.fine[i]), self.names[1]: float(self.accessory_axis[j])}
        return params, float(loss[i, j])

    def search_bounds(self) -> dict[str, tuple[float, float]]:
        """The range each parameter is searched in."""
        return {
            self.names[0]: (float(self.fine[0]), float(self.fine[-1])),
            self.names[1]: (float(self.accessory_axis[0]), float(self.accessory_axis[-1])),
        }

    def on_bounds(self, params: dict) -> dict[str, str]:
        """{parameter: "low" | "high"} for each fitted value that sits on its search bound."""
        return bounds_hit(self.search_bounds(), params)

    def log_grid(self, base, figure_of, what: str) -> np.ndarray:
        """ln ``figure_of(params)`` of ``base`` (:class:`~vpsim.params.Parameters`) at every node of the first
        parameter and both accessory nodes: (len(axis), 2); a non-finite figure (``what``) an error."""
        (sec0, fld0), (sec1, fld1) = (name.split(".") for name in self.names)
        g = np.empty((self.axis.size, len(self.accessory_nodes_w)))
        for i, x in enumerate(self.axis):
            for j, acc in enumerate(self.accessory_nodes_w):
                changes: dict[str, dict] = {sec0: {fld0: float(x)}}
                changes.setdefault(sec1, {})[fld1] = acc
                g[i, j] = math.log(figure_of(base.with_changes(**changes)))
        if not np.all(np.isfinite(g)):
            raise ValueError(f"non-finite {what} on the technology grid")
        return g

    def grid_chunk(
        self, items, base_of, runner_of, column: str, what: str, *, per_test: bool = False, grid_of=None
    ):
        """The grid (:meth:`log_grid`, or ``grid_of(base, figure_of, what)`` where a class has more axes) of
        each (record, tests) of ``items``, a row per test with ``column`` (or None and ``error``).
        ``base_of(rec, test)`` builds the vehicle, once per record (``test`` None) unless ``per_test``;
        ``runner_of(rec, test)`` gives the figure of a params' run on the test."""
        from .run import _kernels_on_one_thread, _one_line

        out = []
        with _kernels_on_one_thread():
            for rec, cycles in items:
                if not per_test:
                    try:
                        base, why = base_of(rec, None), ""
                    except Exception as exc:
                        base, why = None, _one_line(exc)
                for name in cycles:
                    row = {"key": rec.key, "cycle": name, column: None, "error": ""}
                    try:
                        if per_test:
                            base = base_of(rec, name)
                        elif base is None:
                            raise ValueError(why)
                        row[column] = (grid_of or self.log_grid)(base, runner_of(rec, name), what)
                    except Exception as exc:
                        row["error"] = _one_line(exc)
                    out.append(row)
        return out


@dataclass(frozen=True, eq=False)
class ThirdAxis:
    """A third technology parameter ``name`` over a :class:`TechGrid` ``grid``: every vehicle is run on the
    grid at each of its ``nodes``; at each value of ``fine`` the logarithm of the figure is interpolated
    linearly between its two nodes, and the grid's two parameters searched there as :meth:`TechGrid.fit`."""

    name: str
    nodes: np.ndarray
    fine: np.ndarray
    grid: TechGrid

    def log_grid(self, base, figure_of, what: str) -> np.ndarray:
        """:meth:`TechGrid.log_grid` at each node: (len(grid.axis), len(nodes), 2)."""
        sec, fld = self.name.split(".")
        return np.stack(
            [
                self.grid.log_grid(base.with_changes(**{sec: {fld: float(x)}}), figure_of, what)
                for x in self.nodes
            ],
            axis=1,
        )

    def grid_chunk(self, items, base_of, runner_of, column: str, what: str, *, per_test: bool = False):
        """:meth:`TechGrid.grid_chunk` with this axis's :meth:`log_grid`."""
        return self.grid.grid_chunk(
            items, base_of, runner_of, column, what, per_test=per_test, grid_of=self.log_grid
        )

    def fit(self, grid: np.ndarray, log_measured: np.ndarray) -> tuple[dict, float]:
        """The technology minimising mean |ln(predicted / measured)| over the rows; (params, loss).
        ``grid``: rows x grid.axis x nodes x accessory nodes of the figure's logarithm."""
        if grid.shape[0] == 0:
            raise ValueError(f"no {self.grid.what} to fit the technology on")
        nodes, fine = self.nodes, self.fine
        j = np.clip(np.searchsorted(nodes, fine, side="right") - 1, 0, nodes.size - 2)
        w = (fine - nodes[j]) / (nodes[j + 1] - nodes[j])
        best: tuple[dict, float] | None = None
        for k, x in enumerate(fine):
            params, loss = self.grid.fit(
                grid[:, :, j[k], :] * (1.0 - w[k]) + grid[:, :, j[k] + 1, :] * w[k], log_measured
            )
            if best is None or loss < best[1]:
                best = ({**params, self.name: float(x)}, loss)
        return best

    def search_bounds(self) -> dict[str, tuple[float, float]]:
        """The range each technology parameter is searched in."""
        return {**self.grid.search_bounds(), self.name: (float(self.fine[0]), float(self.fine[-1]))}

    def on_bounds(self, params: dict) -> dict[str, str]:
        """{parameter: "low" | "high"} for each fitted value that sits on its search bound."""
        return bounds_hit(self.search_bounds(), params)
