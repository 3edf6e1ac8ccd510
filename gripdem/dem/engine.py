"""One DEM simulation: particle state, neighbour-list rebuilds, and a kernel backend.

Between rebuilds positions are not wrapped (a particle may stand up to half a skin outside
the box) so that the stored integer image shifts stay valid; at a rebuild every particle is
wrapped with the LE remap and z-velocity jump (:func:`gripdem.boundary.wrap_positions`),
a new list is built with the current offset and the tangential history is carried over by
particle pair. Snapshots are wrapped copies at the current time.

Backends: ``numba`` (compiled CPU loop, the fast default) and ``torch`` (vectorised, runs on
``device="cuda"`` when one is present). They share everything but the inner step loop.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

import numpy as np

from gripdem.boundary import wrap_positions
from gripdem.dem import forces_numba
from gripdem.dem.config import GeneratorConfig
from gripdem.dem.neighbours import PairList, build_pairs, transfer_history
from gripdem.dem.params import SOLID_SPHERE_INERTIA

if TYPE_CHECKING:
    import torch


class Simulation:
    """State of one simulation, advanced by :meth:`run`; time = ``step * dt`` from 0.

    positions, velocities: ``(n, 3)`` float64 (wrapped or not); omega defaults to zero.
    ``radius`` may be a scalar or ``(n,)`` (the physics supports per-particle radii).

    Internally particles are stored in x-major cell order (sorted once here), so that
    neighbours sit close in memory (the flow is along z: x-y slabs stay together); every
    public method takes and returns the caller's order. ``pairs`` and the backend arrays are
    in the internal order.

    ``step`` starts the step count elsewhere than 0: a restart from a written frame at
    absolute time t passes ``round(t / dt)`` so that the LE offset is that frame's (its
    positions were wrapped with it).
    """

    def __init__(
        self,
        config: GeneratorConfig,
        positions: np.ndarray,
        velocities: np.ndarray,
        omega: np.ndarray | None = None,
        radius: float | np.ndarray | None = None,
        backend: str | None = None,
        device: str = "cpu",
        step: int = 0,
    ):
        self.config = config
        self.boundary = config.boundary
        self.box = config.box
        self.law = config.force_law()
        self.dt = config.dt
        self.skin = config.skin
        n = positions.shape[0]
        self.order = _memory_order(np.asarray(positions, dtype=np.float64), config)
        rad = config.radius if radius is None else radius
        rad = np.broadcast_to(np.asarray(rad, dtype=np.float64), (n,))
        self.radius = rad[self.order].copy()
        self.mass = config.scene.density * 4.0 / 3.0 * np.pi * self.radius**3
        self.inertia = SOLID_SPHERE_INERTIA * self.mass * self.radius**2
        self.cutoff = 2.0 * self.radius.max() + config.interaction_gap + self.skin
        self.step = int(step)
        self.max_overlap = 0.0  # largest overlap / (r_i + r_j) seen in any step
        self.rebuilds = 0
        pos = np.array(positions, dtype=np.float64)[self.order]
        vel = np.array(velocities, dtype=np.float64)[self.order]
        om = np.zeros_like(pos) if omega is None else np.array(omega, dtype=np.float64)[self.order]
        name = backend or config.backend
        if name == "numba":
            self._backend: _Backend = _NumbaBackend(self, pos, vel, om)
        elif name == "torch":
            self._backend = _TorchBackend(self, pos, vel, om, device)
        else:
            raise ValueError(f"backend must be 'numba' or 'torch', got {name!r}")
        self.pairs = PairList(
            np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3), np.int64), 0.0, self.step
        )
        self._rebuild(np.zeros((0, 3)))
        self._backend.initial_forces()

    # ------------------------------------------------------------------ time and offsets
    @property
    def time(self) -> float:
        return self.step * self.dt

    @property
    def n(self) -> int:
        return self.radius.shape[0]

    def offset(self) -> float:
        """LE offset delta at the current time (float64, wrapped; 0 when periodic)."""
        return float(self.boundary.offset(np.float64(self.time)))

    # ------------------------------------------------------------------ stepping
    def run(self, n_steps: int) -> None:
        """Advance exactly ``n_steps`` steps, rebuilding the neighbour list when needed."""
        left = int(n_steps)
        while left > 0:
            done, rebuild = self._backend.advance(left)
            self.step += done
            left -= done
            if rebuild:
                self._rebuild(self._backend.history())

    def snapshot(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Wrapped ``(positions, velocities, omega)`` copies at the current time."""
        pos, vel, om = self._backend.kinematics()
        pos, vel = wrap_positions(pos, self.box, self.offset(), vel, self.boundary.image_velocity)
        return self._external(pos), self._external(vel), self._external(om)

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The kernel's own ``(positions, velocities, omega)``: not wrapped since the last
        neighbour-list rebuild (wrapped, with the LE remap, at every rebuild)."""
        return tuple(self._external(a) for a in self._backend.kinematics())

    def _external(self, internal: np.ndarray) -> np.ndarray:
        out = np.empty_like(internal)
        out[self.order] = internal
        return out

    def _rebuild(self, history: np.ndarray) -> None:
        delta = self.offset()
        pos, vel, _ = self._backend.kinematics()
        pos, vel = wrap_positions(pos, self.box, delta, vel, self.boundary.image_velocity)
        new = build_pairs(pos, self.box, delta, self.cutoff, self.step)
        carried = transfer_history(self.pairs, history, new, self.n)
        self.pairs = new
        self.rebuilds += 1
        self._backend.load(pos, vel, new, carried)


def _memory_order(positions: np.ndarray, config: GeneratorConfig) -> np.ndarray:
    """Permutation sorting particles by (x cell, y cell, z) with cells of about one list
    cut-off: pairs then touch nearby memory (15% faster steps at 32000 particles, no
    difference up to 8000, whose working set still fits in the caches)."""
    box = config.box
    cells = np.maximum(1, np.floor(box.lengths / config.list_cutoff)).astype(np.int64)
    wrapped = wrap_positions(positions, box)
    idx = np.floor((wrapped / box.lengths + 0.5) * cells).astype(np.int64)
    idx = np.minimum(np.maximum(idx, 0), cells - 1)
    return np.lexsort((wrapped[:, 2], idx[:, 1], idx[:, 0]))


class _Backend:
    """Holds the state arrays of one kernel family."""

    def load(self, pos, vel, pairs: PairList, history) -> None: ...
    def kinematics(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...
    def history(self) -> np.ndarray: ...
    def initial_forces(self) -> None: ...
    def advance(self, n_steps: int) -> tuple[int, bool]: ...


class _NumbaBackend(_Backend):
    def __init__(self, sim: Simulation, pos, vel, omega):
        self.sim = sim
        self.pos, self.vel, self.omega = pos, vel, omega
        self.force = np.zeros_like(pos)
        self.torque = np.zeros_like(pos)
        self.stats = np.zeros(1)

    def load(self, pos, vel, pairs, history):
        self.pos[:] = pos
        self.vel[:] = vel
        self.ref_pos = pos.copy()
        self.pairs = pairs
        self.hist = np.ascontiguousarray(history)
        self.delta_build = pairs.delta

    def kinematics(self):
        return self.pos, self.vel, self.omega

    def history(self):
        return self.hist

    def initial_forces(self):
        s, p = self.sim, self.pairs
        overlap = forces_numba.compute_forces(
            self.pos,
            self.vel,
            self.omega,
            s.radius,
            s.mass,
            p.i,
            p.j,
            p.shift,
            self.hist,
            s.law,
            self.delta_build,
            0.0,
            self.force,
            self.torque,
        )
        s.max_overlap = max(s.max_overlap, overlap)

    def advance(self, n_steps):
        s, p = self.sim, self.pairs
        self.stats[0] = s.max_overlap
        done, due = forces_numba.advance(
            self.pos,
            self.vel,
            self.omega,
            self.force,
            self.torque,
            s.radius,
            s.mass,
            s.inertia,
            p.i,
            p.j,
            p.shift,
            self.hist,
            s.law,
            self.ref_pos,
            s.dt,
            n_steps,
            self.delta_build,
            s.step - p.step,
            s.skin,
            self.stats,
        )
        s.max_overlap = float(self.stats[0])
        return done, due


@contextmanager
def _one_cpu_thread(device: torch.device) -> Iterator[None]:
    """Step tensors hold ~10^4 numbers: intra-op threads only add barriers, which cost a
    scheduler quantum (~15 ms per op, measured) when the CPUs are shared with other jobs."""
    if device.type != "cpu":
        yield
        return
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


class _TorchBackend(_Backend):
    """torch and its force law are imported by this backend only: the default (numba) runs,
    its worker processes among them, do not pay torch's import (about 1.2 s)."""

    def __init__(self, sim: Simulation, pos, vel, omega, device):
        import torch

        from gripdem.dem import forces_torch

        self.forces = forces_torch
        self.sim = sim
        self.device = torch.device(device)
        t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64, device=self.device)  # noqa: E731
        self.state = {
            "pos": t(pos),
            "vel": t(vel),
            "omega": t(omega),
            "force": t(np.zeros_like(pos)),
            "torque": t(np.zeros_like(pos)),
            "radius": t(sim.radius),
            "mass": t(sim.mass),
            "inertia": t(sim.inertia),
        }
        self._t = t
        self._index = lambda a: torch.as_tensor(a, device=self.device)  # int64 pair indices

    def load(self, pos, vel, pairs, history):
        s, t = self.state, self._t
        s["pos"], s["vel"] = t(pos), t(vel)
        s["ref_pos"] = s["pos"].clone()
        s["pair_i"] = self._index(pairs.i)
        s["pair_j"] = self._index(pairs.j)
        s["shift"] = t(pairs.shift)
        s["history"] = t(history)
        self.pairs = pairs
        self.delta_build = pairs.delta

    def kinematics(self):
        s = self.state
        return tuple(s[k].detach().cpu().numpy().copy() for k in ("pos", "vel", "omega"))

    def history(self):
        return self.state["history"].cpu().numpy()

    def initial_forces(self):
        s, sim = self.state, self.sim
        with _one_cpu_thread(self.device):
            s["force"], s["torque"], s["history"], overlap = self.forces.compute_forces(
                s["pos"],
                s["vel"],
                s["omega"],
                s["radius"],
                s["mass"],
                s["pair_i"],
                s["pair_j"],
                s["shift"],
                s["history"],
                sim.law,
                self.delta_build,
                0.0,
            )
        sim.max_overlap = max(sim.max_overlap, float(overlap))

    def advance(self, n_steps):
        sim = self.sim
        with _one_cpu_thread(self.device):
            done, due, overlap = self.forces.advance(
                self.state,
                sim.law,
                sim.dt,
                n_steps,
                self.delta_build,
                sim.step - self.pairs.step,
                sim.skin,
            )
        sim.max_overlap = max(sim.max_overlap, overlap)
        return done, due
