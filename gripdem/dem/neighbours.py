"""O(n) neighbour lists for periodic and Lees-Edwards boxes, with integer image shifts.

A pair ``(i, j, shift)`` with ``shift = (n_x, n_y, n_z)`` means the separation
``r_ij = x_i - x_j - n_x (lx, 0, delta) - n_y (0, ly, 0) - n_z (0, 0, lz)``
(:func:`gripdem.boundary.apply_lattice_shift`). Lists keep the integer shifts so that the
kernels recompute separations with the *current* LE offset between rebuilds
(docs/spec/dem.md#numerical-traps).

Building: a numba cell list proposes candidate pairs (cells at least one cut-off wide; for
the cells across an x face the z range is taken around ``z_i -/+ delta``, so the sliding
images are searched where they are), then :func:`gripdem.boundary.lattice_shift` picks the
minimum image and the cut-off filters. Boxes narrower than three cut-offs fall back to all
pairs. The rebuild rule (docs/spec/dem.md#numerical-traps: ``|delta change| + 2 * largest
displacement > skin``) is checked inside the kernels' step loops.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from gripdem.boundary import Box, apply_lattice_shift, lattice_shift


@dataclass
class PairList:
    """Half neighbour list (each pair once, ``i < j``), grouped by ``i``.

    i, j: ``(pairs,)`` int64; shift: ``(pairs, 3)`` int64 lattice counts; built with offset
    ``delta`` at step ``step``.
    """

    i: np.ndarray
    j: np.ndarray
    shift: np.ndarray
    delta: float
    step: int

    def __len__(self) -> int:
        return int(self.i.shape[0])


@numba.njit(cache=True)
def _cell_of(value: float, length: float, n_cells: int) -> int:
    c = int(np.floor((value / length + 0.5) * n_cells))
    if c < 0:
        c += n_cells * ((-c) // n_cells + 1)
    return c % n_cells


@numba.njit(cache=True)
def _scan_cells(pos, cell, start, members, lz, delta, cutoff, ncx, ncy, ncz, out_i, out_j, fill):
    """Visit the candidate pairs (i < j) of a cell list; store them when ``fill``. Returns
    their number."""
    cz_width = lz / ncz
    total = 0
    for i in range(pos.shape[0]):
        c = cell[i]
        cx = c // (ncy * ncz)
        cy = (c // ncz) % ncy
        for dx in range(-1, 2):
            jx = cx + dx
            n_x = 0
            if jx < 0:
                jx += ncx
                n_x = -1
            elif jx >= ncx:
                jx -= ncx
                n_x = 1
            # the image of j next to i sits at z_j + n_x * delta: search z_j near z_i - n_x delta
            zc = pos[i, 2] - n_x * delta
            lo = int(np.floor((zc - cutoff) / cz_width + 0.5 * ncz))
            hi = int(np.floor((zc + cutoff) / cz_width + 0.5 * ncz))
            if hi - lo + 1 > ncz:
                hi = lo + ncz - 1
            for dy in range(-1, 2):
                jy = (cy + dy + ncy) % ncy
                for kz in range(lo, hi + 1):
                    cj = (jx * ncy + jy) * ncz + kz % ncz
                    for q in range(start[cj], start[cj + 1]):
                        j = members[q]
                        if j > i:
                            if fill:
                                out_i[total] = i
                                out_j[total] = j
                            total += 1
    return total


@numba.njit(cache=True)
def _cell_candidates(pos, lx, ly, lz, delta, cutoff, ncx, ncy, ncz):
    """Candidate pairs (i < j) from a cell list; ``pos`` wrapped into the box."""
    n = pos.shape[0]
    cell = np.empty(n, dtype=np.int64)
    counts = np.zeros(ncx * ncy * ncz + 1, dtype=np.int64)
    for p in range(n):
        cx = _cell_of(pos[p, 0], lx, ncx)
        cy = _cell_of(pos[p, 1], ly, ncy)
        cz = _cell_of(pos[p, 2], lz, ncz)
        cell[p] = (cx * ncy + cy) * ncz + cz
        counts[cell[p] + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    members = np.empty(n, dtype=np.int64)
    for p in range(n):
        members[fill[cell[p]]] = p
        fill[cell[p]] += 1
    none = np.empty(0, dtype=np.int64)
    total = _scan_cells(
        pos, cell, start, members, lz, delta, cutoff, ncx, ncy, ncz, none, none, False
    )
    out_i = np.empty(total, dtype=np.int64)
    out_j = np.empty(total, dtype=np.int64)
    _scan_cells(pos, cell, start, members, lz, delta, cutoff, ncx, ncy, ncz, out_i, out_j, True)
    return out_i, out_j


def _all_pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.triu_indices(n, k=1)
    return i.astype(np.int64), j.astype(np.int64)


def build_pairs(
    positions: np.ndarray, box: Box, delta: float, cutoff: float, step: int = 0
) -> PairList:
    """All pairs with minimum-image centre distance below ``cutoff``.

    positions: ``(n, 3)`` float64, already wrapped into the box with offset ``delta``.
    ``cutoff`` must be below half of every box length.
    """
    lengths = box.lengths
    if cutoff >= 0.5 * lengths.min():
        raise ValueError(
            f"neighbour cut-off {cutoff:g} m must be below half the smallest box length "
            f"{lengths.min():g} m: use more particles or a smaller skin"
        )
    n_cells = np.floor(lengths / cutoff).astype(np.int64)
    if n_cells.min() >= 3:
        ci, cj = _cell_candidates(
            positions, box.lx, box.ly, box.lz, float(delta), float(cutoff), *map(int, n_cells)
        )
    else:
        ci, cj = _all_pairs(positions.shape[0])
    r = positions[ci] - positions[cj]
    shift = lattice_shift(r, box, delta)
    r = apply_lattice_shift(r, shift, box, delta)
    keep = np.einsum("pk,pk->p", r, r) < cutoff * cutoff
    ci, cj, shift = ci[keep], cj[keep], shift[keep].astype(np.int64)
    order = np.lexsort((cj, ci))  # group by i (history transfer and tests rely on it)
    return PairList(ci[order], cj[order], np.ascontiguousarray(shift[order]), float(delta), step)


def brute_force_pairs(positions: np.ndarray, box: Box, delta: float, cutoff: float) -> set:
    """Reference ``{(i, j, nx, ny, nz)}`` from all pairs (tests)."""
    ci, cj = _all_pairs(positions.shape[0])
    r = positions[ci] - positions[cj]
    shift = lattice_shift(r, box, delta)
    r = apply_lattice_shift(r, shift, box, delta)
    keep = np.einsum("pk,pk->p", r, r) < cutoff * cutoff
    return {
        (int(a), int(b), *map(int, s))
        for a, b, s in zip(ci[keep], cj[keep], shift[keep].astype(np.int64), strict=True)
    }


def transfer_history(old: PairList, old_history: np.ndarray, new: PairList, n: int) -> np.ndarray:
    """Tangential spring history ``(pairs, 3)`` carried from ``old`` to ``new`` pairs by
    particle pair ``(i, j)``; new pairs start at zero. Image shifts may differ (a particle
    re-wrapped, delta wrapped): the contact is the same physical pair."""
    history = np.zeros((len(new), 3), dtype=np.float64)
    if len(old) == 0 or len(new) == 0:
        return history
    old_key = old.i * n + old.j
    order = np.argsort(old_key, kind="stable")
    sorted_key = old_key[order]
    new_key = new.i * n + new.j
    at = np.searchsorted(sorted_key, new_key)
    at_clipped = np.minimum(at, len(sorted_key) - 1)
    found = (at < len(sorted_key)) & (sorted_key[at_clipped] == new_key)
    history[found] = old_history[order[at_clipped[found]]]
    return history
