"""A dataset expressed in other units of length and time (e.g. a unit box and a unit frame
interval instead of SI).

Every quantity scales with its dimension: positions, box and radii by ``1 / length``; times
and the LE time origin by ``1 / time``; the shear rate by ``time``; velocities by
``time / length``; the body-force amplitude by ``time^2 / length``. The LE offsets then scale
by ``1 / length`` too (``δ = shear_rate · lx · (t - t0)``), so the rescaled data is the same
flow: every relative measure (RMSE / d, steps / d, crossings) is unchanged, which is what the
units stress test checks end to end.
"""

from __future__ import annotations

import dataclasses

from gripdem.boundary import Boundary, Box, LeesEdwards
from gripdem.data.schema import TrajectoryData


def rescale(data: TrajectoryData, length: float, time: float) -> TrajectoryData:
    """``data`` with lengths in units of ``length`` and times in units of ``time`` (both in
    the data's current units; e.g. ``length = box.lx``, ``time = frame_interval``)."""
    if not (length > 0 and time > 0):
        raise ValueError(f"length and time units must be positive, got {length!r}, {time!r}")
    box = Box.from_lengths(data.box.lengths / length)
    le = data.boundary.lees_edwards
    if le is not None:
        le = LeesEdwards(le.shear_rate * time, le.sign, le.time_origin / time)
    provenance = dict(data.provenance)
    provenance["rescaled"] = {
        "length_unit": length,
        "time_unit": time,
        "from": provenance.get("rescaled"),
    }
    return dataclasses.replace(
        data,
        positions=data.positions / length,
        times=data.times / time,
        boundary=Boundary(box, le),
        radius=data.radius / length,
        body_force_amplitude=data.body_force_amplitude * time**2 / length,
        provenance=provenance,
        velocities=None if data.velocities is None else data.velocities * time / length,
        radii=None if data.radii is None else data.radii / length,
    )
