"""Initial packings without overlaps at the target volume fraction
(docs/spec/dem.md#numerical-traps).

Random sequential insertion jams near phi ~ 0.38, so particles are inserted at a lower
volume fraction (``pack_volume_fraction``, default 0.3) with shrunken radii, then the radii
grow in stages back to full size while overlaps are relaxed geometrically (each overlapping
pair is pushed apart along its normal, Jacobi-style, until the largest overlap is below a
tolerance). At phi = 0.5, well below random close packing, this converges in a few hundred
sweeps. The LE offset is zero at t = 0, so packing uses the plain periodic box.
"""

from __future__ import annotations

import numba
import numpy as np

from gripdem.boundary import Box, wrap_positions
from gripdem.dem.neighbours import build_pairs


@numba.njit(cache=True)
def _insert(n, lengths, diameter, seed_points, max_trials):
    """Random sequential insertion of ``n`` spheres of ``diameter`` (O(n^2) checks; fine for
    the tens of thousands of particles a generator run holds)."""
    pos = np.empty((n, 3))
    placed = 0
    trial = 0
    d2 = diameter * diameter
    while placed < n:
        if trial >= seed_points.shape[0]:
            return pos, placed
        cand = (seed_points[trial] - 0.5) * lengths
        trial += 1
        ok = True
        for q in range(placed):
            s2 = 0.0
            for k in range(3):
                r = cand[k] - pos[q, k]
                r -= lengths[k] * np.floor(r / lengths[k] + 0.5)
                s2 += r * r
            if s2 < d2:
                ok = False
                break
        if ok:
            pos[placed] = cand
            placed += 1
        if trial > max_trials:
            return pos, placed
    return pos, placed


@numba.njit(cache=True)
def _relax_sweep(pos, pair_i, pair_j, shift, lx, ly, lz, diameter, step_fraction, disp):
    """One Jacobi sweep pushing overlapping pairs apart; returns the largest overlap / d."""
    disp[:] = 0.0
    worst = 0.0
    for q in range(pair_i.shape[0]):
        i = pair_i[q]
        j = pair_j[q]
        rx = pos[i, 0] - pos[j, 0] - shift[q, 0] * lx
        ry = pos[i, 1] - pos[j, 1] - shift[q, 1] * ly
        rz = pos[i, 2] - pos[j, 2] - shift[q, 2] * lz
        dist = np.sqrt(rx * rx + ry * ry + rz * rz)
        overlap = diameter - dist
        if overlap > 0.0:
            worst = max(worst, overlap / diameter)
            push = 0.5 * step_fraction * overlap / max(dist, 1e-30)
            disp[i, 0] += push * rx
            disp[i, 1] += push * ry
            disp[i, 2] += push * rz
            disp[j, 0] -= push * rx
            disp[j, 1] -= push * ry
            disp[j, 2] -= push * rz
    pos += disp
    return worst


def _relax(pos, box: Box, diameter, skin, tolerance, max_sweeps) -> tuple[np.ndarray, float]:
    """Relax overlaps of spheres of ``diameter`` until the largest is below ``tolerance`` d."""
    pos = wrap_positions(pos, box)
    pairs = build_pairs(pos, box, 0.0, diameter + skin)
    ref = pos.copy()
    disp = np.zeros_like(pos)
    worst = np.inf
    for _ in range(max_sweeps):
        worst = _relax_sweep(
            pos, pairs.i, pairs.j, pairs.shift, box.lx, box.ly, box.lz, diameter, 0.5, disp
        )
        if worst < tolerance:
            break
        if 2.0 * np.sqrt(((pos - ref) ** 2).sum(1).max()) > skin:
            pos = wrap_positions(pos, box)
            pairs = build_pairs(pos, box, 0.0, diameter + skin)
            ref = pos.copy()
    return wrap_positions(pos, box), float(worst)


def random_packing(
    n: int,
    box: Box,
    diameter: float,
    rng: np.random.Generator,
    insert_fraction: float = 0.3,
    growth_stages: int = 40,
    tolerance: float = 1e-4,
) -> np.ndarray:
    """``(n, 3)`` wrapped centres of ``n`` spheres of ``diameter`` with every overlap below
    ``tolerance * diameter``. Raises if the target cannot be reached."""
    phi = box.volume_fraction(n, diameter)
    start = min(insert_fraction, phi)
    d0 = diameter * (start / phi) ** (1.0 / 3.0)
    lengths = box.lengths
    seeds = rng.random((200 * n + 1000, 3))
    pos, placed = _insert(n, lengths, d0, seeds, seeds.shape[0])
    if placed < n:
        raise RuntimeError(
            f"random insertion placed only {placed} of {n} particles at volume fraction "
            f"{start:.3f}; lower preset.pack_volume_fraction"
        )
    skin = 0.3 * diameter
    for d in np.linspace(d0, diameter, growth_stages + 1)[1:]:
        pos, worst = _relax(pos, box, d, skin, 5e-3, 2000)
    pos, worst = _relax(pos, box, diameter, skin, tolerance, 20000)
    if worst >= tolerance:
        raise RuntimeError(
            f"could not relax overlaps below {tolerance:g} d at volume fraction {phi:.3f} "
            f"(largest {worst:.3g} d); is the volume fraction too close to jamming?"
        )
    return pos
