"""Measured electric machines: an efficiency map (machine and inverter together) on a speed x torque grid.

    >>> import numpy as np
    >>> from vpsim.engines.machine_map import MeasuredMachine
    >>> m = MeasuredMachine(
    ...     name="toy", description="", speed_grid=np.array([0.0, 100.0, 200.0]),
    ...     torque_grid=np.array([-10.0, 0.0, 10.0]), efficiency=np.full((3, 3), 0.9),
    ...     envelope_speed=np.array([0.0, 100.0, 200.0]), max_torque=np.array([10.0, 10.0, 5.0]),
    ...     min_torque=np.array([-10.0, -10.0, -5.0]), inertia=0.0, source="example")
    >>> round(float(m.loss_w(10.0, 100.0)), 3)  # motoring: T w / eta - T w
    111.111
    >>> round(float(m.loss_w(-10.0, 100.0)), 3)  # generating: |T| w (1 - eta)
    100.0

Units are SI: rad/s, N*m, W, kg*m^2. ``efficiency[i, j]`` is at ``speed_grid[i]``, ``torque_grid[j]`` (rows
speed, columns torque, as ADVISOR's ``meshgrid(mc_map_trq, mc_map_spd)``). Positive torque is motoring
(electrical power in, mechanical power out), negative torque is generating.

Efficiency and loss
    ADVISOR's ``mc_eff_map`` includes the inverter: the electrical (DC) power is ``P_elec = T w / eta`` when
    motoring and ``P_elec = T w eta`` when generating (negative: power delivered to the battery). The loss
    is what the machine turns into heat, ``P_elec - T w`` motoring and ``T w - P_elec`` generating, both
    ``>= 0`` because every efficiency is checked to lie in (0, 1].

    At a node with zero torque or zero speed the mechanical power is zero and the efficiency is undefined;
    ADVISOR fills those rows and columns with placeholders (0.2, 0.3, 0.7 ...) that are never used.
    :meth:`MeasuredMachine.loss_w` does what ADVISOR's own files do (``mc_inpwr_map``): the loss at zero
    torque is the loss of the nearest positive-torque column (or the nearest negative one where there is
    none), and the loss at zero speed is the loss of the lowest positive speed. Between nodes the *loss*
    (not the efficiency) is interpolated bilinearly, since it stays finite and smooth through T = 0 while
    the efficiency does not. Outside the grid the speed and torque are clamped to its edges (use
    :meth:`MeasuredMachine.inside_grid` to see where that happened).

Reading ADVISOR files (:func:`load_machine`)
    Motor files (``MC_*.m``) give ``mc_map_spd``, ``mc_map_trq``, ``mc_eff_map``, ``mc_max_trq`` (motoring
    envelope over ``mc_map_spd``) and usually ``mc_max_gen_trq`` (generating envelope, <= 0); where the
    latter is missing the envelope is taken as ``-mc_max_trq`` (what ADVISOR's files assume as "estimate").
    Generator files (``GC_*.m``) use the ``gc_`` prefix and have no generating envelope; their efficiency is
    "of the machine/inverter when run as a motor" (the file's own comment), used here with the same motor
    sign convention. A file whose torque grid holds no negative torques is mirrored (``eta(-T, w) =
    eta(T, w)``), exactly how ADVISOR's MC files build their generating quadrant themselves. A file with
    negative speeds (``GC_PRIUS_JPN``) must be point-symmetric (``eta(-w, T) == eta(w, -T)`` and the envelope
    even in speed); then the half with ``w >= 0`` is kept, otherwise it is refused.

Every problem in a file is one line, :class:`vpsim.errors.MachineFileError`, naming the file, the field and
what was expected; nothing is clipped or filled in silently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EngineFileError, MachineFileError
from .matlab import read_m_file
from .measured import checked_arrays

__all__ = ["MeasuredMachine", "load_machine"]

_TOL = 1e-9


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class MeasuredMachine:
    """An electric machine with its inverter described by a measured efficiency map.

    ``speed_grid`` rad/s (strictly increasing, >= 0), ``torque_grid`` N*m (strictly increasing),
    ``efficiency`` (n_speed, n_torque) in (0, 1] wherever torque and speed are non-zero, ``envelope_speed``
    rad/s with ``max_torque`` (>= 0, motoring) and ``min_torque`` (<= 0, generating) over it, ``inertia``
    kg*m^2 (0 where unknown). Arrays are stored read-only; instances compare by identity.
    """

    name: str
    description: str
    speed_grid: np.ndarray
    torque_grid: np.ndarray
    efficiency: np.ndarray
    envelope_speed: np.ndarray
    max_torque: np.ndarray
    min_torque: np.ndarray
    inertia: float
    source: str

    def __post_init__(self) -> None:
        where = self.source or self.name

        def bad(msg: str) -> MachineFileError:
            return MachineFileError(f"{where}: {msg}")

        arrays = checked_arrays(
            self,
            ("speed_grid", "torque_grid", "efficiency", "envelope_speed", "max_torque", "min_torque"),
            ("speed_grid", "torque_grid", "envelope_speed"),
            bad,
        )
        speed, torque, eff = arrays["speed_grid"], arrays["torque_grid"], arrays["efficiency"]
        if speed[0] < 0 or arrays["envelope_speed"][0] < 0:
            raise bad("speeds must not be negative")
        if not np.any(speed > 0):
            raise bad("speed_grid has no positive speed")
        if not (np.any(torque > 0) and np.any(torque < 0)):
            raise bad("torque_grid must hold positive (motoring) and negative (generating) torques")
        shape = (speed.size, torque.size)
        if eff.shape != shape:
            raise bad(f"efficiency has shape {eff.shape}, expected (n_speed, n_torque) = {shape}")
        t_node, w_node = np.meshgrid(torque, speed)
        used = (t_node != 0) & (w_node != 0)
        if np.any(eff[used] <= 0) or np.any(eff[used] > 1):
            i, j = np.argwhere(used & ((eff <= 0) | (eff > 1)))[0]
            raise bad(
                f"efficiency = {eff[i, j]:g} at {speed[i]:g} rad/s, {torque[j]:g} N*m; expected a fraction "
                "in (0, 1] (0.9, not 90)"
            )
        n_env = arrays["envelope_speed"].size
        for field_name, sign in (("max_torque", 1.0), ("min_torque", -1.0)):
            a = arrays[field_name]
            if a.shape != (n_env,):
                raise bad(f"{field_name} has shape {a.shape}, expected ({n_env},) like envelope_speed")
            if np.any(sign * a < 0):
                kind = "non-negative (motoring)" if sign > 0 else "non-positive (generating)"
                raise bad(f"{field_name} must be {kind} everywhere")
            if not np.any(sign * a > 0):
                raise bad(f"{field_name} is zero everywhere")
        for field_name, a in arrays.items():
            object.__setattr__(self, field_name, _frozen(a))
        try:
            inertia = float(self.inertia)
        except (TypeError, ValueError):
            raise bad("inertia is not a number") from None
        if not math.isfinite(inertia) or inertia < 0:
            raise bad(f"inertia = {inertia:g} kg*m^2; expected a finite number >= 0")
        object.__setattr__(self, "inertia", inertia)
        object.__setattr__(self, "_loss_table", _frozen(self._node_losses()))
        if self.rated_power_w <= 0:
            raise bad("the torque envelope gives no positive power")

    # ------------------------------------------------------------------ envelope and rating

    def max_torque_at(self, speed: Any) -> Any:
        """Motoring torque limit (N*m) at ``speed`` (rad/s), linear in the envelope; 0 beyond its end."""
        w = np.asarray(speed, dtype=float)
        out = np.interp(np.abs(w), self.envelope_speed, self.max_torque, right=0.0)
        return out if out.ndim else float(out)

    def min_torque_at(self, speed: Any) -> Any:
        """Generating torque limit (N*m, <= 0) at ``speed`` (rad/s); 0 beyond the envelope's last speed."""
        w = np.asarray(speed, dtype=float)
        out = np.interp(np.abs(w), self.envelope_speed, self.min_torque, right=0.0)
        return out if out.ndim else float(out)

    @property
    def peak_torque_nm(self) -> float:
        """Highest motoring torque of the envelope (N*m)."""
        return float(self.max_torque.max())

    @property
    def rated_power_w(self) -> float:
        """Peak motoring power, the largest ``T_max(w) w`` over the envelope's nodes (W)."""
        return float(np.max(self.max_torque * self.envelope_speed))

    @property
    def base_speed_radps(self) -> float:
        """Corner speed where the envelope turns from constant torque to constant power: rated power over
        peak torque, ``P_max / T_max`` (rad/s). An ideal envelope holds T_max up to it and P_max above."""
        return self.rated_power_w / self.peak_torque_nm

    @property
    def max_speed_radps(self) -> float:
        """Highest speed of the envelope (rad/s): the speed the machine is rated to run at."""
        return float(self.envelope_speed[-1])

    # ------------------------------------------------------------------ losses

    def _node_losses(self) -> np.ndarray:
        """Loss (W) at every node; zero-torque columns and the zero-speed row copied from neighbours."""
        t_node, w_node = np.meshgrid(self.torque_grid, self.speed_grid)
        p_mech = t_node * w_node
        eff = np.where((t_node != 0) & (w_node != 0), self.efficiency, 1.0)
        loss = np.where(t_node > 0, p_mech / eff - p_mech, -p_mech * (1.0 - eff))
        torque = self.torque_grid
        for j in np.flatnonzero(torque == 0):
            pos = np.flatnonzero(torque > 0)
            loss[:, j] = loss[:, pos[0]] if pos.size else loss[:, np.flatnonzero(torque < 0)[-1]]
        first_moving = int(np.flatnonzero(self.speed_grid > 0)[0])
        loss[:first_moving, :] = loss[first_moving, :]
        return loss

    def loss_w(self, torque: Any, speed: Any) -> Any:
        """Electrical loss (W, >= 0) of machine and inverter at ``torque`` (N*m) and ``speed`` (rad/s).

        ``P_elec - T w`` motoring, ``T w - P_elec`` generating, from the map (see the module docstring for
        zero torque, zero speed and points outside the grid). Negative speeds use ``|w|`` and ``-T``
        (the same power flow), so a reversing machine sees the same loss.
        """
        t = np.asarray(torque, dtype=float)
        w = np.asarray(speed, dtype=float)
        t, w = np.broadcast_arrays(np.where(w < 0, -t, t), np.abs(w))
        out = _bilinear(self.speed_grid, self.torque_grid, self._loss_table, w, t)
        return out if out.ndim else float(out)

    def electric_power_w(self, torque: Any, speed: Any) -> Any:
        """DC electrical power (W) at ``torque`` and ``speed``: ``T w + loss`` (negative when generating)."""
        return np.asarray(torque, dtype=float) * np.asarray(speed, dtype=float) + self.loss_w(torque, speed)

    def inside_grid(self, torque: Any, speed: Any) -> np.ndarray:
        """Whether each point lies on the measured grid (else :meth:`loss_w` clamped it to the edge)."""
        t = np.asarray(torque, dtype=float)
        w = np.abs(np.asarray(speed, dtype=float))
        return (
            (w <= self.speed_grid[-1])
            & (t >= self.torque_grid[0])
            & (t <= self.torque_grid[-1])
            & (w >= self.speed_grid[0])
        )

    def map_points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(torque, speed, efficiency) of the nodes where the efficiency is defined and in the envelope.

        The point set of every comparison against a map: nodes with ``|T| > 1e-6 T_peak`` and
        ``w > 1e-6 w_max`` (the efficiency of zero mechanical power is undefined), with
        ``min_torque(w) <= T <= max_torque(w)`` (relative tolerance 1e-9), both quadrants.
        """
        t_node, w_node = np.meshgrid(self.torque_grid, self.speed_grid)
        keep = (np.abs(t_node) > 1e-6 * self.peak_torque_nm) & (w_node > 1e-6 * self.max_speed_radps)
        slack = _TOL * self.peak_torque_nm
        keep &= t_node <= self.max_torque_at(w_node) + slack
        keep &= t_node >= self.min_torque_at(w_node) - slack
        return t_node[keep], w_node[keep], self.efficiency[keep]

    def summary(self) -> dict[str, Any]:
        """Readable facts of the map (SI units and rpm), for ``vpsim machine import``."""
        _, _, eff = self.map_points()
        rpm = 60.0 / (2.0 * math.pi)
        return {
            "name": self.name,
            "description": self.description,
            "source": self.source,
            "rated_power_kw": self.rated_power_w / 1e3,
            "peak_torque_nm": self.peak_torque_nm,
            "min_generating_torque_nm": float(self.min_torque.min()),
            "base_speed_rpm": self.base_speed_radps * rpm,
            "max_speed_rpm": self.max_speed_radps * rpm,
            "speed_grid_rpm": [float(x) for x in self.speed_grid * rpm],
            "torque_grid_nm": [float(x) for x in self.torque_grid],
            "envelope_speed_rpm": [float(x) for x in self.envelope_speed * rpm],
            "envelope_max_torque_nm": [float(x) for x in self.max_torque],
            "envelope_min_torque_nm": [float(x) for x in self.min_torque],
            "efficiency_min": float(eff.min()),
            "efficiency_max": float(eff.max()),
            "n_map_points": int(eff.size),
            "inertia_kgm2": self.inertia,
        }


def _bilinear(xg: np.ndarray, yg: np.ndarray, table: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of ``table[i, j]`` at (xg[i], yg[j]); queries clamped to the grid."""
    x = np.clip(x, xg[0], xg[-1])
    y = np.clip(y, yg[0], yg[-1])
    i = np.clip(np.searchsorted(xg, x, side="right") - 1, 0, xg.size - 2)
    j = np.clip(np.searchsorted(yg, y, side="right") - 1, 0, yg.size - 2)
    fx = (x - xg[i]) / (xg[i + 1] - xg[i])
    fy = (y - yg[j]) / (yg[j + 1] - yg[j])
    return (
        table[i, j] * (1 - fx) * (1 - fy)
        + table[i + 1, j] * fx * (1 - fy)
        + table[i, j + 1] * (1 - fx) * fy
        + table[i + 1, j + 1] * fx * fy
    )


def load_machine(path: str | Path) -> MeasuredMachine:
    """Read an ADVISOR motor (``MC_*.m``) or generator (``GC_*.m``) file safely into a MeasuredMachine.

    The file is evaluated by :mod:`vpsim.engines.matlab` (never run). Files that scale themselves
    (``mc_spd_scale`` / ``mc_trq_scale`` other than 1) are refused. Any problem raises
    :class:`~vpsim.errors.MachineFileError` with one line naming the file and field.
    """
    p = Path(path)
    try:
        v = read_m_file(p)
    except MachineFileError:
        raise
    except EngineFileError as e:
        raise MachineFileError(str(e)) from None
    if "mc_eff_map" in v or "mc_map_spd" in v:
        pre = "mc"
    elif "gc_eff_map" in v or "gc_map_spd" in v:
        pre = "gc"
    else:
        raise MachineFileError(
            f"{p}: no 'mc_eff_map'/'mc_map_spd' (motor) or 'gc_eff_map'/'gc_map_spd' (generator) assigned; "
            "expected an ADVISOR MC_*.m or GC_*.m file"
        )

    def get(name: str, ndim: int) -> Any:
        key = f"{pre}_{name}"
        if key not in v:
            raise MachineFileError(f"{p}: variable '{key}' is not assigned")
        x = v[key]
        if ndim == 0:
            if not isinstance(x, float):
                raise MachineFileError(f"{p}: '{key}' must be a number")
            return x
        if not isinstance(x, np.ndarray | float):
            raise MachineFileError(f"{p}: '{key}' must be numeric")
        a = np.atleast_1d(np.asarray(x, dtype=float))
        if ndim == 2 and a.ndim != 2:
            raise MachineFileError(f"{p}: '{key}' must be a table (speeds x torques), got shape {a.shape}")
        if ndim == 1 and a.ndim != 1:
            raise MachineFileError(f"{p}: '{key}' must be a vector, got shape {a.shape}")
        return a

    for scale in ("spd_scale", "trq_scale"):
        if f"{pre}_{scale}" in v and get(scale, 0) != 1.0:
            raise MachineFileError(
                f"{p}: {pre}_{scale} = {v[f'{pre}_{scale}']:g}; only unscaled machines (1)"
            )
    speed = get("map_spd", 1)
    torque = get("map_trq", 1)
    eff = get("eff_map", 2)
    if eff.shape != (speed.size, torque.size):
        raise MachineFileError(
            f"{p}: '{pre}_eff_map' has shape {eff.shape}, expected ({speed.size}, {torque.size}) = "
            f"(length of {pre}_map_spd, length of {pre}_map_trq)"
        )
    max_trq = get("max_trq", 1)
    if max_trq.shape != speed.shape:
        raise MachineFileError(
            f"{p}: '{pre}_max_trq' has {max_trq.size} values, expected {speed.size} (one per {pre}_map_spd)"
        )
    if f"{pre}_max_gen_trq" in v:
        min_trq = get("max_gen_trq", 1)
        if min_trq.shape != speed.shape:
            raise MachineFileError(
                f"{p}: '{pre}_max_gen_trq' has {min_trq.size} values, expected {speed.size} "
                f"(one per {pre}_map_spd)"
            )
    else:
        min_trq = -max_trq
    for key, a in (("map_spd", speed), ("map_trq", torque), ("eff_map", eff), ("max_trq", max_trq)):
        if not np.all(np.isfinite(a)):
            raise MachineFileError(f"{p}: '{pre}_{key}' holds non-finite values")
    for key, a in (("map_spd", speed), ("map_trq", torque)):
        if a.size < 2 or not np.all(np.diff(a) > 0):
            raise MachineFileError(f"{p}: '{pre}_{key}' must be strictly increasing with at least 2 values")
    if speed[0] < 0:
        speed, eff, max_trq, min_trq = _fold_negative_speeds(p, pre, speed, torque, eff, max_trq, min_trq)
    if not np.any(torque < 0):
        pos = torque > 0
        torque = np.concatenate([-torque[pos][::-1], torque])
        eff = np.concatenate([eff[:, pos][:, ::-1], eff], axis=1)
    description = v.get(f"{pre}_description")
    description = description if isinstance(description, str) else ""
    inertia = v.get(f"{pre}_inertia", 0.0)
    if not isinstance(inertia, float):
        raise MachineFileError(f"{p}: '{pre}_inertia' must be a number")
    return MeasuredMachine(
        name=p.stem,
        description=description,
        speed_grid=speed,
        torque_grid=torque,
        efficiency=eff,
        envelope_speed=speed,
        max_torque=max_trq,
        min_torque=min_trq,
        inertia=inertia,
        source=str(p),
    )


def _fold_negative_speeds(p, pre, speed, torque, eff, max_trq, min_trq):
    """Keep the ``w >= 0`` half of a map given over negative speeds too, after checking the other half is its
    point reflection (same power flow: ``eta(-w, T) == eta(w, -T)``, envelope even in speed)."""
    neg = speed < 0
    mirrored = -speed[neg][::-1]
    keep = speed >= 0
    if not np.array_equal(np.isin(mirrored, speed[keep]), np.ones(mirrored.size, bool)):
        raise MachineFileError(f"{p}: '{pre}_map_spd' has negative speeds without their positive mirror")
    if not np.allclose(torque, -torque[::-1]):
        raise MachineFileError(f"{p}: '{pre}_map_trq' must be symmetric about 0 when speeds are negative")
    idx = np.searchsorted(speed, mirrored)
    if not np.allclose(eff[neg][::-1][:, ::-1], eff[idx]) or not np.allclose(
        max_trq[neg][::-1], max_trq[idx]
    ):
        raise MachineFileError(
            f"{p}: '{pre}_eff_map' at negative speeds is not the mirror of the positive half; only symmetric "
            "maps are supported"
        )
    return speed[keep], eff[keep], max_trq[keep], min_trq[keep]
