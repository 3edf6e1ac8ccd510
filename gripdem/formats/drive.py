"""The periodic scene's drive for imported data: ``--body-force A`` of ``python -m
gripdem.convert``, a body acceleration ``a_z(x) = A cos(2 pi x / lx)`` along the flow axis z
(docs/spec/conventions.md#scenes), recorded in the dataset's ``body_force_amplitude`` attribute.

Foreign files do not say how their simulation was driven, and a model trained with a drive is
applied (``gripdem.predict``) only to data recorded with the same drive, so the importers take
it from the user and check it:

- finite and ``>= 0`` (``A < 0`` is the same drive shifted by ``lx / 2``: shift the data);
- periodic data only: gripdem's Lees-Edwards scene is driven by the sliding images and has no
  body force, so a Lees-Edwards dataset with ``A != 0`` is refused;
- evidence, printed: the mean z velocity of periodic data fitted as ``C cos(2 pi x / lx) + B``
  over all frame-to-frame steps. A drive ``A > 0`` pushes along +z where ``cos > 0``, so
  ``C`` should be positive; a note says so when it is not (a flipped z axis, or no drive).
"""

from __future__ import annotations

import math

import numpy as np

from gripdem.boundary import Boundary, displacement, wrap_coordinate

#: the option's name in messages
OPTION = "--body-force"


def check_amplitude(value: float | None) -> float:
    """``--body-force`` as a float (0 when not given); refuses NaN/Inf and negatives."""
    if value is None:
        return 0.0
    try:
        amplitude = float(value)
    except (TypeError, ValueError):
        amplitude = math.nan
    if not (math.isfinite(amplitude) and amplitude >= 0):
        raise ValueError(
            f"{OPTION} must be a finite acceleration >= 0 (A of a_z = A cos(2 pi x / lx); m/s^2 "
            f"for SI data), got {value!r}"
        )
    return amplitude


def check_periodic(amplitude: float, sheared: bool, where: str) -> None:
    """Refuse a body force on Lees-Edwards (``sheared``) data: that scene has none."""
    if amplitude != 0 and sheared:
        raise ValueError(
            f"{where}{OPTION} {amplitude:g}: the data is Lees-Edwards (a sheared box), and "
            "gripdem's Lees-Edwards scene has no body force (the sliding images drive it); a "
            f"body force is for periodic data only: omit {OPTION} (or give 0)"
        )


def flow_profile_fit(
    positions: np.ndarray, times: np.ndarray, boundary: Boundary
) -> tuple[float, float]:
    """``(C, B)`` of the mean z velocity ``C cos(2 pi x / lx) + B`` of periodic data
    ``(sims, frames, particles, 3)``, from every frame-to-frame step at its mid-point x."""
    box = boundary.box
    earlier, later = positions[:, :-1], positions[:, 1:]
    steps = displacement(later, earlier, box, None)
    dt = np.diff(times, axis=1)[:, :, None]
    vz = (steps[..., 2] / dt).reshape(-1)
    x_mid = wrap_coordinate(earlier[..., 0] + 0.5 * steps[..., 0], box.lx).reshape(-1)
    basis = np.stack([np.cos(2 * np.pi * x_mid / box.lx), np.ones_like(x_mid)], axis=-1)
    (c, b), *_ = np.linalg.lstsq(basis, vz, rcond=None)
    return float(c), float(b)


def drive_lines(
    amplitude: float, boundary: Boundary, positions: np.ndarray, times: np.ndarray
) -> tuple[list[str], list[str]]:
    """Summary lines and notes on the drive of the imported data."""
    if boundary.is_lees_edwards:
        return ["body force: none (Lees-Edwards data: the shear drives the flow)"], []
    c, b = flow_profile_fit(positions, times, boundary)
    profile = (
        f"flow profile: mean z velocity = {c:.4g} cos(2 pi x / lx) {b:+.3g} (fitted over all "
        "frame-to-frame steps)"
    )
    if amplitude == 0:
        return [
            f"body force: none (give {OPTION} A if the simulation was driven by "
            "A cos(2 pi x / lx) along z)",
            profile,
        ], []
    lines = [
        f"body force: A = {amplitude:.6g} (a_z = A cos(2 pi x / lx), recorded as "
        "body_force_amplitude)",
        profile,
    ]
    notes = []
    if c <= 0:
        notes.append(
            f"{OPTION} {amplitude:g} drives +z where cos(2 pi x / lx) > 0, but the data's mean "
            f"flow there is {c:.3g} (not positive): is the data's z axis flipped, or was it "
            "not driven?"
        )
    return lines, notes
