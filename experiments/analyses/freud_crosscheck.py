"""gripdem's g(r), coordination and MSD beside freud-analysis, on the default datasets.

    python experiments/analyses/freud_crosscheck.py [--preset default] [--frames 20]
        [--out experiments/figures]

Needs ``pip install -e ".[analysis]"`` (freud-analysis). For each scene (``pbc``, ``lebc``; the
cached built-in datasets, :func:`gripdem.dem.output.ensure_scene_dataset`) it computes on
simulation 0, every 10th of the first ``10 * frames`` frames:

- g(r) on identical bins (0-3 d, 0.02 d): :func:`gripdem.evaluation.physics.radial_distribution`
  against ``freud.density.RDF`` (``normalization_mode="finite_size"``, the density (N - 1) / V
  gripdem uses; freud's default ``exact`` uses N / V, a factor N / (N - 1) apart);
- coordination, per particle, within 1.01 d (contacts) and 1.5 d:
  :func:`gripdem.evaluation.physics.coordination_numbers` against freud's ``AABBQuery``;
- MSD of the lattice-continuous trajectory from frame 0: ``mean_squared_displacement`` against
  ``freud.msd.MSD(mode="direct")`` fed a trajectory unwrapped here independently (integer
  lattice images of the LE lattice with the unwrapped offset, chosen by continuity); and the
  non-affine MSD of :func:`gripdem.evaluation.rollout_stats.block_statistics` at lags 1, 10,
  100 against ``MSD(mode="window")``;

and draws ``OUT/freud_crosscheck_{scene}.png`` (g(r) of both, and their difference).

freud's box is triclinic in its own convention (``a1 = (Lx, 0, 0)``, ``a2 = (xy Ly, Ly, 0)``,
``a3 = (xz Lz, yz Lz, Lz)``, tilts dimensionless, centred at the origin). gripdem's LE lattice
``(lx, 0, delta), (0, ly, 0), (0, 0, lz)`` shifts z when x crosses, a tilt of a higher axis
(gradient x) along a lower one (flow z) in freud's order only if the axes are reversed: freud
``(x, y, z)`` = ours ``(z, y, x)``, box ``Lx = lz, Ly = ly, Lz = lx, xz = delta / lx`` (our
``(lx, 0, delta)`` is freud's ``a3 = (delta, 0, lx)``). Reversing the axes is a mirror: distances
and neighbours are unchanged. freud computes in float32, so the comparisons run in diameters.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from gripdem.boundary import Boundary, Box  # noqa: E402
from gripdem.data.dataset_io import read_dataset  # noqa: E402
from gripdem.evaluation import rollout_stats  # noqa: E402
from gripdem.evaluation.physics import (  # noqa: E402
    coordination_numbers,
    mean_squared_displacement,
    pair_distances,
    radial_distribution,
)

R_MAX_D, BIN_D = 3.0, 0.02
#: freud's float32 distances (in diameters, positions up to ~6 d) are good to ~1e-6 d: a pair
#: closer than this to a bin edge may land in the neighbouring bin
EDGE_D = 2e-6
CUTOFFS_D = (1.01, 1.5)


def freud_box(box: Box, offset: float = 0.0, unit: float = 1.0):
    """The freud box of gripdem's LE lattice at ``offset`` (see the module doc), lengths in
    ``unit``."""
    import freud

    lx, ly, lz = (float(v) / unit for v in box.lengths)
    return freud.box.Box(Lx=lz, Ly=ly, Lz=lx, xz=float(offset) / float(box.lx))


def freud_points(positions: np.ndarray, fbox, unit: float = 1.0) -> np.ndarray:
    """Our positions ``(n, 3)`` in freud's axes (reversed) and ``unit``, inside its box."""
    return fbox.wrap(np.ascontiguousarray(positions[:, ::-1] / unit, dtype=np.float64))


def freud_coordination(positions, box: Box, offset: float, cutoff: float, unit: float):
    """Neighbours closer than ``cutoff`` of each particle, by freud's AABB query."""
    import freud

    fbox = freud_box(box, offset, unit)
    points = freud_points(positions, fbox, unit)
    query = freud.locality.AABBQuery(fbox, points)
    nlist = query.query(points, {"r_max": cutoff / unit, "exclude_ii": True}).toNeighborList()
    return np.asarray(nlist.neighbor_counts)


def freud_rdf(frames, offsets, box: Box, r_max: float, bins: int, unit: float):
    """``(bin centres, g, pair counts per bin)`` accumulated over ``frames`` by freud
    (lengths back in the positions' units; pairs counted once)."""
    import freud

    rdf = freud.density.RDF(bins=bins, r_max=r_max / unit, normalization_mode="finite_size")
    for positions, offset in zip(frames, offsets, strict=True):
        fbox = freud_box(box, offset, unit)
        rdf.compute(system=(fbox, freud_points(positions, fbox, unit)), reset=False)
    return rdf.bin_centers * unit, np.asarray(rdf.rdf), np.asarray(rdf.bin_counts) // 2


def lattice_continuous(positions: np.ndarray, times: np.ndarray, boundary: Boundary):
    """``(frames, n, 3)`` continuous trajectory, unwrapped here without gripdem's unwrap: each
    frame's wrapped position plus the whole vectors ``n_x (lx, 0, D(t)) + n_y (0, ly, 0) +
    n_z (0, 0, lz)`` of its LE lattice with the UNWRAPPED offset ``D(t) = sign k lx (t - t0)``
    (the image cells move with the flow) that bring it closest to the previous frame's."""
    box = boundary.box
    le = boundary.lees_edwards
    drift = 0.0 if le is None else le.sign * le.shear_rate * box.lx
    out = [positions[0].copy()]
    for t in range(1, len(positions)):
        p, previous = positions[t], out[-1]
        n_x = np.round((previous[:, 0] - p[:, 0]) / box.lx)
        z = p[:, 2] + n_x * drift * (times[t] - (0.0 if le is None else le.time_origin))
        n_y = np.round((previous[:, 1] - p[:, 1]) / box.ly)
        n_z = np.round((previous[:, 2] - z) / box.lz)
        out.append(np.stack([p[:, 0] + n_x * box.lx, p[:, 1] + n_y * box.ly, z + n_z * box.lz], -1))
    return np.stack(out)


def freud_msd(trajectory: np.ndarray, mode: str) -> np.ndarray:
    """freud's MSD of ``(frames, n, 3)`` (each particle's mean position removed first: freud
    holds positions in float32, whose error grows with their size)."""
    import freud

    msd = freud.msd.MSD(mode=mode)
    msd.compute(np.ascontiguousarray(trajectory - trajectory.mean(axis=0)))
    return np.asarray(msd.msd)


def non_affine_trajectory(positions, times, boundary: Boundary) -> np.ndarray:
    """Cumulative steps minus the fitted mean flow, as ``rollout_stats`` defines them."""
    offsets = boundary.offset(times)
    steps, x_mid = rollout_stats.frame_steps(positions, offsets, boundary)
    fit = rollout_stats.fit_profile(steps, x_mid, boundary)
    steps = steps.copy()
    steps[..., 2] -= rollout_stats.profile_basis(x_mid, boundary) @ fit
    return np.concatenate([np.zeros_like(steps[:1]), np.cumsum(steps, axis=0)])


def bin_edge_pairs(pos, offsets, box: Box, d: float, freud_counts: np.ndarray) -> dict:
    """Pair counts per bin, gripdem's against freud's, and how many of gripdem's pair
    distances lie within :data:`EDGE_D` of a bin edge (where float32 may change the bin)."""
    distances = pair_distances(pos, box, R_MAX_D * d, offsets) / d
    edges = np.linspace(0.0, R_MAX_D, len(freud_counts) + 1)
    ours = np.histogram(distances, bins=edges)[0]
    width = edges[1] - edges[0]
    near = np.abs(distances / width - np.round(distances / width)) * width < EDGE_D
    return {
        "pairs": int(ours.sum()),
        "count_diff": ours - freud_counts,
        "pairs_near_edges": int(near.sum()),
        "pairs_at_contact": int((np.abs(distances - 1.0) < EDGE_D).sum()),
    }


def cross_check(path: Path, frames: int, every: int = 10) -> dict:
    """Everything compared on simulation 0 of ``path`` (see the module doc)."""
    data = read_dataset(path)
    box, d = data.box, data.diameter
    span = slice(0, min(data.n_frames, every * frames), every)
    pos = data.positions[0, span]
    offsets = data.offsets()[0, span]
    bins = round(R_MAX_D / BIN_D)
    r, g = radial_distribution(pos, box, R_MAX_D * d, bins, offsets)
    fr, fg, freud_counts = freud_rdf(pos, offsets, box, R_MAX_D * d, bins, d)
    out = {"scene": data.boundary.kind, "r_over_d": r / d, "g": g, "g_freud": fg}
    out["bin_centres_diff"] = float(np.abs(fr - r).max() / d)
    out.update(bin_edge_pairs(pos, offsets, box, d, freud_counts))
    for c in CUTOFFS_D:
        mismatched = 0
        for p, o in zip(pos, offsets, strict=True):
            ours = coordination_numbers(p, box, c * d, float(o))
            mismatched += int((ours != freud_coordination(p, box, float(o), c * d, d)).sum())
        out[f"coordination_mismatches_{c}"] = mismatched
    full, full_t = data.positions[0], data.times[0]
    lagged = full[: min(len(full), 201)]
    cont = lattice_continuous(lagged, full_t[: len(lagged)], data.boundary) / d
    increment = data.boundary.image_velocity * data.frame_interval
    theirs = freud_msd(cont, "direct")[1:]
    all_offsets = data.boundary.offset(full_t[: len(lagged)])
    ours = (
        mean_squared_displacement(
            lagged[None, 1:], lagged[None, 0], box, all_offsets[None, 1:], increment
        )
        / d**2
    )
    out["msd_direct_rel_diff"] = float(np.max(np.abs(ours - theirs) / np.maximum(theirs, 1e-30)))
    stats = rollout_stats.block_statistics(
        lagged, lagged, full_t[: len(lagged)], data.boundary, d, block=len(lagged) - 1,
        gr_every=50,
    )["blocks"][0]  # fmt: skip
    window = freud_msd(non_affine_trajectory(lagged, full_t[: len(lagged)], data.boundary) / d,
                       "window")  # fmt: skip
    out["msd_window"] = {
        lag: (stats[f"truth/msd_{lag}_over_d2"], float(window[lag]))
        for lag in rollout_stats.LAGS
        if lag < len(lagged)
    }
    return out


def figure(result: dict, path: Path) -> None:
    r, g, fg = result["r_over_d"], result["g"], result["g_freud"]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(6.4, 5.6), sharex=True,
                                      gridspec_kw={"height_ratios": [3, 2]})  # fmt: skip
    top.plot(r, g, "-", lw=1.6, label="gripdem (physics.radial_distribution)")
    top.plot(r, fg, "o", ms=3, mfc="none", label="freud.density.RDF (finite_size)")
    top.set_ylabel("g(r)")
    top.set_title(f"g(r), {result['scene']} default scene: gripdem vs freud")
    top.legend(loc="upper right")
    bottom.plot(r, g - fg, "k-", lw=1)
    bottom.axhline(0.0, color="0.6", lw=0.8)
    bottom.set_ylabel("gripdem - freud")
    bottom.set_xlabel("r / d")
    c = result
    moved = int(np.abs(c["count_diff"]).sum() // 2)
    bottom.set_title(
        f"{c['pairs']} pairs: {moved} in another bin, of the {c['pairs_near_edges']} within "
        f"{EDGE_D:g} d of a bin edge (freud: float32;\n{c['pairs_at_contact']} pairs at "
        f"contact sit on the edge r = d); coordination mismatches "
        f"{c['coordination_mismatches_1.01']} (1.01 d), {c['coordination_mismatches_1.5']} (1.5 d)",
        fontsize=8,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="default")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--out", type=Path, default=Path(__file__).parents[1] / "figures")
    args = parser.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from benchlib import scene_dataset

    for scene in ("pbc", "lebc"):
        result = cross_check(scene_dataset(scene, args.preset), args.frames)
        path = args.out / f"freud_crosscheck_{scene}.png"
        figure(result, path)
        g, fg = result["g"], result["g_freud"]
        print(f"{scene}: g(r) max |gripdem - freud| {np.abs(g - fg).max():.2e} over "
              f"{len(g)} bins (peak {g.max():.3f}); {result['pairs']} pairs, "
              f"{int(np.abs(result['count_diff']).sum() // 2)} in another bin, "
              f"{result['pairs_near_edges']} within {EDGE_D:g} d of an edge; "
              "coordination mismatches "
              f"{result['coordination_mismatches_1.01']} (1.01 d), "
              f"{result['coordination_mismatches_1.5']} (1.5 d); MSD direct max rel diff "
              f"{result['msd_direct_rel_diff']:.1e}; window MSD / d^2 (gripdem, freud) "
              + ", ".join(f"lag {k}: {a:.6g} / {b:.6g} ({a / b - 1:+.1e})" for k, (a, b) in
                          result["msd_window"].items())
              + f"; wrote {path}")  # fmt: skip


if __name__ == "__main__":
    main()
